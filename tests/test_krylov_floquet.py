"""Floquet near +1 and -1 from the probed half-period map (``floquet(solver="window")``,
``continuation.krylov_floquet``) against the dense reference on the CPU: the probe gives the 4N unit columns,
every multiplier the window reports is the dense one to 1e-12 with the same kind, Krein signature and parity,
the instabilities inside the window are the dense ones, the window gives no verdict (``stable`` None: what it saw
is ``partial_stable``), and the result says what it could not see."""

import numpy as np
import pytest

import continuation as ct
from continuation.floquet import half_period_map, multipliers_from_mu
from continuation.krylov_floquet import FloquetWindow
from warpchain.flow import PROBE_MIN_SITES
from warpchain import ChainParams


@pytest.fixture(scope="module", params=[201, 401])
def paper_breather(request):
    p = ChainParams(30.0, 160.0, request.param)
    return ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu"))


def test_the_probe_gives_the_unit_columns(paper_breather):
    b = paper_breather
    lin = b.linearization()
    probed, halfwidth = lin.probed_columns("all")
    dense = half_period_map(lin)
    assert halfwidth == 32 and lin.stats["tangent_columns"] >= 4 * 65
    assert np.max(np.abs(probed.toarray() - dense)) <= 1e-15 * np.max(np.abs(dense))
    for which in ("positions", "velocities"):
        part, _ = lin.probed_columns(which)
        assert np.max(np.abs(part.toarray() - lin.unit_columns(which))) <= 1e-15 * np.max(np.abs(dense))


def test_long_chains_get_probed_unit_columns():
    """From PROBE_MIN_SITES sites on, ``unit_columns`` (Newton's Jacobian, dense Floquet) comes from 2 (2 b + 1)
    runs per half of the state: the same columns as one run per direction."""
    p = ChainParams(30.0, 160.0, PROBE_MIN_SITES)
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu"))
    lin = b.linearization()
    before = lin.stats["tangent_columns"]
    probed = lin.unit_columns("positions")
    assert lin.stats["tangent_columns"] - before == 2 * 65
    N = p.N
    every = lin.columns(np.eye(4 * N)[: 2 * N].reshape(2 * N, 4, N))
    assert np.max(np.abs(probed - every)) <= 1e-15 * np.max(np.abs(every))


def _match(dense, krylov):
    """Index of the dense mu nearest each krylov mu, within the same parity."""
    out = []
    for m, par in zip(krylov.mu, krylov.parity):
        cand = np.flatnonzero(dense.parity == par)
        out.append(cand[np.argmin(np.abs(dense.mu[cand] - m))])
    return np.array(out)


@pytest.mark.parametrize("width", [0.0, 0.1])
def test_the_window_agrees_with_dense(paper_breather, width):
    _agree(paper_breather, width)


@pytest.mark.slow  # a few seconds: the fast set stays under 90 s on 2 cores
def test_the_window_agrees_with_dense_at_801():
    p = ChainParams(30.0, 160.0, 801)
    _agree(ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu")), 0.0)


def _agree(b, width):
    dense = ct.floquet(b, solver="dense")
    krylov = ct.floquet(b, solver="window", window=FloquetWindow(width=width))
    assert dense.complete and not krylov.complete and krylov.path == "window"
    assert krylov.stable is None and np.isnan(krylov.max_modulus) and krylov.verdict == "not decided"
    cov = krylov.coverage
    (lo_minus, hi_minus), (lo_plus, hi_plus) = cov["covered"]
    assert lo_plus <= 1.0 - width and hi_minus >= -1.0 + width and cov["parity_blocks"]
    # every reported mu is a dense one, with its kind, signature and parity
    j = _match(dense, krylov)
    assert np.max(np.abs(dense.mu[j] - krylov.mu)) <= 1e-12
    assert np.array_equal(dense.signature[j], krylov.signature)
    assert np.allclose(dense.participation[j], krylov.participation, rtol=1e-6)
    # and every dense mu inside the covered intervals and strip is reported (one off the strip may be too)
    mu = dense.mu
    inside = ((mu.real >= lo_plus) & (mu.real <= hi_plus)) | ((mu.real >= lo_minus) & (mu.real <= hi_minus))
    surely = inside & (np.abs(mu.imag) < cov["strip_half_height"])
    assert surely.sum() >= 0.9 * inside.sum() and len(krylov.mu) <= inside.sum()
    assert all(np.min(np.abs(krylov.mu - m)) <= 1e-12 for m in mu[surely])
    # the instabilities inside the window, their kinds, moduli and parities
    seen = [i for i in dense.instabilities if i.mu.real >= lo_plus or i.mu.real <= hi_minus]
    assert [i.kind for i in krylov.instabilities] == [i.kind for i in seen]
    assert [i.parity for i in krylov.instabilities] == [i.parity for i in seen]
    # multipliers within 1e-9 (the bar; l - 1 ~ sqrt(2 (mu - 1)) magnifies mu's 1e-14 near +1)
    assert np.allclose([i.modulus for i in krylov.instabilities], [i.modulus for i in seen], rtol=0, atol=1e-9)
    # (the pair (l, 1/l) of each nontrivial mu, as a set: a real mu's +-0j decides which member comes first;
    # the trivial one is the accuracy gauge, l - 1 ~ 1.7e-6 from mu - 1 ~ 1.5e-12, and is left out)
    nontrivial = np.arange(len(j)) != krylov.mu_trivial
    lam_k = multipliers_from_mu(krylov.mu[nontrivial])
    lam_d = multipliers_from_mu(dense.mu[j][nontrivial])
    assert max(float(np.min(np.abs(lam_d - lam))) for lam in lam_k) <= 1e-9
    assert krylov.partial_stable == dense.stable is False  # the localized real pair at mu = 1 + 1e-8: always seen
    assert krylov.partial_max_modulus <= dense.max_modulus + 1e-9
    assert abs(krylov.accuracy["trivial_deviation"] - dense.accuracy["trivial_deviation"]) <= 1e-13
    assert "solver='dense'" in cov["unseen"]


def test_the_paper_quadruplet_needs_the_wider_window():
    p = ChainParams(30.0, 160.0, 201)
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu"))
    narrow = ct.floquet(b, solver="window")
    wide = ct.floquet(b, solver="window", window=FloquetWindow(width=0.1))
    assert narrow.kinds == ("real_pair",)  # mu = 0.9916 lies outside the 60 nearest +1
    assert wide.kinds == ("real_pair", "complex_quadruplet") == ct.floquet(b, solver="dense").kinds


def test_solver_choices_are_checked():
    p = ChainParams(30.0, 160.0, 101)
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu"))
    assert ct.floquet(b).path == "reduced"  # auto: dense below SLICED_MIN_SITES
    with pytest.raises(ValueError, match="solver must be"):
        ct.floquet(b, solver="arnoldi")
    with pytest.raises(ValueError, match="now 'window'"):
        ct.floquet(b, solver="krylov")
    for solver in ("window", "sliced"):
        with pytest.raises(ValueError, match="reduced problem"):
            ct.floquet(b, solver=solver, reduced=False)
    with pytest.raises(ValueError, match="window="):
        ct.floquet(b, solver="dense", window=FloquetWindow())
    with pytest.raises(ValueError, match="count"):
        FloquetWindow(count=2)


def test_a_periodic_ring_is_not_probed():
    """On a ring a perturbation wraps round to the other end, where a colour group's decoding would hand it to
    the wrong site: ``probed_columns`` falls back to one run per direction there."""
    from warpchain import Flow

    p = ChainParams(30.0, 160.0, 201, boundary="periodic")
    rng = np.random.default_rng(7)
    x0 = np.zeros((4, p.N))
    x0[:2] = 1e-2 * rng.standard_normal((2, p.N))
    lin = Flow(device="cpu").linearize(p, x0, 40, 0.2)
    assert not lin.banded
    probed, halfwidth = lin.probed_columns("positions")
    every = lin.columns(np.eye(4 * p.N)[: 2 * p.N].reshape(2 * p.N, 4, p.N))
    assert halfwidth == p.N and np.array_equal(probed.toarray(), every)
    fixed = Flow(device="cpu").linearize(p.replace(boundary="fixed"), x0, 40, 0.2)
    assert fixed.banded


def test_an_outlier_beyond_the_end_discs_is_reported():
    """A strong real pair (mu = 1.3) and a period doubling (mu = -1.2) lie beyond the discs at +-1: the Arnoldi
    without shift finds them, and the merged window reports them with the discs' mu."""
    import scipy.sparse as sp

    from continuation.krylov_floquet import blocks_window

    rng = np.random.default_rng(3)
    diag = np.cos(np.sort(rng.uniform(0.0, np.pi, 400)))
    diag[[10, 390]] = 1.3, -1.2
    Mu = sp.diags(diag, format="csc")
    mu, vec, parity, cov = blocks_window(Mu, [(0, None, None)], FloquetWindow(count=20))
    assert np.min(np.abs(mu - 1.3)) < 1e-12 and np.min(np.abs(mu + 1.2)) < 1e-12
    (_, minus_inner), (plus_inner, _) = cov["covered"]
    near = diag[(diag >= plus_inner) | (diag <= minus_inner)]
    assert len(mu) == len(near) and np.allclose(np.sort(mu.real), np.sort(near))
    assert vec.shape == (400, len(mu)) and not parity.any()


def test_real_pairs_between_the_end_disc_and_the_arnoldis_reach_are_reported():
    """Beyond the first disc at +-1 (far cut 1 + 2e-4 on this spectrum) and below where the Arnoldi without shift
    converges, the outward disc at 1 + OUTWARD_SHIFT holds every eigenvalue: real pairs of |l| 1.02 .. 1.1 and a
    period doubling of the same strength are found, as the strong ones beyond, each once."""
    import scipy.sparse as sp

    from continuation.krylov_floquet import blocks_window

    rng = np.random.default_rng(4)
    diag = np.cos(np.sort(rng.uniform(0.0, np.pi, 4000)))
    extras = [1 + 5e-5, 1 + 2e-4, 1.001, 1.003, 1.006, 1.009, 1.3, -1.0008, -1.004, -1.009, -1.2]
    diag[np.linspace(100, 3900, len(extras)).astype(int)] = extras
    mu, _, _, cov = blocks_window(sp.diags(diag, format="csc"), [(0, None, None)], FloquetWindow(count=20))
    for value in extras:  # each once: 1.009 lies in the outward disc and within the Arnoldi's reach too
        assert np.sum(np.abs(mu - value) < 1e-12) == 1, value
    real = mu[mu.imag == 0]  # +0j at both ends (the multipliers' sqrt branch reads the sign of a zero)
    assert len(real) and not np.signbit(real.imag).any()
    (minus_outer, _), (_, plus_outer) = cov["covered"]
    assert plus_outer > 1.006 and minus_outer < -1.004  # contiguous out to the outward discs' far cuts


def test_the_window_does_not_depend_on_earlier_calls(paper_breather):
    """ARPACK's own starting vector is drawn afresh on every call: the window passes a fixed one, so the same orbit
    gives the same bits whatever ran before (a resumed branch, a sweep's worker) and in worker processes, as on
    long chains, where both sides run one BLAS thread (the workers always, ``window_floquet`` under
    ``blas_threads(1)``: bits are promised only with the same BLAS settings on both sides, so the in-process call
    here takes them too, whatever OPENBLAS_NUM_THREADS says); and its banded solves are LAPACK's
    ``dgbtrf``/``dgbtrs`` on the interleaved band."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from continuation.hostblas import blas_threads
    from continuation.krylov_floquet import BandedShifts, blocks_window

    first = ct.floquet(paper_breather, solver="window")
    spla.eigs(sp.diags(np.arange(1.0, 101.0)), k=3)  # advances ARPACK's seed
    again = ct.floquet(paper_breather, solver="window")
    assert np.array_equal(first.mu, again.mu) and np.array_equal(first.participation, again.participation)

    rng = np.random.default_rng(4)
    diag = np.cos(np.sort(rng.uniform(0.0, np.pi, 600)))
    diag[[50, 550]] = 1.003, -1.2
    Mu = sp.diags(diag, format="csc") + sp.diags(1e-3 * rng.standard_normal(599), 1, format="csc")
    halves = [(1, sp.identity(600, format="csc")[:, :300], np.arange(300)), (-1, None, None)]
    with blas_threads(1):  # the workers' setting
        here = blocks_window(Mu, halves[1:], FloquetWindow(count=20), processes=False)
    there = blocks_window(Mu, halves[1:], FloquetWindow(count=20), processes=True)
    assert not here[3]["processes"] and there[3]["processes"]
    for a, b in zip(here[:3], there[:3]):
        assert np.array_equal(a, b)
    assert np.min(np.abs(here[0] - 1.003)) < 1e-9 and np.min(np.abs(here[0] + 1.2)) < 1e-9

    n, kl, ku = 200, 7, 5
    perm = np.r_[np.arange(n // 2)[:, None], n // 2 + np.arange(n // 2)[:, None]].reshape(2, -1).T.ravel()
    dense = np.empty((n, n))  # banded in the interleaved order (u_1, v_1, u_2, ...), as Mu is
    dense[np.ix_(perm, perm)] = np.triu(np.tril(rng.standard_normal((n, n)), ku), -kl) + 10.0 * np.eye(n)
    shifts = BandedShifts.make(sp.csc_matrix(dense))
    assert (shifts.kl, shifts.ku) == (kl, ku)
    x = rng.standard_normal(n)
    solve = shifts.inverse(0.5)
    y = solve @ x
    assert np.allclose((dense - 0.5 * np.eye(n)) @ y, x, rtol=0, atol=1e-12)
    assert np.array_equal(solve @ (x + 2j * x), y + 2j * y)
    assert np.array_equal(solve @ x.astype(np.float32), solve @ x.astype(np.float32).astype(float))


def test_products_in_row_chunks_are_the_one_call_products_bit_for_bit():
    """``krylov_floquet._products``: each product in row chunks on host threads, whatever the chunk, equals scipy's
    one call bit for bit (a row's sum keeps its order), for the CSC and CSR factors the probed problem hands it."""
    import scipy.sparse as sp

    from continuation.krylov_floquet import _products

    rng = np.random.default_rng(3)
    L = sp.random(300, 200, density=0.05, random_state=rng, format="csc")
    R = sp.random(200, 250, density=0.05, random_state=rng, format="csc")
    L2 = sp.random(300, 300, density=0.02, random_state=rng, format="csr")
    want = [sp.csr_matrix(L @ R), sp.csr_matrix(L2 @ L2.T)]
    for rows in (1, 7, 64, 1000):
        for got, expect in zip(_products([(L, R), (L2, L2.T)], rows=rows), want):
            got, expect = got.copy(), expect.copy()
            got.sort_indices()
            expect.sort_indices()
            assert got.shape == expect.shape and np.array_equal(got.indptr, expect.indptr)
            assert np.array_equal(got.indices, expect.indices) and np.array_equal(got.data, expect.data)
