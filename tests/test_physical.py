"""The continuous surface-wave model and the fit of M, K (warpchain.physical)."""

import math

import numpy as np
import pytest

from warpchain import dispersion
from warpchain import physical as ph

MAT = ph.SILICA_SPHERES_ON_GLASS


@pytest.fixture(scope="module")
def model():
    return MAT.surface_model()


def test_wave_speeds_and_rayleigh_speed():
    c_L, c_T = ph.wave_speeds(70e9, 0.22, 2500.0)
    assert math.isclose(c_L**2 / c_T**2, 2 * (1 - 0.22) / (1 - 2 * 0.22), rel_tol=1e-12)
    c_R = ph.rayleigh_speed(c_L, c_T)
    # Viktorov's approximation xi_R ~ (0.87 + 1.12 nu) / (1 + nu), good to ~0.5%
    assert math.isclose(c_R / c_T, (0.87 + 1.12 * 0.22) / 1.22, rel_tol=5e-3)
    assert abs(ph.rayleigh_function(c_R / c_T, c_T / c_L)) < 1e-13
    # incompressible limit: xi_R^2 is the root of xi^6 - 8 xi^4 + 24 xi^2 - 16 = 0, xi_R = 0.955313
    assert math.isclose(ph.rayleigh_speed(1e6, 1.0), 0.9553, rel_tol=1e-4)
    with pytest.raises(ValueError):
        ph.wave_speeds(70e9, 0.5, 2500.0)
    with pytest.raises(ValueError):
        ph.rayleigh_speed(1.0, 2.0)


@pytest.mark.parametrize("which", ["lower", "upper"])
def test_roots_satisfy_the_boundary_condition_determinant(model, which):
    k_T, _ = model.transverse_line_crossing()
    k = np.linspace(0.05, 3.0, 25) * k_T
    omega = model.branch(k, which)
    found = np.isfinite(omega)
    # the upper branch exists only beyond the c_T crossing k_T: 17 of these 25 wavenumbers
    assert found.sum() == (17 if which == "upper" else 25)
    for kk, w in zip(k[found], omega[found]):
        A = model.boundary_matrix(w, kk)
        scale = np.prod(np.linalg.norm(A, axis=1))
        assert abs(np.linalg.det(A)) <= 1e-12 * scale
        # and a nearby frequency is clearly not a root (the test has teeth)
        assert abs(np.linalg.det(model.boundary_matrix(w * (1 + 1e-5), kk))) > 1e-7 * scale
    if which == "lower":
        assert np.all(omega < model.omega0) and np.all(omega < model.c_R * k)
    else:
        # between the c_R and c_T lines, above w_0; absent (leaky) below the c_T crossing
        assert np.all(omega[found] > model.omega0)
        assert np.all((omega[found] > model.c_R * k[found]) & (omega[found] <= model.c_T * k[found] * (1 + 1e-12)))
        assert not np.isfinite(model.branch([0.99 * k_T], "upper")[0])


def test_upper_branch_meets_the_transverse_line_at_the_closed_form_point(model):
    k_T, omega_T = model.transverse_line_crossing()
    w = model.branch([k_T * (1 + 1e-9)], "upper")[0]
    assert math.isclose(w, omega_T, rel_tol=1e-6)


def test_long_wave_limit_is_the_rayleigh_speed(model):
    k = np.array([1e-5, 1e-4]) * model.omega0 / model.c_R
    deviation = np.abs(model.branch(k, "lower") / k / model.c_R - 1.0)
    assert deviation[0] < 1e-6
    assert 8 < deviation[1] / deviation[0] < 12  # the resonators' correction is O(k)
    # without resonators the relation is the Rayleigh equation at every k
    bare = ph.SurfaceResonatorModel(model.c_L, model.c_T, model.rho, 1e-30, model.omega0, model.cell_area)
    k = np.array([0.1, 0.5, 0.9]) * model.omega0 / model.c_R
    assert np.allclose(bare.branch(k, "lower") / k, model.c_R, rtol=1e-9)


@pytest.mark.parametrize("M, K", [(30.0, 160.0), (5.0, 20.0), (80.0, 1000.0)])
def test_fit_recovers_known_M_K_from_discrete_curves(M, K):
    omega0, D = 2 * math.pi * 215e6, 1e-6
    speed = ph.discrete_long_wave_speed(M, K, omega0, D)
    # the "c_T line" of these synthetic curves: 8% faster than the long-wave speed
    line = 1.08 * speed
    q = __import__("scipy.optimize", fromlist=["brentq"]).brentq(
        lambda q: dispersion(q, M, K)[1] * omega0 - line * q / D, 1e-6, math.pi
    )
    k_star = q / D
    fit = ph.fit_chain(speed, k_star, line * k_star, omega0, D)
    assert math.isclose(fit.M, M, rel_tol=1e-9) and math.isclose(fit.K, K, rel_tol=1e-9)
    assert fit.speed_residual < 1e-12 and fit.crossing_residual < 1e-12
    # the paper's slope convention (K/M) gives a different, wrong answer for the same curves
    paper = ph.fit_chain(speed, k_star, line * k_star, omega0, D, convention="paper")
    assert abs(paper.M / M - 1) > 1e-3


def test_fit_to_the_example_material_lands_near_the_paper():
    fit = ph.fit_to_substrate(MAT)
    paper = ph.fit_to_substrate(MAT, convention="paper")
    assert 20 < fit["M"] < 60 and 100 < fit["K"] < 350
    assert 20 < paper["M"] < 45 and 100 < paper["K"] < 250
    assert fit["residual"] < 1e-12
    assert fit["lower_branch_misfit"] < 0.1
    # exact slope: K/(M+1) = (c_R / (w0 D))^2
    assert math.isclose(fit["K"] / (fit["M"] + 1), (fit["c_R"] / (fit["omega0"] * MAT.diameter)) ** 2, rel_tol=1e-12)


@pytest.mark.parametrize("D, E, nu, w, lam", [(1e-6, 73e9, 0.17, 0.02, 10.0), (2e-6, 5e9, 0.3, 0.1, 7.0)])
def test_appendix_b_estimate_is_the_papers_closed_form_for_one_material(D, E, nu, w, lam):
    # Appendix B's K = k1 / k2 from the Hertz-DMT contact equals the paper's closed form when sphere and
    # substrate are of one material (the closed form assumes that)
    estimate = ph.estimate_stiffness_ratio(D, E, nu, E, nu, w, lam)
    assert math.isclose(estimate, ph.stiffness_ratio_closed_form(D, E, nu, w, lam), rel_tol=1e-13)
    assert not math.isclose(estimate, ph.estimate_stiffness_ratio(D, E, nu, 2 * E, nu, w, lam), rel_tol=1e-3)


def test_fit_errors_are_clear():
    with pytest.raises(ValueError, match="Brillouin"):
        ph.fit_chain(3000.0, 5e6, 1e9, 1e9, 1e-6)
    with pytest.raises(ValueError, match="no K"):
        ph.fit_chain(3000.0, 4e5, 0.5 * 1.35e9, 1.35e9, 1e-6)  # below every optical branch
    with pytest.raises(ValueError):
        MAT.replace(diameter=-1.0)
    with pytest.raises(ValueError):
        ph.SurfaceResonatorModel(1000.0, 2000.0, 1.0, 1.0, 1.0, 1.0)
