"""Parity: the reflection j -> N + 1 - j of a mirror-symmetric orbit splits its reduced Floquet problem into an even
and an odd block (``floquet.parity_blocks`` on the dense half-period map, ``parity_extensions`` on the sparse one),
so that each block costs a quarter of the whole and every Floquet vector's parity is exact.
"""

from __future__ import annotations

import dataclasses
import functools
import threading

import numpy as np
import scipy.sparse as sp

from .hostblas import blas_threads
from .spectrum import _masses, _products


def mirror_symmetric(state: np.ndarray, rtol: float = 1e-6) -> bool:
    """Whether positions equal their reflection j -> N + 1 - j (to rtol of their size)."""
    from .shooting import is_mirror_symmetric

    return is_mirror_symmetric(state, rtol)


def vector_parity(vectors: np.ndarray, threshold: float = 0.9) -> np.ndarray:
    """+1 / -1 where a column (2N: u then v) is (nearly) even / odd under reflection, else 0."""
    n = vectors.shape[0] // 2
    refl = np.concatenate([vectors[:n][::-1], vectors[n:][::-1]])
    p = np.real(np.sum(np.conj(vectors) * refl, axis=0)) / np.maximum(np.sum(np.abs(vectors) ** 2, axis=0), 1e-300)
    return np.where(p > threshold, 1, np.where(p < -threshold, -1, 0)).astype(int)


#: an orbit whose positions equal their reflection to this relative accuracy (the symmetry-projected
#: branches: exactly) has its reduced matrix split into even and odd blocks (``parity_blocks``)
SYMMETRIC_RTOL = 1e-9

#: the parity split is used when the half-period map A couples even and odd vectors by less than this
#: fraction of A's largest entry (round-off, ~1e-14, on a symmetric orbit); otherwise the whole Mu is solved
PARITY_COUPLING_RTOL = 1e-11


@functools.lru_cache(maxsize=8)
def _parity_basis(n: int) -> tuple:
    """Orthonormal even and odd bases of R^(2n) (u then v, each reflected j -> n - 1 - j). Basis vector
    k of each is w1[k] e[i1[k]] + w2[k] e[i2[k]]; returned as (i1, i2, w1, w2) per basis, so that it is
    applied by gathering rows or columns (no dense products). Even: 2 ceil(n/2) vectors, odd: 2 floor(n/2)."""
    half = n // 2
    r = np.sqrt(0.5)
    out = []
    for sign in (1.0, -1.0):
        i1, i2, w1, w2 = [], [], [], []
        for field in (0, 1):
            o = field * n
            for j in range(half):
                i1.append(o + j), i2.append(o + n - 1 - j), w1.append(r), w2.append(sign * r)
            if n % 2 and sign > 0:
                i1.append(o + half), i2.append(o + half), w1.append(1.0), w2.append(0.0)
        out.append((np.array(i1, dtype=int), np.array(i2, dtype=int), np.array(w1, float), np.array(w2, float)))
    return tuple(out)


def _apply_right(X: np.ndarray, basis) -> np.ndarray:
    """X @ S for a basis S from ``_parity_basis``."""
    i1, i2, w1, w2 = basis
    return X[:, i1] * w1 + X[:, i2] * w2


def _apply_left(X: np.ndarray, basis) -> np.ndarray:
    """S^T @ X."""
    i1, i2, w1, w2 = basis
    return X[i1] * w1[:, None] + X[i2] * w2[:, None]


def _expand(Y: np.ndarray, basis, n2: int) -> np.ndarray:
    """S @ Y: vectors in the basis back to the 2N coordinates (i1 and i2 each hold distinct indices,
    so plain fancy-index assignment adds nothing twice; np.add.at was 1 s of a branch). basis None:
    Y is already in those coordinates."""
    if basis is None:
        return Y
    i1, i2, w1, w2 = basis
    out = np.zeros((n2, Y.shape[1]), dtype=Y.dtype)
    out[i1] += Y * w1[:, None]
    out[i2] += Y * w2[:, None]
    return out


@dataclasses.dataclass(frozen=True)
class ParityBlock:
    """The reduced problem restricted to the even (+1) or odd (-1) vectors of a mirror-symmetric orbit.

    Attributes:
        parity: +1 or -1 (0 for the whole problem of an orbit that is not mirror-symmetric).
        basis: the block's orthonormal basis (``_parity_basis``); None for the whole problem.
        Mu: the block of Mu in that basis, (n, n).
        P: the block of the Krein form P = A11^T Mm A21 in that basis, (n, n).
        symplecticity: the gauge of ``reduced_products`` on this block.
        mu: Mu's eigenvalues, (n,); vectors: its eigenvectors in the basis, (n, n).
    """

    parity: int
    basis: tuple
    Mu: np.ndarray
    P: np.ndarray
    symplecticity: float
    mu: np.ndarray
    vectors: np.ndarray


_BLOCK_POOL = None
_BLOCK_POOL_LOCK = threading.Lock()


def _block_pool():
    """Two host threads for the even and the odd block (LAPACK releases the GIL; with one BLAS thread
    per call, ``hostblas``, the two eigs take the time of one)."""
    global _BLOCK_POOL
    with _BLOCK_POOL_LOCK:
        if _BLOCK_POOL is None:
            from concurrent.futures import ThreadPoolExecutor

            _BLOCK_POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="warpchain-floquet")
    return _BLOCK_POOL


def parity_blocks(A: np.ndarray, M: float) -> "tuple[ParityBlock, ParityBlock] | None":
    """The reduced problem of a mirror-symmetric orbit from its half-period map A, per parity.

    The reflection commutes with the orbit's half-period map, so in an orthonormal basis S of even and
    odd vectors each block of A (A11, A12, A21, A22) is block-diagonal, and so is Mm (a basis vector
    pairs two sites of the same field, which have the same mass). Then Mu, P and the symplecticity
    gauge of each parity follow from ``reduced_products`` on the four blocks S^T Aij S of size ~N:
    products and eigs of two problems of ~N instead of one of 2N (about 4x less work each), done on
    two host threads, and every eigenvector's parity is exact instead of read off with a threshold
    (which leaves near-degenerate even/odd pairs mixed, parity 0).

    Returns:
        (even, odd) ParityBlocks, or None when A couples even and odd vectors by more than
        PARITY_COUPLING_RTOL of A's largest entry (not a symmetric orbit).
    """
    n2 = A.shape[0] // 2
    N = n2 // 2
    even, odd = _parity_basis(N)
    parts = (A[:n2, :n2], A[:n2, n2:], A[n2:, :n2], A[n2:, n2:])
    scale = max(float(np.max(np.abs(A))), 1e-300)
    right = [(_apply_right(X, even), _apply_right(X, odd)) for X in parts]
    coupling = max(
        max(float(np.max(np.abs(_apply_left(Xe, odd)))), float(np.max(np.abs(_apply_left(Xo, even)))))
        for Xe, Xo in right
    )
    if coupling > PARITY_COUPLING_RTOL * scale:
        return None
    m = _masses(M, N)

    def block(sign, basis, k):
        Mu, sympl, P = _products(*(_apply_left(r[k], basis) for r in right), m[basis[0]])
        mu, vec = np.linalg.eig(Mu)
        return ParityBlock(sign, basis, Mu, P, sympl, mu, vec)

    with blas_threads(1):  # two LAPACK calls at once, one BLAS thread each (hostblas)
        jobs = [_block_pool().submit(block, sign, basis, k) for k, (sign, basis) in enumerate(((1, even), (-1, odd)))]
        return tuple(job.result() for job in jobs)


def parity_extensions(N: int) -> tuple:
    """Sparse extensions E (2N x m) from the first half of the lattice (the centre included) to even and to odd
    vectors (u then v): x = E y. Mu commutes with the reflection on a mirror-symmetric orbit, so Mu E = E B with
    B = (Mu E)[first half] (banded too: the reflection only couples sites near the centre, or near the ends
    where the breather is linear) and the eigenpairs of Mu per parity are those of B, extended by E."""
    half = N // 2
    centre = [N // 2] if N % 2 else []
    out = []
    for sign in (1, -1):
        first = np.arange(half)
        rows, cols, vals = [first, N - 1 - first], [first, first], [np.ones(half), sign * np.ones(half)]
        if sign == 1 and centre:
            rows.append(np.array(centre))
            cols.append(np.array([half]))
            vals.append(np.ones(1))
        m = half + (1 if sign == 1 and centre else 0)
        r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
        E = sp.csc_matrix((np.r_[v, v], (np.r_[r, r + N], np.r_[c, c + m])), shape=(2 * N, 2 * m))
        keep = np.r_[np.arange(m), N + np.arange(m)] if sign == 1 else np.r_[first, N + first]
        out.append((sign, E, keep))
    return tuple(out)
