import warnings

import numpy as np
import pytest

from conftest import SPLITTING, localized_state
from warpchain import BOUNDARIES, Guard, Placement, Record
from warpchain import (
    METHODS,
    ChainParams,
    IntegrationError,
    StepSizeError,
    energy,
    propagate_tangent,
    simulate,
    stability_limit,
)
from warpchain import reference


LAYOUTS = ["thread", "block"]  # block: the GPU kernels, run here as CPU fibers


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("method", SPLITTING)
def test_warp_matches_numpy_reference_per_lattice_parameters(method, layout):
    """1000 steps, a localized large-amplitude state, per-lattice (M, K): relative agreement <= 1e-12."""
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=3, seed=3)
    M = np.array([30.0, 10.0, 50.0])
    K = np.array([160.0, 40.0, 100.0])
    dt = 0.02
    warp = simulate(
        p,
        x0,
        1000 * dt,
        dt,
        method=method,
        device="cpu",
        M=M,
        K=K,
        record=Record(every=250),
        placement=Placement(layout=layout),
    )
    assert warp.layout == layout
    ref = reference.integrate(method, p, x0, dt, 1000, M=M, K=K, save_every=250)
    scale = np.max(np.abs(ref["x"]))
    assert warp.nsteps == 1000
    assert np.max(np.abs(warp.x - ref["x"])) <= 1e-12 * scale
    assert np.max(np.abs(warp.u - ref["u"])) <= 1e-12 * scale
    assert warp.u.shape == (5, 3, p.N) and warp.t.shape == (5,)
    # the lattices really differ (per-lattice parameters are honoured)
    assert np.max(np.abs(warp.x[0] - warp.x[1])) > 1e-3


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_warp_matches_numpy_reference_boundaries(boundary, layout):
    p = ChainParams(3.0, 4.0, 17, boundary)
    x0 = localized_state(p.N, amplitude=0.5, batch=2, centre=2, seed=4)
    for method in SPLITTING:
        warp = simulate(p, x0, 200 * 0.05, 0.05, method=method, device="cpu", placement=Placement(layout=layout))
        ref = reference.integrate(method, p, x0, 0.05, 200)
        assert np.max(np.abs(warp.x - ref["x"])) <= 1e-12 * np.max(np.abs(ref["x"]))


ORDER_STEPS = {
    "verlet": (0.04, 0.02, 0.01),
    "yoshida4": (0.1, 0.05, 0.025),
    "yoshida6": (0.2, 0.1, 0.05),
    "kahan6": (0.4, 0.2, 0.1),
    "kahan8": (0.8, 0.4, 0.2),
    "rk4": (0.1, 0.05, 0.025),
}


@pytest.fixture(scope="module")
def smooth_reference():
    p = ChainParams(3.0, 4.0, 31)
    x0 = localized_state(p.N, amplitude=0.3, width=3.0)[0]
    exact, _ = reference.solve_ivp_reference(p, x0, 4.0, rtol=1e-13, atol=1e-15)
    return p, x0, exact


def _final(p, x0, t_final, dt, method):
    """The state at t_final: the Warp engine for a splitting method, the numpy reference for RK4."""
    if method in SPLITTING:
        return simulate(p, x0, t_final, dt, method=method, device="cpu").x[0]
    return reference.integrate(method, p, x0[None], dt, round(t_final / dt))["x"][0]


@pytest.mark.parametrize("method", sorted(METHODS))
def test_observed_order_of_convergence(method, smooth_reference):
    p, x0, exact = smooth_reference
    steps = ORDER_STEPS[method]
    errors = [np.max(np.abs(_final(p, x0, 4.0, dt, method) - exact)) for dt in steps]
    slope = np.polyfit(np.log(steps), np.log(errors), 1)[0]
    assert min(errors) > 1e-11, "errors must stay above the reference's own accuracy"
    assert abs(slope - METHODS[method].order) <= 0.3, (method, errors, slope)


@pytest.mark.parametrize("method", ["verlet", "yoshida4", "yoshida6", "kahan6", "kahan8"])
def test_symplectic_energy_bounded_not_drifting(method):
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.5)
    run = simulate(p, x0, 4000 * 0.1, 0.1, method=method, device="cpu", guard=Guard(chunks=40))
    assert run.max_energy_error[0] < 1e-2  # checked at every chunk end along the run
    errs = []
    for n_steps in (500, 1000, 2000, 4000):
        r = simulate(p, x0, n_steps * 0.1, 0.1, method=method, device="cpu")
        errs.append(r.energy_error[0])
    # bounded: the error after 4000 steps is not much larger than after 500 (no secular drift)
    assert max(errs) < 5 * max(errs[0], 1e-14) + 1e-12, errs


def test_rk4_energy_drifts_but_converges():
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.5)
    E0 = energy(p, x0)[0]
    coarse, fine = (abs(energy(p, _final(p, x0[0], 400.0, dt, "rk4"))[0] - E0) / E0 for dt in (0.1, 0.05))
    assert fine < coarse / 8


def test_the_engine_refuses_rk4_and_names_the_reference():
    """RK4 left the engine (``devices.engine_method``): simulate, propagate_tangent, time_steps and Flow say so and
    where it runs; the numpy reference and ReferenceFlow keep it."""
    from warpchain import Flow, ReferenceFlow
    from warpchain.ensemble import time_steps

    p = ChainParams(3.0, 4.0, 9)
    x0 = localized_state(p.N, amplitude=0.5)
    advice = r"not a splitting method.*warpchain\.reference\.integrate\('rk4'.*ReferenceFlow\(method='rk4'\)"
    with pytest.raises(ValueError, match=advice):
        simulate(p, x0, 1.0, 0.05, method="rk4", device="cpu")
    with pytest.raises(ValueError, match=advice):
        propagate_tangent(p, x0, np.eye(4 * p.N).reshape(-1, 4, p.N), 5, 0.05, method="rk4", device="cpu")
    with pytest.raises(ValueError, match=advice):
        time_steps(p, x0, 5, 0.05, method="rk4", device="cpu")
    with pytest.raises(ValueError, match=advice):
        Flow("rk4", 16, device="cpu")
    for bad in (None, 3, ["verlet"]):  # neither a name nor a Method: the unknown-method error, not an AttributeError
        with pytest.raises(ValueError, match="unknown method"):
            simulate(p, x0, 1.0, 0.05, method=bad, device="cpu")
    lin = ReferenceFlow("rk4", 16).linearize(p, x0, 8, 0.05)
    assert lin.unit_columns("all").shape == (4 * p.N, 4 * p.N)


def test_stability_limit_values():
    p = ChainParams(30.0, 160.0)
    assert stability_limit("verlet", p) == pytest.approx(0.4327, abs=1e-4)
    assert METHODS["rk4"].stability_bound == pytest.approx(2 * np.sqrt(2), rel=1e-9)


def test_bad_input_errors(small_chain):
    p = small_chain
    x0 = localized_state(p.N)[0]
    with pytest.raises(ValueError, match="shape"):
        simulate(p, np.zeros((3, p.N)), 1.0, 0.1, device="cpu")
    with pytest.raises(ValueError, match="sites"):
        simulate(p, np.zeros((4, p.N + 1)), 1.0, 0.1, device="cpu")
    bad = x0.copy()
    bad[0, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        simulate(p, bad, 1.0, 0.1, device="cpu")
    with pytest.raises(ValueError, match="dt"):
        simulate(p, x0, 1.0, 0.0, device="cpu")
    with pytest.raises(ValueError, match="dt"):
        simulate(p, x0, 1.0, -0.1, device="cpu")
    with pytest.raises(ValueError, match="t_final"):
        simulate(p, x0, -1.0, 0.1, device="cpu")
    with pytest.raises(ValueError, match="unknown method"):
        simulate(p, x0, 1.0, 0.1, method="euler", device="cpu")
    with pytest.raises(ValueError, match="device"):
        simulate(p, x0, 1.0, 0.1, device="tpu")
    with pytest.raises(ValueError, match="Record.every"):
        simulate(p, x0, 1.0, 0.1, device="cpu", record=Record(every=0))
    with pytest.raises(ValueError, match="per-lattice M"):
        simulate(p, x0, 1.0, 0.1, device="cpu", M=[1.0, 2.0])


def test_step_above_stability_limit_refused_or_warned():
    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.1)
    with pytest.raises(StepSizeError, match=r"0\.4326"):
        simulate(p, x0, 10.0, 0.5, device="cpu")
    with pytest.warns(RuntimeWarning, match="stability limit"):
        with pytest.raises(IntegrationError):
            simulate(p, x0, 200.0, 0.5, device="cpu", guard=Guard(allow_unstable_step=True))


def test_blow_up_raises_integration_error_naming_method_step_limit_and_lattices():
    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.1, batch=3)
    Ks = np.array([10.0, 160.0, 10.0])  # only lattice 1 is past its limit at dt = 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(IntegrationError) as info:
            simulate(p, x0, 400.0, 0.5, device="cpu", K=Ks, guard=Guard(allow_unstable_step=True))
    err = info.value
    assert err.method == "verlet" and err.dt == 0.5 and err.failed == [1]
    message = str(err)
    assert "verlet" in message and "dt = 0.5" in message and "stability limit" in message and "[1]" in message


def test_energy_error_bound_triggers():
    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.9)
    with pytest.raises(IntegrationError, match="energy error"):
        simulate(p, x0, 20.0, 0.4, method="verlet", device="cpu", guard=Guard(max_energy_error=1e-9))


def test_t_final_not_multiple_of_dt_shortens_step(small_chain):
    x0 = localized_state(small_chain.N)
    r = simulate(small_chain, x0, 1.0, 0.3, device="cpu")
    assert r.nsteps == 4 and r.dt == pytest.approx(0.25) and r.t_final == pytest.approx(1.0)
    zero = simulate(small_chain, x0, 0.0, 0.1, device="cpu")
    assert zero.nsteps == 0 and np.array_equal(zero.x, x0)


def test_recording_and_callback(small_chain):
    x0 = localized_state(small_chain.N, batch=2)
    seen = []
    r = simulate(
        small_chain,
        x0,
        3.0,
        0.1,
        device="cpu",
        record=Record(every=3, on_chunk=lambda t, u, v: seen.append((t.copy(), u.shape))),
        guard=Guard(chunks=4),
    )
    assert r.u.shape == (11, 2, small_chain.N)
    assert np.allclose(r.t, np.arange(11) * 0.3)
    assert np.allclose(np.concatenate([s[0] for s in seen]), r.t)
    assert np.allclose(r.u[-1], r.x[:, 0])
    assert r.energy_initial.shape == (2,) and np.allclose(r.energy_initial, energy(small_chain, x0))


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("method", SPLITTING)
def test_tangent_columns_match_reference_and_finite_differences(method, layout):
    p = ChainParams(3.0, 4.0, 9)
    x0 = localized_state(p.N, amplitude=0.7, batch=2, seed=5)
    ncols = 4 * p.N
    eye = np.eye(ncols).reshape(ncols, 4, p.N)
    dx0 = np.concatenate([eye, eye])
    base = np.repeat([0, 1], ncols)
    nsteps, dt = 40, 0.05
    tan = propagate_tangent(p, x0, dx0, nsteps, dt, method=method, column_base=base, device="cpu", layout=layout)
    assert tan.layout == layout
    ref = reference.integrate(method, p, x0, dt, nsteps, dx0=dx0.reshape(2, ncols, 4, p.N))
    J = tan.columns.reshape(2, ncols, ncols)
    assert np.max(np.abs(tan.x - ref["x"])) <= 1e-12 * np.max(np.abs(ref["x"]))
    assert np.max(np.abs(J - ref["dx"].reshape(2, ncols, ncols))) <= 1e-12 * np.max(np.abs(J))
    h = 1e-6
    for c in range(0, ncols, 5):
        xp, xm = x0[1:].copy().reshape(1, -1), x0[1:].copy().reshape(1, -1)
        xp[0, c] += h
        xm[0, c] -= h
        fp = reference.integrate(method, p, xp.reshape(1, 4, p.N), dt, nsteps)["x"]
        fm = reference.integrate(method, p, xm.reshape(1, 4, p.N), dt, nsteps)["x"]
        fd = ((fp - fm) / (2 * h)).ravel()
        assert np.max(np.abs(fd - J[1, c])) <= 1e-7 * max(1.0, np.max(np.abs(J[1, c])))


def test_reference_runs_have_simulates_chunks():
    """``scenarios._common.reference_run`` (RK4's rows in the method scenes) ends its chunks where ``simulate``
    does, also when the steps do not divide evenly, and its energies there are simulate's (the same scheme)."""
    from scenarios._common import reference_run

    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.4)[0]
    run = simulate(p, x0, 10 * 0.05, 0.05, method="verlet", device="cpu", guard=Guard(chunks=4))
    x, t, E = reference_run("verlet", p, x0, 10 * 0.05, 0.05, chunks=4)
    assert np.array_equal(t, run.energy_t) and len(t) == 5
    assert np.array_equal(x, run.x[0])
    assert np.allclose(E, run.energy_trace[:, 0], rtol=1e-13, atol=0)
