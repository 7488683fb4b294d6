"""Branch points: the locator and the switcher on a closed-form pitchfork, then on breathers."""

from __future__ import annotations

import math

import numpy as np
import pytest

import warpchain as wc
from continuation import anticontinuum_seed, find_breather
from continuation import bifurcation as bf
from continuation.floquet import energy_centre
from continuation.newton import NewtonSettings, newton
from warpchain.reference import solve_ivp_reference

# ----------------------------------------------------------------------------- a known pitchfork
#
# x = (a, b), reflection a <-> b; s = (a + b)/2 (even), d = (a - b)/2 (odd):
#   F_s = s - 1 - d^2 / 2,   F_d = d (p - P0 - d^2),   F = (F_s + F_d, F_s - F_d)  (equivariant).
# Symmetric branch: d = 0, s = 1 for every p; its odd Jacobian block is p - P0, zero at p = P0.
# The new branch: d^2 = p - P0, s = 1 + d^2 / 2, so its distance from (1, 1) is ~ sqrt(2 (p - P0)).

P0 = 0.3


def _toy_residual(y):
    a, b, p = y
    s, d = 0.5 * (a + b), 0.5 * (a - b)
    fs, fd = s - 1.0 - 0.5 * d * d, d * (p - P0 - d * d)
    return np.array([fs + fd, fs - fd])


def _toy_jacobian(y):
    """dF/d(a, b, p), shape (2, 3)."""
    a, b, p = y
    d = 0.5 * (a - b)
    dfs = np.array([0.5 - 0.5 * d, 0.5 + 0.5 * d, 0.0])  # d/d(a, b, p) of F_s (dd/da = 1/2, dd/db = -1/2)
    g = p - P0 - 3 * d * d
    dfd = np.array([0.5 * g, -0.5 * g, d])
    return np.vstack([dfs + dfd, dfs - dfd])


class _ToyPoint:
    def __init__(self, y, y_pred, tau):
        self.y, self.row = y, tau
        self.residual = np.append(_toy_residual(y), tau @ (y - y_pred))

    def jacobian(self):
        return np.vstack([_toy_jacobian(self.y), self.row])


class _ToyCorrector:
    """The bordered Newton the switcher expects: correct(y_pred, tau) -> NewtonOutcome."""

    def correct(self, y_pred, tau):
        return newton(y_pred, lambda y: _ToyPoint(y, y_pred, tau), NewtonSettings(tol=1e-13, max_iterations=30))


def _odd_test(p):
    """Odd-block eigenvalue of the Jacobian on the symmetric branch, and its eigenvector."""
    J = _toy_jacobian(np.array([1.0, 1.0, p]))[:, :2]
    odd = np.array([1.0, -1.0]) / math.sqrt(2.0)
    return float(odd @ J @ odd), odd


def test_locate_zero_is_superlinear_and_refuses_a_bracket_without_sign_change():
    loc = bf.locate_zero(lambda x: (math.cos(x), None), 1.0, 2.0, atol=1e-13)
    assert loc.converged and abs(loc.value - math.pi / 2) < 1e-12
    assert loc.evaluations <= 12
    with pytest.raises(ValueError, match="no sign change"):
        bf.locate_zero(lambda x: (x * x + 1.0, None), -1.0, 1.0)


def test_detector_and_switcher_on_a_known_pitchfork():
    ps = np.linspace(-0.5, 1.0, 7)  # a coarse symmetric "branch"
    tests = [_odd_test(p)[0] for p in ps]
    found = bf.brackets(list(range(len(ps))), lambda i: np.sign(tests[i]))
    assert len(found) == 1
    i, j = found[0]
    loc = bf.locate_zero(_odd_test, ps[i], ps[j], atol=1e-14)
    assert abs(loc.value - P0) < 1e-12  # located to 1e-12 (the target for breathers is 1e-6 relative)
    phi = loc.payload
    y_star = np.array([1.0, 1.0, loc.value])
    amplitudes = (1e-3, 2e-3, 4e-3, 8e-3)
    outcomes = bf.switch_branch(_ToyCorrector(), y_star, phi, amplitudes)
    offsets, distances = [], []
    for amp, out in zip(amplitudes, outcomes):
        assert out.success
        a, b, p = out.unknowns
        d = 0.5 * (a - b)
        assert abs(d - amp / math.sqrt(2.0)) < 1e-12  # the constraint <phi, x - x*> = amp
        assert abs(p - (P0 + d * d)) < 1e-12  # on the closed-form branch
        assert abs(0.5 * (a + b) - (1.0 + 0.5 * d * d)) < 1e-12
        offsets.append(p - P0)
        distances.append(math.hypot(a - 1.0, b - 1.0))
    slope = np.polyfit(np.log(offsets), np.log(distances), 1)[0]
    assert abs(slope - 0.5) < 1e-3  # new solutions, at a distance ~ sqrt(p - p*)


def test_suspect_steps_sees_a_window_inside_one_step():
    """mu - 1 of the pinning mode = 1e-4 - (log10 K - 1.05)^2: negative at every sampled point, positive in
    a window of width 0.02 inside the step (1.0, 1.1): the parabola through the neighbours finds it."""
    from types import SimpleNamespace

    def point(c):
        f = 1e-4 - (c - 1.05) ** 2
        return SimpleNamespace(
            K=10.0**c,
            mu=np.array([1.0, 1.0 + f, 0.5]),  # trivial, pinning (odd, 5 sites), a phonon
            parity=np.array([1, -1, -1]),
            participation=np.array([100.0, 5.0, 80.0]),
            central_weight=np.array([0.05, 0.9, 0.02]),
        )

    points = [point(c) for c in (0.8, 0.9, 1.0, 1.1, 1.2)]
    assert all(bf.pinning_value(p, -1) < 0 for p in points)
    steps = bf.suspect_steps(points, -1)
    assert len(steps) == 1 and steps[0][:2] == (2, 3) and abs(steps[0][2] - 1.05) < 1e-9


# ----------------------------------------------------------------------------- breathers


@pytest.fixture(scope="module")
def small_site_family():
    """Site- and bond-centred breathers of a 61-site chain (localized: participation below 6 sites)
    around their first exchange of stability."""
    M, omega, N = 30.0, 1.01, 61
    flow = wc.Flow("kahan8", 32)
    out = {}
    for kind, symmetric in (("site", True), ("bond-in-phase", False)):
        p = wc.ChainParams(M, 0.01, N)
        x = anticontinuum_seed(p, omega, kind)
        pts = []
        for K in (0.01, 0.3, 2.0, 5.0, 7.0, 8.5, 9.5):
            res = find_breather(p.replace(K=K), omega, x, flow=flow, symmetric=symmetric)
            assert res.success, res.message
            x = res.state
            pts.append(res)
        out[kind] = pts
    return M, omega, N, flow, out


def _as_points(results):
    """BranchPoints of shooting results (what the detector reads)."""
    from continuation.driver import Solution, analyse

    return [
        analyse(Solution(r.params, r.omega, r.state, r.iterations, r.residual_history, r.linearization(), 0.0))
        for r in results
    ]


def test_site_pitchfork_is_located_switched_and_the_new_orbits_are_breathers(small_site_family):
    M, omega, N, flow, fams = small_site_family
    site = _as_points(fams["site"])
    found = bf.suspect_steps(site, -1)
    assert len(found) == 1 and found[0][2] is None  # one sign change of the pinning mode's mu - 1
    assert bf.brackets(site, lambda p: bf.localized_real_pairs(p, -1)) == [found[0][:2]]
    i, j, _ = found[0]
    (bif,) = bf.locate_real_pair("site", wc.ChainParams(M, 1.0, N), omega, site[i], site[j], flow, parity=-1)
    assert bif.kind == "symmetry_breaking_pitchfork" and bif.direction == "gained"
    assert 8.5 < bif.K < 9.5 and bif.participation < 0.3 * N and bif.central_weight > 0.5
    assert abs(bif.test) < 1e-9
    # the bond family's real pair disappears at (nearly) the same coupling: an exchange of stability
    bond = _as_points(fams["bond-in-phase"])
    ((bi, bj, _),) = [step for step in bf.suspect_steps(bond) if step[2] is None]  # the one sign change
    (bond_bif,) = bf.locate_real_pair("bond-in-phase", wc.ChainParams(M, 1.0, N), omega, bond[bi], bond[bj], flow)
    assert bond_bif.direction == "lost" and abs(bond_bif.K - bif.K) < 1e-3 * bif.K
    # switching: genuinely new, asymmetric orbits on a square-root branch
    params = wc.ChainParams(M, bif.K, N)
    offsets, distances = [], []
    for amp in (0.01, 0.02, 0.04):
        (state, c, *_), _ = bf.switch_to_asymmetric(bif, params, flow, amp, tol=1e-12)
        K1 = 10.0**c
        sym = find_breather(params.replace(K=K1), omega, bif.state, flow=flow, symmetric=True)
        assert sym.success
        assert energy_centre(state) > energy_centre(bif.state) + 1e-4  # moved towards the bond
        offsets.append(abs(K1 - bif.K))
        distances.append(float(np.linalg.norm(state[:2] - sym.state[:2])))
    slope = np.polyfit(np.log(offsets), np.log(distances), 1)[0]
    assert abs(slope - 0.5) < 0.05  # K - K* ~ 3e-4 a^2: K-offsets of 4e-8 .. 5e-7
    # an independent integrator (DOP853) returns the new orbit after one period
    end, _ = solve_ivp_reference(params.replace(K=K1), state, 2 * math.pi / omega, rtol=1e-11, atol=1e-14)
    assert np.max(np.abs(end - state)) / np.max(np.abs(state[:2])) < 1e-8


def test_finite_size_check_keeps_an_intrinsic_localized_pair(small_site_family):
    M, omega, N, flow, fams = small_site_family
    last = fams["site"][-1]  # K = 9.5: past the pitchfork, the localized odd real pair
    check = bf.finite_size_check(last.params, omega, last.state, flow)
    assert check["N_new"] == 2 * N - 1
    pairs = [r for r in check["classification"] if r["kind"] == "real_pair" and r["localized"]]
    assert pairs and all(r["persists"] and r["class"] == "intrinsic" for r in pairs)
    assert abs(check["energy"][N] - check["energy"][2 * N - 1]) < 1e-9
    with pytest.raises(ValueError):
        bf.pad_chain(last.state, N + 1)
