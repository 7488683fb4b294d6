"""Floquet multipliers of a long lattice without its 4N tangent columns or its 2N eig: the half-period map
probed by colour groups, and the multipliers near +1 and -1 by shift-invert Arnoldi (``floquet(solver="krylov")``).

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
as the cluster at the end does not, and only converged ones are reported). The four solves (two parity blocks,
two ends) run on four threads where scipy's ARPACK is reentrant (``REENTRANT_ARPACK``, scipy >= 1.17; one after
the other before): the banded solves (LAPACK through ctypes) and scipy's sparse products let go of the GIL, and
ARPACK starts from a fixed vector (``eigs``), so each solve gives the same bits alone or beside the others, and in
any process.

**What a window cannot see**: an instability whose mu lies between the covered intervals (a multiplier further
from both +1 and -1 than the window reaches: a quadruplet from a collision in the middle of the circle), one further
off the axis than the strip, or an outlier the last Arnoldi did not converge to. ``FloquetResult.coverage`` says
what was covered; ``stable`` there means "no instability in the window", and the dense path (``solver="dense"``)
sees everything.
"""

from __future__ import annotations

import dataclasses
import inspect
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def _blocks(A, M: float) -> tuple:
    """The four blocks of A (CSC) and the diagonal mass matrix Mm."""
    n2 = A.shape[0] // 2
    N = n2 // 2
    A = sp.csc_matrix(A)
    m = np.concatenate([np.full(N, float(M)), np.ones(N)])
    return A[:n2, :n2], A[:n2, n2:], A[n2:, :n2], A[n2:, n2:], sp.diags(m)


def _mu(A11, A12, A21, A22, Dm) -> tuple:
    """(Mu, X, Y): Mu = Mm^-1 (X + Y), X = A22^T Mm A11, Y = A12^T Mm A21, the two products on two threads
    (scipy's sparse products let go of the GIL)."""
    with ThreadPoolExecutor(2, thread_name_prefix="window-products") as pool:
        X, Y = pool.map(lambda pair: pair[0] @ pair[1], ((A22.T @ Dm, A11), (A12.T @ Dm, A21)))
    return sp.csc_matrix(sp.diags(1.0 / Dm.diagonal()) @ (X + Y)), X, Y


def _checks(X, Y, A11, A12, A21, A22, Dm) -> tuple:
    """(symplecticity, P): the largest entry of S12 = Mm^-1 (X - Y) - 1, P - P^T and Mm^-1 (Z - Z^T) Mm^-1
    (Z = A12^T Mm A22), as ``floquet.reduced_products``, and the Krein form P = A11^T Mm A21. ``krylov_floquet``
    runs it beside the eigensolves, which need Mu alone."""
    Dinv = sp.diags(1.0 / Dm.diagonal())
    P, Z = (A11.T @ Dm) @ A21, (A12.T @ Dm) @ A22
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
    """Which multipliers ``floquet(solver="krylov")`` computes.

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
    SuperLU on the paper chain (0.18 ms against 0.65 ms at N = 3201). LAPACK is called through ctypes (scipy's
    own LAPACK, ``_lapack``), which lets go of the GIL: the eigensolves of ``blocks_window`` can run on threads
    at once. ``None`` from ``make`` when the band is not narrow (then ARPACK factors op - sigma with
    SuperLU)."""

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
        ldab = 2 * kl + ku + 1
        lu = np.zeros((ldab, n), order="F")
        lu[kl + ku + self.rows - self.cols, self.cols] = self.data
        lu[kl + ku, :] -= sigma
        piv = np.zeros(n, np.int32)
        info = _lapack("dgbtrf")(n, n, kl, ku, lu, ldab, piv)
        if info != 0:
            raise np.linalg.LinAlgError(f"op - sigma is singular at sigma = {sigma!r} (dgbtrf info {info})")
        dgbtrs = _lapack("dgbtrs")

        def solve(x):
            x = np.asarray(x).reshape(n)
            x = x.astype(np.complex128 if np.iscomplexobj(x) else np.float64, copy=False)  # what dgbtrs reads
            parts = np.asfortranarray(np.stack([x.real, x.imag], axis=1)[perm] if np.iscomplexobj(x) else x[perm])
            dgbtrs(b"N", n, kl, ku, parts.size // n, lu, ldab, piv, parts, n)
            out = np.empty(n, dtype=np.result_type(x.dtype, np.float64))
            out[perm] = parts[:, 0] + 1j * parts[:, 1] if parts.ndim == 2 else parts
            return out

        return spla.LinearOperator((n, n), matvec=solve, dtype=np.float64)


_LAPACK: dict = {}
_LAPACK_LOCK = threading.Lock()


def _lapack(name: str):
    """scipy's LAPACK routine ``name`` (``dgbtrf`` or ``dgbtrs``) through ctypes, which releases the GIL while it
    runs (scipy's own wrappers hold it). Arguments: integers and arrays as the Fortran routine's, without ``info``,
    which the call returns."""
    with _LAPACK_LOCK:  # ctypes.pythonapi is the process's: set its signatures once
        if name not in _LAPACK:
            import ctypes

            from scipy.linalg import cython_lapack

            capsule = cython_lapack.__pyx_capi__[name]
            api = ctypes.pythonapi
            api.PyCapsule_GetName.restype, api.PyCapsule_GetName.argtypes = ctypes.c_char_p, [ctypes.py_object]
            api.PyCapsule_GetPointer.restype = ctypes.c_void_p
            api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
            pointer = api.PyCapsule_GetPointer(capsule, api.PyCapsule_GetName(capsule))
            c_int, ptr = ctypes.c_int, ctypes.c_void_p
            int_p = ctypes.POINTER(c_int)
            if name == "dgbtrf":  # m, n, kl, ku, ab, ldab, ipiv, info
                signature = [int_p, int_p, int_p, int_p, ptr, int_p, ptr, int_p]
            else:  # trans, n, kl, ku, nrhs, ab, ldab, ipiv, b, ldb, info
                signature = [ctypes.c_char_p, int_p, int_p, int_p, int_p, ptr, int_p, ptr, ptr, int_p, int_p]
            function = ctypes.CFUNCTYPE(None, *signature)(pointer)

            def call(*args):
                info = c_int(0)
                converted = [
                    a
                    if isinstance(a, bytes)
                    else a.ctypes.data
                    if isinstance(a, np.ndarray)
                    else ctypes.byref(c_int(a))
                    for a in args
                ]
                function(*converted, ctypes.byref(info))
                return info.value

            _LAPACK[name] = call
    return _LAPACK[name]


def window_eigs(Mu, window: FloquetWindow) -> tuple:
    """The eigenvalues of the sparse Mu in the windows at +1 and -1, and every one beyond them (|mu| > 1), by
    shift-invert Arnoldi (module docstring). The end at -1 is the end at +1 of -Mu; the two ends are solved on
    two threads where ARPACK is reentrant (the banded solves and the sparse products let go of the GIL), each the
    same as alone.

    Returns:
        (mu (count,), vectors (2N, count), coverage dict).
    """
    k = int(min(window.count, Mu.shape[0] - 2))
    with ThreadPoolExecutor(_threads(2), thread_name_prefix="window-end") as pool:
        ends = list(pool.map(lambda sign: _end(sp.csc_matrix(sign * Mu), window, k), (1.0, -1.0)))
    mu = np.concatenate([sign * end["mu"] for sign, end in zip((1.0, -1.0), ends)])
    order = np.argsort(-np.real(mu), kind="stable")
    plus, minus = ends
    coverage = {
        "count": k,
        "width": float(window.width),
        "covered": [[-minus["outer"], -minus["cut"]], [plus["cut"], plus["outer"]]],
        "beyond_converged": plus["converged"] and minus["converged"],
        "strip_half_height": float(np.sqrt(3.0) / 2.0 * min(plus["radii"] + minus["radii"])),
        "shifts": plus["shifts"] + minus["shifts"],
        "unseen": "multipliers with mu between the two covered intervals (further from +1 and -1 than the window), "
        "further from the real axis than the strip, or beyond the intervals but not among the Arnoldi's converged "
        "extreme eigenvalues (beyond_converged False): solver='dense' sees every one",
    }
    return mu[order], np.hstack([plus["vectors"], minus["vectors"]])[:, order], coverage


def _end(op, window: FloquetWindow, k: int) -> dict:
    """The window at +1 of ``op``: the first disc just outside the end, then inwards to 1 - width, each shift at the
    previous one's cut; then one disc at 1 + ``OUTWARD_SHIFT``, which holds every
    eigenvalue between the first disc's far cut and it (weak real pairs too strong for the first disc, but not
    separated enough for the Arnoldi), then the outliers beyond by the Arnoldi. Returns its mu and vectors, the
    covered interval (``cut``, ``outer``), the discs' radii, the number of shifts and whether the outlier Arnoldi
    converged."""
    banded = BandedShifts.make(op)

    def disc(sigma, count=k):
        """The ``count`` eigenvalues of op nearest sigma, the radius of the disc that surely holds all there, and
        sigma (moved by 1e-9 if it sat on an eigenvalue)."""
        try:
            inverse = banded.inverse(sigma) if banded is not None else None
        except np.linalg.LinAlgError:
            sigma += 1e-9
            inverse = banded.inverse(sigma)
        vals, vectors = eigs(op, k=count, sigma=sigma, which="LM", tol=0, OPinv=inverse)
        d = np.abs(vals - sigma)
        return vals, vectors, d, float(np.max(d)) * (1 - 1e-9), sigma

    def kept(vals, vectors, d, radius, low, high):
        inside = (d < radius) & (np.real(vals) > low) & (np.real(vals) <= high)
        return vals[inside], vectors[:, inside]

    vals, vectors, d, radius, sigma = disc(1.0 + START_OFFSET)
    found, radii = [kept(vals, vectors, d, radius, sigma - 0.5 * radius, sigma + 0.5 * radius)], [radius]
    outer, cut = sigma + 0.5 * radius, sigma - 0.5 * radius
    while cut > 1.0 - window.width:
        vals, vectors, d, radius, _ = disc(cut)
        found.append(kept(vals, vectors, d, radius, cut - 0.5 * radius, cut))
        radii.append(radius)
        cut -= 0.5 * radius
    shifts = len(radii) + 1
    vals, vectors, d, radius, sigma = disc(1.0 + OUTWARD_SHIFT, min(OUTWARD_COUNT, k))
    found.append(kept(vals, vectors, d, radius, outer, np.inf))  # all it holds beyond the first disc
    if sigma - radius <= outer < sigma + 0.5 * radius:  # it reaches back to the first disc's far cut: contiguous
        radii.append(radius)
        outer = sigma + 0.5 * radius
    # the Arnoldi's, but for those within the outward disc's radius: it holds every one there
    beyond, converged = _outliers(sp.csr_matrix(op), outer, min(OUTLIER_COUNT, k), taken=(sigma, radius))
    found.append(beyond)
    return {
        "mu": np.concatenate([v for v, _ in found]),
        "vectors": np.hstack([x for _, x in found]),
        "cut": cut,
        "outer": outer,
        "radii": radii,
        "shifts": shifts,
        "converged": converged,
    }


#: scipy's ARPACK keeps its whole state in the call's arguments since its C translation (scipy 1.17, which also
#: takes ``rng`` for the random vectors it asks for): eigensolves may then run on threads at once. The Fortran
#: ARPACK before kept it in SAVE variables shared by every call, so there they run one after the other.
REENTRANT_ARPACK = "rng" in inspect.signature(spla.eigs).parameters
#: the seed of ARPACK's starting vector (and of any vector it asks for on a restart)
ARPACK_SEED = 20261126


def eigs(op, **options):
    """``scipy.sparse.linalg.eigs`` from a fixed starting vector (and fixed random vectors on a restart, where scipy
    takes an ``rng``). Without one ARPACK draws it afresh (OS entropy in scipy >= 1.17, a process-wide seed that
    advances with every call before), so the same orbit's multipliers would differ in the last bits from call
    to call (a resumed branch, a sweep's worker)."""
    rng = np.random.default_rng(ARPACK_SEED)
    extra = {"rng": rng} if REENTRANT_ARPACK else {}
    return spla.eigs(op, v0=rng.standard_normal(op.shape[0]), **extra, **options)


def _threads(n: int) -> int:
    """Threads for n independent eigensolves: n where ARPACK is reentrant, else 1."""
    return n if REENTRANT_ARPACK else 1


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


def _outliers(op, outer: float, k: int, taken: tuple) -> tuple:
    """The eigenvalues of ``op`` with real part beyond ``outer`` (an end disc's far cut), from ARPACK's ``k``
    eigenvalues of largest real part without shift-invert (a shift far from the spectrum converges slowly;
    Arnoldi finds separated outliers fast; ``op`` CSR: faster products). Eigenpairs are kept when their residual
    is below 1e-10, and unless a disc holds them: ``taken`` = (sigma, radius), the disc's shift and the radius
    within which it found every eigenvalue.

    Returns:
        ((mu, vectors), converged): ``converged`` False when the Arnoldi stopped before its k values converged
        (then only outliers it did converge are known: the usual case, with none, is the cluster at the end).
    """
    try:
        vals, vectors = eigs(op, k=k, which="LR", tol=1e-13, maxiter=OUTLIER_RESTARTS)
        converged = True
    except spla.ArpackNoConvergence as err:
        vals, vectors, converged = err.eigenvalues, err.eigenvectors, False
    if len(vals):
        residual = np.linalg.norm(op @ vectors - vectors * vals[None, :], axis=0) / np.linalg.norm(vectors, axis=0)
        sigma, radius = taken
        good = (np.real(vals) > outer) & (residual < 1e-10) & (np.abs(vals - sigma) >= radius)
        vals, vectors = vals[good], vectors[:, good]
    if not len(vals):
        return (np.zeros(0, complex), np.zeros((op.shape[0], 0), complex)), converged
    return (vals, vectors), converged


def blocks_window(Mu, blocks, window: FloquetWindow) -> tuple:
    """``window_eigs`` on each parity block (``(parity, E, keep)``: ``parity_extensions``, or ``(0, None, None)`` for
    the whole Mu), merged: the mu, their vectors (2N, extended from the block), parities and one coverage. The
    intervals are those every block covered (a block that reached further inwards reports only as far); what lies
    beyond their outer ends (strong real pairs, period doubling: the outlier Arnoldi's) is kept.

    Returns:
        (mu, vectors, parity, coverage).
    """

    def solve(block):
        parity, E, keep = block
        B = Mu if E is None else sp.csc_matrix((Mu @ E)[keep])
        mu, vec, coverage = window_eigs(B, window)
        return mu, (vec if E is None else E @ vec), np.full(len(mu), parity, int), coverage

    with ThreadPoolExecutor(_threads(len(blocks)), thread_name_prefix="window-block") as pool:
        mus, vecs, parities, coverages = zip(*pool.map(solve, blocks))
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
    return mu[keep], vec[:, keep], parity[keep], coverage


def krylov_floquet(lin, M: float, state=None, tolerance=None, window: FloquetWindow | None = None):
    """The reduced Floquet analysis of a reversible orbit from its half-period Linearization, for the multipliers
    in ``window`` (module docstring): a ``FloquetResult`` with ``path="krylov"`` and its ``coverage``. On a
    mirror-symmetric orbit the even and the odd block are solved apart (``parity_extensions``), so each vector's
    parity is exact, as on the dense path."""
    from .floquet import assemble
    from .hostblas import blas_threads
    from .parity import PARITY_COUPLING_RTOL, SYMMETRIC_RTOL, mirror_symmetric, parity_extensions

    start = time.perf_counter()
    window = window or FloquetWindow()
    N = lin.x0.shape[1]
    cols = lin.stats["tangent_columns"]
    A, halfwidth = lin.probed_columns("all")
    blocks_of_A = _blocks(A, M)
    Mu, X, Y = _mu(*blocks_of_A)
    Mu = negligible_dropped(Mu)
    blocks = [(0, None, None)]
    if state is not None and mirror_symmetric(state, SYMMETRIC_RTOL):
        flip = np.r_[np.arange(N)[::-1], N + np.arange(N)[::-1]]
        asym = abs(Mu - Mu[flip][:, flip])
        if asym.nnz == 0 or asym.max() <= PARITY_COUPLING_RTOL * abs(Mu).max():
            blocks = parity_extensions(N)
    with ThreadPoolExecutor(1, thread_name_prefix="window-checks") as side, blas_threads(1):
        checks = side.submit(_checks, X, Y, *blocks_of_A)  # beside the eigensolves: they need Mu alone
        # the solves on threads: BLAS threads of their own would only contend
        mu, vec, parity, coverage = blocks_window(Mu, blocks, window)
        sympl, P = checks.result()
    vec = vec / np.linalg.norm(vec, axis=0)
    # eigenvectors of real mu are real up to a phase: rotate each onto its largest component, then take the
    # real part (the Krein form reads real vectors, as on the dense path)
    big = vec[np.argmax(np.abs(vec), axis=0), np.arange(vec.shape[1])]
    vec = vec * (np.abs(big) / big)[None, :]
    vec = np.where(np.abs(mu.imag)[None, :] > 0, vec, np.real(vec))
    act = np.sum(np.real(vec) * (P @ np.real(vec)), axis=0)
    accuracy = {"symplecticity": sympl, "probe_halfwidth": halfwidth}
    return assemble(
        mu,
        vec,
        parity,
        act,
        M,
        state,
        accuracy,
        tolerance,
        path="krylov",
        coverage=coverage,
        wall_seconds=time.perf_counter() - start,
        stats={"tangent_columns": lin.stats["tangent_columns"] - cols},
    )
