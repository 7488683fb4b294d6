"""continuation.newton.solve_linear: LU when J is square and well conditioned, least squares otherwise."""

import numpy as np
import pytest
import scipy.linalg

from continuation.newton import solve_linear


def _orthogonal(rng, n):
    return np.linalg.qr(rng.standard_normal((n, n)))[0]


def _conditioned(rng, n, cond):
    return (_orthogonal(rng, n) * np.logspace(0, -np.log10(cond), n)) @ _orthogonal(rng, n).T


@pytest.mark.parametrize("layout", ["C", "F", "row block"])
def test_well_conditioned_matches_numpy(layout):
    rng = np.random.default_rng(0)
    n = 60
    J = _conditioned(rng, n, 1e3)
    if layout == "F":
        J = np.asfortranarray(J)
    elif layout == "row block":  # as the reversible Jacobian: velocity rows of an F-ordered column block
        block = np.asfortranarray(rng.standard_normal((2 * n, n)))
        block[n:] = J
        J = block[n:]
    J_before = J.copy()
    r = rng.standard_normal(n)
    x, used_lstsq = solve_linear(J, r)
    expected = np.linalg.solve(J, r)
    assert not used_lstsq
    assert np.linalg.norm(x - expected) <= 1e-12 * np.linalg.norm(expected)
    np.testing.assert_array_equal(J, J_before)  # J is not overwritten


def test_several_right_hand_sides():
    rng = np.random.default_rng(1)
    J, R = _conditioned(rng, 20, 10.0), rng.standard_normal((20, 3))
    X, used_lstsq = solve_linear(J, R)
    assert not used_lstsq and X.shape == (20, 3)
    np.testing.assert_allclose(X, np.linalg.solve(J, R), rtol=1e-12, atol=0)


@pytest.mark.parametrize("how", ["repeated column", "zero row and column"])
def test_singular_falls_back_to_least_squares(how):
    rng = np.random.default_rng(2)
    J = rng.standard_normal((30, 30))
    if how == "repeated column":  # singular up to round-off: caught by the condition estimate
        J[:, 7] = J[:, 3]
    else:  # exactly singular, getrf finds a zero pivot; with the column zeroed too, the singular value is
        J[11] = J[:, 11] = 0.0  # exactly 0, so lstsq's own cutoff cannot keep it (a zero row alone: ~1e-16)
    r = rng.standard_normal(30)
    x, used_lstsq = solve_linear(J, r)
    assert used_lstsq
    expected = np.linalg.lstsq(J, r, rcond=None)[0]  # the minimum-norm least-squares solution
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12)
    # it is a least-squares solution: the residual is orthogonal to the range of J
    assert np.linalg.norm(J.T @ (J @ x - r)) <= 1e-10 * np.linalg.norm(J) * np.linalg.norm(r)


def test_ill_conditioned_falls_back_like_scipy_solve_warns():
    rng = np.random.default_rng(3)
    J, r = _conditioned(rng, 30, 1e18), rng.standard_normal(30)
    with pytest.warns(scipy.linalg.LinAlgWarning):
        scipy.linalg.solve(J, r)
    x, used_lstsq = solve_linear(J, r)
    assert used_lstsq
    np.testing.assert_allclose(x, scipy.linalg.lstsq(J, r)[0], rtol=1e-12, atol=0)


@pytest.mark.parametrize("shape", [(31, 30), (29, 30)])
def test_non_square_uses_least_squares(shape):
    rng = np.random.default_rng(4)
    J, r = rng.standard_normal(shape), rng.standard_normal(shape[0])
    x, used_lstsq = solve_linear(J, r)
    assert used_lstsq and x.shape == (shape[1],)
    np.testing.assert_allclose(x, np.linalg.lstsq(J, r, rcond=None)[0], rtol=1e-10, atol=1e-13)
