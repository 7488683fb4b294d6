"""Floquet analysis: multipliers of a periodic orbit, their kinds, and stability.

**Reduced Floquet for time-reversible orbits** (the default for breathers found in the reversible
formulation). Coordinates x = (q, q') with q = (u, v) (2N each); the reversor R = diag(I, -I) flips
velocities. Let A be the derivative of the half-period map at the orbit's start x0 = (q0, 0), with
blocks A11 = dq/dq0, A12 = dq/dq0', A21 = dq'/dq0, A22 = dq'/dq0' at T/2.

1. Reversibility: the orbit's second half is the time reverse of the first, x(T/2 + s) = R x(T/2 - s),
   so the second half's derivative is R A^-1 R and the monodromy is V = R A^-1 R A. This holds for
   the discrete map too, because every splitting method here is a palindromic composition
   (R Phi_h R = Phi_h^-1) and the half period is a whole number of steps.
2. V = R Q with Q = A^-1 R A: a product of two involutions. Then V + V^-1 = RQ + QR commutes with R,
   so on R's +1 eigenspace (pure positions, x = (a, 0)) it acts as 2 P+ Q P+: the eigenvalues mu of
   the top-left block of Q are (l + 1/l) / 2 over the multipliers l, each pair (l, 1/l) once.
3. Symplecticity in (q, p = Mm q'), Mm = diag(M I_N, I_N), gives A^-1 = [[Mm^-1 A22^T Mm,
   -Mm^-1 A12^T Mm], [-Mm^-1 A21^T Mm, Mm^-1 A11^T Mm]] without a solve, hence

       Mu = Mm^-1 (A22^T Mm A11 + A12^T Mm A21)        (2N x 2N),   l = mu +- sqrt(mu^2 - 1).

   Check: a harmonic oscillator with A a rotation by theta gives mu = cos 2 theta, V a rotation by
   2 theta. tests/test_floquet.py checks Mu against the full 4N eig of the monodromy.
4. Floquet thus costs A's 4N tangent columns over half a period, replayed on the converged orbit's
   recorded trajectory (no base run), and a 2N eig: half the integration of the 4N columns over a
   whole period and ~1/8 of a 4N eig. (Newton's last Jacobian was formed at the previous iterate,
   not at the converged point, so its columns are not reused: they would carry that step's error.)
   The trivial Jordan pair at l = +1 becomes one simple, well-conditioned mu = 1.

**Kinds.** Real mu in (-1, 1): a pair on the unit circle (``elliptic``); real mu > 1: a real pair
through +1 (``real_pair``: symmetry breaking, branch point); mu < -1: a pair through -1
(``period_doubling``); complex mu (they come in conjugate pairs): a Krein quadruplet
(``complex_quadruplet``).

**Krein signature** of an elliptic mu with eigenvector a (Mu a = mu a): the V-eigenvector of the
upper-half-plane multiplier is a + beta c with c the velocity part of Q a and beta = i / sqrt(1-mu^2),
and its symplectic signature reduces to sigma = -sign((A11 a)^T Mm (A21 a)). A harmonic oscillator of
frequency w gives sigma = sign(sin w T), as it must. Only elliptic multipliers of opposite signature
can collide and leave the circle (Krein), so these are the collisions continuation watches.

**Parity.** When the orbit is mirror-symmetric (q0 equal to its reflection j -> N + 1 - j), Mu
commutes with the reflection and each eigenvector is even (+1) or odd (-1); multipliers of different
parity cannot interact. Unknown or mixed: 0.

**Accuracy gauge and tolerance** (what decides "stable"). Two measured quantities:
``trivial_deviation`` = |mu_trivial - 1| (exactly 0 for an exactly periodic orbit of the exact
discrete map, so it measures Newton's residual and the round-off of the whole chain of computation)
and ``symplecticity`` = max |W^T J W - J| of the half-period map in (q, p) coordinates (0 for an
exactly symplectic map; it bounds the error of using the transpose formula for A^-1). A mu counts as
unstable when its distance from the real segment [-1, 1] exceeds

    tolerance = 10 * max(trivial_deviation, symplecticity, 1e-13).

On the paper breather (M = 30, K = 160, N = 201, kahan8, 32 steps per period) the two gauges are
1.5e-12 and 9e-14, so the tolerance is 1.5e-11 in mu, i.e. |l| - 1 of 5.5e-6 for a real pair and
~1.5e-11 / sin(arg l) for a quadruplet. The full-monodromy path (``reduced=False``, and the only path
for non-reversible orbits or non-symplectic methods such as RK4) keeps the pairing-error gauge:
tol = max(10 * pairing error, 1e-12) on ||l| - 1|.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from warpchain import ChainParams, Flow, get_method, propagate_tangent
from warpchain.lattice import neighbour_table
from warpchain.model import dispersion, real_number

from .spectrum import (  # noqa: F401 (the results and their measures: importable from here as before)
    CENTRAL_SITES,
    KINDS,
    LOCALIZED_FRACTION,
    VERDICTS,
    FloquetResult,
    Instability,
    SpectralData,
    assemble,
    central_weight,
    energy_centre,
    half_map_symplecticity,
    mu_kind,
    multipliers_from_mu,
    outer_modulus,
    pairing_error,
    participation,
    reduced_matrix,
    reduced_products,
    site_measures,
    symplecticity_error,
)
from .parity import (  # noqa: F401 (ParityBlock: importable from here as before)
    SYMMETRIC_RTOL,
    ParityBlock,
    _expand,
    mirror_symmetric,
    parity_blocks,
    patch_mirror,
    vector_parity,
)


#: a full-path tolerance above this cannot resolve the weak instabilities breathers have (|l| - 1 of
#: 1e-5 .. 1e-3 on the paper chain): ``floquet`` refuses such a verdict unless given a tolerance
UNRELIABLE_TOLERANCE = 1e-6


#: ``floquet(solver="auto")`` takes the sliced path (every multiplier from the probed sparse Mu, counted:
#: ``continuation.slicing``) from this many sites on, the dense path (4N tangent columns, dense eig) below
SLICED_MIN_SITES = 1601


# ----------------------------------------------------------------------------- building blocks


def monodromy(params: ChainParams, state, period_steps: int, dt: float, *, method: str, device=None) -> np.ndarray:
    """V with V[:, i] the end-of-period derivative along the i-th state coordinate (4N x 4N)."""
    n = 4 * params.N
    tan = propagate_tangent(
        params, state, np.eye(n).reshape(n, 4, params.N), period_steps, dt, method=method, device=device
    )
    return tan.columns.reshape(n, n).T


# ----------------------------------------------------------------------------- the two paths


def half_period_map(lin) -> np.ndarray:
    """A (4N x 4N, on (q, q')) from a half-period Linearization: position then velocity columns."""
    return np.hstack([lin.unit_columns("positions"), lin.unit_columns("velocities")])


def reduced_floquet(
    A: np.ndarray,
    M: float,
    state: np.ndarray | None = None,
    tolerance: float | None = None,
    *,
    wall_seconds: float = 0.0,
    stats: dict | None = None,
    lattice=None,
) -> FloquetResult:
    """Floquet analysis of a time-reversible orbit from its half-period map A (module docstring).

    Args:
        A: half-period map at x0 = (q0, 0), shape (4N, 4N), on (q, q').
        M: the chain's mass ratio.
        state: the orbit's start (4, N), for the parity test (None: parity unknown).
        tolerance: override of the measured tolerance (in mu).
        lattice: a patch's ``Lattice``: a mirror of it that the orbit keeps splits each parity block in two
            (``parity_blocks``).
    """
    start = time.perf_counter()
    N = A.shape[0] // 4
    symmetric = state is not None and mirror_symmetric(state, SYMMETRIC_RTOL)
    mirror = patch_mirror(lattice, state) if symmetric else None
    blocks = parity_blocks(A, M, mirror) if symmetric else None
    if blocks is None and mirror is not None:  # A does not keep the mirror as well as the state: the rotation alone
        blocks = parity_blocks(A, M)
    split = blocks is not None
    if not split:
        Mu, sympl, P = reduced_products(A, M)
        blocks = (ParityBlock(0, None, Mu, P, sympl, *np.linalg.eig(Mu)),)
    mu = np.concatenate([b.mu for b in blocks])
    vec = np.hstack([_expand(b.vectors, b.basis, 2 * N) for b in blocks])
    if split:
        parity = np.concatenate([np.full(len(b.mu), b.parity, int) for b in blocks])
    else:
        parity = vector_parity(vec) if state is not None and mirror_symmetric(state) else np.zeros(len(mu), int)
    sympl = max(b.symplecticity for b in blocks)
    # a = S y with S real: a^T P a = y^T (S^T P S) y, each block's own P
    act = np.concatenate([np.sum(np.real(b.vectors) * (b.P @ np.real(b.vectors)), axis=0) for b in blocks])
    pr, weight = site_measures(vec, M, energy_centre(state) if state is not None else np.nan)
    return assemble(
        mu,
        parity,
        act,
        pr,
        weight,
        N,
        {"symplecticity": sympl},
        tolerance,
        path="reduced",
        vectors=vec,
        spectral=SpectralData(blocks),
        wall_seconds=wall_seconds + time.perf_counter() - start,
        stats=stats,
    )


#: the reduced analysis' paths (``floquet(solver=...)``): four complete ones and the partial window
SOLVERS = ("dense", "sliced", "probed", "auto", "window")


#: ``floquet(solver="auto")`` on the host (no GPU eig) takes the probed path below this many sites, the sliced path
#: from here: the blocks' dense eigs on the host against the slices, the paper breather on the 2-core CPU: 2.1 s
#: against 3.8 s at N = 1601, 6.5 s against 7.4 s at 2401, 30.8 s against 13.0 s at 3201
PROBED_HOST_MAX_SITES = 2000


def floquet_path(solver: str, N: int, device: str | None = None) -> str:
    """``"dense"``, ``"sliced"``, ``"probed"`` or ``"window"``: the path ``solver`` names on N sites (``"auto"``:
    dense below ``SLICED_MIN_SITES`` sites; from there probed where ``device`` is a GPU and CuPy imports (the blocks'
    dense eig there) or below ``PROBED_HOST_MAX_SITES`` sites, else sliced)."""
    if solver == "krylov":
        raise ValueError(
            "solver='krylov' is now 'window' (the multipliers near +1 and -1 only: no stability verdict); "
            "'sliced' or 'auto' give every multiplier of a long lattice and a complete verdict"
        )
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(map(repr, SOLVERS))}, got {solver!r}")
    if solver == "auto":
        if N < SLICED_MIN_SITES:
            return "dense"
        from .slicing import has_gpu_eig

        return "probed" if has_gpu_eig(device) or N < PROBED_HOST_MAX_SITES else "sliced"
    return solver


#: ``linear_mu`` of a lattice patch takes its Laplacian's eigenvalues (a dense eigvalsh) up to this many sites;
#: beyond, no hint (the sliced path then cuts its segments at equal arg l)
LINEAR_MU_MAX_SITES = 4096


def linear_mu(params, lin) -> "np.ndarray | None":
    """The mu = cos(w T) of the linear lattice's 2N modes over the period T of a half-period Linearization: where a
    breather's multipliers lie, but for its few core modes (the sliced path cuts its segments by them). The chain
    (``ChainParams``): fixed-end Bloch numbers j pi / (N + 1); a ``LatticeParams`` patch: its Laplacian's
    eigenvalues (both branches at each), or None beyond ``LINEAR_MU_MAX_SITES`` sites."""
    period = 2.0 * lin.nsteps * lin.dt
    if isinstance(params, ChainParams):
        q = np.arange(1, params.N + 1) * np.pi / (params.N + 1)
        return np.cos(np.concatenate(dispersion(q, params.M, params.K)) * period)
    if params.N > LINEAR_MU_MAX_SITES:
        return None
    from warpchain.lattice import _two_branches

    lam = np.linalg.eigvalsh(params.lattice.laplacian_matrix().toarray())
    return np.cos(np.concatenate(_two_branches(params.K * np.maximum(lam, 0.0), params.M)) * period)


def reduced_analysis(
    lin, M: float, state=None, tolerance=None, *, solver: str = "auto", window=None, params=None
) -> FloquetResult:
    """The reduced Floquet analysis of a reversible orbit from its half-period Linearization, on the path ``solver``
    names (``floquet_path``, with the Linearization's device): every multiplier (``reduced_floquet`` on A's 4N
    columns, or ``slicing.sliced_floquet`` / ``slicing.probed_floquet`` on the probed sparse Mu, counted) or the
    window near +1 and -1 (``krylov_floquet.window_floquet``; ``window``: its ``FloquetWindow``). ``floquet`` and
    the continuation driver both analyse through here; ``params``: the orbit's lattice, whose linear mu
    (``linear_mu``) cut the sliced path's segments (computed only on that path)."""
    device = getattr(lin, "device", None)
    path = floquet_path(solver, lin.x0.shape[1], device)
    if path == "window":
        from .krylov_floquet import window_floquet

        return window_floquet(lin, M, state, tolerance, window)
    if window is not None:
        raise ValueError("window= chooses the window path's multipliers; the complete paths compute all of them")
    if path == "probed":
        from .slicing import probed_floquet

        lattice = None if params is None else neighbour_table(params)
        return probed_floquet(lin, M, state, tolerance, lattice=lattice, device=device)
    if path == "sliced":
        from .slicing import sliced_floquet

        hint = linear_mu(params, lin) if params is not None else None
        lattice = None if params is None else neighbour_table(params)
        return sliced_floquet(lin, M, state, tolerance, hint=hint, lattice=lattice)
    start = time.perf_counter()
    cols = lin.stats["tangent_columns"]
    A = half_period_map(lin)
    return reduced_floquet(
        A,
        M,
        state,
        tolerance,
        wall_seconds=time.perf_counter() - start,
        stats={"tangent_columns": lin.stats["tangent_columns"] - cols},
        lattice=None if params is None else neighbour_table(params),
    )


def analyse_multipliers(multipliers: np.ndarray, tolerance: float | None = None) -> dict:
    """Full path: trivial pair, pairing error, tolerance, largest nontrivial modulus and the verdict."""
    lam = np.asarray(multipliers)
    trivial = np.argsort(np.abs(lam - 1.0))[:2]
    mask = np.ones(len(lam), bool)
    mask[trivial] = False
    err = pairing_error(lam)
    if tolerance is not None and not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance!r}")
    tol = max(10.0 * err, 1e-12) if tolerance is None else float(tolerance)
    nontrivial = lam[mask]
    max_mod = float(np.max(np.abs(nontrivial))) if nontrivial.size else 1.0
    stable = bool(np.all(np.abs(np.abs(nontrivial) - 1.0) <= tol))
    return {"trivial": trivial, "pairing_error": err, "tolerance": tol, "max_modulus": max_mod, "stable": stable}


def full_floquet(
    V: np.ndarray,
    M: float,
    tolerance: float | None = None,
    *,
    keep_monodromy: bool = False,
    wall_seconds: float = 0.0,
    stats: dict | None = None,
) -> FloquetResult:
    """Floquet analysis from the full monodromy V (4N x 4N): any periodic orbit, any method."""
    start = time.perf_counter()
    lam = np.linalg.eigvals(V)
    info = analyse_multipliers(lam, tolerance)
    if tolerance is None and info["tolerance"] > UNRELIABLE_TOLERANCE:
        raise ValueError(
            f"no stability verdict: the tolerance would be {info['tolerance']:.1e} (10 x the pairing error "
            f"{info['pairing_error']:.1e}) because the map is far from symplectic (a non-symplectic method such as "
            "rk4, or too large a step), and instabilities weaker than that could not be told from its error. Use a "
            "symplectic method, or pass tolerance= explicitly to accept a coarse verdict"
        )
    mask = np.ones(len(lam), bool)
    mask[info["trivial"]] = False
    instabilities = []
    tol = info["tolerance"]
    for lam_i in lam[mask]:
        if abs(lam_i) <= 1.0 + tol or (lam_i.imag < -tol):
            continue
        mu = 0.5 * (lam_i + 1.0 / lam_i)
        kind = str(mu_kind(np.array([mu]), 0.0)[0])
        kind = (
            "real_pair"
            if kind == "elliptic" and lam_i.real > 0
            else ("period_doubling" if kind == "elliptic" else kind)
        )
        instabilities.append(
            Instability(
                kind=kind,
                mu=complex(mu),
                modulus=float(abs(lam_i)),
                participation=float("nan"),
                localized=False,
                parity=0,
            )
        )
    instabilities.sort(key=lambda s: -s.modulus)
    return FloquetResult(
        multipliers=lam,
        trivial=info["trivial"],
        max_modulus=info["max_modulus"],
        tolerance=tol,
        stable=info["stable"],
        instabilities=tuple(instabilities),
        mu=None,
        mu_trivial=None,
        signature=None,
        parity=None,
        participation=None,
        accuracy={"pairing_error": info["pairing_error"]},
        path="full",
        pairing_error=info["pairing_error"],
        symplecticity_error=symplecticity_error(V, M),
        monodromy=V if keep_monodromy else None,
        wall_seconds=wall_seconds + time.perf_counter() - start,
        stats=dict(stats or {}),
    )


# ----------------------------------------------------------------------------- public entry point


def _is_reversible_method(method: str) -> bool:
    m = get_method(method)
    return m.symplectic and m.family == "splitting"


def floquet(
    breather,
    *,
    method: str | None = None,
    reduced: bool | None = None,
    device=None,
    keep_monodromy: bool = False,
    tolerance: float | None = None,
    flow: Flow | None = None,
    solver: str = "auto",
    window=None,
) -> FloquetResult:
    """Floquet multipliers of a converged breather, with the integrator and step of its shooting.

    Args:
        breather: a converged ``ShootingResult``.
        method: another integrator: the orbit is first re-converged with it (with a warning),
            since an orbit is periodic only for the map it was solved with.
        reduced: use the reduced 2N problem (default where it applies: reversible formulation and a
            symplectic palindromic method) or the full 4N monodromy (``False``).
        keep_monodromy: keep V on the result (full path).
        tolerance: override of the measured tolerance (>= 0).
        flow: the Flow to use (default: the breather's own).
        solver: ``"dense"`` (every multiplier: 4N tangent columns and the eig of Mu, the reference), ``"sliced"``
            (every multiplier from the probed sparse Mu by shift-invert slices, with a count that proves none was
            missed: ``continuation.slicing``), ``"probed"`` (every multiplier from the probed sparse Mu by a dense
            eig per parity block, on the GPU with CuPy where the flow runs on one, counted the same way), ``"auto"``
            (dense below ``SLICED_MIN_SITES`` sites; from there probed on a GPU with CuPy or below
            ``PROBED_HOST_MAX_SITES`` sites, else sliced) or ``"window"`` (the multipliers near +1 and -1 only,
            ``continuation.krylov_floquet``: a partial analysis, ``stable`` None, what it saw in
            ``partial_stable``). The reduced paths need a reversible orbit; the full path is always dense.
        window: the window path's ``FloquetWindow`` (default: the 60 mu nearest each end).

    Raises:
        TypeError: ``breather`` is not a ShootingResult.
        ValueError: the solve had not converged (its multipliers would describe no orbit), or a bad option.
    """
    from .shooting import ShootingResult, find_breather

    if not isinstance(breather, ShootingResult):
        raise TypeError(f"floquet() takes a ShootingResult from find_breather, got {type(breather).__name__}")
    if not breather.success:
        raise ValueError(
            f"floquet() of a failed solve: there is no periodic orbit to analyse "
            f"({breather.status.value}: {breather.message})"
        )
    if tolerance is not None:  # a real number >= 0 (True is no tolerance: it read as 1.0, every point stable)
        tolerance = real_number("tolerance", tolerance, nonnegative=True)
    flow = flow or breather.flow
    if device is not None:
        flow = flow.replace(device=device)
    if reduced and not (breather.formulation == "reversible" and _is_reversible_method(method or flow.method)):
        raise ValueError(
            "the reduced Floquet problem needs a reversible orbit (reversible formulation) and a "
            f"symplectic palindromic method; got {breather.formulation!r} with {method or flow.method!r}: "
            "use reduced=False"
        )
    if method is not None and method != breather.method:
        flow = flow.replace(method=method)  # a method the flow cannot run fails here, before the warning
        warnings.warn(
            f"floquet(method={method!r}) on an orbit converged with {breather.method!r}: the orbit is "
            f"re-converged with {method!r} first (it is periodic only for the map it was solved with)",
            RuntimeWarning,
            stacklevel=2,
        )
        from .shooting import require

        breather = require(
            find_breather(breather.params, breather.omega, breather.state, formulation=breather.formulation, flow=flow)
        )
    if reduced is None:
        reduced = breather.formulation == "reversible" and _is_reversible_method(flow.method)
    params = breather.params
    floquet_path(solver, params.N)  # a bad name fails before any work
    if solver in ("sliced", "probed", "window") and not reduced:
        raise ValueError(f"solver={solver!r} works on the reduced problem (reversible orbit, symplectic method)")
    if reduced:
        lin = breather.linearization(flow)
        return reduced_analysis(lin, params.M, breather.state, tolerance, solver=solver, window=window, params=params)
    if window is not None:
        raise ValueError("window= chooses the window path's multipliers; the full path computes all of them")
    start = time.perf_counter()
    half = breather.nsteps if breather.formulation == "reversible" else breather.nsteps // 2
    lin = flow.linearize(params, breather.state, 2 * half, breather.dt)
    V = lin.unit_columns("all", probe=False)  # the monodromy, dense: one tangent run per unit direction
    return full_floquet(
        V,
        params.M,
        tolerance,
        keep_monodromy=keep_monodromy,
        wall_seconds=time.perf_counter() - start,
        stats={"tangent_columns": lin.stats["tangent_columns"]},
    )
