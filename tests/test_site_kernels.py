"""The ``"sites"`` layout (``warpchain.engine.site_kernels``: a thread per site, a launch per force evaluation,
the GPU path for lattices longer than a block) against the numpy reference, bit for bit on the CPU: base runs
with frames, per-lattice parameters and losses, every boundary and splitting method; tangent columns; the
Flow's replayed graphs; the guard of a lattice longer than a block; and where ``auto`` picks it."""

import numpy as np
import pytest

from conftest import localized_state
from warpchain import BOUNDARIES, METHODS, ChainParams, Guard, Placement, Record, energy, propagate_tangent
from warpchain import reference, simulate
from warpchain.engine import tuning
from warpchain.engine.devices import resolve_layout
from warpchain.flow import Flow, ReferenceFlow
from warpchain.integrators import SplittingMethod
from warpchain.losses import Damping

SPLITTING = sorted(name for name, m in METHODS.items() if isinstance(m, SplittingMethod))


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("method", SPLITTING)
def test_runs_bit_for_bit_with_the_reference(method, boundary):
    p = ChainParams(30.0, 160.0, 23, boundary=boundary)
    x0 = localized_state(p.N, amplitude=0.8, batch=3, seed=3)
    M, K = np.array([30.0, 10.0, 50.0]), np.array([160.0, 40.0, 100.0])
    run = simulate(
        p, x0, 60 * 0.02, 0.02, method=method, device="cpu", M=M, K=K, record=Record(every=7),
        placement=Placement(layout="sites"), guard=Guard(chunks=2),
    )  # fmt: skip
    ref = reference.integrate(method, p, x0, 0.02, run.nsteps, M=M, K=K, save_every=7)
    assert run.layout == "sites"
    assert np.array_equal(run.x, ref["x"]) and np.array_equal(run.u, ref["u"]) and np.array_equal(run.v, ref["v"])
    assert np.allclose(run.energy_final, energy(p, run.x, M, K), rtol=1e-13, atol=0)


def test_losses_bit_for_bit_with_the_reference():
    p = ChainParams(30.0, 160.0, 19)
    x0 = localized_state(p.N, amplitude=0.8, batch=2, seed=5)
    damping = Damping(contact=np.array([0.0, 0.02]), substrate=np.array([0.0, 0.01]))
    run = simulate(
        p, x0, 40 * 0.05, 0.05, method="kahan6", device="cpu", damping=damping, placement=Placement(layout="sites")
    )
    ref = reference.integrate("kahan6", p, x0, run.dt, run.nsteps, damping=damping)
    assert np.array_equal(run.x, ref["x"]) and not np.array_equal(run.x[0], run.x[1])


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("method", ["verlet", "kahan8"])
def test_tangent_columns_bit_for_bit_with_the_reference(method, boundary):
    p = ChainParams(30.0, 160.0, 17, boundary=boundary)
    x0 = localized_state(p.N, amplitude=0.5, batch=2, seed=1)
    dx0 = np.random.default_rng(2).normal(size=(5, 4, p.N))
    base = np.array([0, 1, 1, 0, 1], dtype=np.int32)
    M, K = np.array([30.0, 20.0]), np.array([160.0, 90.0])
    out = propagate_tangent(
        p, x0, dx0, 6, 0.05, method=method, column_base=base, M=M, K=K, device="cpu", layout="sites"
    )
    thread = propagate_tangent(
        p, x0, dx0, 6, 0.05, method=method, column_base=base, M=M, K=K, device="cpu", layout="thread"
    )
    assert out.layout == "sites"
    assert np.array_equal(out.x, thread.x) and np.array_equal(out.columns, thread.columns)
    for c in range(len(base)):  # the reference, column by column against its base lattice
        b = base[c]
        pb = ChainParams(M[b], K[b], p.N, boundary=boundary)
        ref = reference.integrate(method, pb, x0[b : b + 1], 0.05, 6, dx0=dx0[None, c : c + 1])
        assert np.array_equal(out.columns[c], ref["dx"][0, 0])


def test_flow_on_sites_replayed_as_a_graph_bit_for_bit(monkeypatch):
    """The Flow's base run and unit columns on the sites layout, replayed as a graph (Warp's CPU graphs)
    from the second call: the reference's bits, also for a new state and dt."""
    with tuning.override(graphs_on_cpu=True):
        monkeypatch.setenv("WARPCHAIN_CPU_THREADS", "1")
        p = ChainParams(30.0, 160.0, 15)
        x0 = localized_state(p.N, amplitude=0.3, batch=2, seed=4)
        flow, ref = Flow("yoshida4", 16, device="cpu", layout="sites"), ReferenceFlow("yoshida4", 16)
        for x, dt in [(x0[:1], 0.05), (x0[1:], 0.05), (x0[:1], 0.04)] * 2:
            a, b = flow.linearize(p, x, 8, dt), ref.linearize(p, x, 8, dt)
            assert np.array_equal(a.x_end, b.x_end) and a.min_contact == b.min_contact
            assert np.array_equal(a.unit_columns("positions"), b.unit_columns("positions"))
            d = np.random.default_rng(0).normal(size=(3, 4, p.N))
            assert np.array_equal(a.columns(d), b.columns(d))
        replays = [r for slot in flow._pool.values() for runner in slot["runners"] for r in runner._replays.values()]
        assert sum(r.graph is not None for r in replays) >= 2


def test_guard_of_a_lattice_longer_than_a_block():
    """The guard on the sites layout runs one block whose threads each sum several sites: energy to rounding,
    min contact and the finite flag exact."""
    p = ChainParams(30.0, 160.0, 1100)
    x0 = localized_state(p.N, amplitude=0.8, batch=1, seed=6)
    run = simulate(p, x0, 2 * 0.05, 0.05, method="verlet", device="cpu", placement=Placement(layout="sites"))
    ref = reference.integrate("verlet", p, x0, 0.05, 2, save_every=1)
    assert np.array_equal(run.x, ref["x"])
    assert np.allclose(run.energy_final, energy(p, run.x), rtol=1e-13, atol=0)
    assert np.array_equal(run.min_contact, np.min(1 + ref["u"] - ref["v"], axis=(0, 2)))


def test_auto_picks_sites_for_long_lattices_on_a_gpu_only():
    assert resolve_layout("auto", "cuda:0", 3201) == "sites"
    assert resolve_layout("auto", "cuda:0", 1024) == "block"
    assert resolve_layout("auto", "cpu", 3201) == "thread"
    assert resolve_layout("auto", "cpu", 21, table=True) == "sites"
    with pytest.raises(ValueError, match="needs N <= 1024"):
        resolve_layout("block", "cuda:0", 3201)
