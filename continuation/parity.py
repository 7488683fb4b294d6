"""Parity: the reflection j -> N + 1 - j of a mirror-symmetric orbit splits its reduced Floquet problem into an even
and an odd block (``floquet.parity_blocks`` on the dense half-period map, ``parity_extensions`` on the sparse one),
so that each block costs a quarter of the whole and every Floquet vector's parity is exact. On a patch the reversal
is the 180-degree rotation, and a mirror of the patch that the orbit keeps (``patch_mirror``) splits each parity once
more (``symmetry_bases``: four blocks of the group {1, R, m, R m}).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.sparse as sp

from .hostblas import HostPool, blas_threads
from .spectrum import _masses, _products


def mirror_symmetric(state: np.ndarray, rtol: float = 1e-6, sites=None) -> bool:
    """Whether positions equal their reflection j -> N + 1 - j (or their image under the site permutation
    ``sites``) to rtol of their size."""
    from .shooting import is_mirror_symmetric

    return is_mirror_symmetric(state, rtol, sites)


def vector_parity(vectors: np.ndarray, threshold: float = 0.9) -> np.ndarray:
    """+1 / -1 where a column (2N: u then v) is (nearly) even / odd under reflection, else 0."""
    n = vectors.shape[0] // 2
    refl = np.concatenate([vectors[:n][::-1], vectors[n:][::-1]])
    p = np.real(np.sum(np.conj(vectors) * refl, axis=0)) / np.maximum(np.sum(np.abs(vectors) ** 2, axis=0), 1e-300)
    return np.where(p > threshold, 1, np.where(p < -threshold, -1, 0)).astype(int)


#: an orbit whose positions equal their reflection to this relative accuracy (the symmetry-projected
#: branches: exactly) has its reduced matrix split into even and odd blocks (``parity_blocks``)
SYMMETRIC_RTOL = 1e-9


def patch_quarter(lattice, state) -> "np.ndarray | None":
    """The quarter turn of a square patch (``Lattice.symmetries``' ``rot90``) when the orbit's positions keep it to
    ``SYMMETRIC_RTOL``: with the mirror, the group D4 (``symmetry_extensions``); None elsewhere."""
    if lattice is None or len(lattice.shape) == 1 or state is None:
        return None
    q = lattice.symmetries().get("rot90")
    return q if q is not None and mirror_symmetric(state, SYMMETRIC_RTOL, q) else None


def patch_mirror(lattice, state) -> "np.ndarray | None":
    """A mirror of a patch (``Lattice.symmetries``, in their order) that leaves the orbit's positions unchanged to
    ``SYMMETRIC_RTOL``: ``parity_blocks``' second symmetry; None on a chain, without a lattice, or when none does."""
    if lattice is None or len(lattice.shape) == 1 or state is None:
        return None
    for name, p in lattice.symmetries().items():
        if name.startswith("mirror") and mirror_symmetric(state, SYMMETRIC_RTOL, p):
            return p
    return None


#: the parity split is used when the half-period map A couples even and odd vectors by less than this
#: fraction of A's largest entry (round-off, ~1e-14, on a symmetric orbit); otherwise the whole Mu is solved
PARITY_COUPLING_RTOL = 1e-11


@functools.lru_cache(maxsize=8)
def _parity_basis(n: int) -> tuple:
    """Orthonormal even and odd bases of R^(2n) (u then v, each reflected j -> n - 1 - j). Basis vector
    k of each is w[k, 0] e[i[k, 0]] + w[k, 1] e[i[k, 1]]; returned as (i, w) per basis, so that it is
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
        out.append((np.column_stack([i1, i2]).astype(int), np.column_stack([w1, w2]).astype(float)))
    return tuple(out)


def _orbits(images: np.ndarray, chi) -> list:
    """The orbits of a group of site permutations that carry the character ``chi``: ``images`` (n, |G|) holds each
    site's image under every element (column 0 the identity), ``chi`` the character's value on each. One entry per
    orbit, (its smallest site, sum_g chi(g) e[g site] as a dict {site: coefficient}); orbits where the character
    vanishes (every coefficient 0: it is not trivial on the stabilizer) are left out."""
    sites = np.arange(images.shape[0])
    orbits = []
    for s in sites[images.min(axis=1) == sites]:  # one site per orbit: its smallest
        coefficient: dict = {}
        for t, site in enumerate(images[s]):
            coefficient[int(site)] = coefficient.get(int(site), 0.0) + chi[t]
        if abs(coefficient[int(s)]) >= 0.5:
            orbits.append((int(s), coefficient))
    return orbits


def _character_orbits(n: int, mirror) -> list:
    """The group {1, R, m, R m} on n sites (R: s -> n - 1 - s; m: ``mirror``) per character, in the order (R, m) =
    (+, +), (+, -), (-, +), (-, -): (sign under R, ``_orbits``); characters no orbit carries (a 2 x 2 patch's
    diagonal mirror) are left out. ``symmetry_bases`` and ``symmetry_extensions`` share it."""
    mirror = np.asarray(mirror)
    reverse = n - 1 - np.arange(n)
    images = np.stack([np.arange(n), reverse, mirror, reverse[mirror]], axis=1)  # (n, 4): e, R, m, R m
    out = []
    for sr, sm in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        orbits = _orbits(images, (1.0, sr, sm, sr * sm))
        if orbits:
            out.append((sr, orbits))
    return out


def symmetry_bases(n: int, mirror: np.ndarray) -> tuple:
    """Orthonormal bases of R^(2n) (u then v) per character of the group {1, R, m, R m}: R the reversal
    s -> n - 1 - s (a patch's 180-degree rotation about its centre, the chain's mirror), m a site permutation that
    is an involution commuting with R (a patch's mirror, ``Lattice.symmetries``). Basis vector k is
    sum_t w[k, t] e[i[k, t]] over the orbit of one site (sites fixed by an element: repeated with weight 0), the
    characters in the order of ``_character_orbits``, those that no orbit carries left out. Returns
    ((sign under R, (i, w)), ...)."""
    out = []
    for sr, orbits in _character_orbits(n, mirror):
        idx, w = [], []
        for _, vec in orbits:
            norm = np.sqrt(sum(x * x for x in vec.values()))
            entries = sorted(vec.items())
            row = entries + [(entries[0][0], 0.0)] * (4 - len(entries))
            idx.append([site for site, _ in row])
            w.append([x / norm for _, x in row])
        i, ww = np.array(idx, int).reshape(-1, 4), np.array(w, float).reshape(-1, 4)
        out.append((sr, (np.concatenate([i, i + n]), np.concatenate([ww, ww]))))
    return tuple(out)


def _apply_right(X: np.ndarray, basis) -> np.ndarray:
    """X @ S for a basis S from ``_parity_basis`` or ``symmetry_bases``."""
    i, w = basis
    out = X[:, i[:, 0]] * w[:, 0]
    for t in range(1, i.shape[1]):
        out = out + X[:, i[:, t]] * w[:, t]
    return out


def _apply_left(X: np.ndarray, basis) -> np.ndarray:
    """S^T @ X."""
    i, w = basis
    out = X[i[:, 0]] * w[:, 0, None]
    for t in range(1, i.shape[1]):
        out = out + X[i[:, t]] * w[:, t, None]
    return out


def _expand(Y: np.ndarray, basis, n2: int) -> np.ndarray:
    """S @ Y: vectors in the basis back to the 2N coordinates (each column of i holds distinct indices, so plain
    fancy-index assignment adds nothing twice; np.add.at was 1 s of a branch). basis None: Y is already in those
    coordinates."""
    if basis is None:
        return Y
    i, w = basis
    out = np.zeros((n2, Y.shape[1]), dtype=Y.dtype)
    for t in range(i.shape[1]):
        out[i[:, t]] += Y * w[:, t, None]
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


#: four host threads for the parity blocks (LAPACK releases the GIL; with one BLAS thread per call, ``hostblas``, the
#: blocks' eigs take the time of one where there are cores for them)
_block_pool = HostPool(4, "warpchain-floquet")


def parity_blocks(A: np.ndarray, M: float, mirror=None) -> "tuple[ParityBlock, ...] | None":
    """The reduced problem of a mirror-symmetric orbit from its half-period map A, per parity.

    The reflection commutes with the orbit's half-period map, so in an orthonormal basis S of even and
    odd vectors each block of A (A11, A12, A21, A22) is block-diagonal, and so is Mm (a basis vector
    pairs two sites of the same field, which have the same mass). Then Mu, P and the symplecticity
    gauge of each parity follow from ``reduced_products`` on the four blocks S^T Aij S of size ~N:
    products and eigs of two problems of ~N instead of one of 2N (about 4x less work each), done on
    host threads, and every eigenvector's parity is exact instead of read off with a threshold
    (which leaves near-degenerate even/odd pairs mixed, parity 0).

    ``mirror``: a second symmetry of a patch's orbit (a site permutation commuting with the reversal, the 180-degree
    rotation: ``symmetry_bases``), which splits each parity once more: four blocks of ~N / 2, ~16x less work than
    the whole for the products and the eigs (51 x 51 square patch, H200 host: the eigs took 11.7 s of the 20 s in two
    blocks), and a square patch's doubles (its x <-> y pairs) fall into different blocks. A block's ``parity`` stays
    the sign under the reversal.

    Returns:
        the ParityBlocks (even, odd; or the four with ``mirror``), or None when A couples them by more than
        PARITY_COUPLING_RTOL of A's largest entry (not a symmetric orbit).
    """
    n2 = A.shape[0] // 2
    N = n2 // 2
    if mirror is None:
        even, odd = _parity_basis(N)
        bases = ((1, even), (-1, odd))
    else:
        bases = symmetry_bases(N, mirror)
    parts = (A[:n2, :n2], A[:n2, n2:], A[n2:, :n2], A[n2:, n2:])
    scale = max(float(np.max(np.abs(A))), 1e-300)
    pool = _block_pool()  # numpy's gathers let go of the GIL too: the four parts at once

    def coupling_of(r):
        others = [(k, other) for k in range(len(bases)) for j, (_, other) in enumerate(bases) if j != k]
        return max(float(np.max(np.abs(_apply_left(r[k], other)), initial=0.0)) for k, other in others)

    right = list(pool.map(lambda X: [_apply_right(X, basis) for _, basis in bases], parts))
    if max(pool.map(coupling_of, right)) > PARITY_COUPLING_RTOL * scale:
        return None
    m = _masses(M, N)

    def block(sign, basis, k):
        Mu, sympl, P = _products(*(_apply_left(r[k], basis) for r in right), m[basis[0][:, 0]])
        mu, vec = np.linalg.eig(Mu)
        return ParityBlock(sign, basis, Mu, P, sympl, mu, vec)

    with blas_threads(1):  # LAPACK calls at once, one BLAS thread each (hostblas)
        jobs = [pool.submit(block, sign, basis, k) for k, (sign, basis) in enumerate(bases)]
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


def _extension(N: int, orbits: list) -> tuple:
    """The sparse E (2N x 2m) from the values at each orbit's own site (``_orbits``) to the vectors of the orbits'
    character, x = E y (E is 1 at the own site), and those sites' rows (``keep``)."""
    rows, cols, vals = [], [], []
    for k, (s, coefficient) in enumerate(orbits):
        own = coefficient[s]
        for site, c in coefficient.items():
            if c != 0.0:
                rows.append(site), cols.append(k), vals.append(c / own)
    m = len(orbits)
    kept = np.array([s for s, _ in orbits], int)
    r, c, v = np.array(rows, int), np.array(cols, int), np.array(vals, float)
    E = sp.csc_matrix((np.r_[v, v], (np.r_[r, r + N], np.r_[c, c + m])), shape=(2 * N, 2 * m))
    return E, np.r_[kept, N + kept]


def symmetry_extensions(N: int, mirror: np.ndarray, quarter=None) -> tuple:
    """``parity_extensions`` for the group {1, R, m, R m} of ``symmetry_bases``: per character (in its order), the
    sparse E (2N x 2m) from the values at one site of each orbit (its smallest; orbits where the character vanishes
    left out) to the vectors of that character, x = E y (E is 1 at the orbit's own site), and those sites' rows
    (``keep``): Mu E = E B with B = (Mu E)[keep].

    ``quarter``: a quarter turn Q (Q Q = R) that the orbit keeps too (a square patch's ``rot90``, ``patch_quarter``):
    with the mirror it makes the group D4 (eight elements). Its four one-dimensional characters split the even
    (R = +1) vectors in four blocks, (m, Q) = (+, +), (+, -), (-, +), (-, -), of roughly a quarter of them each
    (30, 20, 12 and 20 of 82 rows on 9 x 9). The odd vectors carry D4's two-dimensional character: Q maps the
    (R, m) = (-, +) block onto the (-, -) block (m Q m = Q^-1 = R Q, so m Q x = -Q x for an odd x that m keeps), so
    the two have the same B and the same multipliers, with vectors mapped by Q and the same Krein forms and
    participations (Q permutes sites and keeps P), and the second is the *twin* of the first: found once (its central
    weights are measured with the first's vectors: the central window is a row of sites, which Q moves). Six blocks
    (fewer on the smallest patches, where a character has no orbit), five of them solved, of about 1/8, 1/8, 1/8,
    1/8, 1/4 and 1/4 of the problem: the dense eigs take 1.5 times the cost of one of the four blocks of
    {1, R, m, R m} instead of 4 times.

    Returns:
        (blocks, twins): blocks ((sign under R, E, keep), ...); twins {block: the block it is the twin of}.
    """
    if quarter is None:
        return tuple((sr, *_extension(N, orbits)) for sr, orbits in _character_orbits(N, mirror)), {}
    m, Q = np.asarray(mirror), np.asarray(quarter)
    R = N - 1 - np.arange(N)
    if not (np.array_equal(Q[Q], R) and np.array_equal(m[Q[m]], Q[R])):
        raise ValueError("quarter must be a quarter turn (Q Q = R) that the mirror reverses (m Q m = Q^-1)")
    # D4's elements e, R, m, R m, Q, R Q, m Q, R m Q as site images; its even characters by their values on (m, Q)
    images = np.stack([np.arange(N), R, m, R[m], Q, R[Q], m[Q], R[m[Q]]], axis=1)
    blocks, twins = [], {}
    for sm, sq in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        orbits = _orbits(images, (1.0, 1.0, sm, sm, sq, sq, sm * sq, sm * sq))
        if orbits:
            blocks.append((1, *_extension(N, orbits)))
    odd = [orbits for sr, orbits in _character_orbits(N, m) if sr == -1]
    if odd:  # (-, +) solved, (-, -) its image under Q; or no odd vectors at all (no site off the centre)
        E, keep = _extension(N, odd[0])
        both = np.r_[Q, N + Q]  # the site permutation on u and v: row r of E goes to row both[r]
        coo = E.tocoo()
        twin = sp.csc_matrix((coo.data, (both[coo.row], coo.col)), shape=E.shape)
        blocks += [(-1, E, keep), (-1, twin, both[keep])]
        twins[len(blocks) - 1] = len(blocks) - 2
    return tuple(blocks), twins
