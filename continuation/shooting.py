"""Newton shooting on the period map.

Two formulations:

* ``"reversible"`` (default): time-reversible breathers are at rest at t = 0. Unknowns are the
  positions q = (u, v) at t = 0 (2N), the residual is the velocities at T/2 (2N): at a root the
  orbit is symmetric about t = T/2 and hence T-periodic. The Jacobian is the velocity block of
  the discrete map's derivative over half a period: 2N tangent columns.
* ``"general"``: unknowns the full state x0 (4N), residual x(T) - x0 plus the phase condition
  <x0 - x_ref, f(x_ref)> = 0; the (4N + 1) x 4N system is solved in the least-squares sense
  (the monodromy has the trivial double multiplier at +1, so V - I alone is singular).

The integrator is seen only through a ``warpchain.Flow``: each Newton point is one
``Flow.linearize`` (the base trajectory, run once with its contact stiffness recorded), from which
the residual, the end state and the min contact are read at once, and the Jacobian's tangent
columns are replayed only when Newton asks for them. The converged point's Linearization stays on
the result, so ``floquet`` replays its tangent columns on that trajectory without integrating it
again. Finite-difference columns (batched perturbed trajectories, ``jacobian="finite-difference"``)
exist as a check.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time

import numpy as np
import scipy.linalg

from warpchain import ChainParams, Flow, band_edges, energy
from warpchain.model import accelerations, as_batch, real_number
from warpchain.lattice import neighbour_table

from .krylov import KrylovSettings, LinearLatticePreconditioner, gmres_step, preconditioned
from .newton import NewtonOutcome, NewtonSettings, ShootingStatus, newton, solve_linear

# the cheapest at the accuracy breathers need (work-precision scene, smooth case): kahan8 with 32
# steps per period reaches a final-state error of 1.8e-9 over 20 periods with 480 force evaluations
# per period; yoshida6 needs 128 steps (896 evaluations) for 8e-9
DEFAULT_METHOD = "kahan8"
DEFAULT_STEPS_PER_PERIOD = 32

__all__ = [
    "DEFAULT_METHOD",
    "DEFAULT_STEPS_PER_PERIOD",
    "NewtonOutcome",
    "NewtonSettings",
    "PeriodMap",
    "ShootingError",
    "ShootingResult",
    "ShootingStatus",
    "find_breather",
    "frequency_report",
    "make_flow",
    "require",
    "solve_linear",
    "time_grid",
]


@dataclasses.dataclass(frozen=True)
class ShootingResult:
    """A breather (or the reason there is none).

    Attributes:
        state: the periodic orbit's state at t = 0, shape (4, N).
        omega, period: frequency and period.
        energy: Hamiltonian of the orbit.
        residual: final residual norm (2-norm of the velocities at T/2, or of x(T) - x0).
        residual_history: residual norm at every iterate, the seed first.
        iterations: Newton iterations taken.
        status: a ShootingStatus; message: what happened and what to do.
        min_contact: min over sites and step boundaries of 1 + u - v over the shooting interval (half
            a period for reversible orbits, which covers the whole orbit by symmetry).
        method, dt, nsteps: integrator, step, and steps per half period (reversible) or period.
        formulation, jacobian: what was solved and how its Jacobian was formed.
        used_lstsq: iterations whose linear solve fell back to least squares.
        wall_seconds: time taken.
        flow: the Flow it was solved with.
        stats: counters (``evaluations``, ``jacobians``, ``tangent_columns``).
    """

    state: np.ndarray
    omega: float
    period: float
    energy: float
    residual: float
    residual_history: tuple
    iterations: int
    status: ShootingStatus
    message: str
    min_contact: float
    method: str
    dt: float
    nsteps: int
    formulation: str
    jacobian: str
    used_lstsq: int
    wall_seconds: float
    params: ChainParams
    flow: Flow | None = None
    stats: dict = dataclasses.field(default_factory=dict)
    _linearization: object = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def success(self) -> bool:
        return self.status is ShootingStatus.CONVERGED

    def linearization(self, flow: Flow | None = None):
        """The Linearization of the shooting interval at ``state`` (the one Newton ended on when the
        flow is the very Flow it ran on; computed afresh otherwise: a Linearization replays its Flow's buffers, so
        another Flow, e.g. another thread's, gets its own)."""
        flow = flow or self.flow
        if self._linearization is not None and flow is self.flow:
            return self._linearization
        return flow.linearize(self.params, self.state, self.nsteps, self.dt)


class ShootingError(RuntimeError):
    """Raised by ``require`` when a ShootingResult did not converge."""


def require(result: ShootingResult) -> ShootingResult:
    """Return a converged result, or raise ShootingError with its message."""
    if not result.success:
        raise ShootingError(result.message)
    return result


def frequency_report(params: ChainParams, omega: float, harmonics: int = 5) -> dict:
    """Where omega and its harmonics sit relative to the phonon bands of the infinite chain."""
    e = band_edges(params.M, params.K)

    def where(w):
        if w <= e["acoustic_top"]:
            return "acoustic band"
        if w < e["optical_bottom"]:
            return "gap"
        if w <= e["optical_top"]:
            return "optical band"
        return "above the bands"

    return {
        "omega": omega,
        "location": where(omega),
        **e,
        "harmonics_in_bands": [n for n in range(2, harmonics + 1) if where(n * omega).endswith("band")],
    }


def time_grid(omega: float, dt: float | None, steps_per_period: int | None) -> tuple[int, float]:
    """Steps per half period and the step, so that the half period is a whole number of steps."""
    omega = real_number("omega", omega, positive=True)
    half = math.pi / omega
    if dt is not None:
        dt = real_number("dt", dt, positive=True)
        n_half = max(1, math.ceil(half / dt - 1e-9))
    else:
        spp = DEFAULT_STEPS_PER_PERIOD if steps_per_period is None else int(steps_per_period)
        if spp < 2:
            raise ValueError("steps_per_period must be >= 2")
        n_half = max(1, math.ceil(spp / 2))
    return n_half, half / n_half


def mirror_projector(N: int):
    """Projection of positions (u then v, the first 2N entries; anything after them, such as a
    frequency, is left alone) onto profiles that equal their reflection j -> N + 1 - j."""

    def project(y):
        out = np.array(y, dtype=float, copy=True)
        q = out[: 2 * N].reshape(2, N)
        q[:] = 0.5 * (q + q[:, ::-1])
        return out

    return project


def _state(params, q):
    N = params.N
    x = np.zeros((4, N))
    x[:2] = q.reshape(2, N)
    return x


_solve = solve_linear  # older name, kept for scripts


def make_flow(
    flow: Flow | None = None,
    *,
    method: str | None = None,
    steps_per_period: int | None = None,
    dt: float | None = None,
    omega: float | None = None,
    device: str | None = None,
) -> Flow:
    """The Flow to solve with: ``flow`` as given, or one built from method / steps per period (or a
    step ``dt`` at frequency ``omega``, rounded so the half period is a whole number of steps) / device."""
    if flow is not None:
        if not isinstance(flow, Flow):
            raise TypeError(f"flow must be a warpchain.Flow, got {type(flow).__name__}")
        if any(v is not None for v in (method, steps_per_period, dt)):
            raise ValueError("give either flow= or method/steps_per_period/dt, not both")
        return flow if device is None else flow.replace(device=device)
    if dt is not None:
        if steps_per_period is not None:
            raise ValueError("give dt or steps_per_period, not both")
        n_half, _ = time_grid(omega, dt, None)
        steps_per_period = 2 * n_half
    return shared_flow(
        method or DEFAULT_METHOD, DEFAULT_STEPS_PER_PERIOD if steps_per_period is None else steps_per_period, device
    )


_FLOWS: dict = {}
_FLOWS_LOCK = threading.Lock()


def shared_flow(method: str, steps_per_period: int, device: str | None) -> Flow:
    """One Flow per (method, steps per period, device) for the whole process, so that calls solving breather after
    breather (a scan, a size series) reuse its runners, buffers and captured graphs instead of building them per
    call (on a GPU a new runner captures its graphs anew; at N = 801 its unit directions alone are 82 MB). The Flow
    keeps the runners of its last ``warpchain.flow.POOL_KEYS`` shapes; threads may share it (every operation holds
    the device's lock, and a history handed to another call since is re-run)."""
    key = (method, int(steps_per_period), device)
    with _FLOWS_LOCK:
        if key not in _FLOWS:
            _FLOWS[key] = Flow(method, steps_per_period, device)
        return _FLOWS[key]


class PeriodMap:
    """Residual and Jacobian of one formulation at one frequency, evaluated through a Flow.

    ``evaluate(unknowns)`` returns a ``ShootingPoint`` (one base trajectory); its ``jacobian()``
    propagates the tangent columns on that trajectory's recorded history.
    """

    def __init__(
        self,
        params: ChainParams,
        omega: float,
        flow: Flow,
        formulation: str = "reversible",
        jacobian: str = "tangent",
        fd_step: float = 1e-7,
        x_ref=None,
        solver: str = "dense",
        krylov: KrylovSettings | None = None,
    ):
        self.params, self.omega, self.flow, self.formulation = params, float(omega), flow, formulation
        self.jacobian, self.fd_step = jacobian, fd_step
        self.solver, self.krylov = solver, krylov or KrylovSettings()
        self.krylov_iterations: list = []  # GMRES matrix-vector products per Newton step (solver "krylov")
        self.krylov_unconverged = 0  # GMRES solves that missed their tolerance (a dense step replaced them)
        self.tangent_columns = 0  # tangent runs of the dense Jacobians (unit columns, or colour groups when probed)
        n_half, self.dt = flow.grid(omega)
        N = params.N
        if formulation == "reversible":
            self.nsteps = n_half
            self.n_unknowns = 2 * N
            self.preconditioner = None
            if solver == "krylov" and preconditioned(params.boundary, self.krylov):
                half_period = self.nsteps * self.dt
                self.preconditioner = LinearLatticePreconditioner(
                    params.M, params.K, N, half_period, self.krylov.regularization, lattice=neighbour_table(params)
                )
        else:
            self.nsteps = 2 * n_half
            self.n_unknowns = 4 * N
            self.x_ref = np.array(x_ref, dtype=float)
            self.phase_row = np.concatenate(
                [self.x_ref[2:].ravel(), accelerations(params, self.x_ref[None])[0].ravel()]
            )

    def to_state(self, unknowns):
        return _state(self.params, unknowns) if self.formulation == "reversible" else unknowns.reshape(4, self.params.N)

    def from_state(self, x):
        return x[:2].ravel().copy() if self.formulation == "reversible" else x.ravel().copy()

    def residual_from_end(self, x0, x_end):
        if self.formulation == "reversible":
            return x_end[2:].ravel().copy()
        r = x_end.ravel() - x0.ravel()
        return np.append(r, self.phase_row @ (x0.ravel() - self.x_ref.ravel()))

    def evaluate(self, unknowns) -> "ShootingPoint":
        x0 = self.to_state(unknowns)
        lin = self.flow.linearize(self.params, x0, self.nsteps, self.dt)
        return (KrylovShootingPoint if self.solver == "krylov" else ShootingPoint)(self, x0, lin)


class ShootingPoint:
    """One Newton point: residual, end state and min contact now; the Jacobian on request."""

    def __init__(self, pmap: PeriodMap, x0, lin):
        self.pmap, self.x0, self.linearization = pmap, x0, lin
        self.residual = pmap.residual_from_end(x0, lin.x_end)
        self._jacobian = None

    @property
    def min_contact(self) -> float:
        return self.linearization.min_contact

    def columns(self) -> np.ndarray:
        """End-state derivatives along the unknowns' directions, shape (4N, n_unknowns)."""
        pmap, N = self.pmap, self.pmap.params.N
        which = "positions" if pmap.formulation == "reversible" else "all"
        if pmap.jacobian == "tangent":
            before = self.linearization.stats["tangent_columns"]
            cols = self.linearization.unit_columns(which)
            pmap.tangent_columns += self.linearization.stats["tangent_columns"] - before  # fewer when probed
            return cols
        eye = np.eye(4 * N).reshape(4 * N, 4, N)
        directions = eye[: 2 * N] if which == "positions" else eye
        h = pmap.fd_step
        batch = np.concatenate([self.x0[None] + h * directions, self.x0[None] - h * directions])
        x_end = pmap.flow.run(pmap.params, batch, pmap.nsteps, pmap.dt).x_end
        n = len(directions)
        return ((x_end[:n] - x_end[n:]) / (2 * h)).reshape(n, -1).T

    def jacobian(self) -> np.ndarray:
        if self._jacobian is None:
            cols = self.columns()
            if self.pmap.formulation == "reversible":
                self._jacobian = cols[2 * self.pmap.params.N :, :]  # velocity rows
            else:
                self._jacobian = np.vstack([cols - np.eye(cols.shape[0]), self.pmap.phase_row[None]])
        return self._jacobian


class KrylovShootingPoint(ShootingPoint):
    """A Newton point of the matrix-free path: ``solve`` runs GMRES on Jacobian-vector products, each one
    tangent column replayed on this point's base trajectory (``continuation.krylov``)."""

    def jvp(self, v: np.ndarray) -> np.ndarray:
        N = self.pmap.params.N
        d = np.zeros((1, 4, N))
        d[0, :2] = np.asarray(v).reshape(2, N)
        return self.linearization.columns(d)[2 * N :, 0]

    def solve(self, r: np.ndarray) -> tuple[np.ndarray, bool]:
        """Newton's step: GMRES; when it does not reach its tolerance, the dense step instead (the 2N
        tangent columns and LU, ``newton.solve_linear``), counted in ``pmap.krylov_unconverged``."""
        step, info = gmres_step(self.jvp, r, self.pmap.krylov, self.pmap.preconditioner)
        self.pmap.krylov_iterations.append(info["iterations"])
        if info["converged"]:
            return step, False
        self.pmap.krylov_unconverged += 1
        return solve_linear(self.jacobian(), r)


def chord_solver(J0: np.ndarray):
    """(evaluation, r) -> J0^-1 r with J0 factored once; None when J0 is singular."""
    try:
        lu = scipy.linalg.lu_factor(np.asarray(J0, dtype=float), check_finite=True)
    except (ValueError, scipy.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(lu[0])) or np.min(np.abs(np.diag(lu[0]))) == 0.0:
        return None
    return lambda ev, r: scipy.linalg.lu_solve(lu, r, check_finite=False)


def is_mirror_symmetric(state, rtol: float, sites=None) -> bool:
    """Whether the positions equal their reflection j -> N + 1 - j (or their image under the site permutation
    ``sites``) to rtol of their size."""
    q = np.asarray(state)[:2]
    image = q[:, ::-1] if sites is None else q[:, sites]
    return bool(np.max(np.abs(q - image)) <= rtol * max(float(np.max(np.abs(q))), 1e-300))


#: an orbit whose max |u - v| is below this is the rest state, whatever its seed: the residual tolerance is
#: absolute (1e-10), so a seed of amplitude 1e-10 met it at once and "converged" to the rest state (E ~ 1e-15),
#: which the collapse test relative to the seed cannot see. Breathers of the gap have max |u - v| of 1e-2 and up
#: (the frequency branch starts from the eigenmode at 0.03).
REST_AMPLITUDE = 1e-6

#: ``find_breather(solver="auto")`` solves matrix-free from this many sites on. On the 2-core CPU the
#: matrix-free path was faster at every size measured (paper breather from the NLS seed: 6.7x at N = 201,
#: 53x at 801, 168x at 1601; ``benchmarks/newton_krylov.py``, ``benchmarks/results/cpu-2core-2026-11-25c.json``),
#: and on an H200 too (1.1x at 201, 13x at 801, ``benchmarks/results/h200-2026-11-25/5a574a7.json``; with the
#: sites layout 9.0x at 1601 and 32x at 3201, ``.../f5f67b4.json``); the threshold keeps the paper's chains
#: (N <= 401) on the dense reference path, whose Jacobian continuation and Floquet reuse.
KRYLOV_MIN_SITES = 1024


def auto_solver(params: ChainParams, formulation: str, jacobian: str, hinted: bool, krylov=None) -> str:
    """``find_breather(solver="auto")``'s choice: ``"krylov"`` for the reversible formulation with the tangent
    Jacobian and no chord hint, on ``KRYLOV_MIN_SITES`` sites or more, where the linear lattice's preconditioner
    exists (fixed ends; plain GMRES does not converge on long chains); else ``"dense"``."""
    matrix_free = formulation == "reversible" and jacobian == "tangent" and not hinted
    exists = preconditioned(params.boundary, krylov or KrylovSettings())
    return "krylov" if matrix_free and exists and params.N >= KRYLOV_MIN_SITES else "dense"


def find_breather(
    params: ChainParams,
    omega: float,
    seed,
    *,
    formulation: str = "reversible",
    flow: Flow | None = None,
    method: str | None = None,
    dt: float | None = None,
    steps_per_period: int | None = None,
    tol: float = 1e-10,
    max_iterations: int = 30,
    jacobian: str = "tangent",
    fd_step: float = 1e-7,
    collapse_ratio: float = 1e-3,
    symmetric: bool | None = None,
    jacobian_hint: np.ndarray | None = None,
    solver: str = "auto",
    krylov: KrylovSettings | None = None,
    device: str | None = None,
    log=None,
) -> ShootingResult:
    """Newton shooting for a breather of frequency ``omega`` from ``seed``.

    Args:
        params: the chain.
        omega: breather frequency (period T = 2 pi / omega).
        seed: initial guess, a (4, N) state (the reversible formulation uses its positions).
        formulation: ``"reversible"`` or ``"general"``.
        flow: the integrator (a ``warpchain.Flow``); or build one from ``method``, ``dt`` or
            ``steps_per_period`` (default kahan8, 32 steps per period) and ``device``.
        tol: convergence threshold on the residual's 2-norm.
        jacobian: ``"tangent"`` (exact derivative of the discrete map) or ``"finite-difference"``.
        collapse_ratio: an iterate whose max |u - v| falls below this fraction of the seed's (0 < ratio < 1),
            or below ``REST_AMPLITUDE`` whatever the seed, is reported as ``TRIVIAL`` (the rest state is not a
            breather).
        symmetric: keep every iterate mirror-symmetric (j -> N + 1 - j). None (default): when the
            seed is (to 1e-9 of its size) and the formulation is reversible. Newton then cannot drift
            off a site-centred family through round-off amplified by a near-symmetry-breaking
            direction; False solves without the constraint (e.g. for asymmetric breathers).
        jacobian_hint: an approximate Jacobian of the residual (e.g. a neighbouring solution's, as
            continuation has it): Newton takes chord steps with it, factored once, while they
            converge fast, and forms true Jacobians only when they do not.
        solver: the linear solves of Newton: ``"dense"`` (all 2N tangent columns, LU: the reference),
            ``"krylov"`` (GMRES on Jacobian-vector products with the linear lattice's preconditioner,
            ``continuation.krylov``; reversible formulation, tangent Jacobian; a GMRES solve that does not
            converge is replaced by a dense step, counted in ``stats["krylov_unconverged"]``) or ``"auto"``
            (krylov from ``KRYLOV_MIN_SITES`` sites on for fixed ends, where the preconditioner exists; dense
            otherwise).
        krylov: options of the matrix-free solves (``KrylovSettings``).
        log: optional callable receiving one line per iteration.

    Returns:
        ShootingResult (check ``.success``; ``require(result)`` raises on failure).
    """
    start = time.perf_counter()
    omega = real_number("omega", omega, positive=True)
    if formulation not in ("reversible", "general"):
        raise ValueError(f"formulation must be 'reversible' or 'general', got {formulation!r}")
    if jacobian not in ("tangent", "finite-difference"):
        raise ValueError(f"jacobian must be 'tangent' or 'finite-difference', got {jacobian!r}")
    seed = as_batch(seed, params.N, "seed")
    if seed.shape[0] != 1:
        raise ValueError(f"seed must be one state of shape (4, {params.N}), got a batch of {seed.shape[0]}")
    seed = seed[0]
    if solver not in ("dense", "krylov", "auto"):
        raise ValueError(f"solver must be 'dense', 'krylov' or 'auto', got {solver!r}")
    if solver == "auto":
        solver = auto_solver(params, formulation, jacobian, jacobian_hint is not None, krylov)
    if solver == "krylov" and (formulation != "reversible" or jacobian != "tangent"):
        raise ValueError("solver='krylov' solves the reversible formulation with the tangent Jacobian")
    flow = make_flow(flow, method=method, steps_per_period=steps_per_period, dt=dt, omega=omega, device=device)
    settings = NewtonSettings(tol=real_number("tol", tol, positive=True), max_iterations=max_iterations)
    fd_step = real_number("fd_step", fd_step, positive=True)
    pmap = PeriodMap(params, omega, flow, formulation, jacobian, fd_step, seed, solver=solver, krylov=krylov)
    seed_amplitude = float(np.max(np.abs(seed[0] - seed[1])))
    collapse_ratio = real_number("collapse_ratio", collapse_ratio, positive=True)
    if collapse_ratio >= 1.0:
        raise ValueError(f"collapse_ratio must be below 1 (a fraction of the seed's amplitude), got {collapse_ratio}")

    def amplitude(unknowns):
        x = pmap.to_state(unknowns)
        return float(np.max(np.abs(x[0] - x[1])))

    if symmetric is None:
        symmetric = formulation == "reversible" and is_mirror_symmetric(seed, 1e-9)
    if symmetric and formulation != "reversible":
        raise ValueError("symmetric=True needs the reversible formulation")
    outcome = newton(
        pmap.from_state(seed),
        pmap.evaluate,
        settings,
        chord=chord_solver(jacobian_hint) if jacobian_hint is not None else None,
        amplitude=amplitude,
        collapse_below=max(collapse_ratio * seed_amplitude, REST_AMPLITUDE),
        project=mirror_projector(params.N) if symmetric else None,
        log=log,
    )
    return shooting_result(pmap, outcome, start)


def shooting_result(pmap: PeriodMap, outcome: NewtonOutcome, start: float) -> ShootingResult:
    """Package a Newton outcome on ``pmap`` as a ShootingResult (message with advice on failure)."""
    params, omega = pmap.params, pmap.omega
    status, history, iterations = outcome.status, outcome.history, outcome.iterations
    state = pmap.to_state(outcome.unknowns)
    if status is ShootingStatus.CONVERGED:
        message = (
            f"converged in {iterations} iterations to residual {history[-1]:.3g} "
            f"(omega = {omega:.6g}, {pmap.formulation} formulation, {pmap.jacobian} Jacobian)"
        )
    else:
        report = frequency_report(params, omega)
        message = (
            f"Newton failed for omega = {omega:.6g} ({report['location']}): {outcome.message}. "
            f"What to do: {status.advice}."
        )
    ev = outcome.evaluation
    lin = ev.linearization if ev is not None and status is not ShootingStatus.INTEGRATION_ERROR else None
    columns = pmap.tangent_columns if pmap.jacobian == "tangent" else outcome.stats["jacobians"] * pmap.n_unknowns
    stats = dict(outcome.stats, tangent_columns=columns)
    if pmap.solver == "krylov":
        stats.update(
            solver="krylov", krylov_iterations=list(pmap.krylov_iterations), krylov_unconverged=pmap.krylov_unconverged
        )
        stats["tangent_columns"] = sum(pmap.krylov_iterations) + pmap.tangent_columns
    else:
        stats["solver"] = "dense"
    return ShootingResult(
        state=state,
        omega=float(omega),
        period=2 * math.pi / omega,
        energy=float(energy(params, state)[0]),
        residual=history[-1] if history else float("nan"),
        residual_history=history,
        iterations=iterations,
        status=status,
        message=message,
        min_contact=lin.min_contact if lin is not None else float("nan"),
        method=pmap.flow.method,
        dt=pmap.dt,
        nsteps=pmap.nsteps,
        formulation=pmap.formulation,
        jacobian=pmap.jacobian,
        used_lstsq=outcome.used_lstsq,
        wall_seconds=time.perf_counter() - start,
        params=params,
        flow=pmap.flow,
        stats=stats,
        _linearization=lin if pmap.jacobian == "tangent" else None,
    )
