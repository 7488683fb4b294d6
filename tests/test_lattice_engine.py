"""Lattices given as neighbour tables (``warpchain.lattice.LatticeParams``: square and triangular monolayers, the
chain as a table) on the Warp engine: ``simulate``, ``propagate_tangent`` and the ``Flow`` run them in the
``"sites"`` layout, whose one kernel reads a site's neighbours from the table. Bit for bit with the numpy
reference on the CPU (the GPU runs of ``tests/test_gpu_engine.py`` use the same checks); a 1 x N strip and the
chain as a table give the chain's own kernels' bits, a square lattice without cross bonds independent chains'."""

import numpy as np
import pytest

from warpchain import (
    BOUNDARIES,
    ChainParams,
    Guard,
    Placement,
    Record,
    StepSizeError,
    energy,
    propagate_tangent,
    reference,
    simulate,
)
from warpchain.flow import Flow, ReferenceFlow
from warpchain.integrators import stability_limit
from warpchain.lattice import LatticeParams, chain, square, triangular
from warpchain.losses import Damping
from warpchain.observe import Observation

BUILDERS = {"square": square, "triangular": triangular}


def _state(n: int, batch: int, seed: int, amplitude: float = 0.3) -> np.ndarray:
    return amplitude * np.random.default_rng(seed).normal(size=(batch, 4, n))


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("geometry", sorted(BUILDERS))
@pytest.mark.parametrize("method", ["verlet", "kahan8"])
def test_2d_runs_bit_for_bit_with_the_reference(method, geometry, boundary):
    p = LatticeParams(30.0, 4.0, BUILDERS[geometry](5, 4, boundary))
    x0 = _state(p.N, 3, seed=7)
    M, K = np.array([30.0, 10.0, 50.0]), np.array([4.0, 1.0, 8.0])
    run = simulate(
        p, x0, 40 * 0.05, 0.05, method=method, device="cpu", M=M, K=K, record=Record(every=7), guard=Guard(chunks=2)
    )
    ref = reference.integrate(method, p, x0, 0.05, run.nsteps, M=M, K=K, save_every=7)
    assert run.layout == "sites"
    assert np.array_equal(run.x, ref["x"]) and np.array_equal(run.u, ref["u"]) and np.array_equal(run.v, ref["v"])
    # the guard's energy (the table's bonds, each held once) is the Hamiltonian
    assert np.allclose(run.energy_final, energy(p, run.x, M, K), rtol=1e-13, atol=0)
    assert np.allclose(run.energy_trace[0], energy(p, x0, M, K), rtol=1e-13, atol=0)


def test_2d_losses_bit_for_bit_with_the_reference():
    p = LatticeParams(30.0, 2.0, triangular(4, 4, "fixed"))
    x0 = _state(p.N, 2, seed=5)
    damping = Damping(contact=np.array([0.0, 0.02]), substrate=np.array([0.0, 0.01]))
    run = simulate(p, x0, 40 * 0.05, 0.05, method="kahan6", device="cpu", damping=damping)
    ref = reference.integrate("kahan6", p, x0, run.dt, run.nsteps, damping=damping)
    assert np.array_equal(run.x, ref["x"]) and not np.array_equal(run.x[0], run.x[1])


@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_tangent_columns_bit_for_bit_with_the_reference(geometry):
    p = LatticeParams(30.0, 3.0, BUILDERS[geometry](4, 3, "periodic"))
    x0 = _state(p.N, 2, seed=1)
    dx0 = np.random.default_rng(2).normal(size=(5, 4, p.N))
    base = np.array([0, 1, 1, 0, 1], dtype=np.int32)
    M, K = np.array([30.0, 20.0]), np.array([3.0, 1.5])
    out = propagate_tangent(p, x0, dx0, 6, 0.05, method="kahan8", column_base=base, M=M, K=K, device="cpu")
    assert out.layout == "sites"
    for c in range(len(base)):
        b = base[c]
        pb = p.replace(M=M[b], K=K[b])
        ref = reference.integrate("kahan8", pb, x0[b : b + 1], 0.05, 6, dx0=dx0[None, c : c + 1])
        assert np.array_equal(out.columns[c], ref["dx"][0, 0])


@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_flow_bit_for_bit_with_the_reference_flow(geometry):
    """The Flow (Newton's and Floquet's seam) on a patch: end state, min contact and every unit column."""
    p = LatticeParams(30.0, 2.0, BUILDERS[geometry](4, 4, "fixed"))
    x0 = _state(p.N, 1, seed=3)
    flow, ref = Flow("kahan8", 16, device="cpu"), ReferenceFlow("kahan8", 16)
    for dt in (0.05, 0.04):
        a, b = flow.linearize(p, x0, 8, dt), ref.linearize(p, x0, 8, dt)
        assert not a.banded
        assert np.array_equal(a.x_end, b.x_end) and a.min_contact == b.min_contact
        assert np.array_equal(a.unit_columns("all"), b.unit_columns("all"))
    # a second geometry of the same size is not served the first one's kept runner
    other = LatticeParams(30.0, 2.0, BUILDERS[geometry](2, 8, "fixed"))
    assert np.array_equal(flow.run(other, x0, 8, 0.05).x_end, ref.run(other, x0, 8, 0.05).x_end)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_strip_and_chain_table_are_the_chain(boundary):
    """A 1 x N strip (no bond across) and the chain given as a table: the chain's kernels' bits, in the sites
    layout and in the chain's own thread layout."""
    N = 13
    line = ChainParams(30.0, 160.0, N, boundary=boundary)
    x0 = _state(N, 2, seed=11, amplitude=0.5)
    expect = simulate(line, x0, 30 * 0.02, 0.02, device="cpu", record=Record(every=5))
    sites = simulate(line, x0, 30 * 0.02, 0.02, device="cpu", record=Record(every=5), placement=Placement("sites"))
    assert np.array_equal(expect.x, sites.x)
    for lat in (square(N, 1, boundary, weights=(1.0, 0.0)), chain(N, boundary)):
        run = simulate(LatticeParams(30.0, 160.0, lat), x0, 30 * 0.02, 0.02, device="cpu", record=Record(every=5))
        assert np.array_equal(run.x, expect.x) and np.array_equal(run.u, expect.u)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_square_without_cross_bonds_is_independent_chains(boundary):
    nx, ny = 9, 3
    p = LatticeParams(30.0, 160.0, square(nx, ny, boundary, weights=(1.0, 0.0)))
    x0 = _state(p.N, 1, seed=13, amplitude=0.5)
    run = simulate(p, x0, 30 * 0.02, 0.02, device="cpu")
    rows = x0.reshape(4, ny, nx).transpose(1, 0, 2)  # site i + nx j: row j is chain j
    line = simulate(ChainParams(30.0, 160.0, nx, boundary=boundary), rows, 30 * 0.02, 0.02, device="cpu")
    assert np.array_equal(run.x.reshape(4, ny, nx).transpose(1, 0, 2), line.x)


def test_2d_step_limit_and_refusals():
    """The step limit is the lattice's optical top (lam_max 8 on the square, 4 on the chain); the layouts that
    do not read a table refuse it in one line."""
    chain_p, square_p = ChainParams(30.0, 4.0, 16), LatticeParams(30.0, 4.0, square(4, 4))
    assert stability_limit("verlet", square_p) < stability_limit("verlet", chain_p)
    x0 = np.zeros((1, 4, 16))
    dt = 0.5 * (stability_limit("verlet", square_p) + stability_limit("verlet", chain_p))
    simulate(chain_p, x0, 4 * dt, dt, method="verlet", device="cpu")
    with pytest.raises(StepSizeError):
        simulate(square_p, x0, 4 * dt, dt, method="verlet", device="cpu")
    with pytest.raises(ValueError, match="runs in the 'sites' layout"):
        simulate(square_p, x0, 0.1, 0.05, device="cpu", placement=Placement("thread"))
    with pytest.raises(ValueError, match="splitting methods"):
        simulate(square_p, x0, 0.1, 0.05, method="rk4", device="cpu")


@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_newton_and_floquet_on_the_warp_flow_equal_the_reference_flow(geometry):
    """Dense Newton shooting and the complete reduced Floquet verdict on a 7 x 7 patch through the Warp Flow: the
    reference flow's breather and multipliers, bit for bit (the ``monolayer`` scene's path)."""
    import continuation as ct

    params = LatticeParams(30.0, 1.0, BUILDERS[geometry](7, 7, "fixed"))
    seed = ct.anticontinuum_seed(params, 1.005)
    found = [
        ct.require(ct.find_breather(params, 1.005, seed, flow=flow, solver="dense"))
        for flow in (Flow("kahan8", 32, device="cpu"), ReferenceFlow("kahan8", 32))
    ]
    assert np.array_equal(found[0].state, found[1].state) and found[0].energy == found[1].energy
    verdicts = [ct.floquet(b, solver="dense") for b in found]
    assert verdicts[0].complete and verdicts[0].stable is True
    assert np.array_equal(verdicts[0].multipliers, verdicts[1].multipliers)


def _cuda_devices() -> list[str]:
    from warpchain.engine.devices import available_devices

    return [d for d in available_devices() if d.startswith("cuda")]


@pytest.mark.skipif(not _cuda_devices(), reason="needs a GPU (CI has none: the CPU tests above hold the bits)")
@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_on_a_gpu_equals_the_reference(geometry):
    """On a GPU (FMA contraction: rounding, not bits): simulate with frames and losses, the Flow's end state and
    unit columns (replayed as CUDA graphs from the second call), a 21 x 21 patch."""
    device = _cuda_devices()[0]
    p = LatticeParams(30.0, 2.0, BUILDERS[geometry](21, 21, "fixed"))
    x0 = _state(p.N, 3, seed=17)
    damping = Damping(contact=np.array([0.0, 0.02, 0.0]), substrate=np.array([0.0, 0.01, 0.0]))
    run = simulate(p, x0, 50 * 0.05, 0.05, method="kahan8", device=device, record=Record(every=10), damping=damping)
    ref = reference.integrate("kahan8", p, x0, run.dt, run.nsteps, save_every=10, damping=damping)
    assert run.layout == "sites"
    np.testing.assert_allclose(run.x, ref["x"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.u, ref["u"], rtol=0, atol=1e-12)
    assert np.allclose(run.energy_final[2], energy(p, run.x[2:]), rtol=1e-12, atol=0)
    small = LatticeParams(30.0, 2.0, BUILDERS[geometry](5, 5, "periodic"))
    flow, reference_flow = Flow("kahan8", 16, device=device), ReferenceFlow("kahan8", 16)
    for _ in range(2):
        a, b = (
            flow.linearize(small, x0[:1, :, : small.N], 8, 0.05),
            reference_flow.linearize(small, x0[:1, :, : small.N], 8, 0.05),
        )
        np.testing.assert_allclose(a.x_end, b.x_end, rtol=0, atol=1e-13)
        np.testing.assert_allclose(a.unit_columns("all"), b.unit_columns("all"), rtol=0, atol=1e-12)


@pytest.mark.skipif(not _cuda_devices(), reason="needs a GPU (CI has none: the CPU tests above hold the bits)")
def test_observables_in_the_sites_layout_on_a_gpu():
    """On a GPU the sites layout reduces the observables of a 21 x 21 triangular patch (with losses) and of a chain
    longer than a block (N = 1201: auto picks the sites layout there) as the oracle does (rounding: 1e-11; the same
    peaks)."""
    device = _cuda_devices()[0]
    cases = [(LatticeParams(3.0, 1.0, triangular(21, 21, "fixed")), 2.5), (ChainParams(3.0, 1.0, 1201), 5.0)]
    for p, spot in cases:
        x0 = np.zeros((2, 4, p.N))
        x0[:, 1, p.N // 2] = 0.6
        x0[:, 1] += 0.05 * np.random.default_rng(5).standard_normal((2, p.N))
        obs = Observation(frame_every=10, threshold=0.05, radius=3, contrast=0.5, spot=spot)
        damping = Damping(contact=np.array([0.0, 0.05]), substrate=0.0)
        run = simulate(p, x0, 60 * 0.05, 0.05, device=device, observe=obs, damping=damping)
        values, env, x = reference.observe("verlet", p, x0, run.dt, run.nsteps, obs, damping=damping)
        assert run.layout == "sites"
        np.testing.assert_allclose(run.x, x, rtol=0, atol=1e-12)
        assert np.array_equal(run.observed["peaks"], values[..., 0])
        np.testing.assert_allclose(run.observed.values, values, rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(run.observed.envelope, env, rtol=0, atol=1e-12)


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_observables_on_the_device_equal_the_oracle(geometry, boundary):
    """``simulate(..., observe=...)`` on a table (the sites layout): frame by frame the observables of
    ``reference.observe`` (the table's peak rule, the disc of the spot, energies summed in another order: 1e-12),
    the same peaks and envelopes, the state bit for bit; with losses on one lattice, over several chunks."""
    p = LatticeParams(3.0, 1.0, BUILDERS[geometry](9, 8, boundary))
    x0 = np.zeros((3, 4, p.N))
    x0[:, 1, p.lattice.centre] = 0.6
    x0[:, 1] += 0.05 * np.random.default_rng(3).standard_normal((3, p.N))
    obs = Observation(frame_every=10, threshold=0.05, radius=2, contrast=0.5, spot=np.array([2.0, 0.0, 3.5]))
    damping = Damping(contact=np.array([0.0, 0.05, 0.0]), substrate=0.0)
    run = simulate(p, x0, 60 * 0.05, 0.05, device="cpu", observe=obs, damping=damping, guard=Guard(chunks=3))
    values, env, x = reference.observe("verlet", p, x0, run.dt, run.nsteps, obs, damping=damping)
    assert run.layout == "sites" and np.array_equal(run.x, x)
    assert np.array_equal(run.observed["peaks"], values[..., 0]) and run.observed["peaks"].max() >= 1
    assert np.array_equal(run.observed.envelope, env)
    np.testing.assert_allclose(run.observed.values, values, rtol=1e-12, atol=1e-300)
    assert run.observed["dissipated"][-1, 1] > 0 and run.observed["dissipated"][-1, 0] == 0


def test_long_chain_observables_in_the_sites_layout():
    """A chain in the sites layout (a GPU's for N > 1024; forced here) reduces the chain's observables: the windows
    of ``peak_mask``, not the table's, so that a ring gives the thread layout's values."""
    for boundary in ("fixed", "periodic"):
        p = ChainParams(3.0, 1.0, 61, boundary)
        x0 = np.zeros((2, 4, p.N))
        x0[:, 1, [3, 30, 58]] = 0.6
        obs = Observation(frame_every=8, threshold=0.05, radius=4, contrast=0.5, spot=5.0)
        runs = {
            layout: simulate(p, x0, 40 * 0.05, 0.05, device="cpu", observe=obs, placement=Placement(layout))
            for layout in ("sites", "thread")
        }
        values, env, _ = reference.observe("verlet", p, x0, runs["sites"].dt, runs["sites"].nsteps, obs)
        for run in runs.values():
            assert np.array_equal(run.observed["peaks"], values[..., 0]) and np.array_equal(run.observed.envelope, env)
            np.testing.assert_allclose(run.observed.values, values, rtol=1e-12, atol=1e-300)


def test_the_table_peak_rule_is_the_chains_on_a_chain():
    """``reference.table_peak_mask`` on a chain's table with fixed or free ends is ``peak_mask`` (ties included)."""
    rng = np.random.default_rng(1)
    for boundary in ("fixed", "free"):
        table = chain(57, boundary)
        for _ in range(20):
            env = np.round(np.abs(rng.standard_normal((3, 57))) * (rng.random((3, 57)) < 0.5), 1)
            for radius, contrast in ((1, 1.0), (2, 0.5), (5, 0.5)):
                expected = reference.peak_mask(env, 0.1, radius, contrast)
                assert np.array_equal(reference.table_peak_mask(table, env, 0.1, radius, contrast), expected)


def test_spot_peaks_equal_the_full_disc_filter():
    """monolayer-spot's peaks (candidates from a box inside the disc, then checked over disc and rim) and the sites
    they cover equal those of the plain full-disc maximum filter, on smooth fields with noise, every geometry."""
    from scipy import ndimage

    from scenarios.monolayer_spot import _footprints, _peaks

    rng, found = np.random.default_rng(0), 0
    for lat in (triangular(41, 37, "fixed"), square(30, 30, "periodic"), chain(101, "fixed"), chain(60, "periodic")):
        grid, wrap = lat.shape[::-1], lat.boundary == "periodic"
        mode = "wrap" if wrap else "constant"
        for radius in (1.0, 4.0, 6.5):
            disc, rim = _footprints(lat, radius)
            for floor in (1e-4, 0.3):
                e = ndimage.gaussian_filter(rng.random(grid), 2, mode=mode) + 1e-3 * rng.random(grid)
                e = e / e.max()
                largest = ndimage.maximum_filter(e, footprint=disc, mode=mode, cval=0.0)
                edge = ndimage.maximum_filter(e, footprint=rim, mode=mode, cval=0.0)
                expect = (e > floor) & (e >= largest) & (edge <= 0.9 * e)
                covered = ndimage.maximum_filter(expect, footprint=disc, mode=mode, cval=False)
                peaks, near = _peaks(e, floor, disc, rim, 0.9, wrap)
                assert np.array_equal(peaks, expect.ravel()) and np.array_equal(near, covered.ravel())
                found += int(peaks.sum())
    assert found > 20


@pytest.mark.slow
@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_probed_columns_equal_the_plain_ones(geometry):
    """The Flow's probed columns on a patch (colour groups of the lattice's own colouring, each site's column read
    over its ball of bonds, the rim checked): the plain unit columns to far below rounding, from fewer runs; on a
    periodic patch (a perturbation wraps round) the plain columns."""
    p = LatticeParams(30.0, 0.1, BUILDERS[geometry](25, 25, "fixed"))
    x0 = _state(p.N, 1, seed=5, amplitude=0.05)
    lin = Flow("kahan8", 16, device="cpu").linearize(p, x0, 8, 0.1)
    A, b = lin.probed_columns("positions")
    runs = lin.stats["tangent_columns"]
    plain = lin._plain_columns("positions")
    assert b < p.N and runs < 2 * p.N
    # the rim's entries are below PROBE_TOLERANCE (1e-16) of their run's largest, and the entries beyond it, which
    # the colour groups alias, fall faster still (6e-23 here, at the ball radius the measured decay asked for)
    assert np.abs(A.toarray() - plain).max() <= 1e-20 * np.abs(plain).max()
    ring = LatticeParams(30.0, 0.1, BUILDERS[geometry](6, 6, "periodic"))
    lin = Flow("kahan8", 16, device="cpu").linearize(ring, _state(ring.N, 1, seed=6, amplitude=0.05), 8, 0.1)
    assert lin.lattice is None and lin.probed_columns("positions")[1] == ring.N


@pytest.mark.parametrize("geometry", sorted(BUILDERS))
def test_2d_kahan8_order_against_dop853(geometry):
    """The Warp kernels on a patch converge to scipy's DOP853 (rtol 1e-13) at eighth order (measured 8.05 on both
    lattices; an amplitude that keeps contact: the contact law's kink would cut the order)."""
    from warpchain.reference import solve_ivp_reference

    p = LatticeParams(30.0, 1.0, BUILDERS[geometry](5, 5, "fixed"))
    x0 = _state(p.N, 1, seed=1, amplitude=0.05)
    ref, _ = solve_ivp_reference(p, x0[0], 4.0)
    errors = [np.abs(simulate(p, x0, 4.0, dt, method="kahan8", device="cpu").x[0] - ref).max() for dt in (0.4, 0.2)]
    assert errors[0] < 1e-8 and 7.5 < np.log2(errors[0] / errors[1]) < 8.5


def test_spot_footprints_hold_the_whole_disc():
    """monolayer-spot's disc and rim hold every site within the radius on each lattice (the triangular disc reaches
    2 R / sqrt(3) along an axis: a (2R + 1)^2 patch cut it, 343 of 367 sites at R = 10)."""
    from scenarios.monolayer_spot import _footprints

    for lat, big in ((triangular(5, 5), triangular(81, 81)), (square(5, 5), square(81, 81)), (chain(5), chain(201))):
        d = big.distances(big.centre)
        for radius in (1.0, 4.5, 10.0):
            disc, rim = _footprints(lat, radius)
            assert all(s % 2 == 1 for s in disc.shape) and disc[tuple(s // 2 for s in disc.shape)]
            assert disc.sum() == np.sum(d <= radius + 1e-9)
            assert rim.sum() == np.sum((d > radius - 1.0 + 1e-9) & (d <= radius + 1e-9))


def test_a_hand_built_table_is_not_served_its_builders_runner():
    """The kept runners are keyed by the table's contents: the same patch with one bond removed runs its own table
    (a key by name, shape, boundary and weights handed it the intact patch's, found by review)."""
    import dataclasses

    intact = square(5, 5, "fixed")
    weights = np.array(intact.weights)
    c = intact.centre
    weights[c, 1] = weights[c + 1, 0] = 0.0  # the centre's +x bond, both ends
    cut = dataclasses.replace(intact, weights=weights)
    x0 = _state(25, 1, seed=9)
    flow, ref = Flow("verlet", 16, device="cpu"), ReferenceFlow("verlet", 16)
    for params in (LatticeParams(30.0, 2.0, intact),) * 2 + (LatticeParams(30.0, 2.0, cut),) * 2:
        assert np.array_equal(flow.run(params, x0, 8, 0.05).x_end, ref.run(params, x0, 8, 0.05).x_end)


def test_peak_tracks_refuses_a_2d_lattices_envelopes():
    from warpchain.observe import peak_tracks

    env = np.zeros((1, 100))
    with pytest.raises(ValueError, match="table_peak_mask"):
        peak_tracks(env, env, 1.0, Observation(frame_every=10), 1.0, lattice=square(10, 10))
