import math

import numpy as np
import pytest

import continuation as ct
from warpchain import ChainParams, dispersion, linear_modes, simulate


@pytest.fixture(scope="module")
def chain():
    return ChainParams(30.0, 160.0, 41)


@pytest.fixture(scope="module")
def breather(chain):
    return ct.require(ct.find_breather(chain, 1.01, ct.nls_seed(chain, 1.01)))


# ----------------------------------------------------------------------------- seeds


def test_anticontinuum_orbit_has_the_requested_frequency_and_conserves_energy():
    M = 30.0
    orbit = ct.anticontinuum_orbit(1.01, M)
    assert orbit.period == pytest.approx(2 * math.pi / 1.01, rel=1e-10)
    assert ct.oscillator_frequency(orbit.z_max, M) == pytest.approx(1.01, rel=1e-10)
    assert orbit.z_min < 0 < orbit.z_max and orbit.z_max < -orbit.z_min  # softening: asymmetric
    w0sq = (1 + M) / M
    potential = lambda z: (4 * (1 + M) / (15 * M)) * ((1 + z) ** 2.5 - 2.5 * z)  # noqa: E731
    assert potential(orbit.z_max) == pytest.approx(potential(orbit.z_min), rel=1e-9)
    with pytest.raises(ValueError, match="w0"):
        ct.anticontinuum_orbit(math.sqrt(w0sq) + 1e-3, M)


@pytest.mark.parametrize("kind", ["site", "bond-in-phase", "bond-out-of-phase"])
def test_anticontinuum_seeds(kind):
    p = ChainParams(30.0, 0.01, 21)
    x = ct.anticontinuum_seed(p, 1.01, kind)
    excited = np.flatnonzero(np.abs(x[0] - x[1]) > 0)
    assert list(excited) == ([10] if kind == "site" else [10, 11])
    assert np.allclose(p.M * x[0] + x[1], 0.0) and np.all(x[2:] == 0)
    if kind == "bond-out-of-phase":
        assert (x[0, 10] - x[1, 10]) * (x[0, 11] - x[1, 11]) < 0


def test_nls_coefficients_checked_against_dispersion_and_oscillator():
    M, K = 30.0, 160.0
    D, G = ct.nls_coefficients(M)
    w0 = math.sqrt((M + 1) / M)
    # D: d(w^2)/d(k^2) of the optical band at k = 0, with k^2 = K q^2
    q = 1e-3
    _, w_op = dispersion(np.array([q]), M, K)
    assert (w_op[0] ** 2 - w0**2) / (K * q * q) == pytest.approx(D, rel=1e-5)
    # G: a uniform oscillation of amplitude a = 2|A| shifts the frequency by nu = G a^2 / (8 w0)
    a = 0.01
    nu = w0 - ct.oscillator_frequency(a, M)
    assert 8 * w0 * nu / a**2 == pytest.approx(G, rel=1e-2)


def test_nls_profile_approaches_the_breather_near_the_band_edge():
    p = ChainParams(30.0, 160.0, 101)
    diffs = []
    for omega in (1.016, 1.014):
        b = ct.require(ct.find_breather(p, omega, ct.nls_seed(p, omega)))
        diffs.append(np.max(np.abs(b.state[:2] - ct.nls_seed(p, omega)[:2])) / np.max(np.abs(b.state[1])))
    assert diffs[0] < 0.05 and diffs[0] < diffs[1]


def test_eigenmode_seed_scaling():
    p = ChainParams(30.0, 160.0, 41)
    x = ct.eigenmode_seed(p, 0.02)
    assert abs(x[1, 20]) == pytest.approx(0.02) and np.all(x[2:] == 0)


# ----------------------------------------------------------------------------- shooting


def test_newton_converges_quadratically(breather):
    h = breather.residual_history
    assert breather.residual <= 1e-10 and breather.iterations <= 6
    tail = [(a, b) for a, b in zip(h[:-1], h[1:]) if a < 1e-2]
    assert len(tail) >= 2
    for a, b in tail:
        assert b <= 100 * a * a, h  # the residual roughly squares each iteration
    assert breather.min_contact > 0


def test_breather_is_periodic_under_direct_simulation(chain, breather):
    run = simulate(chain, breather.state, 20 * breather.period, breather.dt, method=breather.method, device="cpu")
    assert np.max(np.abs(run.x[0] - breather.state)) < 1e-8


def test_general_formulation_and_finite_difference_jacobian_agree(chain, breather):
    seed = breather.state.copy()
    seed[:2] += 1e-5  # positions only: the phase condition then pins the same phase (turning point)
    general = ct.require(ct.find_breather(chain, 1.01, seed, formulation="general"))
    assert general.energy == pytest.approx(breather.energy, rel=1e-8)
    assert np.max(np.abs(general.state - breather.state)) < 1e-8
    fd = ct.require(ct.find_breather(chain, 1.01, ct.nls_seed(chain, 1.01), jacobian="finite-difference"))
    assert np.max(np.abs(fd.state - breather.state)) < 1e-9


def test_collapse_to_rest_is_reported_not_returned(chain):
    r = ct.find_breather(chain, 1.01, 1e-3 * ct.nls_seed(chain, 1.01))
    assert not r.success and r.status is ct.ShootingStatus.TRIVIAL
    assert "rest state" in r.message
    with pytest.raises(ct.ShootingError, match="rest state"):
        ct.require(r)


def test_failure_in_the_acoustic_band_says_where_omega_is(chain):
    r = ct.find_breather(chain, 0.995, ct.nls_seed(chain, 1.01), max_iterations=4)
    assert not r.success and "acoustic band" in r.message and "What to do" in r.message


def test_bad_arguments(chain):
    seed = ct.nls_seed(chain, 1.01)
    with pytest.raises(ValueError, match="formulation"):
        ct.find_breather(chain, 1.01, seed, formulation="x")
    with pytest.raises(ValueError, match="omega"):
        ct.find_breather(chain, -1.0, seed)
    with pytest.raises(ValueError, match="jacobian"):
        ct.find_breather(chain, 1.01, seed, jacobian="autodiff")


# ----------------------------------------------------------------------------- Floquet


def test_floquet_of_the_breather(breather):
    fl = ct.floquet(breather)
    assert len(fl.multipliers) == 4 * breather.params.N
    assert np.all(np.abs(fl.multipliers[fl.trivial] - 1) < 1e-4)
    assert fl.pairing_error < 1e-8
    assert fl.symplecticity_error < 1e-10
    assert fl.max_modulus == pytest.approx(np.max(np.abs(fl.nontrivial)))
    assert fl.stable == bool(np.all(np.abs(np.abs(fl.nontrivial) - 1) <= fl.tolerance))


def test_floquet_multipliers_of_the_rest_state_are_the_linear_modes():
    p = ChainParams(3.0, 2.0, 8)
    T = 2 * math.pi / 1.3
    n = 400
    V = ct.monodromy(p, np.zeros((4, p.N)), n, T / n, method="yoshida6")
    lam = np.linalg.eigvals(V)
    freqs, _ = linear_modes(p)
    expected = np.concatenate([np.exp(1j * freqs * T), np.exp(-1j * freqs * T)])
    for e in expected:
        assert np.min(np.abs(lam - e)) < 1e-8
    assert ct.analyse_multipliers(lam)["stable"]


def test_unstable_spectrum_is_flagged():
    lam = np.array([1.0 + 1e-7, 1.0 - 1e-7, 1.01, 1 / 1.01, np.exp(0.3j), np.exp(-0.3j)])
    info = ct.analyse_multipliers(lam)
    assert not info["stable"] and info["max_modulus"] == pytest.approx(1.01)


def test_a_tiny_seed_is_the_rest_state_not_a_breather():
    """The residual tolerance is absolute: a seed of amplitude 1e-10 met it at once and was called converged
    (E ~ 1e-15); the absolute floor (``shooting.REST_AMPLITUDE``) reports it as the rest state."""
    from continuation.shooting import ShootingStatus

    p = ChainParams(30.0, 160.0, 41)
    res = ct.find_breather(p, 1.0164, ct.eigenmode_seed(p, 1e-10), device="cpu")
    assert not res.success and res.status is ShootingStatus.TRIVIAL and "rest state" in res.message
    for bad in (float("nan"), -1.0, 0.0, 1.5):
        with pytest.raises(ValueError, match="collapse_ratio"):
            ct.find_breather(p, 1.0164, ct.eigenmode_seed(p, 1e-2), device="cpu", collapse_ratio=bad)


def test_breathers_solved_one_after_another_share_one_flow_and_its_runners():
    """``find_breather`` built from names uses one Flow per (method, steps, device) for the process, so a scan reuses
    its runners (on a GPU their captured graphs too); the Flow keeps the runners of its last POOL_KEYS shapes."""
    import continuation as ct
    from continuation.shooting import shared_flow
    from warpchain import ChainParams
    from warpchain.flow import POOL_KEYS

    p = ChainParams(30.0, 160.0, 31)
    seed = ct.nls_seed(p, 1.01)
    a = ct.find_breather(p, 1.01, seed, method="yoshida4", steps_per_period=32, device="cpu")
    b = ct.find_breather(p, 1.01, a.state, method="yoshida4", steps_per_period=32, device="cpu")
    flow = shared_flow("yoshida4", 32, "cpu")
    assert a.success and b.success and len(flow._pool) >= 1
    runners = {id(r) for slot in flow._pool.values() for r in slot["runners"]}
    ct.find_breather(p, 1.01, b.state, method="yoshida4", steps_per_period=32, device="cpu")
    assert {id(r) for slot in flow._pool.values() for r in slot["runners"]} == runners  # reused, not rebuilt
    for n in range(33, 33 + 2 * (POOL_KEYS + 1), 2):  # more shapes than it keeps: the oldest go
        q = ChainParams(30.0, 160.0, n)
        ct.find_breather(q, 1.01, ct.nls_seed(q, 1.01), method="yoshida4", steps_per_period=32, device="cpu")
    assert len(flow._pool) <= POOL_KEYS
