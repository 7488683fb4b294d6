"""Losses (exact damped kicks) and the device-side observables, against the numpy reference and DOP853."""

import numpy as np
import pytest

from warpchain import Guard, Placement, Record
from warpchain import ChainParams, IntegrationError, reference, simulate, stability_limit
from warpchain.losses import Damping, damping_matrix, dissipation, kick_dissipation, kick_matrices, rhs_flat
from warpchain.observe import Observation, observe, peak_mask, peak_tracks

N = 41
PARAMS = ChainParams(30.0, 160.0, N)


def _spots(batch, amplitude=0.3, width=4.0, seed=0):
    rng = np.random.default_rng(seed)
    j = np.arange(N)
    x = np.zeros((batch, 4, N))
    x[:, 2] = amplitude * np.exp(-(((j - N // 2) / width) ** 2))
    x[:, 2] += 0.01 * rng.standard_normal((batch, N))
    return x


DAMPING = Damping(np.array([0.0, 0.05, 0.02, 0.0]), np.array([0.0, 0.0, 0.01, 0.03]))


def test_kick_matrices_solve_the_damped_velocity_equation():
    """E, F, H and the energy a kick dissipates against a fine explicit integration of w' = a - G w (with
    int w dt and int P dt as extra states), and the exact zero-damping form."""
    M, gc, gs, h = 30.0, 0.2, 0.05, 0.37
    coef = kick_matrices((1.0,), h, [M], Damping(gc, gs), 1)[0, 0]
    E, F, H = coef[:4].reshape(2, 2), coef[4:8].reshape(2, 2), coef[8:].reshape(2, 2)
    G = damping_matrix(M, gc, gs)
    C = np.diag([M, 1.0]) @ G  # the power lost is w . C w
    w0, a = np.array([0.3, -0.7]), np.array([1.1, 0.4])
    y = np.concatenate([w0, [0.0, 0.0, 0.0]])  # w, int w dt, int P dt
    n = 20000
    for _ in range(n):  # RK4, far below its error scale
        f = lambda y: np.concatenate([a - G @ y[:2], y[:2], [y[:2] @ C @ y[:2]]])  # noqa: E731
        k1 = f(y)
        k2 = f(y + 0.5 * h / n * k1)
        k3 = f(y + 0.5 * h / n * k2)
        k4 = f(y + h / n * k3)
        y = y + h / n / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(E @ w0 + F @ a, y[:2], rtol=1e-12)
    np.testing.assert_allclose(F @ w0 + H @ a, y[2:4], rtol=1e-12)
    lost = kick_dissipation(w0.reshape(1, 2, 1), a.reshape(1, 2, 1), coef[None], [M])
    np.testing.assert_allclose(lost, [y[4]], rtol=1e-11)
    # C is the matrix of the power ``dissipation`` reports
    state = np.concatenate([[0.0, 0.0], w0]).reshape(1, 4, 1)
    np.testing.assert_allclose(dissipation(state, M, Damping(gc, gs)), [w0 @ C @ w0], rtol=1e-14)
    # d(u' - v')/dt from the losses is -gamma_c (u' - v') - gamma_s u' (so z'' = ... - gamma_c z')
    np.testing.assert_allclose(-(G[0] - G[1]), [-gc - gs, gc], rtol=1e-14)
    zero = kick_matrices((0.5, 0.25), 0.1, [M], Damping(0.0, 0.0), 1)[0]
    assert np.array_equal(zero[:, :4], np.tile([1.0, 0.0, 0.0, 1.0], (2, 1)))
    assert np.array_equal(zero[:, 4], np.array([0.5 * 0.1, 0.25 * 0.1])) and np.all(zero[:, 5:7] == 0)


@pytest.mark.parametrize("method", ["verlet", "yoshida4", "yoshida6", "kahan6"])
def test_damped_schemes_keep_their_order_against_dop853(method):
    x0 = _spots(1)
    damping = Damping(0.05, 0.02)
    from scipy.integrate import solve_ivp

    T = 4.0
    sol = solve_ivp(rhs_flat(PARAMS, None, None, 0.05, 0.02), (0, T), x0[0].ravel(), "DOP853", rtol=1e-13, atol=1e-14)
    exact = sol.y[:, -1].reshape(4, N)
    errors = [
        np.abs(reference.integrate(method, PARAMS, x0, T / n, n, damping=damping)["x"][0] - exact).max()
        for n in (80, 160)
    ]
    order = {"verlet": 2, "yoshida4": 4, "yoshida6": 6, "kahan6": 6}[method]
    assert np.log2(errors[0] / errors[1]) == pytest.approx(order, abs=0.25)


@pytest.mark.parametrize("method", ["yoshida4", "kahan6"])
def test_dissipated_energy_keeps_the_scheme_order_against_dop853(method):
    """``dissipated`` (exact over each damped kick) against DOP853 with the dissipation integral as an extra
    state: its error falls at the scheme's order, and so does E + D - E0 (the trapezoid rule made it 2)."""
    from scipy.integrate import solve_ivp

    x0 = _spots(1)
    gc, gs = 0.05, 0.02
    damping, T = Damping(gc, gs), 4.0
    rhs = rhs_flat(PARAMS, None, None, gc, gs)

    def extended(t, y):
        return np.append(rhs(t, y[:-1]), dissipation(y[:-1].reshape(1, 4, N), PARAMS.M, damping)[0])

    sol = solve_ivp(extended, (0, T), np.append(x0[0].ravel(), 0.0), "DOP853", rtol=1e-13, atol=1e-14)
    D_exact = sol.y[-1, -1]
    E0 = reference.model.energy(PARAMS, x0)[0]
    errors, balance = [], []
    for n in (40, 80):
        x, lost = x0.copy(), np.zeros(1)
        for _ in range(n):
            x = reference.step(method, PARAMS, x, T / n, damping=damping, dissipated=lost)
        errors.append(abs(lost[0] - D_exact))
        balance.append(abs(reference.model.energy(PARAMS, x)[0] + lost[0] - E0))
    order = {"yoshida4": 4, "kahan6": 6}[method]
    assert D_exact > 1e-3 * E0
    assert np.log2(errors[0] / errors[1]) == pytest.approx(order, abs=0.5)
    assert np.log2(balance[0] / balance[1]) > order - 0.5


@pytest.mark.parametrize("layout", ["thread", "block"])
@pytest.mark.parametrize("method", ["verlet", "kahan6"])
def test_damped_kernels_match_the_reference_bit_for_bit(layout, method):
    x0 = _spots(4)
    run = simulate(
        PARAMS, x0, 3.0, 0.05, method=method, device="cpu", damping=DAMPING, placement=Placement(layout=layout)
    )
    ref = reference.integrate(method, PARAMS, x0, run.dt, run.nsteps, damping=DAMPING)["x"]
    assert np.array_equal(run.x, ref)
    lossless = simulate(PARAMS, x0, 3.0, 0.05, method=method, device="cpu", placement=Placement(layout=layout))
    assert np.array_equal(run.x[0], lossless.x[0])  # the lattice without losses: today's scheme, bit for bit
    assert np.all(run.energy_final[1:] < run.energy_initial[1:])


def test_losses_are_refused_where_they_have_no_sub_flow():
    with pytest.raises(ValueError, match="splitting"):
        simulate(PARAMS, _spots(1), 1.0, 0.05, method="rk4", device="cpu", damping=(0.1, 0.0))
    with pytest.raises(ValueError, match="conservative"):
        reference.step("verlet", PARAMS, _spots(1), 0.05, dx=np.zeros((1, 1, 4, N)), damping=(0.1, 0.0))
    with pytest.raises(ValueError, match=">= 0"):
        simulate(PARAMS, _spots(1), 1.0, 0.05, device="cpu", damping=(-0.1, 0.0))


@pytest.mark.parametrize("layout", ["thread", "block"])
def test_observables_match_the_reference(layout):
    x0 = _spots(4)
    obs = Observation(
        frame_every=10, threshold=0.02, radius=2, contrast=0.9, spot=np.array([3.0, 4.0, 5.0, 6.0]), lag_frames=3
    )
    run = observe(
        PARAMS, x0, 12.0, 0.05, observation=obs, method="verlet", damping=DAMPING, device="cpu", layout=layout
    )
    values, env, x = reference.observe("verlet", PARAMS, x0, run.dt, run.nsteps, obs, damping=DAMPING)
    assert np.array_equal(run.x, x)
    assert np.array_equal(run["peaks"], values[..., 0])
    np.testing.assert_allclose(run.values, values, rtol=1e-12, atol=1e-13)
    assert np.array_equal(run.envelope, env)
    assert run["peaks"].max() >= 2  # the test spot does break up into several peaks
    np.testing.assert_allclose(run["energy"][0], reference.model.energy(PARAMS, x0), rtol=1e-13)
    lost = run["dissipated"][-1]
    assert lost[0] == 0 and np.all(lost[1:] > 1e-3 * run["energy"][0, 1:])  # lattice 0 has no losses
    # energy plus what the losses took stays the initial energy, to the scheme's accuracy (what the guard checks)
    total = run["energy"] + run["dissipated"]
    np.testing.assert_allclose(total, np.broadcast_to(total[0], total.shape), rtol=2e-4)


@pytest.mark.parametrize("layout", ["thread", "block"])
def test_zero_damping_observe_is_simulate_bit_for_bit(layout):
    x0 = _spots(2)
    obs = Observation(frame_every=8, threshold=0.05)
    run = observe(
        PARAMS, x0, 4.0, 0.05, observation=obs, method="yoshida4", device="cpu", damping=(0.0, 0.0), layout=layout
    )
    plain = simulate(PARAMS, x0, run.t[-1], run.dt, method="yoshida4", device="cpu", placement=Placement(layout=layout))
    assert plain.nsteps == run.nsteps and np.array_equal(run.x, plain.x)


def test_observe_is_an_option_of_simulate():
    x0 = _spots(4)
    obs = Observation(frame_every=8, threshold=0.05, lag_frames=2)
    kept = observe(PARAMS, x0, 4.0, 0.05, observation=obs, damping=DAMPING, device="cpu")
    run = simulate(PARAMS, x0, 4.0, 0.05, damping=DAMPING, device="cpu", observe=obs, guard=Guard(chunks=3))
    assert np.array_equal(run.observed.values, kept.values) and np.array_equal(run.x, kept.x)  # any chunks
    assert np.array_equal(run.observed.envelope_lag, kept.envelope_lag) and run.observed.t_lag == kept.t_lag
    assert run.nsteps == kept.nsteps and run.dt == kept.dt and run.energy_t.size == 4
    with pytest.raises(ValueError, match="exclusive"):
        simulate(PARAMS, x0, 4.0, 0.05, device="cpu", observe=obs, record=Record(every=8))
    with pytest.raises(ValueError, match="splitting"):
        simulate(PARAMS, x0, 4.0, 0.05, method="rk4", device="cpu", observe=obs)


def test_observe_never_lengthens_the_step_and_checks_the_one_it_uses():
    obs = Observation(frame_every=80)
    run = observe(PARAMS, _spots(1), 10.0, 0.1, observation=obs, device="cpu")
    assert run.dt <= 0.1 and run.nsteps % 80 == 0 and np.isclose(run.t[-1], 10.0)
    from warpchain import StepSizeError

    with pytest.raises(StepSizeError):
        observe(PARAMS, _spots(1), 10.0, 0.5, observation=Observation(frame_every=4), device="cpu")
    with pytest.raises(ValueError, match="chunks"):
        observe(PARAMS, _spots(1), 1.0, 0.05, observation=Observation(frame_every=4), device="cpu", chunks=0)
    limit = stability_limit("verlet", PARAMS)  # asked above the limit, run below it: ten steps become a frame of 80
    run = observe(PARAMS, _spots(1), 10 * limit, 1.3 * limit, observation=Observation(frame_every=80), device="cpu")
    assert run.nsteps == 80 and run.dt < limit


def test_observed_guard_bounds_energy_plus_dissipated_at_every_chunk():
    """A lattice whose energy plus what the losses took drifts past the bound stops the run at the first chunk
    where it does, with the lossy lattices named (a bound far below the scheme's error at this step)."""
    x0 = np.zeros((3, 4, 17))
    x0[:, 2, 6:11] = 0.3
    chain = ChainParams(30.0, 160.0, 17)
    damping = Damping(np.array([0.0, 0.05, 0.05]), np.array([0.0, 0.0, 0.02]))
    with pytest.raises(IntegrationError) as error:
        observe(
            chain,
            x0,
            40.0,
            0.2,
            observation=Observation(frame_every=10),
            damping=damping,
            device="cpu",
            chunks=4,
            max_energy_error=2e-4,
        )
    assert error.value.failed == [0, 1, 2] and error.value.t == pytest.approx(10.0)


def test_peaks_and_tracks():
    env = np.zeros((1, 40))
    env[0, 5], env[0, 6], env[0, 7] = 0.2, 0.5, 0.3  # one peak, off-centre to the left of 6.5
    env[0, 20], env[0, 21] = 0.4, 0.4  # a plateau counts once (its left site)
    env[0, 25] = 0.01  # below threshold
    env[0, 30:38] = [0.3, 0.32, 0.33, 0.34, 0.33, 0.32, 0.31, 0.3]  # a wide hump: not localized
    mask = peak_mask(env, 0.05, 2, contrast=0.5)
    assert mask.sum() == 2 and mask[0, 6] and mask[0, 20]
    assert peak_mask(env, 0.05, 2, contrast=1.0)[0, 33]  # without the localization test the hump counts
    moved = np.roll(env, 2, axis=-1)
    obs = Observation(frame_every=1, threshold=0.05, radius=2, contrast=0.5)
    assert np.isnan(peak_tracks(env, moved, 4.0, obs, max_speed=0.25)[2]).all()  # 2 sites > 0.25 x 4
    position, amplitude, velocity = (v[0] for v in peak_tracks(env, moved, 4.0, obs, max_speed=1.0, max_peaks=4))
    assert np.isfinite(position).sum() == 2 and np.isnan(position[2:]).all()
    np.testing.assert_allclose(velocity[:2], 0.5)  # two sites in four time units
    assert 7.5 < position[0] < 8.5 and amplitude[0] == 0.5
    # a peak that appears within the lag is not given a neighbour's motion
    born = moved.copy()
    born[0, 12] = 0.45
    p, _, v = (a[0] for a in peak_tracks(env, born, 4.0, obs, max_speed=1.0, max_peaks=4))
    assert np.isfinite(p).sum() == 3 and np.isnan(v[1])  # the new peak at 12 has no mutual match


@pytest.mark.parametrize("layout", ["thread", "block"])
def test_a_kept_runner_follows_its_losses(layout):
    # a pooled runner (on a GPU, kept between simulate calls) keeps its Lattice structs while the losses' arrays stay:
    # losses on, off, other rates and on again must each give the reference's bits
    from warpchain.engine.runner import _Runner
    from warpchain.integrators import get_method
    from warpchain.model import per_lattice_parameters

    x0, dt, n = _spots(4), 0.05, 20
    M, K = per_lattice_parameters(PARAMS, 4, None, None)
    runner = _Runner(get_method("kahan6"), PARAMS, x0, M, K, "cpu", layout=layout)
    other = Damping(np.array([0.03, 0.0, 0.0, 0.01]), np.array([0.0, 0.02, 0.0, 0.0]))
    for damping in (None, DAMPING, None, other, DAMPING):
        runner.upload(x0)
        runner.set_damping(damping, dt)
        runner.launch(n, dt)
        ref = reference.integrate("kahan6", PARAMS, x0, dt, n, damping=damping)["x"]
        assert np.array_equal(runner.download(), ref), damping
