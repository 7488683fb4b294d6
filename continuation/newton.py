"""Damped Newton on any problem that can be evaluated at a point.

A problem is a callable ``evaluate(y) -> Evaluation``; an ``Evaluation`` has ``residual`` (an
array) and ``jacobian()`` (computed on first request, then cached). Newton evaluates each trial
point once: when the damped step is accepted, the trial's own evaluation becomes the next iterate,
so its Jacobian replays the trajectory already integrated for its residual (``Flow.linearize``)
and nothing is integrated twice. The last evaluation is returned, so that Floquet can reuse the
columns of its Jacobian.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from typing import Callable, Protocol

import numpy as np
import scipy.linalg

from warpchain import IntegrationError
from warpchain.model import real_number, whole_number


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
            "trivial": "the iterate collapsed onto the rest state, which is not a breather: raise the seed "
            "amplitude or move the frequency further into the gap",
            "integration_error": "the orbit blew up: reduce dt (steps_per_period) or the seed amplitude",
        }[self.value]


class Evaluation(Protocol):
    residual: np.ndarray

    def jacobian(self) -> np.ndarray: ...


#: a chord step is kept when it multiplies the residual by at most this; chord steps per solve are
#: limited to CHORD_BUDGET x max_iterations
CHORD_CONTRACTION = 0.25
CHORD_BUDGET = 3


@dataclasses.dataclass(frozen=True)
class NewtonSettings:
    """Newton's options.

    Attributes:
        tol: stop when ||r||_2 <= tol.
        max_iterations: at most this many Newton steps (>= 0).
        max_halvings: damping: the step is halved at most this many times while the residual grows.
    """

    tol: float = 1e-10
    max_iterations: int = 30
    max_halvings: int = 8

    def __post_init__(self):
        real_number("tol", self.tol, positive=True)
        for name in ("max_iterations", "max_halvings"):
            whole_number(name, getattr(self, name), minimum=0)


@dataclasses.dataclass(frozen=True)
class NewtonOutcome:
    """What ``newton`` returns: the last iterate and its evaluation, residual norms, and why it stopped.

    Attributes:
        stats: ``evaluations`` (trial points included) and ``jacobians`` formed.
    """

    unknowns: np.ndarray
    evaluation: object
    history: tuple
    iterations: int
    status: ShootingStatus
    message: str
    used_lstsq: int
    stats: dict

    @property
    def success(self) -> bool:
        return self.status is ShootingStatus.CONVERGED


def solve_linear(J, r):
    """Solve J x = r by LU, or by least squares when J is not square, singular or ill-conditioned.

    Returns (x, used_lstsq). The LU path is LAPACK getrf / gecon / getrs on one Fortran-ordered copy
    of J; it falls back to ``scipy.linalg.lstsq`` when getrf finds an exactly zero pivot or the
    estimated reciprocal 1-norm condition number is below machine epsilon (or NaN) - the same tests,
    on the same estimate, as ``scipy.linalg.solve``'s LinAlgError / LinAlgWarning, which this
    function used to turn into the fallback (no longer by toggling the process-wide warning filters,
    which is not thread-safe). Calling LAPACK directly skips what scipy.linalg.solve (1.17+) adds
    around the same three calls: a strided copy plus a transposing copy of J and a structure-detection
    pass. On the Newton loop's J (a non-contiguous row block of an F-ordered array) that measured
    5-22% faster at n = 402 (0.1-0.4 ms of 1.5-2 ms) and 11-16% at n = 804 (best and median of
    interleaved calls, 2-core CPU, 1 and 2 BLAS threads; benchmarks/linear_solve.py).
    """
    J, r = np.asarray(J), np.asarray(r)
    if J.ndim == 2 and J.shape[0] == J.shape[1] > 0:
        getrf, gecon, getrs, lange = scipy.linalg.lapack.get_lapack_funcs(("getrf", "gecon", "getrs", "lange"), (J, r))
        a = np.array(J, dtype=getrf.dtype, order="F")  # our own copy: factored in place, J is left alone
        anorm = lange("1", a)  # before getrf overwrites a
        lu, piv, info = getrf(a, overwrite_a=True)
        if info == 0:  # info > 0: an exactly zero pivot, J is singular
            rcond, info = gecon(lu, anorm, norm="1")
            # a NaN estimate (non-finite J) fails this test too and falls back, as in scipy.linalg.solve
            if info == 0 and rcond >= np.finfo(lu.dtype).eps:
                try:
                    x, info = getrs(lu, piv, r)
                except ValueError:  # r does not match J: lstsq below reports it
                    info = -1
                if info == 0:
                    return x, False
    return scipy.linalg.lstsq(J, r, check_finite=False)[0], True


def newton(
    unknowns,
    evaluate: Callable[[np.ndarray], Evaluation],
    settings: NewtonSettings = NewtonSettings(),
    *,
    amplitude: Callable[[np.ndarray], float] | None = None,
    collapse_below: float = 0.0,
    project: Callable[[np.ndarray], np.ndarray] | None = None,
    chord: Callable[[object, np.ndarray], np.ndarray] | None = None,
    log=None,
) -> NewtonOutcome:
    """Damped Newton: LU solve (least squares when singular, ill-conditioned or not square), step
    halved while the residual grows.

    Args:
        unknowns: initial iterate.
        evaluate: y -> Evaluation (residual now, Jacobian on request).
        settings: NewtonSettings.
        amplitude, collapse_below: an iterate with amplitude(y) < collapse_below (or 0) is reported
            as ``TRIVIAL`` (Newton fell onto the rest state).
        project: maps every iterate (the first included) onto an invariant subspace, e.g. mirror-
            symmetric profiles, so that round-off cannot lead the iteration off a symmetric branch.
        chord: (evaluation, residual) -> step from an approximate Jacobian (e.g. a neighbouring
            solution's, factored once). Chord steps cost no tangent columns and do not count against
            ``max_iterations`` (at most CHORD_BUDGET times it); they are taken while each one reduces
            the residual by CHORD_CONTRACTION or better, and Newton switches to true Jacobians for good
            at the first that does not (the iterate is then not moved by it).
        log: optional callable receiving one line per iteration.
    """
    history, used_lstsq, iterations, message = [], 0, 0, ""
    stats = {"evaluations": 0, "jacobians": 0, "chord_steps": 0}
    status, ev = None, None
    if project is not None:
        unknowns = project(unknowns)
    try:
        ev = evaluate(unknowns)
        stats["evaluations"] += 1
        norm = float(np.linalg.norm(ev.residual))
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
            if norm <= settings.tol:
                status = ShootingStatus.CONVERGED
                break
            if iterations >= settings.max_iterations:
                status = ShootingStatus.MAX_ITERATIONS
                message = f"residual {norm:.3g} > tol {settings.tol:g} after {iterations} iterations"
                break
            if chord is not None and stats["chord_steps"] < CHORD_BUDGET * max(settings.max_iterations, 1):
                step = chord(ev, ev.residual)
                trial = unknowns - step if project is None else project(unknowns - step)
                trial_ev = evaluate(trial)
                stats["evaluations"] += 1
                trial_norm = float(np.linalg.norm(trial_ev.residual))
                if math.isfinite(trial_norm) and trial_norm <= CHORD_CONTRACTION * norm:
                    stats["chord_steps"] += 1  # cheap steps: not counted against max_iterations
                    unknowns, ev, norm = trial, trial_ev, trial_norm
                    history.append(norm)
                    if log is not None:
                        log(f"chord {stats['chord_steps']}: residual {norm:.3e}")
                    continue
                chord = None  # poor contraction: true Newton (with its whole budget) from here on
            if hasattr(ev, "solve"):  # matrix-free: the evaluation solves with its own Jacobian-vector products
                step, lstsq_used = ev.solve(ev.residual)
                stats["linear_solves"] = stats.get("linear_solves", 0) + 1
            else:
                J = ev.jacobian()
                stats["jacobians"] += 1
                step, lstsq_used = solve_linear(J, ev.residual)
            used_lstsq += int(lstsq_used)
            lam, trial, trial_ev, trial_norm = 1.0, None, None, math.inf
            for _ in range(settings.max_halvings + 1):
                trial = unknowns - lam * step if project is None else project(unknowns - lam * step)
                trial_ev = evaluate(trial)
                stats["evaluations"] += 1
                trial_norm = float(np.linalg.norm(trial_ev.residual))
                if math.isfinite(trial_norm) and trial_norm < norm:
                    break
                lam *= 0.5
            iterations += 1
            if not (math.isfinite(trial_norm) and trial_norm < norm):
                status = ShootingStatus.STAGNATED
                message = f"no damped step (down to 1/{2**settings.max_halvings}) reduced the residual {norm:.3g}"
                break
            unknowns, ev, norm = trial, trial_ev, trial_norm
            history.append(norm)
            if log is not None:
                log(f"newton {iterations}: residual {norm:.3e} (damping {lam:g}{', lstsq' if lstsq_used else ''})")
    except IntegrationError as exc:
        status, message = ShootingStatus.INTEGRATION_ERROR, str(exc)
    return NewtonOutcome(
        unknowns=unknowns,
        evaluation=ev,
        history=tuple(history),
        iterations=iterations,
        status=status,
        message=message,
        used_lstsq=used_lstsq,
        stats=stats,
    )
