"""Every Floquet multiplier of a long lattice, and a count that proves none was missed (``floquet(solver="sliced")``).

**The slices.** Per parity block of the probed sparse Mu (``krylov_floquet.probed_problem``: the half-period map
from colour-group tangent runs, no 4N columns), the real segment [-1 - ``OUTER``, 1 + ``OUTER``] is cut into
segments holding equal numbers of the linear chain's mu (``segments``), and each segment is swept from its top by
shift-invert Arnoldi (ARPACK, the solves by the banded LU of ``BandedShifts``): at a shift sigma the
``SLICE_COUNT`` eigenvalues nearest sigma fill a disc of radius r that holds every eigenvalue nearer, so the shift
keeps those whose real part lies within ``KEEP`` r of sigma, and whatever of the segment it did not cover, above or
below, gets a shift of its own (``sweep``). Kept intervals tile the segment without overlap, so no eigenvalue is
counted twice, and each covers a strip of half-height sqrt(1 - KEEP^2) r around the axis. Every kept eigenpair's
residual is below ``RESIDUAL_TOL``; a shift whose rim falls in a dense cluster, which converges slowly, asks for
fewer eigenvalues (``_shift``). The segments run in worker processes at once (``continuation.workers``). Beyond
+-(1 + ``OUTER``) an outward disc and an Arnoldi of largest (smallest) real part look for outliers (real pairs,
period doubling).

**The count.** Slices find what lies near the axis; the count says whether that is all. Mu is self-adjoint in the
Krein form P = A11^T Mm A21 (P Mu = Mu^T P: ``floquet``'s module docstring; measured symmetric to 1e-14), so in
the basis of its eigenvectors P is block diagonal: a real mu with eigenvector a adds the sign of a^T P a (its Krein
signature, opposite) to P's inertia, a complex pair adds one positive and one negative. Hence, per block,

    n+(P) = (real mu with a^T P a > 0) + (complex pairs),    n-(P) = (real mu with a^T P a < 0) + (complex pairs),

and n0(P) = (real mu with a^T P a = 0): P's kernel is Mu-invariant (on a periodic ring it holds the uniform
translation, which moves no velocity). The found eigenvalues (genuine: their residuals; distinct: the kept
intervals) are all of them exactly when the three hold (n+ + n- + n0 = n; a Jordan block at an exact Krein
collision, non-generic, would not close the count). P's inertia comes from a block LDL^T in the interleaved band
order (``inertia``: dense diagonal blocks, Haynsworth's inertia additivity; a block whose eigenvalues come near zero
is merged with the next), O(n b^2). A lattice's symmetry makes double real mu (the square patch's x <-> y), which
Arnoldi returns as mu +- 1e-17 i: a pair whose Krein form is definite on its plane is a double real mu, and counts
as one (``degenerate_reals``; a genuine pair's form is indefinite there). A count that does not close makes the
verdict incomplete (``stable=None``), never a guess: a missed eigenvalue, wherever it lies in the plane, shows.
Checked against the dense eig (``tests/test_slicing.py``: the paper breather at N = 201 and 401, the K = 3 site
breather, an off-centre one, a periodic ring, square and triangular 11 x 11 patches: the same mu to 2e-14) and on an
H100 machine at N = 1601 .. 3201 (``benchmarks/breather_scaling.py``: to 2.7e-14).

**The probed path** (``floquet(solver="probed")``, ``probed_floquet``) finds each block's eigenvalues by one dense eig
of the block instead of slices (``dense_eig``: CuPy's, cuSOLVER's geev, on the flow's GPU where CuPy has it; LAPACK's
on the host otherwise), the blocks on threads of their own, and closes the same count. ``floquet(solver="auto")``
takes it from ``SLICED_MIN_SITES`` sites on a GPU with CuPy, and on the host below ``PROBED_HOST_MAX_SITES`` sites
(``continuation.floquet``).
"""

from __future__ import annotations

import contextlib
import re
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import ArpackError, ArpackNoConvergence

from .hostblas import host_pool
from .krylov_floquet import OUTWARD_COUNT, OUTWARD_SHIFT, BandedShifts, _arnoldi, _disc, real_phase
from .spectrum import assemble, central_sites, energy_centre, site_measures

#: the slices cover [-1 - OUTER, 1 + OUTER]; the outward discs and the outlier Arnoldi look beyond. Small: a first
#: shift far from the cluster at +1 converges slowly (paper breather, N = 1601: the segment from 1.02 down took 1.0 s
#: of the block's 2.5 s, its first shift alone 98 ms against 16 ms for a shift at 0.9995)
OUTER = 1e-4

#: eigenvalues asked of each shift (ARPACK's k): fewer make more shifts, but cheaper ones (paper breather, N = 1601,
#: one parity block, one process: k = 16 182 shifts in 2.8 s, 24 122 in 2.8 s, 32 94 in 2.1 s; N = 801: 30 in 0.7 s
#: against 60 in 1.7 s)
SLICE_COUNT = 32

#: Arnoldi vectors per wanted eigenvalue (ARPACK's ncv / k; its default is 2): in the acoustic band edge's cluster,
#: where the k-th and the next eigenvalue lie close, 3 converges faster (N = 1601, one BLAS thread: 99 ms against
#: 125 ms per shift at mu = 0.9978; 15 ms either way at mu = 0.9)
LANCZOS_FACTOR = 3

#: a shift keeps the eigenvalues whose real part lies within KEEP times its disc's radius (strip: sqrt(1 - KEEP^2) r)
KEEP = 0.8

#: segments per worker process (load balance: the segments' costs differ)
SEGMENTS_PER_WORKER = 4

#: outliers asked of each Arnoldi beyond the slices (strong real pairs, period doubling)
OUTLIERS = 6


def _interleaved(n: int) -> np.ndarray:
    half = n // 2
    perm = np.empty(n, int)
    perm[0::2], perm[1::2] = np.arange(half), half + np.arange(half)
    return perm


#: a diagonal block of ``inertia`` whose smallest |eigenvalue| is below this fraction of the matrix's largest entry
#: is merged with the next (its inverse would amplify round-off into the Schur complement)
PIVOT_RTOL = 1e-9


def inertia(S) -> dict:
    """Inertia of a symmetric banded sparse matrix (n x n, u then v, band in the interleaved order), by block
    LDL^T: dense diagonal blocks D_k (at least the half-bandwidth), their eigenvalues' signs counted, the Schur
    complement F D_k^-1 F^T carried into the next (Haynsworth: In(S) = In(D) + In(S / D)).

    Returns:
        {"positive", "negative", "zero", "worst_condition"}: counts and the largest condition number of a
        diagonal block used.
    """
    n = S.shape[0]
    perm = _interleaved(n) if n % 2 == 0 else np.arange(n)
    S = sp.csr_matrix(S)[perm][:, perm]
    coo = S.tocoo()
    w = int(np.max(np.abs(coo.row - coo.col))) if coo.nnz else 0
    scale = float(np.max(np.abs(S.data))) if S.nnz else 1.0
    step = max(w, 32)
    counts = {"positive": 0, "negative": 0, "zero": 0, "worst_condition": 1.0}
    i, carry = 0, None
    while i < n:
        j = min(n, i + step)
        while True:
            D = S[i:j, i:j].toarray()
            if carry is not None:
                D[: carry.shape[0], : carry.shape[0]] -= carry
            lam, Q = np.linalg.eigh(D)
            small = float(np.min(np.abs(lam)))
            if small > PIVOT_RTOL * scale or j == n:
                break
            j = min(n, j + step)
        counts["worst_condition"] = max(counts["worst_condition"], float(np.max(np.abs(lam))) / max(small, 1e-300))
        counts["positive"] += int(np.sum(lam > PIVOT_RTOL * scale))
        counts["negative"] += int(np.sum(lam < -PIVOT_RTOL * scale))
        counts["zero"] += int(np.sum(np.abs(lam) <= PIVOT_RTOL * scale))
        if j == n:
            break
        G = S[j : min(n, j + w), i:j].toarray() @ Q
        carry = (G / lam[None, :]) @ G.T
        i = j
    return counts


def segments(count: int, hint=None) -> list:
    """``count`` segments (lo, hi] of [-1 - OUTER, 1 + OUTER], highest first: equal in arg l (mu = cos arg l), or,
    given the expected mu (``hint``: the linear lattice's, ``floquet.linear_mu``), with nearly equal numbers of them
    (the acoustic band's flat top puts a quarter of the paper chain's multipliers within 1e-4 of one mu: that
    segment would take as long as all others), each cut in the widest gap between expected mu within a quarter of a
    segment of the equal-count cut (a cut inside a tight cluster sets a disc's rim among nearly equal eigenvalues,
    which converges slowly: ``TIE_RESTARTS``)."""
    if hint is None or len(hint) < 4 * count:
        edges = np.cos(np.linspace(0.0, np.pi, count + 1))
    else:
        h = np.sort(np.clip(np.real(hint), -1.0, 1.0))[::-1]
        n, reach = len(h), max(1, len(h) // (4 * count))
        edges = np.empty(count + 1)
        for i in range(1, count):
            at = int(round(i * n / count))
            window = np.arange(max(0, at - reach), min(n - 1, at + reach))
            j = window[np.argmax(h[window] - h[window + 1])]
            edges[i] = 0.5 * (h[j] + h[j + 1])
    edges[0], edges[-1] = 1.0 + OUTER, -1.0 - OUTER
    return [(float(edges[i + 1]), float(edges[i])) for i in range(count)]


def _measures(mu, vectors, P, E, M: float, centre: float, twin_near=None) -> tuple:
    """Krein form a^T P a (of the real vectors of real mu: ``krylov_floquet.real_phase``, as the window takes it),
    participation and central weight of eigenvectors in a block's coordinates (E: the block's extension to 2N, None
    for the whole Mu). Each column's numbers depend on that column alone: more than ``MEASURE_CHUNK`` columns (a
    dense block's thousands) are taken in chunks on host threads (numpy and scipy's sparse products let go of the
    GIL), each column's arithmetic the same either way. ``twin_near``: the sites whose weight is a twin block's
    central weight (``_probed_blocks``), a fourth column."""
    n = vectors.shape[1]
    if n <= MEASURE_CHUNK:
        return _column_measures(mu, vectors, P, E, M, centre, twin_near)
    # near-equal chunks, none of one column: numpy sums a lone (contiguous) column pairwise, a wider slice row by
    # row, as the whole array
    edges = np.linspace(0, n, -(-n // MEASURE_CHUNK) + 1).round().astype(int)
    chunks = [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]
    parts = list(host_pool().map(lambda c: _column_measures(mu[c], vectors[:, c], P, E, M, centre, twin_near), chunks))
    return tuple(np.concatenate(column) for column in zip(*parts))


def _column_measures(mu, vectors, P, E, M: float, centre: float, twin_near=None) -> tuple:
    vec = real_phase(vectors, mu)
    real = np.real(vec)
    act = np.sum(real * (P @ real), axis=0)
    x = vec if E is None else E @ vec
    return (act, *site_measures(x, M, centre, () if twin_near is None else (twin_near,)))


#: ``_measures`` takes more columns than this in chunks of this many, on ``hostblas.host_pool``'s threads
MEASURE_CHUNK = 256


#: a disc whose rim falls inside a dense cluster (the acoustic band's flat top: 110 of the paper chain's 6402 mu within
#: 1e-6 of one mu at N = 3201, where the group velocity vanishes; seen from a shift
#: 2e-4 away: its eigenvalues lie at nearly one distance) converges slowly, from either side (N = 3201: 2210 to 3404
#: solves at d_k / d_(k-1) = 1.0001 against ~100-260 elsewhere: 1 s of its segment's 2.5 s). After TIE_RESTARTS
#: restarts the shift asks for k / 8 instead, whose rim lies among the few eigenvalues of the sparse region around it
#: (``_shift``; 1.7 s for that segment)
TIE_RESTARTS = 6

#: an eigenpair kept from a disc has |Mu a - mu a| / |a| below this (ARPACK's own convergence test is relative to
#: the largest inverse eigenvalue: a shift 8e-9 from the symmetry-breaking pair left 1e-7 errors, residuals 1e-5)
RESIDUAL_TOL = 1e-11


def _residuals(op, vals, vectors) -> np.ndarray:
    """|op a - mu a| / |a| per column, in real arithmetic: op times the real parts, and times the imaginary parts of
    the complex mu's vectors only (a real mu's vector is real). A third of the complex product's time (N = 1601, one
    process: the check took 1.3 s of the slices' 6.4 s)."""
    x, y = vectors.real, vectors.imag
    r = op @ x - x * vals.real[None, :]
    complex_ = np.flatnonzero(vals.imag != 0)
    out = np.sum(r * r, axis=0)
    if len(complex_):
        yc, lr, li = y[:, complex_], vals.real[complex_], vals.imag[complex_]
        rr = r[:, complex_] + yc * li[None, :]
        ri = op @ yc - yc * lr[None, :] - x[:, complex_] * li[None, :]
        out[complex_] = np.sum(rr * rr, axis=0) + np.sum(ri * ri, axis=0)
    return np.sqrt(out) / np.linalg.norm(vectors, axis=0)


def _shift(op, banded, sigma: float, k: int) -> tuple:
    """One shift, ``_disc``'s tuple: k eigenvalues, or k / 8 (at least 4) when k does not converge in TIE_RESTARTS
    restarts, or k with twice the Arnoldi vectors and no limit when neither does (ARPACK's "no shifts could be
    applied" on a cluster larger than k included), or, failing that too, 4 k and 16 k (a cluster of equidistant
    eigenvalues around the k-th: a triangular patch's outward disc at -1 met eight at one distance from rank 3 on; at
    most op's order - 2). A disc whose eigenpairs' residuals exceed RESIDUAL_TOL (a shift within 1e-8 of an
    eigenvalue) is solved again a thousandth of its radius lower."""
    wider = sorted({min(c, op.shape[0] - 2) for c in (4 * k, 16 * k)} - {k})
    attempts = (  # (eigenvalues, Arnoldi vectors, restarts)
        (k, LANCZOS_FACTOR * k, TIE_RESTARTS),
        (max(4, k // 8), LANCZOS_FACTOR * max(4, k // 8), TIE_RESTARTS),
        (k, 2 * LANCZOS_FACTOR * k, None),
        *((c, LANCZOS_FACTOR * c, 4 * TIE_RESTARTS) for c in wider),
    )
    for _ in range(4):
        for i, (count, ncv, restarts) in enumerate(attempts):
            try:
                out = _disc(op, banded, sigma, count, ncv, restarts)
                break
            except (ArpackNoConvergence, ArpackError):  # the last, more Arnoldi vectors and no limit: raised
                if i == len(attempts) - 1:
                    raise
        residual = _residuals(op, out[0], out[1])
        if float(np.max(residual)) <= RESIDUAL_TOL * max(1.0, abs(sigma)):
            return out
        sigma -= 1e-3 * out[3]
    raise np.linalg.LinAlgError(f"no accurate disc near mu = {sigma!r}: residuals up to {np.max(residual):.1e}")


def sweep(op, lo: float, hi: float, k: int) -> tuple:
    """Every eigenvalue of ``op`` with real part in (lo, hi] and within the strip (module docstring): the highest
    interval not yet covered gets a shift one guessed radius below its top (the last disc's; its top for the first);
    the disc (``_shift``) covers the real parts within ``KEEP`` of its radius, and what it left of the interval, above
    or below, goes back on the list. Returns (mu, vectors, strip half-height, shifts)."""
    banded = BandedShifts.make(op)
    found, strip, shifts, todo, guess = [], np.inf, 0, [(lo, hi)], None
    while todo:
        low, high = todo.pop()  # the highest left
        sigma = high if guess is None else max(high - KEEP * guess, 0.5 * (low + high))
        vals, vectors, d, radius, at = _shift(op, banded, sigma, k)
        shifts += 1
        while radius < 1e-12 and len(vals) < op.shape[0] - 2:  # more than k (nearly) equal eigenvalues: ask more
            more = min(2 * len(vals), op.shape[0] - 2)
            vals, vectors, d, radius, at = _disc(op, banded, sigma, more, LANCZOS_FACTOR * more)
            shifts += 1
        bottom, top = max(low, at - KEEP * radius), min(high, at + KEEP * radius)
        inside = (d < radius) & (vals.real > bottom) & (vals.real <= top)
        found.append((vals[inside], vectors[:, inside]))
        strip, guess = min(strip, float(np.sqrt(1.0 - KEEP**2) * radius)), radius
        todo += [piece for piece in ((low, bottom), (top, high)) if piece[1] > piece[0]]
    mu = np.concatenate([v for v, _ in found]) if found else np.zeros(0, complex)
    vectors = np.hstack([x for _, x in found]) if found else np.zeros((op.shape[0], 0), complex)
    return mu, vectors, strip, shifts


def slice_task(op, P, E, lo: float, hi: float, k: int, M: float, centre: float, twin_near=None) -> dict:
    """One segment of one block (a worker's task): the eigenvalues, their Krein forms, participations and central
    weights (the vectors stay in the worker: 2N x 2N of them would not fit a long lattice's memory)."""
    start = time.perf_counter()
    mu, vectors, strip, shifts = sweep(op, lo, hi, k)
    return _report(
        mu, vectors, P, E, M, centre, twin_near, strip=strip, shifts=shifts, seconds=time.perf_counter() - start
    )  # fmt: skip


def outlier_task(op, P, E, sign: float, k: int, M: float, centre: float, twin_near=None) -> dict:
    """The eigenvalues of ``op`` beyond +(1 + OUTER) (``sign`` 1) or -(1 + OUTER) (-1): every one in the outward disc
    at 1 + ``OUTWARD_SHIFT`` (``krylov_floquet``'s, of ``OUTWARD_COUNT`` eigenvalues, fewer where its rim falls on a
    lattice's double eigenvalue: ``_shift``), and the converged ones of an
    Arnoldi of largest (smallest) real part beyond it (strong real pairs, period doubling). Any that neither sees is
    left to the count: an outward disc that converges in none of ``_shift``'s attempts finds nothing (``converged``
    False), and the verdict is incomplete unless the Arnoldi and the slices still account for every eigenvalue."""
    start = time.perf_counter()
    op = sp.csc_matrix(sign * op)
    try:
        vals, vectors, d, radius, sigma = _shift(op, BandedShifts.make(op), 1.0 + OUTWARD_SHIFT, min(OUTWARD_COUNT, k))
        disc = True
    except (ArpackNoConvergence, ArpackError, np.linalg.LinAlgError):
        vals, vectors, d, radius, sigma = np.zeros(0, complex), np.zeros((op.shape[0], 0)), np.zeros(0), 0.0, np.inf
        disc = False
    near = (d < radius) & (np.real(vals) > 1.0 + OUTER)
    far, far_vectors, residual, converged = _arnoldi(sp.csr_matrix(op), k)
    converged = converged and disc
    good = (residual < 1e-10) & (np.real(far) > 1.0 + OUTER) & (np.abs(far - sigma) >= radius)
    mu = np.concatenate([vals[near], far[good]])
    vectors = np.hstack([vectors[:, near], far_vectors[:, good]])
    return _report(
        sign * mu, vectors, P, E, M, centre, twin_near, converged=converged, seconds=time.perf_counter() - start
    )  # fmt: skip


def _plane_basis(columns: np.ndarray) -> "np.ndarray | None":
    """An orthonormal basis of the span of real ``columns`` (QR), or None when they are nearly dependent (a diagonal
    entry of R below 1e-6 of the largest: no basis of the span)."""
    basis, R = np.linalg.qr(columns)
    diagonal = np.abs(np.diag(R))
    if np.min(diagonal) < 1e-6 * np.max(diagonal):
        return None
    return basis


def _krein_plane(columns: np.ndarray, P) -> "tuple | None":
    """(B, lam, Q): an orthonormal basis B of the span of real ``columns`` (``_plane_basis``) and the
    eigen-decomposition of the Krein form on it, B^T P B = Q diag(lam) Q^T (so B Q are the form's eigenvectors, lam
    their forms); None when the columns have no basis. ``degenerate_reals`` reads a pair's forms through it
    (``hidden_neutral`` the same, for many clusters at once)."""
    basis = _plane_basis(columns)
    if basis is None:
        return None
    lam, Q = np.linalg.eigh(basis.T @ (P @ basis))
    return basis, lam, Q


def degenerate_reals(mu, vectors, P) -> tuple:
    """(mu, vectors) with each conjugate pair that is a double real eigenvalue written as two real ones.

    A lattice's symmetries make some multipliers double (the square patch's x <-> y: 7 to 9 pairs in the odd block
    of the rotation alone on a 15 x 15 patch), and Arnoldi, whose arithmetic does not keep Mu's Krein symmetry,
    returns such a double as mu +- i eps (eps ~ 1e-17). Which it is, the Krein form decides: a genuine pair's
    eigenvector a = x + i y has a^H P a = x^T P x + y^T P y = 0, so P on span{x, y} is indefinite, while a double
    real eigenvalue whose two modes have one Krein sign (the only kind that perturbations keep on the axis) has P
    definite there. A pair whose 2 x 2 form G = [x y]^T P [x y] is definite beyond ``neutral_form`` is replaced by
    its real part, twice, with the real vectors that diagonalize G (their Krein forms are G's eigenvalues); every
    other pair stays a pair, and so does one with |Im mu| above ``DOUBLE_IMAG`` or with x and y nearly parallel
    (then span{x, y} is no plane of eigenvectors)."""
    mu, vectors = np.array(mu, complex), np.asarray(vectors, complex)
    neutral = neutral_form(P)
    copied = False  # the vectors are copied before the first change (a dense block's are 2.6 GB)
    for i in np.flatnonzero((mu.imag > 0) & (mu.imag <= DOUBLE_IMAG * np.maximum(1.0, np.abs(mu)))):
        partners = np.flatnonzero((mu.imag < 0) & (np.abs(mu - np.conj(mu[i])) <= 1e-12 * max(1.0, abs(mu[i]))))
        if not len(partners):
            continue
        plane = _krein_plane(np.column_stack([vectors[:, i].real, vectors[:, i].imag]), P)
        if plane is None:
            continue
        basis, lam, Q = plane
        if np.all(lam > neutral) or np.all(lam < -neutral):
            j = partners[0]
            mu[i] = mu[j] = mu[i].real
            if not copied:
                vectors, copied = vectors.copy(), True
            vectors[:, [i, j]] = basis @ Q
    return mu, vectors


#: ``degenerate_reals`` looks at pairs with |Im mu| at most this (relative to max(1, |mu|)): the doubles seen came
#: with 1e-17 to 2e-16 (and a genuine pair, whose form is indefinite, is never converted at any |Im mu|: the limit is
#: a second guard)
DOUBLE_IMAG = 1e-12


def neutral_form(P) -> float:
    """A Krein form a^T P a (unit a) at most this large is zero: ``PIVOT_RTOL`` of P's largest entry, as P's
    inertia counts (``inertia``)."""
    return PIVOT_RTOL * (float(np.max(np.abs(P.data))) if P.nnz else 1.0)


#: real mu this close (relative to max(1, |mu|)) form one cluster for ``hidden_neutral``
CLUSTER_RTOL = 1e-9


#: ``hidden_neutral`` forms P x for this many clusters' columns at a time (one sparse product for all of them)
CLUSTER_BATCH = 1024


def hidden_neutral(mu, vectors, P):
    """``vectors`` with each cluster of (nearly) equal real mu that hides a direction of P's kernel written in the
    vectors that diagonalize the Krein form on its span. On a periodic or free lattice the uniform translation moves
    no velocity (P t = 0) and shares mu = 1 with the phase mode; Arnoldi returns two mixtures of them, each with a
    positive form, and the count (one positive, one zero) did not close (a 9 x 9 periodic patch, a periodic ring at
    K = 3). Where the form on the cluster's span has an eigenvalue below ``neutral_form`` while every vector's own is
    above it, the cluster's vectors become G's eigenvectors (G = B^T P B over an orthonormal basis B of the span):
    their forms are G's eigenvalues, one of them neutral. Every other cluster is left as it is.

    The products with P are formed for many clusters at once (``CLUSTER_BATCH`` columns: a square patch's x <-> y
    symmetry makes thousands of doubles, and P was read once per cluster); each column's product is the one it has
    alone, so the result is the same bit for bit."""
    real = np.flatnonzero(mu.imag == 0)
    if len(real) < 2:
        return vectors
    copied = False  # the vectors are copied before the first change
    neutral = neutral_form(P)
    order = real[np.argsort(mu.real[real])]
    values = mu.real[order]
    breaks = np.flatnonzero(np.diff(values) > CLUSTER_RTOL * np.maximum(1.0, np.abs(values[1:]))) + 1
    clusters = [c for c in np.split(order, breaks) if len(c) >= 2]
    while clusters:
        batch, width = [], 0
        while clusters and (not batch or width + len(clusters[0]) <= CLUSTER_BATCH):
            batch.append(clusters.pop(0))
            width += len(batch[-1])
        xs = [real_phase(vectors[:, c], mu[c]).real for c in batch]
        edges = np.cumsum([0] + [x.shape[1] for x in xs])
        PX = P @ np.hstack(xs)
        bases = [_plane_basis(x) for x in xs]
        kept = [b for b in bases if b is not None]
        PB = P @ np.hstack(kept) if kept else None
        at = 0
        for cluster, x, basis, lo, hi in zip(batch, xs, bases, edges[:-1], edges[1:]):
            if basis is None:
                continue
            lam, Q = np.linalg.eigh(basis.T @ PB[:, at : at + basis.shape[1]])
            at += basis.shape[1]
            own = np.sum(x * PX[:, lo:hi], axis=0)
            if np.min(np.abs(lam)) <= neutral and np.all(np.abs(own) > neutral):
                if not copied:
                    vectors, copied = np.array(vectors, copy=True), True
                vectors[:, cluster] = basis @ Q
    return vectors


def _report(mu, vectors, P, E, M, centre, twin_near=None, **extra) -> dict:
    """The measures of a block's found eigenpairs (``_measures``); with ``twin_near``, the twin block's central weights
    too (``twin_central_weight``: its vectors are these under the quarter turn, which moves the central window)."""
    if len(mu):
        mu, vectors = degenerate_reals(mu, vectors, P)
        vectors = hidden_neutral(mu, vectors, P)
    columns = 3 if twin_near is None else 4
    measures = _measures(mu, vectors, P, E, M, centre, twin_near) if len(mu) else (np.zeros(0),) * columns
    names = ("act", "participation", "central_weight", "twin_central_weight")
    return {"mu": mu, **dict(zip(names, measures)), **extra}


#: a block of at most this many rows (a small patch's D4 blocks: 2 rows on 5 x 5, where ARPACK's k = rows - 2 is 0)
#: gets a dense eig, not slices
SMALL_BLOCK_ROWS = 8

#: from this many rows of a parity block on, the slices run in worker processes (below, here: the workers' start
#: and the operator's transfer cost more than they save)
PROCESS_MIN_ROWS = 600


def _probed_blocks(lin, M: float, state, lattice) -> dict:
    """The probed problem (``krylov_floquet.probed_problem``) as per-block operators: ``ops`` (B = (Mu E)[keep], or
    Mu), their Krein forms ``forms`` (E^T P E) and extensions, the symplecticity gauge and the energy centre. A twin
    block (``problem["twins"]``) shares its source's operator and form: its multipliers are found once, for both
    (``solved``). Runs under ``blas_threads(1)`` (the caller's)."""
    from .krylov_floquet import probed_problem

    problem = probed_problem(lin, M, state, lattice)
    Mu, blocks, twins = problem["Mu"], problem["blocks"], problem["twins"]
    # the operators need Mu alone: made while the checks' thread forms P (``probed_problem``), then the forms
    ops, forms, extensions = [], [], [E for _, E, _ in blocks]
    for b, (_, E, keep) in enumerate(blocks):  # a twin has its source's B and form (``parity.symmetry_extensions``)
        ops.append(Mu if E is None else ops[twins[b]] if b in twins else sp.csc_matrix((Mu @ E)[keep]))
    sympl, P = problem["checks"].result()
    P = sp.csc_matrix(0.5 * (P + P.T))
    for b, (_, E, _) in enumerate(blocks):
        forms.append(P if E is None else forms[twins[b]] if b in twins else sp.csc_matrix(E.T @ P @ E))
    centre = energy_centre(state) if state is not None else float("nan")
    solved = [b for b in range(len(ops)) if b not in twins]
    # a twin's vectors are its source's under the quarter turn Q (x_twin[Q r] = x[r]): its central weight is the
    # source vectors' weight on the sites that Q takes into the central window
    twin_near = {}
    if problem["quarter"] is not None and np.isfinite(centre):
        window = central_sites(problem["N"], centre)
        twin_near = {source: window[problem["quarter"]] for source in twins.values()}
    return {
        **problem, "ops": ops, "forms": forms, "extensions": extensions, "symplecticity": sympl, "centre": centre,
        "solved": solved, "twin_near": twin_near,
    }  # fmt: skip


def _with_twins(problem: dict, reports: list, owner: list) -> tuple:
    """The solved blocks' reports, and each twin block's from its source's: the same mu, Krein forms and
    participations (the quarter turn maps one block's vectors onto the other's, permuting sites, and keeps P), and the
    central weights the source's task measured for the twin (``twin_central_weight``: the central window is a row of
    sites, which the quarter turn moves). A double mu's two weights depend on the basis chosen in its plane (here
    (w(x), w(Q x)), split otherwise by the dense eig); their sum does not."""
    extra = [
        ({**r, "central_weight": r["twin_central_weight"]}, b)
        for b, source in problem["twins"].items()
        for r, o in zip(reports, owner)
        if o == source
    ]
    return reports + [r for r, _ in extra], owner + [b for _, b in extra]


def _start_counts(problem: dict) -> dict:
    """P's inertia in each solved block (``inertia``), started side by side on ``hostblas.host_pool`` (one BLAS thread
    each: the caller's ``blas_threads(1)``), so that they run beside the eigensolves: {block: future}. The caller
    wraps its eigensolves in ``_dropped_on_error``."""
    pool = host_pool()
    return {b: pool.submit(inertia, problem["forms"][b]) for b in problem["solved"]}


@contextlib.contextmanager
def _dropped_on_error(counts: dict):
    """Where the eigensolves fail, the counts not yet started are cancelled once the error reaches here (on the probed
    path after the blocks' eigs already running have ended); a count already running ends on its own, unread."""
    try:
        yield
    except BaseException:
        for future in counts.values():
            future.cancel()
        raise


def _counted(
    problem: dict, reports: list, owner: list, coverage: dict, tolerance, *, path: str, start, seconds, counts=None
):
    """The result of a path that found eigenvalues per block (``reports``, each of block ``owner[i]``): each block's
    count against P's inertia (module docstring), complete when every one closes. ``counts``: ``_start_counts``'
    futures where the caller started them early; ``seconds["count"]`` is the wait for them here."""
    mark = time.perf_counter()
    forms, twins = problem["forms"], problem["twins"]
    reports, owner = _with_twins(problem, reports, owner)
    counts = {b: f.result() for b, f in (counts if counts is not None else _start_counts(problem)).items()}
    counts.update({b: counts[source] for b, source in twins.items()})  # a twin's form is its source's
    seconds["count"] = time.perf_counter() - mark
    parts, coverage_blocks = [], []
    for b, (parity, _, _) in enumerate(problem["blocks"]):
        mine = [r for r, o in zip(reports, owner) if o == b]
        part = {key: np.concatenate([r[key] for r in mine]) for key in ("mu", "act", "participation", "central_weight")}
        part["parity"] = np.full(len(part["mu"]), parity, int)
        mu, act = part["mu"], part["act"]
        # P's kernel (a ring's uniform translation: it moves no velocity, so P a = 0) is Mu-invariant, hence spanned
        # by eigenvectors of Mu whose Krein form vanishes: each such eigenvalue matches a zero of P's inertia
        neutral = neutral_form(forms[b])
        real = mu.imag == 0
        found = {
            "real_positive": int(np.sum(real & (act > neutral))),
            "real_negative": int(np.sum(real & (act < -neutral))),
            "real_neutral": int(np.sum(real & (np.abs(act) <= neutral))),
            "pairs": int(np.sum(mu.imag > 0)),
            "unpaired": int(np.sum(mu.imag > 0)) - int(np.sum(mu.imag < 0)),
        }
        c = counts[b]
        closed = (
            found["unpaired"] == 0
            and found["real_positive"] + found["pairs"] == c["positive"]
            and found["real_negative"] + found["pairs"] == c["negative"]
            and found["real_neutral"] == c["zero"]
        )
        coverage_blocks.append(
            {
                "parity": int(parity),
                "rows": int(problem["ops"][b].shape[0]),
                "inertia": {k: c[k] for k in ("positive", "negative", "zero")},
                "inertia_worst_condition": c["worst_condition"],
                "found": found,
                "closed": bool(closed),
                **({"twin_of": int(twins[b])} if b in twins else {}),
            }
        )
        parts.append(part)
    closed = all(b["closed"] for b in coverage_blocks)
    coverage = {
        **coverage,
        "counts": coverage_blocks,
        "closed": closed,
        "unseen": "nothing when closed (P's inertia equals what was found in every block); otherwise the missing "
        "count per block is in counts: solver='dense' sees every one",
    }
    return assemble(
        np.concatenate([p["mu"] for p in parts]),
        np.concatenate([p["parity"] for p in parts]),
        np.concatenate([p["act"] for p in parts]),
        np.concatenate([p["participation"] for p in parts]),
        np.concatenate([p["central_weight"] for p in parts]),
        problem["N"],
        {"symplecticity": problem["symplecticity"], "probe_halfwidth": problem["halfwidth"]},
        tolerance,
        path=path,
        vectors=None,
        coverage=coverage,
        complete=closed,
        wall_seconds=time.perf_counter() - start,
        stats={"tangent_columns": problem["tangent_columns"], "shifts": coverage.get("shifts", 0), "seconds": seconds},
    )


def sliced_floquet(
    lin, M: float, state=None, tolerance=None, *, hint=None, processes: bool | None = None, lattice=None
):
    """Every multiplier of a reversible orbit from its half-period Linearization, counted (module docstring): a
    ``FloquetResult`` with ``path="sliced"``, complete (a verdict) when the count closes in every parity block,
    else ``stable`` None with the counts in ``coverage``; no ``vectors`` (2N x 2N of them). ``hint``: the expected
    mu, to cut segments of equal work (``segments``). ``processes``: the slices in worker processes (default: from
    ``PROCESS_MIN_ROWS`` rows of a block on). ``lattice``: a patch's, whose mirror splits the blocks once more
    (``krylov_floquet.probed_problem``)."""
    from .hostblas import blas_threads
    from .workers import Shared, Workers

    start = time.perf_counter()
    with blas_threads(1):
        problem = _probed_blocks(lin, M, state, lattice)
        seconds = {"probe": time.perf_counter() - start}
        counts = _start_counts(problem)  # on host threads beside the slices
        with _dropped_on_error(counts):
            ops, forms, extensions = problem["ops"], problem["forms"], problem["extensions"]
            centre = problem["centre"]
            if processes is None:
                processes = max(op.shape[0] for op in ops) >= PROCESS_MIN_ROWS
            workers = Workers.shared() if processes else None
            count = max(1, (workers.count if workers else 1) * SEGMENTS_PER_WORKER // len(problem["solved"]))
            tasks, owner = [], []
            small = []  # blocks too small to slice (ARPACK's k < rows - 1): a dense eig here
            for b, (op, form, E) in enumerate(zip(ops, forms, extensions)):
                near = problem["twin_near"].get(b)
                if b in problem["twins"]:
                    continue  # found with its source (``_counted``)
                if op.shape[0] <= SMALL_BLOCK_ROWS:
                    small.append((b, dense_task(op, form, E, M, centre, None, near)))
                    continue
                shared = (Shared(op), Shared(form), Shared(E)) if processes else (op, form, E)
                k = int(min(SLICE_COUNT, op.shape[0] - 2))
                for lo, hi in segments(count, hint):
                    tasks.append(("slice_task", (*shared, lo, hi, k, M, centre, near)))
                    owner.append(b)
                for sign in (1.0, -1.0):
                    tasks.append(("outlier_task", (*shared, sign, int(min(OUTLIERS, k)), M, centre, near)))
                    owner.append(b)
            mark = time.perf_counter()
            if processes:
                reports = workers.map("continuation.slicing", tasks, what="Floquet slice")
            else:
                reports = [globals()[f](*args) for f, args in tasks]
            seconds["slices"] = time.perf_counter() - mark
            slices = [r for r in reports if "strip" in r]
            coverage = {
                "method": "sliced",
                "interval": [-1.0 - OUTER, 1.0 + OUTER],
                "segments": len(slices),
                "shifts": int(sum(r["shifts"] for r in slices)),
                "strip_half_height": float(min((r["strip"] for r in slices), default=np.inf)),
                "outliers_converged": all(r["converged"] for r in reports if "strip" not in r),
                "processes": bool(processes),
                "dense_blocks": [b for b, _ in small],
            }
            reports, owner = list(reports) + [r for _, r in small], owner + [b for b, _ in small]
            return _counted(
                problem, reports, owner, coverage, tolerance, path="sliced", start=start, seconds=seconds,
                counts=counts,
            )  # fmt: skip


def dense_eig(matrix: np.ndarray, device=None) -> tuple:
    """Eigenvalues and right eigenvectors of a dense real matrix: with CuPy on ``device``'s GPU where ``has_gpu_eig``
    (``cupy.linalg.eig``, cuSOLVER's geev: 7.6 s for the eigenvalues of a 12800-square matrix on an H200, against
    5.6 s for a 3200-square one by the host's LAPACK on 16 cores), else LAPACK's on the host. The GPU's part runs
    under the device's lock (``warpchain.engine.devices.device_lock``: no allocation or sync while another thread
    captures a Warp graph there), and CuPy's pool gives its memory back after."""
    if not has_gpu_eig(device):
        return np.linalg.eig(matrix)
    import cupy

    from warpchain.engine.devices import device_lock

    with device_lock(str(device)), cupy.cuda.Device(gpu_index(device)):
        try:
            mu, vectors = cupy.linalg.eig(cupy.asarray(matrix))
            return cupy.asnumpy(mu), cupy.asnumpy(vectors)
        finally:
            mu = vectors = None
            cupy.get_default_memory_pool().free_all_blocks()


def gpu_index(device) -> "int | None":
    """The CUDA ordinal ``device`` names (``"cuda"``, ``"cuda:1"``), or None for anything else (the CPU, numpy)."""
    match = re.fullmatch(r"cuda(?::(\d+))?", str(device).strip().lower()) if device is not None else None
    return None if match is None else int(match.group(1) or 0)


def has_gpu_eig(device) -> bool:
    """Whether ``dense_eig`` runs on a GPU for ``device``: it names one, CuPy imports, and its ``linalg.eig`` is there
    with cuSOLVER's geev (CuPy 14 on CUDA 12.6 or later); otherwise the host's LAPACK does the work."""
    if gpu_index(device) is None:
        return False
    try:
        import cupy
        from cupyx import cusolver
    except ImportError:
        return False
    try:
        return hasattr(cupy.linalg, "eig") and bool(cusolver.check_availability("geev"))
    except Exception:  # an older cupyx without the name, or no driver: the host's eig
        return False


def dense_task(op, P, E, M: float, centre: float, device=None, twin_near=None) -> dict:
    """One block's eigenvalues all at once, by a dense eig of its probed operator (``dense_eig``), with their Krein
    forms, participations and central weights."""
    start = time.perf_counter()
    mu, vectors = dense_eig(op.toarray(), device)
    return _report(mu, vectors, P, E, M, centre, twin_near, seconds=time.perf_counter() - start)


def probed_floquet(lin, M: float, state=None, tolerance=None, *, lattice=None, device=None):
    """Every multiplier of a reversible orbit from the probed sparse Mu (no 4N tangent columns), by a dense eig of
    each parity block (``dense_eig``: on the GPU with CuPy where ``device`` is one), then counted against P's inertia
    as the slices are (module docstring): ``path="probed"``, complete when every block's count closes.

    Every host LAPACK call runs on one BLAS thread (``hostblas``), side by side: P's inertia per block from the
    moment the forms are made (``_start_counts``), and each block's measures (Krein forms, participations) on a
    thread of its own. On the GPU the eigs run one after another, the largest block first, so that the smaller ones
    and every block's measures fall within the largest one's eig (a 101 x 101 square patch: one block of 1/4 and
    four of 1/8); on the host each block's eig is on its thread."""
    from .hostblas import blas_threads

    start = time.perf_counter()
    gpu = has_gpu_eig(device)
    with blas_threads(1):
        problem = _probed_blocks(lin, M, state, lattice)
        seconds = {"probe": time.perf_counter() - start}
        counts = _start_counts(problem)
        with _dropped_on_error(counts):
            mark = time.perf_counter()
            solved, centre = problem["solved"], problem["centre"]
            ops, forms, extensions = problem["ops"], problem["forms"], problem["extensions"]
            order = sorted(solved, key=lambda b: -ops[b].shape[0])
            with ThreadPoolExecutor(len(order)) as pool:
                if gpu:
                    futures = {}
                    for b in order:
                        t = time.perf_counter()
                        mu, vectors = dense_eig(ops[b].toarray(), device)
                        futures[b] = pool.submit(
                            _report, mu, vectors, forms[b], extensions[b], M, centre, problem["twin_near"].get(b),
                            seconds=time.perf_counter() - t,
                        )  # fmt: skip
                        mu = vectors = None
                else:
                    futures = {
                        b: pool.submit(
                            dense_task, ops[b], forms[b], extensions[b], M, centre, None, problem["twin_near"].get(b)
                        )
                        for b in order
                    }
                reports = [futures[b].result() for b in solved]
            seconds["eig"] = time.perf_counter() - mark
            coverage = {"method": "probed", "eig": "gpu" if gpu else "host"}
            return _counted(
                problem, reports, list(solved), coverage, tolerance, path="probed", start=start, seconds=seconds,
                counts=counts,
            )  # fmt: skip
