"""Floquet multipliers of a long lattice without its 4N tangent columns or its 2N eig: the half-period map
probed by colour groups (``probed_problem``: what the complete sliced path, ``continuation.slicing``, starts from
too), and the multipliers near +1 and -1 by shift-invert Arnoldi (``floquet(solver="window")``: a partial
analysis, no verdict).

**The half-period map is banded.** A tangent perturbation travels a few sites per unit time and beyond that light
cone its amplitude falls faster than exponentially (an entry of the paper chain's full-period Mu is 1e-14 of the
largest at 30 sites from the diagonal, 1e-28 at 40). So one tangent run from a colour group of sites 2 b + 1 apart
gives all of their columns at once, and 4 (2 b + 1) runs give all of A whatever N: 260 at b = 32 instead of 4N
(6404 at N = 1601, 51 204 at 12 801), checked at the band's edge (``warpchain.Linearization.probed_columns``).

**Products stay sparse.** Mu = Mm^-1 (A22^T Mm A11 + A12^T Mm A21), P = A11^T Mm A21 (the Krein form) and the
symplecticity gauge are formed from A's sparse blocks exactly as ``floquet.reduced_products`` forms them from
dense ones (bandwidth 2 b).

**Which multipliers: windows at +1 and -1.** mu = cos(arg l) on the unit circle, so the multipliers within
angle theta of +1 (or -1) are the mu in [cos theta, 1] (or [-1, -cos theta]). Every instability of the breathers
seen so far sits there: the symmetry-breaking real pair (mu = 1 + 1e-8), and the finite-size quadruplets
(Re mu in [0.92, 0.997] at N = 201 .. 801), collisions of the acoustic modes with the optical ones near 2 w_b.
Per parity block and per end, shift-invert Arnoldi (ARPACK through ``scipy.sparse.linalg.eigs``; the solves by
LAPACK's banded LU of Mu - sigma in the interleaved order, ``BandedShifts``) returns the ``count`` eigenvalues nearest
a shift sigma just outside the end; the disc out to the last of them holds every eigenvalue there, so the shift keeps
those whose real part lies within half the disc's radius of sigma. With ``width`` > 0 further shifts sweep inwards,
each at the previous one's cut, until the window reaches 1 - width (and -1 + width). The discs cover the real
segment and a strip around it of half-height >= sqrt(3)/2 times the smallest radius
(``coverage["strip_half_height"]``). Beyond the first disc one more shift, at 1 + ``OUTWARD_SHIFT``, holds every
eigenvalue out to ~1.008 (real pairs of |l| up to ~1.13, which the first disc at large N no longer reaches and the
plain Arnoldi does not yet separate from the cluster at the end); beyond that (strong real pairs, period doubling:
|mu| well above 1) an Arnoldi without shift looks for the eigenvalues of largest real part, which converge fast
when they stand apart (``coverage["beyond_converged"]`` says whether all it was asked for converged: usually not,
as the cluster at the end does not, and only converged ones are reported). ARPACK starts from a fixed vector
(``eigs``), so a solve gives the same bits in any process and after any other call. The four solves (two parity
blocks, two ends) are independent; on long chains (``PROCESS_MIN_ROWS``) they run in worker processes, all at once
(``_ends``, ``continuation.workers``): ARPACK holds the GIL, so threads would run them one after the other.

**What a window cannot see**: an instability whose mu lies between the covered intervals (a multiplier further
from both +1 and -1 than the window reaches: a quadruplet from a collision in the middle of the circle), one further
off the axis than the strip, or an outlier the last Arnoldi did not converge to. ``FloquetResult.coverage`` says
what was covered. So a window gives no verdict: ``stable`` is None, ``partial_stable`` says whether it saw an
instability. The paper breather at N = 1601 and 2401 is unstable through extended quadruplets the default window does
not reach; ``solver="sliced"`` and ``"dense"`` see every multiplier.
"""

from __future__ import annotations

import dataclasses
import inspect
import operator
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg.lapack import dgbtrf, dgbtrs

from .hostblas import host_pool
from .spectrum import assemble, energy_centre, site_measures


def _blocks(A, M: float) -> tuple:
    """The four blocks of A (CSC) and the diagonal mass matrix Mm."""
    n2 = A.shape[0] // 2
    N = n2 // 2
    A = sp.csc_matrix(A)
    m = np.concatenate([np.full(N, float(M)), np.ones(N)])
    return A[:n2, :n2], A[:n2, n2:], A[n2:, :n2], A[n2:, n2:], sp.diags(m)


#: rows of a product's left factor per task of ``_products``
PRODUCT_ROWS = 512


def _products(pairs, rows: int = PRODUCT_ROWS) -> list:
    """[L @ R for (L, R) in pairs], sparse, each in chunks of ``rows`` rows of L on ``hostblas.host_pool`` (scipy's
    sparse products let go of the GIL). scipy multiplies CSR by CSR row by row, a row's sum over L's row in its
    stored order whatever rows go with it: for the canonical CSR (or CSC, which scipy turns into CSR on the right)
    factors of the probed problem, the one-call product bit for bit, on any number of threads. A 101 x 101 patch's
    four products (``_mu``, ``_checks``) were most of its probe's host time on one thread each. Each product's chunks
    are let go once it is stacked (the chunks and the stack are two copies of it, briefly)."""
    pool, pending = host_pool(), []
    for L, R in pairs:
        L, R = sp.csr_matrix(L), sp.csr_matrix(R)
        pending.append([pool.submit(operator.matmul, L[i : i + rows], R) for i in range(0, max(1, L.shape[0]), rows)])
    out = []
    while pending:
        chunks = pending.pop(0)
        out.append(sp.vstack([f.result() for f in chunks], format="csr"))
        del chunks
    return out


def _mu(A11, A12, A21, A22, Dm) -> tuple:
    """(Mu, X, Y): Mu = Mm^-1 (X + Y), X = A22^T Mm A11, Y = A12^T Mm A21 (``_products``)."""
    X, Y = _products([(A22.T @ Dm, A11), (A12.T @ Dm, A21)])
    return sp.csc_matrix(sp.diags(1.0 / Dm.diagonal()) @ (X + Y)), X, Y


def _checks(X, Y, A11, A12, A21, A22, Dm) -> tuple:
    """(symplecticity, P): the largest entry of S12 = Mm^-1 (X - Y) - 1, P - P^T and Mm^-1 (Z - Z^T) Mm^-1
    (Z = A12^T Mm A22), as ``floquet.reduced_products``, and the Krein form P = A11^T Mm A21. ``krylov_floquet``
    runs it beside the eigensolves, which need Mu alone."""
    Dinv = sp.diags(1.0 / Dm.diagonal())
    P, Z = _products([(A11.T @ Dm, A21), (A12.T @ Dm, A22)])
    S12 = Dinv @ (X - Y) - sp.identity(X.shape[0])
    S22 = Dinv @ (Z - Z.T) @ Dinv

    def amax(S):
        S = sp.csr_matrix(S)
        return float(np.max(np.abs(S.data))) if S.nnz else 0.0

    return max(amax(S12), amax(P - P.T), amax(S22)), sp.csc_matrix(P)


#: entries of Mu below this fraction of its largest are dropped before the eigensolves: far below a float64's
#: resolution of the eigenvalues, and they halve the band (the paper chain's Mu falls to 1e-17 of its largest
#: 32 sites off the diagonal and to 1e-28 at 40, where the products of the probed A reach 64)
MU_DROP = 1e-20


def negligible_dropped(Mu):
    """Mu (CSC) without its entries below ``MU_DROP`` of the largest: a narrower band for the banded LU's solves."""
    Mu = sp.csc_matrix(Mu, copy=True)
    if Mu.nnz:
        Mu.data[np.abs(Mu.data) < MU_DROP * np.max(np.abs(Mu.data))] = 0.0
        Mu.eliminate_zeros()
    return Mu


#: the first shift sits this far beyond +1 (and -1), where the trivial mu sits: a shift exactly on an eigenvalue
#: would factor a singular matrix. Small, so that the first disc's radius goes inwards: at 1.2345e-3 the first disc
#: at N = 12801 covered nothing below 1, and each end took two or three shifts instead of one (N = 3201: 6 shifts
#: in 1.64 s against 4 in 1.35 s at 1e-4; 12801: 10 shifts against 4). What lies further out is the outward disc's
#: (``OUTWARD_SHIFT``).
START_OFFSET = 1e-4


@dataclasses.dataclass(frozen=True)
class FloquetWindow:
    """Which multipliers ``floquet(solver="window")`` computes.

    Attributes:
        count: eigenvalues per shift (ARPACK's k): the first shift at each end returns the ``count`` mu nearest
            +1 (or -1), so ``count`` alone sets the window (0.99956 .. 1 at N = 3201 for 60).
        width: sweep on inwards until the window reaches 1 - width (and -1 + width): more shifts, every mu there
            (0: the first shift's disc only).
    """

    count: int = 60
    width: float = 0.0

    def __post_init__(self):
        if not (isinstance(self.count, int) and self.count >= 4):
            raise ValueError(f"count must be an integer >= 4, got {self.count!r}")
        if not 0.0 <= self.width <= 2.0:
            raise ValueError(f"width must be in [0, 2], got {self.width!r}")


class BandedShifts:
    """(op - sigma)^-1 for many shifts sigma of one sparse op, by LAPACK's banded LU (dgbtrf / dgbtrs) in the
    interleaved order (u_1, v_1, u_2, v_2, ...), where Mu's band is 2 (2 b + 1) wide: ~3.5x faster solves than
    SuperLU on the paper chain (0.18 ms against 0.65 ms at N = 3201). ``None`` from ``make`` when the band is not
    narrow (then ARPACK factors op - sigma with SuperLU)."""

    def __init__(self, n, perm, rows, cols, data, kl, ku):
        self.n, self.perm, self.rows, self.cols, self.data, self.kl, self.ku = n, perm, rows, cols, data, kl, ku

    @classmethod
    def make(cls, op):
        n = op.shape[0]
        half = n // 2
        perm = np.empty(n, int)
        perm[0::2], perm[1::2] = np.arange(half), half + np.arange(half)
        coo = sp.coo_matrix(sp.csr_matrix(op)[perm][:, perm])
        kl, ku = int(max(0, np.max(coo.row - coo.col))), int(max(0, np.max(coo.col - coo.row)))
        if n % 2 or 4 * (kl + ku) > n:
            return None
        return cls(n, perm, coo.row, coo.col, coo.data, kl, ku)

    def inverse(self, sigma: float):
        n, kl, ku, perm = self.n, self.kl, self.ku, self.perm
        ab = np.zeros((2 * kl + ku + 1, n))
        ab[kl + ku + self.rows - self.cols, self.cols] = self.data
        ab[kl + ku, :] -= sigma
        lu, piv, info = dgbtrf(ab, kl, ku, overwrite_ab=True)
        if info != 0:
            raise np.linalg.LinAlgError(f"op - sigma is singular at sigma = {sigma!r} (dgbtrf info {info})")

        def solve(x):
            x = np.asarray(x).reshape(n)
            parts = np.stack([x.real, x.imag], axis=1)[perm] if np.iscomplexobj(x) else x[perm, None]
            y, _ = dgbtrs(lu, kl, ku, parts, piv, overwrite_b=True)
            out = np.empty(n, dtype=np.result_type(x.dtype, np.float64))
            out[perm] = y[:, 0] + 1j * y[:, 1] if np.iscomplexobj(x) else y[:, 0]
            return out

        return spla.LinearOperator((n, n), matvec=solve, dtype=np.float64)


def _window(plus: dict, minus: dict, k: int, width: float) -> tuple:
    """One op's window from its two ends (``_end`` of op and of -op): the mu, their vectors and the coverage.

    Returns:
        (mu (count,), vectors (2N, count), coverage dict).
    """
    mu = np.concatenate([plus["mu"], -1.0 * minus["mu"]])  # not -mu: a real mu keeps its +0j (the sqrt branch)
    order = np.argsort(-np.real(mu), kind="stable")
    coverage = {
        "count": k,
        "width": float(width),
        "covered": [[-minus["outer"], -minus["cut"]], [plus["cut"], plus["outer"]]],
        "beyond_converged": plus["converged"] and minus["converged"],
        "strip_half_height": float(np.sqrt(3.0) / 2.0 * min(plus["radii"] + minus["radii"])),
        "shifts": plus["shifts"] + minus["shifts"],
        "unseen": "multipliers with mu between the two covered intervals (further from +1 and -1 than the window), "
        "further from the real axis than the strip, or beyond the intervals but not among the Arnoldi's converged "
        "extreme eigenvalues (beyond_converged False): solver='dense' sees every one",
    }
    return mu[order], np.hstack([plus["vectors"], minus["vectors"]])[:, order], coverage


#: an end's three eigensolves (``_solve``), independent of each other: the unit of work of ``_ends``
PARTS = ("discs", "outward", "beyond")


def _solve(op, part: str, width: float, k: int):
    """One of the three eigensolves of the window at +1 of ``op`` (CSC), which ``_end`` merges:

    - ``"discs"``: the first disc just outside the end, then inwards to 1 - width, each shift at the previous
      one's cut: a list of ``_disc`` results;
    - ``"outward"``: the disc at 1 + ``OUTWARD_SHIFT``, which holds every eigenvalue between the first disc's far
      cut and it (weak real pairs too strong for the first disc, but not separated enough for the Arnoldi);
    - ``"beyond"``: the Arnoldi without shift for the outliers beyond (``_arnoldi``).
    """
    if part not in PARTS:
        raise ValueError(f"part must be one of {PARTS}, got {part!r}")
    if part == "beyond":
        return _arnoldi(sp.csr_matrix(op), min(OUTLIER_COUNT, k))
    banded = BandedShifts.make(op)
    if part == "outward":
        return _disc(op, banded, 1.0 + OUTWARD_SHIFT, min(OUTWARD_COUNT, k))
    discs = [_disc(op, banded, 1.0 + START_OFFSET, k)]
    cut = discs[0][4] - 0.5 * discs[0][3]
    while cut > 1.0 - width:
        discs.append(_disc(op, banded, cut, k))
        cut -= 0.5 * discs[-1][3]
    return discs


def _disc(op, banded, sigma: float, count: int, ncv: int | None = None, restarts: int | None = None) -> tuple:
    """The ``count`` eigenvalues of op nearest sigma by shift-invert Arnoldi (``ncv`` Lanczos vectors; None: ARPACK's
    2 count + 1; at most ``restarts`` restarts, else ``ArpackNoConvergence``), their vectors and distances to sigma,
    the radius of the disc that surely holds all there, and sigma (moved by 1e-9 if it sat on an eigenvalue)."""
    try:
        inverse = banded.inverse(sigma) if banded is not None else None
    except np.linalg.LinAlgError:
        sigma += 1e-9
        inverse = banded.inverse(sigma)
    extra = {} if ncv is None else {"ncv": int(min(ncv, op.shape[0]))}
    extra |= {} if restarts is None else {"maxiter": int(restarts)}
    vals, vectors = eigs(op, k=count, sigma=sigma, which="LM", tol=0, OPinv=inverse, **extra)
    d = np.abs(vals - sigma)
    return vals, vectors, d, float(np.max(d)) * (1 - 1e-9), sigma


def _end(discs: list, outward: tuple, beyond: tuple) -> dict:
    """The window at +1 of an op from its three eigensolves (``_solve``): each disc keeps the eigenvalues whose real
    part lies within half its radius of its shift (the first) or of its cut (the sweep's), the outward disc all it
    holds beyond the first disc's far cut, the Arnoldi the converged ones beyond the outward disc. Returns the mu
    and vectors, the covered interval (``cut``, ``outer``), the discs' radii, the number of shifts and whether the
    Arnoldi converged."""

    def kept(vals, vectors, d, radius, low, high):
        inside = (d < radius) & (np.real(vals) > low) & (np.real(vals) <= high)
        return vals[inside], vectors[:, inside]

    vals, vectors, d, radius, sigma = discs[0]
    found, radii = [kept(vals, vectors, d, radius, sigma - 0.5 * radius, sigma + 0.5 * radius)], [radius]
    outer, cut = sigma + 0.5 * radius, sigma - 0.5 * radius
    for vals, vectors, d, radius, _ in discs[1:]:
        found.append(kept(vals, vectors, d, radius, cut - 0.5 * radius, cut))
        radii.append(radius)
        cut -= 0.5 * radius
    shifts = len(radii) + 1
    vals, vectors, d, radius, sigma = outward
    found.append(kept(vals, vectors, d, radius, outer, np.inf))  # all it holds beyond the first disc
    if sigma - radius <= outer < sigma + 0.5 * radius:  # it reaches back to the first disc's far cut: contiguous
        radii.append(radius)
        outer = sigma + 0.5 * radius
    # the Arnoldi's, but for those within the outward disc's radius: it holds every one there
    vals, vectors, residual, converged = beyond
    good = (np.real(vals) > outer) & (residual < 1e-10) & (np.abs(vals - sigma) >= radius)
    found.append((vals[good], vectors[:, good]))
    return {
        "mu": np.concatenate([v for v, _ in found]),
        "vectors": np.hstack([x for _, x in found]),
        "cut": cut,
        "outer": outer,
        "radii": radii,
        "shifts": shifts,
        "converged": converged,
    }


#: the seed of ARPACK's starting vector (and of any vector it asks for on a restart)
ARPACK_SEED = 20261126


def eigs(op, **options):
    """``scipy.sparse.linalg.eigs`` from a fixed starting vector (and fixed random vectors on a restart, where scipy
    takes an ``rng``: 1.17 on). Without one ARPACK draws it afresh (OS entropy in scipy >= 1.17, a process-wide
    seed that advances with every call before), so the same orbit's multipliers would differ in the last bits from
    call to call (a resumed branch, a sweep's worker)."""
    rng = np.random.default_rng(ARPACK_SEED)
    extra = {"rng": rng} if _TAKES_RNG else {}
    return spla.eigs(op, v0=rng.standard_normal(op.shape[0]), **extra, **options)


_TAKES_RNG = "rng" in inspect.signature(spla.eigs).parameters

#: the outward disc's shift beyond +1 (and -1): its disc holds the cluster at the end on its rim and every
#: eigenvalue nearer, so it covers from the first disc's far cut (1 + 6e-4 at N = 3201) to 1 + 1.5 OUTWARD_SHIFT,
#: where the Arnoldi alone left real pairs of mu 1.001 .. 1.005 (|l| 1.05 .. 1.1) unseen at N = 3201; not a round
#: number, so that it does not sit on an eigenvalue put there by hand
OUTWARD_SHIFT = 5.1234e-3

#: eigenvalues asked of the outward disc: the cluster at the end sits on its rim whatever the count (so it reaches
#: back), and a few converge 3x (N = 3201) to 8x faster than the end discs' 60 (12801: 1.3 s against 7.5 s)
OUTWARD_COUNT = 10

#: extreme eigenvalues asked of the Arnoldi beyond the end discs (strong real pairs, period doubling)
OUTLIER_COUNT = 4

#: Arnoldi restarts for them: a separated outlier converges in a few; the cluster at the end does not, and needs not
OUTLIER_RESTARTS = 20


def _arnoldi(op, k: int) -> tuple:
    """ARPACK's ``k`` eigenvalues of ``op`` (CSR: faster products) of largest real part without shift-invert, for
    the outliers beyond the discs (a shift far from the spectrum converges slowly; Arnoldi finds separated outliers
    fast), each with its relative residual (``_end`` keeps those below 1e-10).

    Returns:
        (mu, vectors, residuals, converged): ``converged`` False when the Arnoldi stopped before its k values
        converged (then only outliers it did converge are known: the usual case, with none, is the cluster at the
        end).
    """
    try:
        vals, vectors = eigs(op, k=k, which="LR", tol=1e-13, maxiter=OUTLIER_RESTARTS)
        converged = True
    except spla.ArpackNoConvergence as err:
        vals, vectors, converged = err.eigenvalues, err.eigenvectors, False
    if not len(vals):
        return np.zeros(0, complex), np.zeros((op.shape[0], 0), complex), np.zeros(0), converged
    residual = np.linalg.norm(op @ vectors - vectors * vals[None, :], axis=0) / np.linalg.norm(vectors, axis=0)
    return vals, vectors, residual, converged


#: from this many rows of Mu on, the window's eigensolves run in worker processes, all at once (``_ends``).
#: scipy's ARPACK holds the GIL while it orthogonalises, so four threads ran them one after the other, and slower
#: (H100 host, N = 12801: 13.4 s on four threads). H100 host at 1d65c2b, the eigensolves of one window, here and
#: in the workers once started (``benchmarks/results/h100-2026-11-26e.json``): N = 1601 1.0 s against 0.25 s,
#: 3201 1.8 s against 0.32 s, 12801 23 s against 5.6 s; the first call of a process also starts them (~0.9 s)
PROCESS_MIN_ROWS = 3000

#: the module's settings a worker takes from the caller with each task (a script or a test may have changed them)
_SETTINGS = ("START_OFFSET", "OUTWARD_SHIFT", "OUTWARD_COUNT", "OUTLIER_COUNT", "OUTLIER_RESTARTS", "ARPACK_SEED")


def window_part(op, part: str, width: float, k: int, settings: dict):
    """A worker's task (``continuation.workers``): ``_solve`` with the caller's module settings."""
    globals().update(settings)
    return _solve(op, part, width, k)


def _ends(ops: list, width: float, ks: list, processes: bool) -> list:
    """``_end`` of each op (CSC) and its k from its three eigensolves (``_solve``), here one after the other, or
    all twelve (two parity blocks, two ends) in the worker processes at once (``processes``,
    ``continuation.workers``): the same code on the same libraries from the same starting vector, so the same
    bits, whatever the BLAS threads (one BLAS thread both here and there: ``krylov_floquet`` runs under
    ``blas_threads(1)``)."""
    tasks = [(op, part, k) for op, k in zip(ops, ks) for part in PARTS]
    if not processes:
        parts = [_solve(op, part, width, k) for op, part, k in tasks]
    else:
        from .workers import Workers

        settings = {name: globals()[name] for name in _SETTINGS}  # as set in this process, not as in the file
        jobs = [("window_part", (op, part, width, k, settings)) for op, part, k in tasks]
        parts = Workers.shared().map("continuation.krylov_floquet", jobs, what="window eigensolve")
    return [_end(*parts[i : i + len(PARTS)]) for i in range(0, len(parts), len(PARTS))]


def blocks_window(Mu, blocks, window: FloquetWindow, *, processes: bool | None = None) -> tuple:
    """The window at +1 and -1 of each parity block (``(parity, E, keep)``: ``parity_extensions``, or
    ``(0, None, None)`` for the whole Mu), merged: the mu, their vectors (2N, extended from the block), parities
    and one coverage. The end at -1 is the end at +1 of -Mu. The intervals are those every block covered (a block
    that reached further inwards reports only as far); what lies beyond their outer ends (strong real pairs,
    period doubling: the outlier Arnoldi's) is kept. ``processes``: the ends' eigensolves in worker processes at
    once (default: from ``PROCESS_MIN_ROWS`` rows of Mu on; the same bits either way).

    Returns:
        (mu, vectors, parity, coverage).
    """
    if processes is None:
        processes = Mu.shape[0] >= PROCESS_MIN_ROWS
    ops = [Mu if E is None else sp.csc_matrix((Mu @ E)[keep]) for _, E, keep in blocks]
    ks = [int(min(window.count, B.shape[0] - 2)) for B in ops for _ in (1.0, -1.0)]
    ends = _ends([sp.csc_matrix(sign * B) for B in ops for sign in (1.0, -1.0)], window.width, ks, processes)
    mus, vecs, parities, coverages = [], [], [], []
    for i, (parity, E, _) in enumerate(blocks):
        mu, vec, coverage = _window(ends[2 * i], ends[2 * i + 1], ks[2 * i], window.width)
        mus.append(mu)
        vecs.append(vec if E is None else E @ vec)
        parities.append(np.full(len(mu), parity, int))
        coverages.append(coverage)
    mu, vec, parity = np.concatenate(mus), np.hstack(vecs), np.concatenate(parities)
    covered = [
        [max(c["covered"][0][0] for c in coverages), min(c["covered"][0][1] for c in coverages)],
        [max(c["covered"][1][0] for c in coverages), min(c["covered"][1][1] for c in coverages)],
    ]
    (minus_outer, minus_inner), (plus_inner, plus_outer) = covered
    keep = (mu.real <= minus_inner) | (mu.real >= plus_inner)
    coverage = dict(coverages[0])
    coverage["covered"] = covered
    coverage["strip_half_height"] = min(c["strip_half_height"] for c in coverages)
    coverage["shifts"] = sum(c["shifts"] for c in coverages)
    coverage["beyond_converged"] = all(c["beyond_converged"] for c in coverages)
    coverage["parity_blocks"] = len(blocks) == 2
    coverage["processes"] = bool(processes)
    return mu[keep], vec[:, keep], parity[keep], coverage


def probed_problem(lin, M: float, state=None, lattice=None) -> dict:
    """The reduced problem of a reversible orbit from its half-period Linearization, sparse: A probed by colour
    groups, Mu (entries below ``MU_DROP`` dropped), the Krein form P and the symplecticity gauge (formed beside),
    and the parity blocks (``(parity, E, keep)``: ``parity_extensions`` when the orbit is mirror-symmetric and Mu
    commutes with the reflection, else ``(0, None, None)``; on a patch (``lattice``) whose mirror the orbit keeps
    too, ``symmetry_extensions``' four; up to six on a square patch whose quarter turn it keeps, ``twins`` naming the
    block that has another's multipliers and ``quarter`` the turn). ``window_floquet`` and ``slicing.sliced_floquet``
    start here."""
    from .parity import (
        PARITY_COUPLING_RTOL,
        SYMMETRIC_RTOL,
        mirror_symmetric,
        parity_extensions,
        patch_mirror,
        patch_quarter,
        symmetry_extensions,
    )

    N = lin.x0.shape[1]
    cols = lin.stats["tangent_columns"]
    A, halfwidth = lin.probed_columns("all")
    blocks_of_A = _blocks(A, M)
    Mu, X, Y = _mu(*blocks_of_A)
    side = ThreadPoolExecutor(1, thread_name_prefix="window-checks")
    checks = side.submit(_checks, X, Y, *blocks_of_A)  # beside the symmetry checks and the eigensolves: Mu alone
    side.shutdown(wait=False)
    Mu = negligible_dropped(Mu)

    def commutes(sites) -> bool:  # Mu with the site permutation (on u and v alike), to PARITY_COUPLING_RTOL
        both = np.r_[sites, N + sites]
        asym = abs(Mu - Mu[both][:, both])
        return asym.nnz == 0 or asym.max() <= PARITY_COUPLING_RTOL * abs(Mu).max()

    blocks, twins, quarter = [(0, None, None)], {}, None
    if state is not None and mirror_symmetric(state, SYMMETRIC_RTOL) and commutes(np.arange(N)[::-1]):
        blocks = parity_extensions(N)
        mirror = patch_mirror(lattice, state)
        if mirror is not None and commutes(mirror):
            quarter = patch_quarter(lattice, state)
            blocks, twins = symmetry_extensions(
                N, mirror, quarter if quarter is not None and commutes(quarter) else None
            )
    return {
        "N": N,
        "Mu": Mu,
        "blocks": blocks,
        "twins": twins,
        "quarter": quarter if twins else None,
        "checks": checks,
        "halfwidth": halfwidth,
        "tangent_columns": lin.stats["tangent_columns"] - cols,
    }


def real_phase(vec: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Unit eigenvectors, each rotated onto its largest component; those of real mu real (real up to a phase). A new
    array (one, written in place after the division: a dense block's 12801^2 vectors are 2.6 GB)."""
    vec = vec / np.linalg.norm(vec, axis=0)
    big = vec[np.argmax(np.abs(vec), axis=0), np.arange(vec.shape[1])]
    vec *= (np.abs(big) / big)[None, :]
    if np.iscomplexobj(vec):
        vec.imag[:, ~(np.abs(mu.imag) > 0)] = 0.0
    return vec


def window_floquet(lin, M: float, state=None, tolerance=None, window: FloquetWindow | None = None):
    """The multipliers in ``window`` of a reversible orbit from its half-period Linearization (module docstring): a
    partial ``FloquetResult`` (``path="window"``, ``complete`` False, ``stable`` None: no verdict; what the window
    decided is ``partial_stable``) with its ``coverage``. On a mirror-symmetric orbit the even and the odd block are
    solved apart (``parity_extensions``), so each vector's parity is exact, as on the dense path."""
    from .hostblas import blas_threads

    start = time.perf_counter()
    window = window or FloquetWindow()
    with blas_threads(1):  # the products and solves are small, and spinning OpenBLAS threads would contend
        problem = probed_problem(lin, M, state)
        mu, vec, parity, coverage = blocks_window(problem["Mu"], problem["blocks"], window)
        sympl, P = problem["checks"].result()
    vec = real_phase(vec, mu)
    act = np.sum(np.real(vec) * (P @ np.real(vec)), axis=0)
    accuracy = {"symplecticity": sympl, "probe_halfwidth": problem["halfwidth"]}
    centre = energy_centre(state) if state is not None else np.nan
    pr, weight = site_measures(vec, M, centre)
    return assemble(
        mu,
        parity,
        act,
        pr,
        weight,
        problem["N"],
        accuracy,
        tolerance,
        path="window",
        vectors=vec,
        coverage=coverage,
        complete=False,
        wall_seconds=time.perf_counter() - start,
        stats={"tangent_columns": problem["tangent_columns"]},
    )
