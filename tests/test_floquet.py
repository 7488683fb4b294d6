import warnings

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

import continuation as ct
from continuation.floquet import multipliers_from_mu, reduced_matrix
from warpchain import ChainParams, Flow, ReferenceFlow


@pytest.fixture(scope="module")
def breather():
    p = ChainParams(30.0, 160.0, 41)
    return ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01)))


def test_reduced_floquet_agrees_with_the_full_monodromy(breather):
    red = ct.floquet(breather)
    full = ct.floquet(breather, reduced=False)
    assert red.path == "reduced" and full.path == "full"
    assert abs(red.max_modulus - full.max_modulus) < 1e-10
    # every multiplier matched (the full eig splits the trivial Jordan pair by ~sqrt(eps))
    cost = np.abs(red.multipliers[:, None] - full.multipliers[None, :])
    r, c = linear_sum_assignment(cost)
    assert np.sort(cost[r, c])[-3] < 1e-9
    assert red.stable == full.stable
    # the trivial mu is 1 to the accuracy gauge, and the tolerance comes from the measured gauges
    assert abs(red.mu[red.mu_trivial] - 1) == pytest.approx(red.accuracy["trivial_deviation"])
    assert red.tolerance == pytest.approx(
        10 * max(red.accuracy["trivial_deviation"], red.accuracy["symplecticity"], 1e-13)
    )


def test_reduced_matrix_of_a_harmonic_rotation():
    # one site, no coupling, rotation by theta: mu = cos(2 theta); Krein signature sign(sin w T)
    theta, w = 0.7, 1.3
    A = np.array([[np.cos(theta), np.sin(theta) / w], [-w * np.sin(theta), np.cos(theta)]])
    # embed as N = 1 with two masses (u: M, v: 1), identical decoupled rotations
    A4 = np.zeros((4, 4))
    A4[np.ix_([0, 2], [0, 2])] = A
    A4[np.ix_([1, 3], [1, 3])] = A
    mu = np.linalg.eigvals(reduced_matrix(A4, 2.0))
    assert np.allclose(mu, np.cos(2 * theta))
    lam = multipliers_from_mu(mu)
    assert np.allclose(np.abs(lam), 1.0)


def test_reduced_floquet_on_the_reference_flow_is_bit_for_bit_the_warp_one(breather):
    ref = ct.floquet(breather, flow=ReferenceFlow("kahan8", 32))
    warp = ct.floquet(breather, flow=Flow("kahan8", 32, "cpu"))
    assert np.array_equal(np.sort_complex(ref.mu), np.sort_complex(warp.mu))


def test_floquet_refuses_misuse(breather):
    p = breather.params
    failed = ct.find_breather(p, 1.01, np.zeros((4, p.N)) + 1e-12, max_iterations=1)
    assert not failed.success
    with pytest.raises(ValueError, match="failed solve"):
        ct.floquet(failed)
    with pytest.raises(TypeError, match="ShootingResult"):
        ct.floquet("b")
    with pytest.raises(ValueError, match="tolerance"):
        ct.floquet(breather, tolerance=-1.0)
    with pytest.raises(ValueError, match="reduced"):
        ct.floquet(breather, method="rk4", reduced=True)


def test_the_full_path_takes_every_column_of_the_monodromy(breather, monkeypatch):
    """The full path's monodromy is dense (one tangent run per unit direction), also where a linearization would
    probe colour groups (``PROBE_MIN_SITES``, lowered here to the test's chain), and its count says so."""
    import warpchain.flow

    full = ct.floquet(breather, reduced=False)
    monkeypatch.setattr(warpchain.flow, "PROBE_MIN_SITES", 10)
    again = ct.floquet(breather, reduced=False)
    assert again.stats["tangent_columns"] == full.stats["tangent_columns"] == 4 * breather.params.N
    assert np.array_equal(again.multipliers, full.multipliers)


def test_another_method_re_converges_the_orbit_with_a_warning(breather):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fl = ct.floquet(breather, method="yoshida6")
    assert any("re-converged" in str(w.message) for w in caught)
    assert fl.max_modulus == pytest.approx(ct.floquet(breather).max_modulus, abs=1e-5)


def test_instabilities_carry_kind_and_localization(breather):
    fl = ct.floquet(breather)
    for inst in fl.instabilities:
        assert inst.kind in ("real_pair", "period_doubling", "complex_quadruplet")
        assert inst.modulus > 1 and 1 <= inst.participation <= breather.params.N
    assert fl.stable == (not fl.instabilities)


def test_a_non_symplectic_map_gives_no_verdict_unless_asked(breather):
    with pytest.raises(ValueError, match="ReferenceFlow"):  # RK4 is not on the Warp engine: the error says where
        ct.floquet(breather, method="rk4")
    ref = ReferenceFlow(breather.method, breather.flow.steps_per_period)
    with pytest.warns(RuntimeWarning, match="re-converged"), pytest.raises(ValueError, match="far from symplectic"):
        ct.floquet(breather, method="rk4", flow=ref)  # re-converged with rk4, then the full path: pairing error ~0.1
    with pytest.warns(RuntimeWarning, match="re-converged"):
        coarse = ct.floquet(breather, method="rk4", tolerance=2.0, flow=ref)  # explicitly accepted
    assert coarse.path == "full" and coarse.tolerance == 2.0


def test_parity_blocks_split_the_reduced_problem_exactly(breather):
    from continuation.floquet import _expand, half_period_map, parity_blocks, reduced_products, vector_parity

    fl = ct.floquet(breather)
    A = half_period_map(breather.linearization(breather.flow))
    M = breather.params.M
    Mu, sympl, P = reduced_products(A, M)
    blocks = parity_blocks(A, M)
    assert [b.parity for b in blocks] == [1, -1] and sum(len(b.mu) for b in blocks) == Mu.shape[0]
    mu = np.concatenate([b.mu for b in blocks])
    vec = np.hstack([_expand(b.vectors, b.basis, Mu.shape[0]) for b in blocks])
    parity = np.concatenate([np.full(len(b.mu), b.parity) for b in blocks])
    full = np.linalg.eigvals(Mu)
    r, c = linear_sum_assignment(np.abs(mu[:, None] - full[None, :]))
    assert np.max(np.abs(mu[r] - full[c])) < 1e-11
    # each eigenvector is exactly even or odd, and an eigenvector of the whole Mu
    assert np.array_equal(vector_parity(vec, threshold=1 - 1e-12), parity)
    assert np.max(np.abs(Mu @ vec - vec * mu)) < 1e-11
    # the blocks' Krein forms and gauges are those of the whole problem, restricted
    a = np.real(vec)
    whole = np.sum(a * (P @ a), axis=0)
    per_block = np.concatenate([np.sum(np.real(b.vectors) * (b.P @ np.real(b.vectors)), axis=0) for b in blocks])
    assert np.allclose(per_block, whole, rtol=1e-9, atol=1e-12 * np.max(np.abs(whole)))
    assert max(b.symplecticity for b in blocks) <= 2 * sympl + 1e-15
    # the Floquet result uses them: parity known for every multiplier of a symmetric orbit
    assert np.all(fl.parity != 0) and fl.spectral is not None and fl.spectral.parities == (1, -1)
    # an orbit that is not mirror-symmetric: no split
    rng = np.random.default_rng(1)
    assert parity_blocks(A + 1e-6 * rng.standard_normal(A.shape), M) is None


def test_fused_products_equal_the_separate_reduced_matrix_symplecticity_and_signature(breather):
    from continuation.floquet import half_map_symplecticity, half_period_map, reduced_products

    A = half_period_map(breather.linearization(breather.flow))
    M = breather.params.M
    Mu, sympl, P = reduced_products(A, M)
    ref = reduced_matrix(A, M)
    assert np.max(np.abs(Mu - ref)) <= 1e-13 * np.max(np.abs(ref))
    assert sympl == pytest.approx(half_map_symplecticity(A, M), rel=0.2, abs=1e-15)  # a max of round-off
    n2 = A.shape[0] // 2
    m = np.concatenate([np.full(n2 // 2, M), np.ones(n2 // 2)])
    a = np.random.default_rng(0).standard_normal((n2, 5))
    act = np.sum((A[:n2, :n2] @ a) * m[:, None] * (A[n2:, :n2] @ a), axis=0)
    assert np.allclose(np.sum(a * (P @ a), axis=0), act, rtol=1e-10, atol=1e-12 * np.max(np.abs(act)))


def test_a_tolerance_must_be_a_real_number():
    """``floquet(tolerance=True)`` read as 1.0 (every point stable); NaN and negative values are refused too."""
    p = ChainParams(30.0, 160.0, 21)
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu"))
    for bad in (True, float("nan"), -1e-9, "1e-9"):
        with pytest.raises(ValueError, match="tolerance"):
            ct.floquet(b, tolerance=bad)
    assert ct.floquet(b, tolerance=1e-9).tolerance == 1e-9
