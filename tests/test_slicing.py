"""Every multiplier from the probed sparse Mu by shift-invert slices, certified by a count
(``floquet(solver="sliced")``, ``continuation.slicing``), against the dense reference on the CPU: the same 2N mu to
1e-11 (a bijection per parity), the same verdict, kinds, Krein signatures and participations, and the count per
parity block equals the one read off the dense eigenvectors; the same mu in process and in worker processes;
``inertia`` against numpy's eigenvalues; a sweep that skips a segment is caught by the count (no verdict, and the
continuation driver refuses the point); ``solver="auto"`` takes the probed or the sliced path from
``SLICED_MIN_SITES`` sites on; and ``sweep`` finds every copy of a multiple eigenvalue."""

import functools
import importlib

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import linear_sum_assignment

import continuation as ct
from continuation import driver, slicing
from warpchain import ChainParams

floquet_module = importlib.import_module("continuation.floquet")  # ``continuation.floquet`` is also the function

M = 30.0


def _seed(name: str, p: ChainParams):
    if name.startswith("paper"):
        return ct.nls_seed(p, 1.01)
    if name.startswith("offsite"):  # a site breather away from the chain's centre: not mirror-symmetric
        return ct.anticontinuum_seed(p, 1.01, centre=150)
    return ct.anticontinuum_seed(p, 1.01)


ORBITS = {
    "paper201": ChainParams(M, 160.0, 201),  # the paper breather
    "paper401": ChainParams(M, 160.0, 401),
    "site401": ChainParams(M, 3.0, 401),  # a site breather at K = 3, weakly unstable (|l| - 1 ~ 1e-5)
    "offsite401": ChainParams(M, 3.0, 401),  # the same, centred on site 150 of 401: one block of parity 0
}


@functools.lru_cache(maxsize=None)
def _breather(name: str):
    p = ORBITS[name]
    return ct.require(ct.find_breather(p, 1.01, _seed(name, p), device="cpu"))


@functools.lru_cache(maxsize=None)
def _results(name: str):
    b = _breather(name)
    return b, ct.floquet(b, solver="dense"), ct.floquet(b, solver="sliced")


def _match(a: np.ndarray, b: np.ndarray) -> tuple:
    """A bijection between two sets of complex numbers minimising the total distance: (index into a, index into b,
    distances)."""
    assert len(a) == len(b)
    cost = np.abs(a[:, None] - b[None, :])
    i, j = linear_sum_assignment(cost)
    return i, j, cost[i, j]


def _dense_counts(dense) -> dict:
    """Per parity: the count that a closed sliced block must show, read off the dense eigenvectors (real mu with
    a^T P a > 0, < 0, complex pairs) and P's inertia from numpy."""
    out = {}
    for block in dense.spectral.blocks:
        vec = np.real(block.vectors)
        act = np.sum(vec * (block.P @ vec), axis=0)
        real = block.mu.imag == 0
        lam = np.linalg.eigvalsh(0.5 * (block.P + block.P.T))
        out[int(block.parity)] = {
            "real_positive": int(np.sum(real & (act > 0))),
            "real_negative": int(np.sum(real & (act < 0))),
            "pairs": int(np.sum(block.mu.imag > 0)),
            "inertia": {"positive": int(np.sum(lam > 0)), "negative": int(np.sum(lam < 0)), "zero": 0},
        }
    return out


def _assert_same_mu_sets(a, b, atol):
    for parity in np.unique(a.parity):
        x, y = a.mu[a.parity == parity], b.mu[b.parity == parity]
        assert len(x) == len(y)
        _, _, dist = _match(x, y)
        assert dist.max() <= atol, (parity, dist.max())


# ----------------------------------------------------------------------------- sliced against dense


@pytest.mark.parametrize("name", list(ORBITS))
def test_sliced_is_the_dense_spectrum(name):
    b, dense, sliced = _results(name)
    N = b.params.N
    assert dense.path == "reduced" and sliced.path == "sliced"
    assert len(dense.mu) == len(sliced.mu) == 2 * N
    assert sliced.complete is True and sliced.coverage["closed"] is True
    assert sliced.coverage["method"] == "sliced" and sliced.vectors is None
    if name.startswith("offsite"):
        assert set(np.unique(dense.parity)) == {0}  # not mirror-symmetric
        assert [c["parity"] for c in sliced.coverage["counts"]] == [0]
    else:
        assert sorted(c["parity"] for c in sliced.coverage["counts"]) == [-1, 1]
    # the same mu per parity, to 1e-11 both ways (a bijection)
    assert sorted(np.unique(dense.parity)) == sorted(np.unique(sliced.parity))
    for parity in np.unique(dense.parity):
        di, si = np.flatnonzero(dense.parity == parity), np.flatnonzero(sliced.parity == parity)
        assert len(di) == len(si), parity
        i, j, dist = _match(dense.mu[di], sliced.mu[si])
        assert dist.max() <= 1e-11, (parity, dist.max())
        di, si = di[i], si[j]
        # Krein signatures on the elliptic mu (0 elsewhere and on the trivial mu, on both)
        assert np.array_equal(dense.signature[di], sliced.signature[si])
        elliptic = dense.signature[di] != 0
        assert elliptic.sum() > len(di) // 2
        assert np.allclose(sliced.participation[si], dense.participation[di], rtol=1e-6, atol=0)
        assert np.allclose(sliced.central_weight[si], dense.central_weight[di], rtol=1e-6, atol=1e-12)
    # the verdict
    assert sliced.stable == dense.stable and sliced.verdict == dense.verdict
    assert abs(sliced.max_modulus - dense.max_modulus) <= 1e-9
    assert sliced.partial_stable is None and np.isnan(sliced.partial_max_modulus)
    assert sliced.unstable_counts == dense.unstable_counts
    assert [(i.kind, i.parity, i.localized) for i in sliced.instabilities] == [
        (i.kind, i.parity, i.localized) for i in dense.instabilities
    ]
    for s, d in zip(sliced.instabilities, dense.instabilities):
        assert abs(s.modulus - d.modulus) <= 1e-9 and abs(s.mu - d.mu) <= 1e-11
    if name != "paper201":  # these orbits are unstable: the comparison must see instabilities
        assert dense.instabilities
    # the count per block equals the dense one
    expected = _dense_counts(dense)
    for block in sliced.coverage["counts"]:
        want = expected[block["parity"]]
        assert block["closed"] is True
        assert block["found"]["unpaired"] == 0
        for key in ("real_positive", "real_negative", "pairs"):
            assert block["found"][key] == want[key], (block["parity"], key, block["found"], want)
        assert block["inertia"] == want["inertia"]
        assert block["inertia"]["positive"] + block["inertia"]["negative"] == block["rows"]


@pytest.mark.parametrize("name", ["paper201", "offsite401"])
def test_in_process_and_worker_processes_agree(name):
    """``processes=False`` (every slice here) and ``processes=True`` (the slices in worker processes, cut into more
    segments) give the same mu as sets to 1e-13, both complete."""
    b, _, sliced = _results(name)
    lin = b.linearization()
    local = slicing.sliced_floquet(lin, M, b.state, processes=False)
    workers = slicing.sliced_floquet(lin, M, b.state, processes=True)
    assert local.coverage["processes"] is False and workers.coverage["processes"] is True
    assert local.complete and workers.complete
    assert len(local.mu) == len(workers.mu) == 2 * b.params.N
    _assert_same_mu_sets(local, workers, 1e-13)
    _assert_same_mu_sets(local, sliced, 1e-13)  # and floquet()'s own (segments cut by the linear lattice's mu)
    assert local.stable == workers.stable == sliced.stable


# ----------------------------------------------------------------------------- inertia


def _banded_interleaved(n: int, w: int, rng) -> np.ndarray:
    """A random symmetric matrix whose band (half-width w) is in the interleaved order (u_1, v_1, u_2, ...)."""
    B = np.zeros((n, n))
    for k in range(w + 1):
        d = rng.standard_normal(n - k)
        B += np.diag(d, k) + (np.diag(d, -k) if k else 0.0)
    return B


def _to_u_then_v(B: np.ndarray) -> np.ndarray:
    """The interleaved-order matrix B in u-then-v order (what ``inertia`` takes)."""
    inv = np.argsort(slicing._interleaved(B.shape[0]))
    return B[inv][:, inv]


def _signs(S: np.ndarray, zero: float = 1e-9) -> dict:
    lam = np.linalg.eigvalsh(S)
    scale = np.max(np.abs(S))
    return {
        "positive": int(np.sum(lam > zero * scale)),
        "negative": int(np.sum(lam < -zero * scale)),
        "zero": int(np.sum(np.abs(lam) <= zero * scale)),
    }


@pytest.mark.parametrize("n, w, seed", [(10, 2, 0), (64, 3, 1), (200, 5, 2), (300, 40, 3), (402, 13, 4)])
def test_inertia_of_random_banded_matrices(n, w, seed):
    S = _to_u_then_v(_banded_interleaved(n, w, np.random.default_rng(seed)))
    got = slicing.inertia(sp.csr_matrix(S))
    want = _signs(S)
    assert want["zero"] == 0
    assert {k: got[k] for k in ("positive", "negative", "zero")} == want
    assert got["positive"] + got["negative"] == n
    assert np.isfinite(got["worst_condition"]) and got["worst_condition"] >= 1.0


def test_inertia_of_a_definite_and_an_indefinite_shift():
    """A shifted matrix counts the eigenvalues below and above the shift."""
    rng = np.random.default_rng(5)
    B = _banded_interleaved(120, 4, rng)
    lam = np.linalg.eigvalsh(B)
    for shift in (lam[0] - 1.0, lam[-1] + 1.0, 0.5 * (lam[40] + lam[41])):
        S = _to_u_then_v(B - shift * np.eye(120))
        got = slicing.inertia(sp.csc_matrix(S))
        assert got["negative"] == int(np.sum(lam < shift)) and got["positive"] == int(np.sum(lam > shift))
        assert got["zero"] == 0


def _inertia_with_block_sizes(S, monkeypatch) -> tuple:
    """``slicing.inertia`` of S and the sizes of the diagonal blocks it decomposed (a spy on ``eigh``)."""
    sizes = []
    eigh = np.linalg.eigh

    def spy(D):
        sizes.append(D.shape[0])
        return eigh(D)

    monkeypatch.setattr(slicing.np.linalg, "eigh", spy)
    got = slicing.inertia(sp.csr_matrix(S))
    monkeypatch.undo()
    return got, sizes


def test_inertia_merges_a_nearly_singular_leading_block(monkeypatch):
    """The first diagonal block (32 rows) is made singular (one of its eigenvalues subtracted from it) while the
    whole matrix is not: ``inertia`` must merge it with the next block rather than divide by ~0."""
    n, w = 200, 4
    rng = np.random.default_rng(6)
    B = _banded_interleaved(n, w, rng)
    lead = np.linalg.eigvalsh(B[:32, :32])
    B[:32, :32] -= lead[7] * np.eye(32)  # the leading block's smallest |eigenvalue| is now ~1e-15
    assert np.min(np.abs(np.linalg.eigvalsh(B[:32, :32]))) < 1e-12
    assert np.min(np.abs(np.linalg.eigvalsh(B))) > 1e-6  # the whole matrix is well away from singular
    S = _to_u_then_v(B)
    got, sizes = _inertia_with_block_sizes(S, monkeypatch)
    assert sizes[:2] == [32, 64], sizes  # tried 32 rows, merged into 64
    assert {k: got[k] for k in ("positive", "negative", "zero")} == _signs(S)
    assert got["worst_condition"] < 1e9  # the singular block was not used


def test_inertia_merges_a_nearly_singular_block_after_the_first(monkeypatch):
    """A block made nearly singular (to 1e-13, below PIVOT_RTOL) by the Schur complement carried into it."""
    n, w = 160, 3
    rng = np.random.default_rng(7)
    B = _banded_interleaved(n, w, rng)
    # the Schur complement of the first 32 rows in the first 64: make it singular by shifting rows 32..63
    A11, A21, A22 = B[:32, :32], B[32:64, :32], B[32:64, 32:64]
    schur = A22 - A21 @ np.linalg.solve(A11, A21.T)
    B[32:64, 32:64] -= (np.linalg.eigvalsh(schur)[3] + 1e-13) * np.eye(32)
    S = _to_u_then_v(B)
    assert np.min(np.abs(np.linalg.eigvalsh(B))) > 1e-6
    got, sizes = _inertia_with_block_sizes(S, monkeypatch)
    assert sizes[:3] == [32, 32, 64], sizes  # the second block (after the carry) was merged with the third
    assert {k: got[k] for k in ("positive", "negative", "zero")} == _signs(S)


@pytest.mark.parametrize("where", [5, 100, 199])
def test_inertia_counts_an_exact_zero_eigenvalue(where):
    """A row and column of zeros (in the interleaved order: at the start, the middle or the end) is an exact zero
    eigenvalue: counted as zero, the others as numpy counts them."""
    n, w = 200, 4
    B = _banded_interleaved(n, w, np.random.default_rng(8))
    B[where, :] = 0.0
    B[:, where] = 0.0
    S = _to_u_then_v(B)
    got = slicing.inertia(sp.csr_matrix(S))
    want = _signs(S)
    assert want["zero"] == 1
    assert {k: got[k] for k in ("positive", "negative", "zero")} == want


def test_inertia_of_an_odd_order_matrix_in_natural_order():
    """Odd n: no interleaving, the band is taken as it stands."""
    n = 101
    B = _banded_interleaved(n, 3, np.random.default_rng(9))
    got = slicing.inertia(sp.csr_matrix(B))
    assert {k: got[k] for k in ("positive", "negative", "zero")} == _signs(B)


# ----------------------------------------------------------------------------- the count catches a miss


def _dropping_a_segment(monkeypatch):
    """``segments`` that cuts four segments and leaves the second out (its multipliers go unseen)."""
    original = slicing.segments

    def fewer(count, hint=None):
        cut = original(max(count, 4), hint)
        return cut[:1] + cut[2:]

    monkeypatch.setattr(slicing, "segments", fewer)


def test_a_skipped_segment_leaves_no_verdict(monkeypatch):
    b, dense, _ = _results("paper201")
    _dropping_a_segment(monkeypatch)
    fl = ct.floquet(b, solver="sliced")
    assert len(fl.mu) < 2 * b.params.N  # some multipliers were not found
    assert fl.complete is False and fl.coverage["closed"] is False
    assert fl.stable is None and fl.verdict == "not decided"
    assert np.isnan(fl.max_modulus)
    assert np.isfinite(fl.partial_max_modulus) and fl.partial_stable is not None
    assert any(not c["closed"] for c in fl.coverage["counts"])
    for c in fl.coverage["counts"]:
        found = c["found"]["real_positive"] + c["found"]["real_negative"] + 2 * c["found"]["pairs"]
        assert found <= c["rows"]
        if not c["closed"]:
            assert found < c["rows"]
    # what it did find is the dense spectrum's
    for parity in np.unique(fl.parity):
        x, y = fl.mu[fl.parity == parity], dense.mu[dense.parity == parity]
        assert np.min(np.abs(x[:, None] - y[None, :]), axis=1).max() <= 1e-11


def test_the_driver_refuses_a_point_whose_count_does_not_close(monkeypatch):
    p = ChainParams(M, 3.0, 41)
    b = ct.require(ct.find_breather(p, 1.01, ct.anticontinuum_seed(p, 1.01), device="cpu"))
    solution = driver.Solution(
        params=p, omega=1.01, state=b.state, iterations=0, residual_history=(), linearization=b.linearization(), s=3.0
    )
    settings = driver.ContinuationSettings(floquet_solver="sliced")
    point = driver.analyse(solution, settings=settings)  # the count closes: a complete verdict
    assert point.complete is True and point.stable is not None and len(point.mu) == 2 * p.N
    _dropping_a_segment(monkeypatch)
    with pytest.raises(driver.IncompleteVerdict, match="did not close"):
        driver.analyse(solution, settings=settings)


def test_a_wider_outer_interval_than_the_slices_cover_is_caught(monkeypatch):
    """``OUTER`` made negative (the slices stop at +-0.98) and the outliers' Arnoldi returning nothing: the mu
    beyond +-0.98 go unseen, and the count says so."""
    b, dense, _ = _results("paper201")
    assert np.sum(np.abs(dense.mu.real) > 0.98) > 10
    monkeypatch.setattr(slicing, "OUTER", -0.02)  # the slices stop at +-0.98
    monkeypatch.setattr(slicing, "outlier_task", _no_outliers)
    fl = slicing.sliced_floquet(b.linearization(), M, b.state, processes=False)
    assert fl.complete is False and fl.stable is None and np.isnan(fl.max_modulus)
    assert fl.verdict == "not decided"


def _no_outliers(op, P, E, sign, k, M, centre, twin_near=None):
    return slicing._report(np.zeros(0, complex), np.zeros((op.shape[0], 0)), P, E, M, centre, twin_near, converged=True)


# ----------------------------------------------------------------------------- auto


def test_auto_takes_the_sliced_path_from_sliced_min_sites(monkeypatch):
    b, dense, _ = _results("paper201")
    assert floquet_module.floquet_path("auto", 201) == "dense"
    assert ct.floquet(b).path == "reduced"  # below SLICED_MIN_SITES: dense
    monkeypatch.setattr(floquet_module, "SLICED_MIN_SITES", 201)
    monkeypatch.setattr(floquet_module, "PROBED_HOST_MAX_SITES", 201)  # the host's probed path below this
    assert floquet_module.floquet_path("auto", 201) == "sliced"
    fl = ct.floquet(b)
    assert fl.path == "sliced" and fl.complete and fl.coverage["method"] == "sliced"
    _assert_same_mu_sets(fl, dense, 1e-11)
    monkeypatch.setattr(floquet_module, "SLICED_MIN_SITES", 202)
    assert ct.floquet(b).path == "reduced"


# ----------------------------------------------------------------------------- the probed path (dense eig per block)


@pytest.mark.parametrize("name", list(ORBITS))
def test_probed_is_the_dense_spectrum(name):
    """``solver="probed"``: the probed sparse Mu's blocks by a dense eig (the host's LAPACK here), counted as the
    slices are: the dense mu (to 1e-11 per parity), verdict, largest modulus, signatures and kinds; every count
    closes."""
    b, dense, _ = _results(name)
    fl = ct.floquet(b, solver="probed")
    assert fl.path == "probed" and fl.complete is True and fl.coverage["method"] == "probed"
    assert fl.coverage["eig"] == "host" and all(c["closed"] for c in fl.coverage["counts"])
    assert len(fl.mu) == 2 * b.params.N
    _assert_same_mu_sets(dense, fl, 1e-11)
    assert fl.stable is dense.stable and abs(fl.max_modulus - dense.max_modulus) <= 1e-9
    assert sorted(fl.signature) == sorted(dense.signature)
    assert [i.kind for i in fl.instabilities] == [i.kind for i in dense.instabilities]


def test_measures_in_column_chunks_are_the_whole_ones(monkeypatch):
    """``_measures`` of many columns (a dense block's) runs in column chunks on threads: the same Krein forms,
    participations and central weights, bit for bit, as in one piece."""
    from continuation.parity import parity_extensions

    rng = np.random.default_rng(5)
    _, E, _ = parity_extensions(101)[0]
    n = E.shape[1]
    vectors = rng.standard_normal((n, 700)) + 1j * rng.standard_normal((n, 700))
    mu = rng.uniform(-1, 1, 700) + 1j * np.where(rng.uniform(size=700) < 0.2, rng.uniform(size=700), 0.0)
    P = sp.random(n, n, density=0.05, random_state=6, format="csc")
    P = sp.csc_matrix(P + P.T)
    for columns, chunk in ((700, 64), (257, 256), (513, 256)):  # no chunk of one column (summed otherwise)
        monkeypatch.setattr(slicing, "MEASURE_CHUNK", 10_000)
        whole = slicing._measures(mu[:columns], vectors[:, :columns], P, E, M, 50.0)
        monkeypatch.setattr(slicing, "MEASURE_CHUNK", chunk)
        chunked = slicing._measures(mu[:columns], vectors[:, :columns], P, E, M, 50.0)
        for a, b in zip(whole, chunked):
            assert a.shape == (columns,) and np.array_equal(a, b), (columns, chunk)


def test_the_measures_pool_starts_afresh_in_a_forked_child():
    """A forked child has none of its parent's threads: its ``_measures`` must not wait for the parent's pool."""
    import os

    rng = np.random.default_rng(1)
    n = 40
    vectors = rng.standard_normal((n, 600)) + 0j
    P = sp.csc_matrix(sp.identity(n))
    want = slicing._measures(np.zeros(600), vectors, P, None, M, np.nan)  # the parent's pool now exists
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: exit 0 if the measures come out, the same
        got = slicing._measures(np.zeros(600), vectors, P, None, M, np.nan)
        os._exit(0 if all(np.array_equal(a, b, equal_nan=True) for a, b in zip(want, got)) else 1)
    os.close(write)
    for _ in range(200):  # up to 20 s
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        import time

        time.sleep(0.1)
    else:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        raise AssertionError("the forked child's _measures hung")
    os.close(read)
    assert os.waitstatus_to_exitcode(status) == 0


def test_auto_takes_the_probed_path_where_a_gpu_eig_is_there(monkeypatch):
    """From ``SLICED_MIN_SITES`` sites on, ``auto`` is the probed path where the flow's device is a GPU and CuPy
    imports (``slicing.has_gpu_eig``) or below ``PROBED_HOST_MAX_SITES`` sites, the sliced path elsewhere; below,
    dense either way."""
    assert floquet_module.floquet_path("auto", 1601, "cpu") == "probed"
    assert floquet_module.floquet_path("auto", 3201, "cpu") == "sliced"
    assert floquet_module.floquet_path("auto", 3201, "numpy") == "sliced"
    assert slicing.gpu_index("cuda") == 0 and slicing.gpu_index("cuda:1") == 1 and slicing.gpu_index("cpu") is None
    monkeypatch.setattr(slicing, "has_gpu_eig", lambda device: str(device).startswith("cuda"))
    assert floquet_module.floquet_path("auto", 3201, "cuda:0") == "probed"
    assert floquet_module.floquet_path("auto", 3201, "cpu") == "sliced"
    assert floquet_module.floquet_path("auto", 1600, "cuda:0") == "dense"


def _cuda_with_cupy() -> bool:
    try:
        import cupy  # noqa: F401
        import warp as wp

        wp.init()
        return wp.get_cuda_device_count() > 0
    except Exception:
        return False


@pytest.mark.skipif(not _cuda_with_cupy(), reason="needs a CUDA device and CuPy")
def test_probed_on_the_gpu_is_the_hosts():
    """The probed path with its eig on the GPU (CuPy, cuSOLVER's geev) gives the host's mu (to 1e-11), verdict and
    closed counts, on the paper breather and the off-centre site breather (one block of parity 0)."""
    for name in ("paper201", "offsite401"):
        b = _breather(name)
        lin = b.linearization(b.flow.replace(device="cuda:0"))
        assert lin.device == "cuda:0"
        gpu = slicing.probed_floquet(lin, M, b.state, device=lin.device)
        host = slicing.probed_floquet(lin, M, b.state)
        assert gpu.coverage["eig"] == "gpu" and gpu.complete is True
        _assert_same_mu_sets(host, gpu, 1e-11)
        assert gpu.stable is host.stable and abs(gpu.max_modulus - host.max_modulus) <= 1e-9


# ----------------------------------------------------------------------------- multiple eigenvalues


def _givens_banded(values: np.ndarray, layers: int = 3, seed: int = 0) -> sp.csc_matrix:
    """diag(values) under a random orthogonal similarity by layers of rotations of neighbours (in the interleaved
    order): the same eigenvalues in a banded, non-diagonal op (u-then-v order)."""
    n = len(values)
    rng = np.random.default_rng(seed)
    B = np.diag(values)
    for layer in range(layers):
        for i in range(layer % 2, n - 1, 2):
            c, s = np.cos(t := rng.uniform(0, 2 * np.pi)), np.sin(t)
            G = np.array([[c, -s], [s, c]])
            B[i : i + 2, :] = G @ B[i : i + 2, :]
            B[:, i : i + 2] = B[:, i : i + 2] @ G.T
    B[np.abs(B) < 1e-17 * np.max(np.abs(B))] = 0.0
    return sp.csc_matrix(_to_u_then_v(0.5 * (B + B.T)))


def _cluster_values(copies: int = 100, spread: int = 150, width: float = 0.0) -> np.ndarray:
    rng = np.random.default_rng(1)
    values = np.concatenate([0.3 + width * np.linspace(0.0, 1.0, copies), rng.uniform(-1.0, 1.0, spread)])
    rng.shuffle(values)
    return values


def _assert_found_once(mu: np.ndarray, values: np.ndarray, atol: float = 1e-12):
    assert len(mu) == len(values), (len(mu), len(values), int(np.sum(np.abs(mu - 0.3) < 1e-9)))
    assert np.max(np.abs(mu.imag)) <= atol
    assert np.max(np.abs(np.sort(mu.real) - np.sort(values))) <= atol


@pytest.mark.parametrize(
    "spread, width",
    [(150, 0.0), pytest.param(300, 1e-6, marks=pytest.mark.slow), pytest.param(150, 1e-4, marks=pytest.mark.slow)],
)
def test_sweep_finds_every_copy_of_a_multiple_eigenvalue_of_a_banded_op(spread, width):
    """100 equal (or nearly equal) eigenvalues, more than SLICE_COUNT, in a banded op (not diagonal): each found
    exactly once, with the spread ones."""
    values = _cluster_values(spread=spread, width=width)
    assert slicing.SLICE_COUNT < 100
    op = _givens_banded(values)
    assert op.nnz > 5 * len(values)  # not diagonal
    mu, vectors, strip, shifts = slicing.sweep(op, -1.0 - slicing.OUTER, 1.0 + slicing.OUTER, slicing.SLICE_COUNT)
    _assert_found_once(mu, values)
    assert np.sum(np.abs(mu - 0.3) <= width + 1e-12) == 100
    assert vectors.shape == (len(values), len(values)) and strip > 0 and shifts > 1


# A cluster of 100 equal or nearly equal eigenvalues (more than k = SLICE_COUNT) near a shift made ARPACK stop with
# ArpackError 3 ("No shifts could be applied": 100 copies of 0.3 among 50 spread values, rotation seed 1) or
# ArpackNoConvergence (100 within 1e-6 among 100, seed 1), out of ``sliced_floquet``; ``slicing._shift`` now asks
# again with fewer eigenvalues, then with more Arnoldi vectors and no limit (found by the test helper).
@pytest.mark.parametrize("spread, width, seed", [(50, 0.0, 1), (100, 1e-6, 1)])
def test_sweep_on_a_tight_cluster_of_a_banded_op(spread, width, seed):
    values = _cluster_values(spread=spread, width=width)
    op = _givens_banded(values, seed=seed)
    mu, _, _, _ = slicing.sweep(op, -1.02, 1.02, slicing.SLICE_COUNT)  # (the shifts, hence the failure, depend on it)
    _assert_found_once(mu, values)


def test_a_multiple_eigenvalue_beyond_krylov_reach_is_caught_by_the_count():
    """On a *diagonal* op an exactly multiple eigenvalue's eigenspace is entered by the Krylov space only along the
    start vector's component (shift-invert scales those coordinates by one factor exactly), so the sweep sees a few
    of its 100 copies: no Krylov method can do better from one start vector. What makes the verdict safe is the
    count: with P = I (every eigenvalue real with a^T P a > 0) the inertia says 400 and the found fall short, so the
    block's count does not close."""
    values = _cluster_values(copies=100, spread=300)
    op = sp.csc_matrix(sp.diags(values))
    mu, vectors, _, _ = slicing.sweep(op, -1.0 - slicing.OUTER, 1.0 + slicing.OUTER, slicing.SLICE_COUNT)
    counts = slicing.inertia(sp.identity(len(values), format="csc"))
    act = np.sum(np.real(vectors) ** 2, axis=0)
    found_positive = int(np.sum((mu.imag == 0) & (act > 0)))
    assert counts["positive"] == len(values) and found_positive < counts["positive"]  # the count refuses
    distinct = np.unique(values)
    assert all(np.min(np.abs(mu - v)) < 1e-12 for v in distinct)  # every distinct value is seen


def test_sweep_finds_a_diagonal_ops_distinct_eigenvalues_once():
    values = np.random.default_rng(3).uniform(-1.0, 1.0, 300)
    mu, _, _, shifts = slicing.sweep(sp.csc_matrix(sp.diags(values)), -1.02, 1.02, slicing.SLICE_COUNT)
    _assert_found_once(mu, values)
    assert shifts >= len(values) // slicing.SLICE_COUNT


def test_a_periodic_ring_closes_its_count_with_the_translation_in_p_kernel():
    """On a periodic ring the uniform translation moves no velocity, so the Krein form P has a kernel (one zero in
    each parity block's inertia) holding an eigenvector of Mu whose form vanishes: the count matches it with a
    neutral real mu and closes; the verdict and the mu are the dense ones."""
    p = ChainParams(30.0, 160.0, 101, boundary="periodic")
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device="cpu"))
    dense = ct.floquet(b, solver="dense")
    for sliced in (ct.floquet(b, solver="sliced"), ct.floquet(b, solver="probed")):
        assert sliced.complete and sliced.stable is dense.stable is False
        assert all(c["inertia"]["zero"] == c["found"]["real_neutral"] == 1 for c in sliced.coverage["counts"])
        assert max(np.min(np.abs(dense.mu - m)) for m in sliced.mu) <= 1e-12 and len(sliced.mu) == len(dense.mu)
        assert abs(sliced.max_modulus - dense.max_modulus) <= 1e-9


# ----------------------------------------------------------------------------- lattice patches


PATCHES = {  # (lattice, family, w_b): an 11 x 11 patch at K = 1, fixed walls
    "square-site": ("square", "site", 1.0140),  # stable; the x <-> y mirror makes double mu
    "square-bond": ("square", "bond", 1.0150),  # one real pair
    "triangular-site": ("triangular", "site", 1.0140),  # stable
    "triangular-triangle": ("triangular", "triangle", 1.0140),  # two real pairs
}


@functools.lru_cache(maxsize=None)
def _patch(name: str):
    from scenarios.monolayer import _seed as family_seed
    from warpchain.lattice import LatticeParams, square, triangular

    lattice, family, omega = PATCHES[name]
    params = LatticeParams(M, 1.0, {"square": square, "triangular": triangular}[lattice](11, 11, "fixed"))
    b = ct.require(ct.find_breather(params, omega, family_seed(params, omega, family), device="cpu", solver="dense"))
    return b, ct.floquet(b, solver="dense"), ct.floquet(b, solver="sliced")


@pytest.mark.parametrize("name", list(PATCHES))
def test_sliced_is_the_dense_spectrum_on_a_patch(name):
    """Square and triangular patches: the sliced path's count closes in every symmetry block, with the dense mu (to
    1e-12), verdict and largest modulus. The square patch's doubles (Arnoldi returns them as mu +- 1e-17 i) count as
    two real mu, not as a pair (``slicing.degenerate_reals``): before, nine of them left the odd block's count open
    (with the mirror's four blocks they fall apart anyway; the bond breather keeps neither symmetry)."""
    b, dense, sliced = _patch(name)
    assert sliced.complete is True and all(c["closed"] for c in sliced.coverage["counts"])
    _assert_same_mu_sets(dense, sliced, 1e-12)
    assert sliced.stable == dense.stable and abs(sliced.max_modulus - dense.max_modulus) <= 1e-9
    assert [i.kind for i in sliced.instabilities] == [i.kind for i in dense.instabilities]
    assert dense.stable is (name.endswith("site"))
    assert sliced.unstable_counts == dense.unstable_counts
    # the site breathers keep the rotation and a mirror: four blocks (symmetry_extensions); the square one the quarter
    # turn too: six, the last the twin of the fifth (found once); the others neither
    blocks = {"square-site": [1, 1, 1, 1, -1, -1], "triangular-site": [1, 1, -1, -1]}.get(name, [0])
    assert [c["parity"] for c in sliced.coverage["counts"]] == blocks
    assert [c.get("twin_of") for c in sliced.coverage["counts"]] == [None] * (len(blocks) - 1) + (
        [4] if name == "square-site" else [None]
    )
    if name == "square-site":  # the doubles are there; in the rotation's two blocks alone they meet in one block
        assert np.sum(np.diff(np.sort(dense.mu.real)) < 1e-10) >= 5
        two = slicing.sliced_floquet(b.linearization(), M, b.state)  # no lattice: no mirror
        assert [c["parity"] for c in two.coverage["counts"]] == [1, -1] and two.complete
        _assert_same_mu_sets(dense, two, 1e-12)


@pytest.mark.parametrize("name", list(PATCHES))
def test_probed_is_the_dense_spectrum_on_a_patch(name):
    """On a patch (the mirror's four blocks, or one block) the probed path's counts close with the dense mu."""
    b, dense, _ = _patch(name)
    fl = ct.floquet(b, solver="probed")
    assert fl.complete is True and all(c["closed"] for c in fl.coverage["counts"])
    _assert_same_mu_sets(dense, fl, 1e-12)
    assert fl.stable is dense.stable and abs(fl.max_modulus - dense.max_modulus) <= 1e-9


def test_a_double_real_mu_of_one_krein_sign_is_two_real_mu_and_a_pair_stays_a_pair():
    """``degenerate_reals`` on P-self-adjoint examples: a double mu = 0.3 with P = -1 on its plane, returned as
    0.3 +- 1e-17 i, becomes two real 0.3 whose Krein forms are -1; a genuine pair 0.5 +- 0.2 i (P = diag(1, -1),
    Mu = [[0.5, 0.2], [-0.2, 0.5]], so P Mu is symmetric) stays complex."""
    P = sp.csc_matrix(sp.diags([-1.0, -1.0, 1.0, -1.0]))
    x, y = np.array([1.0, 1.0, 0, 0]) / np.sqrt(2), np.array([1.0, -1.0, 0, 0]) / np.sqrt(2)
    mu = np.array([0.3 + 1e-17j, 0.3 - 1e-17j, 0.5 + 0.2j, 0.5 - 0.2j])
    pair = np.array([0, 0, 1.0, 1j]) / np.sqrt(2)  # Mu's pair lives on the last two coordinates
    vectors = np.column_stack([x + 1j * y, x - 1j * y, pair, np.conj(pair)])
    out, vec = slicing.degenerate_reals(mu, vectors, P)
    assert np.array_equal(out[:2], [0.3, 0.3]) and np.all(out[:2].imag == 0)
    assert np.allclose(np.sum(vec[:, :2].real * (P @ vec[:, :2].real), axis=0), -1.0)
    assert np.array_equal(out[2:], mu[2:]) and np.array_equal(vec[:, 2:], vectors[:, 2:])


@pytest.mark.parametrize("name", list(PATCHES))
def test_a_patch_mirror_splits_the_dense_blocks_in_four(name):
    """A site breather keeps the patch's 180-degree rotation and a mirror: four blocks (two of each parity) whose mu
    are the whole Mu's (to 1e-12) and whose Krein signatures are the two-block split's; a bond or triangle breather
    keeps neither here (one block)."""
    from warpchain.lattice import neighbour_table

    b, dense, _ = _patch(name)
    A = floquet_module.half_period_map(b.linearization())
    whole = np.linalg.eigvals(floquet_module.reduced_products(A, M)[0])
    _, _, dist = _match(whole, dense.mu)
    assert dist.max() <= 1e-12
    if name.endswith("site"):
        assert dense.spectral.parities == (1, 1, -1, -1)
        assert sum(bl.Mu.shape[0] for bl in dense.spectral.blocks) == 2 * b.params.N
        two = floquet_module.reduced_floquet(A, M, b.state)  # no lattice: the reversal alone
        assert two.spectral.parities == (1, -1)
        i, j, dist = _match(two.mu, dense.mu)
        assert dist.max() <= 1e-12 and np.array_equal(two.signature[i], dense.signature[j])
        assert neighbour_table(b.params).symmetries()  # the mirror came from the lattice
    else:
        assert dense.spectral.parities == (0,)


def test_the_quarter_turn_splits_a_square_patch_in_six_blocks_one_a_twin():
    """A 9 x 9 square site breather keeps D4: the even vectors fall into four blocks of its one-dimensional
    characters, the odd ones into the (R, m) = (-, +) block and its image under the quarter turn, whose B equals the
    first's to round-off (``symmetry_extensions``); together the six extensions span R^2N, and the probed path's mu
    (the twin's copied) are the dense eig's of the whole Mu. A permutation that is not a quarter turn is refused."""
    from continuation.krylov_floquet import probed_problem
    from continuation.parity import patch_mirror, patch_quarter, symmetry_extensions
    from warpchain.lattice import LatticeParams, square

    lattice = square(9, 9, "fixed")
    p = LatticeParams(M, 1.0, lattice)
    b = ct.require(ct.find_breather(p, 1.014, ct.anticontinuum_seed(p, 1.014), device="cpu", solver="dense"))
    assert patch_quarter(lattice, b.state) is not None
    problem = probed_problem(b.linearization(), M, b.state, lattice)
    blocks, Mu = problem["blocks"], problem["Mu"]
    assert [s for s, _, _ in blocks] == [1, 1, 1, 1, -1, -1] and problem["twins"] == {5: 4}
    E = sp.hstack([e for _, e, _ in blocks]).toarray()
    assert E.shape == (2 * p.N, 2 * p.N) and np.linalg.matrix_rank(E) == 2 * p.N
    B = [(Mu @ e)[keep].toarray() for _, e, keep in blocks]
    assert np.max(np.abs(B[5] - B[4])) <= 1e-11 * np.max(np.abs(B[4]))
    for (_, e, _), Bk in zip(blocks, B):  # each block is invariant: Mu E = E B
        assert np.max(np.abs(Mu @ e - e @ Bk)) <= 1e-11 * np.max(np.abs(Bk))
    fl = ct.floquet(b, solver="probed")
    assert fl.complete is True and [c.get("twin_of") for c in fl.coverage["counts"]] == [None] * 5 + [4]
    _, _, dist = _match(np.linalg.eigvals(Mu.toarray()), fl.mu)
    assert dist.max() <= 1e-12
    mirror = patch_mirror(lattice, b.state)
    with pytest.raises(ValueError, match="quarter turn"):
        symmetry_extensions(p.N, mirror, mirror)
    # the twin's central weights are measured, not copied: the central window is a row, which the quarter turn moves
    # (copied, the odd vectors' weights summed to 8.008 against the dense 4.004)
    dense = ct.floquet(b, solver="dense")
    odd = np.asarray(dense.central_weight)[np.asarray(dense.parity) == -1].sum()
    for path in (fl, ct.floquet(b, solver="sliced")):
        weight = np.asarray(path.central_weight)
        assert abs(weight.sum() - np.sum(dense.central_weight)) <= 1e-9 * weight.sum()
        assert abs(weight[np.asarray(path.parity) == -1].sum() - odd) <= 1e-9 * odd


@pytest.mark.parametrize("n", [3, 5])
def test_a_small_square_patch_gets_dense_blocks_on_the_sliced_path(n):
    """D4 makes blocks of 2 rows on 3 x 3 and 5 x 5 patches, too few for ARPACK: the sliced path gives blocks of at
    most ``SMALL_BLOCK_ROWS`` rows a dense eig (it crashed on k = 0), and its count closes with the dense mu."""
    from warpchain.lattice import LatticeParams, square

    p = LatticeParams(M, 1.0, square(n, n, "fixed"))
    b = ct.require(ct.find_breather(p, 1.014, ct.anticontinuum_seed(p, 1.014), device="cpu", solver="dense"))
    fl = ct.floquet(b, solver="sliced")
    assert fl.complete is True and fl.coverage["dense_blocks"]
    _, _, dist = _match(ct.floquet(b, solver="dense").mu, fl.mu)
    assert dist.max() <= 1e-12


def test_a_mirror_the_map_does_not_keep_falls_back_to_the_rotations_two_blocks():
    """A 9 x 9 site breather moved off its mirror by 5e-10 of its size (rotation-even, mirror-odd): the state keeps
    the mirror to SYMMETRIC_RTOL, the map does not to PARITY_COUPLING_RTOL, so the split is the rotation's two blocks
    (not the whole Mu), with the whole Mu's mu."""
    from continuation.parity import parity_blocks, patch_mirror
    from warpchain.lattice import LatticeParams, square

    lattice = square(9, 9, "fixed")
    p = LatticeParams(M, 1.0, lattice)
    b = ct.require(ct.find_breather(p, 1.014, ct.anticontinuum_seed(p, 1.014), device="cpu", solver="dense"))
    m, R = lattice.symmetries()["mirror_0"], p.N - 1 - np.arange(p.N)
    noise = np.random.default_rng(0).standard_normal((2, p.N))
    noise = noise + noise[:, R]
    noise = noise - noise[:, m]
    state = b.state.copy()
    state[:2] += 5e-10 * np.max(np.abs(b.state[:2])) * noise / np.max(np.abs(noise))
    A = floquet_module.half_period_map(b.flow.linearize(p, state, b.nsteps, b.dt))
    assert patch_mirror(lattice, state) is not None and parity_blocks(A, M, patch_mirror(lattice, state)) is None
    fl = floquet_module.reduced_floquet(A, M, state, lattice=lattice)
    assert fl.spectral.parities == (1, -1)
    _, _, dist = _match(np.linalg.eigvals(floquet_module.reduced_products(A, M)[0]), fl.mu)
    assert dist.max() <= 1e-12


@pytest.mark.parametrize("build", ["square", "triangular"])
def test_a_character_no_orbit_carries_is_left_out(build):
    """On 2 x 2 patches a diagonal mirror leaves one of the four characters empty: three blocks, the whole Mu's mu
    (an empty block crashed the products before)."""
    from continuation.seeds import anticontinuum_orbit, state_from_positions
    from warpchain.lattice import LatticeParams, square, triangular

    lattice = {"square": square, "triangular": triangular}[build](2, 2, "fixed")
    p = LatticeParams(M, 1.0, lattice)
    z = np.zeros(p.N)
    z[[0, 1, 2, 3] if build == "triangular" else [0, 3]] = anticontinuum_orbit(1.014, M).z_max
    seed = state_from_positions(z / (M + 1.0), -M * z / (M + 1.0))
    b = ct.require(ct.find_breather(p, 1.014, seed, device="cpu", solver="dense"))
    fl = ct.floquet(b, solver="dense")
    assert len(fl.spectral.parities) == 3 and len(fl.mu) == 2 * p.N
    A = floquet_module.half_period_map(b.linearization())
    _, _, dist = _match(np.linalg.eigvals(floquet_module.reduced_products(A, M)[0]), fl.mu)
    assert dist.max() <= 1e-12


def test_blocks_of_another_mirror_are_not_the_same_blocks():
    """``SpectralData.same_blocks`` (what ``bubbles.predict`` asks before subtracting two points' blocks): the same
    parities (1, 1, -1, -1) from two different mirrors are different bases."""
    from continuation.parity import parity_blocks
    from continuation.spectrum import SpectralData

    b, dense, _ = _patch("square-site")
    symmetries = b.params.lattice.symmetries()
    A = floquet_module.half_period_map(b.linearization())
    first = SpectralData(parity_blocks(A, M, symmetries["mirror_0"]))
    other = SpectralData(parity_blocks(A, M, symmetries["mirror_45"]))
    assert first.parities == other.parities == (1, 1, -1, -1)
    assert first.same_blocks(dense.spectral) and dense.spectral.same_blocks(first)
    assert not first.same_blocks(other)


@pytest.mark.parametrize(
    "case", ["square-periodic", "square-free", "triangular-periodic", "chain-periodic", "chain-free"]
)
def test_a_translation_hidden_in_the_trivial_cluster_closes_the_count(case):
    """Free and periodic lattices: the uniform translation (P t = 0) shares mu = 1 with the phase mode, and Arnoldi
    returns two mixtures with positive forms; ``hidden_neutral`` writes them in the form's eigenvectors, so the count
    (one positive, one zero) closes and the verdict is dense's (before: ``stable`` None on every such lattice)."""
    import warpchain as wc
    from warpchain.lattice import LatticeParams, square, triangular

    name, boundary = case.split("-")
    if name == "chain":
        params = wc.ChainParams(M, 3.0, 41, boundary=boundary)
    else:
        params = LatticeParams(M, 1.0, {"square": square, "triangular": triangular}[name](9, 9, boundary))
    b = ct.require(ct.find_breather(params, 1.014, ct.anticontinuum_seed(params, 1.014), device="cpu", solver="dense"))
    sliced, dense = ct.floquet(b, solver="sliced"), ct.floquet(b, solver="dense")
    assert sliced.complete and all(c["closed"] for c in sliced.coverage["counts"])
    assert sum(c["found"]["real_neutral"] for c in sliced.coverage["counts"]) == 1
    assert sliced.stable == dense.stable
    _assert_same_mu_sets(dense, sliced, 1e-12)
