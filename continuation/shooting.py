"""Newton shooting on the period map.

Two formulations:

* ``"reversible"`` (default): time-reversible breathers are at rest at t = 0. Unknowns are the
  positions q = (u, v) at t = 0 (2N), the residual is the velocities at T/2 (2N): at a root the
  orbit is symmetric about t = T/2 and hence T-periodic. The Jacobian is the velocity block of
  the discrete map's derivative over half a period: 2N tangent columns.
* ``"general"``: unknowns the full state x0 (4N), residual x(T) - x0 plus the phase condition
  <x0 - x_ref, f(x_ref)> = 0; the (4N + 1) x 4N system is solved in the least-squares sense
  (the monodromy has the trivial double multiplier at +1, so V - I alone is singular).

Jacobian columns come from tangent trajectories of the same discrete integrator (exact
derivative of the discrete map), or, selectable by name, from central finite differences of
batched perturbed trajectories (``jacobian="finite-difference"``), both in one launch.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import time
import warnings

import numpy as np
import scipy.linalg

from warpchain import ChainParams, IntegrationError, band_edges, energy, min_contact, propagate_tangent, simulate
from warpchain.model import accelerations, as_batch

# the cheapest at the accuracy breathers need (work-precision scene, smooth case): kahan8 with 32
# steps per period reaches a final-state error of 1.8e-9 over 20 periods with 480 force evaluations
# per period; yoshida6 needs 128 steps (896 evaluations) for 8e-9
DEFAULT_METHOD = "kahan8"
DEFAULT_STEPS_PER_PERIOD = 32


class ShootingStatus(enum.Enum):
    """Outcome of a Newton solve; ``.advice`` says what to do about it."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"
    STAGNATED = "stagnated"
    TRIVIAL = "trivial"
    INTEGRATION_ERROR = "integration_error"

    @property
    def advice(self) -> str:
        return {
            "converged": "",
            "max_iterations": "Newton did not reach the tolerance: start closer (continuation with a smaller step), "
                              "or check that the frequency lies in a gap (see frequency_report)",
            "stagnated": "the damped Newton step could not reduce the residual: the seed is too far from a solution "
                         "or none exists at this frequency (e.g. inside a phonon band); use continuation",
            "trivial": "the iterate collapsed onto the rest state, which is not a breather: raise the seed amplitude or "
                       "move the frequency further into the gap",
            "integration_error": "the orbit blew up: reduce dt (steps_per_period) or the seed amplitude",
        }[self.value]


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
        min_contact: min over sites of 1 + u - v at t = 0 and t = T/2.
        method, dt, nsteps: integrator, step, and steps per half period (reversible) or period.
        formulation, jacobian: what was solved and how its Jacobian was formed.
        used_lstsq: iterations whose linear solve fell back to least squares.
        wall_seconds: time taken.
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

    @property
    def success(self) -> bool:
        return self.status is ShootingStatus.CONVERGED


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

    return {"omega": omega, "location": where(omega), **e,
            "harmonics_in_bands": [n for n in range(2, harmonics + 1) if where(n * omega).endswith("band")]}


def time_grid(omega: float, dt: float | None, steps_per_period: int | None) -> tuple[int, float]:
    """Steps per half period and the step, so that the half period is a whole number of steps."""
    if not (isinstance(omega, (int, float, np.floating)) and math.isfinite(omega) and omega > 0):
        raise ValueError(f"omega must be a finite number > 0, got {omega!r}")
    half = math.pi / omega
    if dt is not None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt!r}")
        n_half = max(1, math.ceil(half / dt - 1e-9))
    else:
        spp = DEFAULT_STEPS_PER_PERIOD if steps_per_period is None else int(steps_per_period)
        if spp < 2:
            raise ValueError("steps_per_period must be >= 2")
        n_half = max(1, math.ceil(spp / 2))
    return n_half, half / n_half


def _state(params, q):
    N = params.N
    x = np.zeros((4, N))
    x[:2] = q.reshape(2, N)
    return x


def _solve(J, r):
    """LU solve with a least-squares fallback for singular or ill-conditioned J; (step, used_lstsq)."""
    if J.shape[0] == J.shape[1]:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
                return scipy.linalg.solve(J, r, check_finite=False), False
        except (scipy.linalg.LinAlgError, scipy.linalg.LinAlgWarning, ValueError):
            pass
    return scipy.linalg.lstsq(J, r, check_finite=False)[0], True


class _PeriodMap:
    """Residual and Jacobian of one formulation, on one device."""

    def __init__(self, params, omega, formulation, method, n_half, dt, jacobian, fd_step, device, x_ref):
        self.params, self.omega, self.formulation = params, omega, formulation
        self.method, self.n_half, self.dt, self.jacobian, self.fd_step = method, n_half, dt, jacobian, fd_step
        self.device = device
        N = params.N
        if formulation == "reversible":
            self.nsteps = n_half
            self.n_unknowns = 2 * N
            self.directions = np.eye(4 * N)[: 2 * N].reshape(2 * N, 4, N)  # position columns
        else:
            self.nsteps = 2 * n_half
            self.n_unknowns = 4 * N
            self.directions = np.eye(4 * N).reshape(4 * N, 4, N)
            self.x_ref = x_ref.copy()
            self.phase_row = np.concatenate([np.zeros(2 * N), accelerations(params, x_ref[None])[0].ravel()])
            self.phase_row[: 2 * N] = x_ref[2:].ravel()  # f(x_ref) = (x_ref', a(x_ref))

    def to_state(self, unknowns):
        return _state(self.params, unknowns) if self.formulation == "reversible" else unknowns.reshape(4, self.params.N)

    def from_state(self, x):
        return x[:2].ravel().copy() if self.formulation == "reversible" else x.ravel().copy()

    def _residual_from_end(self, x0, x_end):
        if self.formulation == "reversible":
            return x_end[2:].ravel()
        r = x_end.ravel() - x0.ravel()
        return np.append(r, self.phase_row @ (x0.ravel() - self.x_ref.ravel()))

    def residual(self, unknowns):
        x0 = self.to_state(unknowns)
        run = simulate(self.params, x0, self.nsteps * self.dt, self.dt, method=self.method, device=self.device,
                       max_energy_error=None, chunks=1)
        return self._residual_from_end(x0, run.x[0])

    def residual_and_jacobian(self, unknowns):
        x0 = self.to_state(unknowns)
        if self.jacobian == "tangent":
            tan = propagate_tangent(self.params, x0, self.directions, self.nsteps, self.dt, method=self.method,
                                    device=self.device)
            x_end, cols = tan.x[0], tan.columns.reshape(len(self.directions), -1).T  # (4N, ncols)
        else:
            h = self.fd_step
            batch = np.concatenate([x0[None], x0[None] + h * self.directions, x0[None] - h * self.directions])
            run = simulate(self.params, batch, self.nsteps * self.dt, self.dt, method=self.method, device=self.device,
                           max_energy_error=None, chunks=1)
            n = len(self.directions)
            x_end = run.x[0]
            cols = ((run.x[1 : n + 1] - run.x[n + 1 :]) / (2 * h)).reshape(n, -1).T
        r = self._residual_from_end(x0, x_end)
        if self.formulation == "reversible":
            J = cols[2 * self.params.N :, :]  # velocity rows
        else:
            J = np.vstack([cols - np.eye(cols.shape[0]), self.phase_row[None]])
        return r, J, x_end


@dataclasses.dataclass(frozen=True)
class NewtonOutcome:
    """What ``newton`` returns: the last iterate, residual norms, and why it stopped."""

    unknowns: np.ndarray
    history: tuple
    iterations: int
    status: ShootingStatus
    message: str
    used_lstsq: int


def newton(unknowns, residual_and_jacobian, residual, *, tol: float, max_iterations: int, amplitude=None,
           collapse_below: float = 0.0, max_halvings: int = 8, log=None) -> NewtonOutcome:
    """Damped Newton: LU solve (least squares when singular or ill-conditioned, or when J is not
    square), step halved while the residual grows.

    Args:
        unknowns: initial iterate.
        residual_and_jacobian: y -> (r, J); residual: y -> r (for the damped trial points).
        tol: stop when ||r||_2 <= tol.
        amplitude, collapse_below: an iterate with amplitude(y) < collapse_below is reported as
            ``TRIVIAL`` (Newton fell onto the rest state).
    """
    history, used_lstsq, iterations, message = [], 0, 0, ""
    status = None
    try:
        r, J = residual_and_jacobian(unknowns)
        norm = float(np.linalg.norm(r))
        history.append(norm)
        while True:
            if not math.isfinite(norm):
                status, message = ShootingStatus.INTEGRATION_ERROR, "the residual is not finite"
                break
            if amplitude is not None:
                amp = amplitude(unknowns)
                if amp < collapse_below or amp == 0.0:
                    status = ShootingStatus.TRIVIAL
                    message = f"amplitude collapsed to {amp:.3g}: the rest state is not a breather"
                    break
            if norm <= tol:
                status = ShootingStatus.CONVERGED
                break
            if iterations >= max_iterations:
                status = ShootingStatus.MAX_ITERATIONS
                message = f"residual {norm:.3g} > tol {tol:g} after {iterations} iterations"
                break
            step, lstsq_used = _solve(J, r)
            used_lstsq += int(lstsq_used)
            lam, trial_norm = 1.0, math.inf
            for _ in range(max_halvings):
                trial = unknowns - lam * step
                trial_norm = float(np.linalg.norm(residual(trial)))
                if math.isfinite(trial_norm) and trial_norm < norm:
                    break
                lam *= 0.5
            iterations += 1
            if not (math.isfinite(trial_norm) and trial_norm < norm):
                status = ShootingStatus.STAGNATED
                message = f"no damped step (down to 1/{2 ** max_halvings}) reduced the residual {norm:.3g}"
                break
            unknowns = trial
            r, J = residual_and_jacobian(unknowns)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            if log is not None:
                log(f"newton {iterations}: residual {norm:.3e} (damping {lam:g}{', lstsq' if lstsq_used else ''})")
    except IntegrationError as exc:
        status, message = ShootingStatus.INTEGRATION_ERROR, str(exc)
    return NewtonOutcome(unknowns=unknowns, history=tuple(history), iterations=iterations, status=status,
                         message=message, used_lstsq=used_lstsq)


def find_breather(params: ChainParams, omega: float, seed, *, formulation: str = "reversible",
                  method: str = DEFAULT_METHOD, dt: float | None = None, steps_per_period: int | None = None,
                  tol: float = 1e-10, max_iterations: int = 30, jacobian: str = "tangent", fd_step: float = 1e-7,
                  collapse_ratio: float = 1e-3, device: str | None = None, log=None) -> ShootingResult:
    """Newton shooting for a breather of frequency ``omega`` from ``seed``.

    Args:
        params: the chain.
        omega: breather frequency (period T = 2 pi / omega).
        seed: initial guess, a (4, N) state (the reversible formulation uses its positions).
        formulation: ``"reversible"`` or ``"general"``.
        method, dt, steps_per_period: integrator and time grid (the half period is a whole number of
            steps; default 32 steps per period).
        tol: convergence threshold on the residual's 2-norm.
        jacobian: ``"tangent"`` (exact derivative of the discrete map) or ``"finite-difference"``.
        collapse_ratio: an iterate whose max |u - v| falls below this fraction of the seed's is
            reported as ``TRIVIAL`` (the rest state is not a breather).
        log: optional callable receiving one line per iteration.

    Returns:
        ShootingResult (check ``.success``; ``require(result)`` raises on failure).
    """
    start = time.perf_counter()
    if formulation not in ("reversible", "general"):
        raise ValueError(f"formulation must be 'reversible' or 'general', got {formulation!r}")
    if jacobian not in ("tangent", "finite-difference"):
        raise ValueError(f"jacobian must be 'tangent' or 'finite-difference', got {jacobian!r}")
    seed = as_batch(seed, params.N, "seed")[0]
    n_half, dt_used = time_grid(omega, dt, steps_per_period)
    pmap = _PeriodMap(params, omega, formulation, method, n_half, dt_used, jacobian, fd_step, device, seed)
    unknowns = pmap.from_state(seed)
    seed_amplitude = float(np.max(np.abs(seed[0] - seed[1])))

    def amplitude(unknowns):
        x = pmap.to_state(unknowns)
        return float(np.max(np.abs(x[0] - x[1])))

    outcome = newton(unknowns, lambda y: pmap.residual_and_jacobian(y)[:2], pmap.residual, tol=tol,
                     max_iterations=max_iterations, amplitude=amplitude,
                     collapse_below=collapse_ratio * seed_amplitude, log=log)
    unknowns, history, iterations = outcome.unknowns, outcome.history, outcome.iterations
    status, message, used_lstsq = outcome.status, outcome.message, outcome.used_lstsq
    state = pmap.to_state(unknowns)
    if status is ShootingStatus.CONVERGED:
        message = (f"converged in {iterations} iterations to residual {history[-1]:.3g} "
                   f"(omega = {omega:.6g}, {formulation} formulation, {jacobian} Jacobian)")
    else:
        report = frequency_report(params, omega)
        message = (f"Newton failed for omega = {omega:.6g} ({report['location']}): {message}. What to do: {status.advice}.")
    half = simulate(params, state, n_half * dt_used, dt_used, method=method, device=device, max_energy_error=None,
                    chunks=1) if status is not ShootingStatus.INTEGRATION_ERROR else None
    contact = float(min(min_contact(state)[0], min_contact(half.x)[0])) if half is not None else float("nan")
    return ShootingResult(
        state=state, omega=float(omega), period=2 * math.pi / omega, energy=float(energy(params, state)[0]),
        residual=history[-1] if history else float("nan"), residual_history=history, iterations=iterations,
        status=status, message=message, min_contact=contact, method=method, dt=dt_used,
        nsteps=pmap.nsteps, formulation=formulation, jacobian=jacobian, used_lstsq=used_lstsq,
        wall_seconds=time.perf_counter() - start, params=params)
