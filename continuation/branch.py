"""Branches of breathers: the two continuation problems the driver walks, and short entry points.

* ``NaturalParameter`` (continuation in the coupling K at fixed w_b): the coordinate is log10 K (or
  K); secant predictor on the states; corrector: fixed-K Newton shooting (reversible formulation);
  lands exactly on requested ``targets``.
* ``PseudoArclength`` (continuation in the frequency at fixed K, ``FrequencyAxis``; or in log10 K at
  fixed w_b through folds, ``CouplingAxis``, for the families of ``continuation.bifurcation``):
  unknowns y = (q, w_b), secant
  tangent tau, corrector Newton on [R(q, w); <tau, y - y_pred>_W = 0] with the weighted inner product
  <a, b>_W = a_q . b_q + theta^2 a_w b_w, theta = 1 / (gap width), so that crossing the gap counts
  like a unit change of the profile. The half period keeps a fixed number of steps (dt follows w).
  dR/dw is read from the same trajectory: R is the velocity at T/2 = n dt, so
  dR/dw = -(pi / w^2) a(q(T/2)) up to the integrator's error in the modified flow (O(dt^8) for kahan8),
  which leaves Newton's convergence unchanged at the tolerances used; no extra trajectory is run.
  In log10 K the force changes, so dR/d(log10 K) costs two extra runs (a central difference).

Every corrector step is one ``Flow.linearize`` per Newton point (``shooting``), and the converged
point's linearization (its recorded trajectory) is what the reduced Floquet problem's columns replay.

``continue_in_coupling`` and ``continue_in_frequency`` build the problem and call
``driver.continuation``; ``start_from_eigenmode`` gives the two first points of the frequency branch.
"""

from __future__ import annotations

import math

import numpy as np

from warpchain import ChainParams, Flow, band_edges, lowest_optical_mode
from warpchain.model import accelerations

from .driver import ContinuationSettings, continuation
from .newton import NewtonSettings, newton
from .results import Branch, BranchPoint, Failure, Solution
from .shooting import PeriodMap, chord_solver, find_breather, is_mirror_symmetric, make_flow, mirror_projector

__all__ = [
    "ArclengthCorrector",
    "Branch",
    "BranchPoint",
    "CouplingAxis",
    "FrequencyAxis",
    "ContinuationSettings",
    "NaturalParameter",
    "PseudoArclength",
    "continue_in_coupling",
    "continue_in_frequency",
    "start_from_eigenmode",
]


# ----------------------------------------------------------------------------- continuation in K


class _JacobianMemory:
    """The residual Jacobians of the last few analysed points (the velocity rows of the position
    columns of their half-period maps, which Floquet computed anyway): the corrector's chord steps
    start from the neighbour's."""

    _KEEP = 6

    def remember(self, point, J) -> None:
        memory = self.__dict__.setdefault("_jacobians", {})
        memory[id(point)] = (point, J)
        while len(memory) > self._KEEP:
            memory.pop(next(iter(memory)))

    def hint(self, point):
        entry = self.__dict__.get("_jacobians", {}).get(id(point))
        return None if entry is None or entry[0] is not point else entry[1]

    def age(self, point) -> int | None:
        """How many Jacobians were remembered after ``point``'s (None: it is no longer held)."""
        keys = list(self.__dict__.get("_jacobians", {}))
        return len(keys) - 1 - keys.index(id(point)) if self.hint(point) is not None else None

    def restore(self, point, J, age: int) -> None:
        """Hold ``J`` for ``point`` as it was held ``age`` Jacobians ago (placeholders stand for the later ones,
        so that it is dropped when it was in the walk that stored the state)."""
        self.remember(point, J)
        for _ in range(age):
            placeholder = object()
            self.remember(placeholder, None)


def _revisit(params: ChainParams, omega: float, point: BranchPoint, flow: Flow) -> Solution:
    """A stored point's Solution: its half-period map evaluated at its state exactly as both correctors
    evaluate their last iterate (``PeriodMap(...).evaluate``, which is where their linearization comes from)."""
    pmap = PeriodMap(params, omega, flow)
    lin = pmap.evaluate(pmap.from_state(point.state)).linearization
    return Solution(params, omega, point.state, point.iterations, point.residual_history, lin, point.s)


class NaturalParameter(_JacobianMemory):
    """Continuation in K at fixed omega from ``params.K`` to ``K_end`` (natural parameter), in steps of log10 K
    (its ``CouplingAxis``).

    Args:
        params: the chain at the first K.
        omega: the breather frequency.
        seed: a (4, N) state near the solution at params.K (e.g. the anti-continuum seed).
        K_end: the end of the branch.
        flow: the integrator.
        targets: K values the branch must land on exactly.
    """

    def __init__(self, params: ChainParams, omega: float, seed, K_end: float, flow: Flow, *, targets=()):
        if not (isinstance(K_end, (int, float, np.integer, np.floating)) and math.isfinite(K_end) and K_end > 0):
            raise ValueError(f"K_end must be a finite number > 0, got {K_end!r}")
        self.params, self.omega, self.seed, self.K_end, self.flow = params, float(omega), seed, float(K_end), flow
        self.axis = CouplingAxis(params, omega)
        self.parameter = self.axis.name
        self.direction = 1.0 if K_end >= params.K else -1.0
        self.targets = sorted(
            {float(t) for t in targets if (t - params.K) * self.direction > 0 and (K_end - t) * self.direction > 0}
            | {float(K_end)},
            reverse=self.direction < 0,
        )
        self.description = f"K-continuation, w_b = {omega:g}"

    def _solve(self, value: float, guess, s: float, max_newton: int, tol: float, hint=None):
        pr, omega = self.axis.at(value)
        res = find_breather(pr, omega, guess, flow=self.flow, tol=tol, max_iterations=max_newton, jacobian_hint=hint)
        if not res.success:
            return Failure(res.message)
        return Solution(pr, omega, res.state, res.iterations, res.residual_history, res.linearization(), s)

    def prepare(self, settings: ContinuationSettings, resume=None, walk=None) -> None:
        self._settings = settings

    def revisit(self, point: BranchPoint) -> Solution:
        """The Solution at a stored point as its corrector ended on it: the same linearization, so its
        analysis gives the same multipliers, spectra and chord Jacobian (a resumed walk needs them)."""
        return _revisit(*self.axis.at(self.axis.value(point)), point, self.flow)

    def start(self):
        settings = self._settings
        first = self.params.K
        return [self._solve(first, self.seed, self.axis.of(first), 3 * settings.max_newton, settings.newton_tol)]

    def _next_target(self, value: float) -> float:
        return next(t for t in self.targets if (t - value) * self.direction > 1e-12 * max(1.0, abs(t)))

    def clip_step(self, last: BranchPoint, h: float) -> float:
        return min(h, abs(self.axis.of(self._next_target(self.axis.value(last))) - self.axis.coordinate(last)))

    def step(self, points, h: float):
        axis, last = self.axis, points[-1]
        s_last = axis.coordinate(last)
        s_new = s_last + self.direction * h
        target = self._next_target(axis.value(last))
        value = target if abs(s_new - axis.of(target)) <= 1e-12 * max(1.0, abs(s_new)) else axis.value_of(s_new)
        if len(points) >= 2 and axis.value(points[-2]) != axis.value(last):
            s_prev = axis.coordinate(points[-2])
            guess = last.state + (last.state - points[-2].state) * (s_new - s_last) / (s_last - s_prev)
        else:
            guess = last.state
        return self._solve(value, guess, s_new, self._settings.max_newton, self._settings.newton_tol, self.hint(last))

    def between(self, a: BranchPoint, b: BranchPoint, t: float = 0.5):
        s = (1.0 - t) * self.axis.coordinate(a) + t * self.axis.coordinate(b)
        return self._solve(
            self.axis.value_of(s),
            (1.0 - t) * a.state + t * b.state,
            s,
            self._settings.max_newton,
            self._settings.newton_tol,
            self.hint(a),
        )

    def is_between(self, a, m, b) -> bool:
        value = self.axis.value
        return (value(m) - value(a)) * (value(b) - value(m)) > 0

    def is_forward(self, points, new) -> bool:
        return (self.axis.value(new) - self.axis.value(points[-1])) * self.direction > 0

    def finished(self, last: BranchPoint):
        if abs(self.axis.value(last) - self.K_end) <= 1e-12 * max(1.0, abs(self.K_end)):
            return True, f"K = {last.K:.8g}"
        return False, ""

    def progress(self, first: BranchPoint, last: BranchPoint) -> float:
        total = self.axis.of(self.K_end) - self.axis.coordinate(first)
        return (self.axis.coordinate(last) - self.axis.coordinate(first)) / total if total else 1.0

    def describe(self, p: BranchPoint) -> str:
        return self.axis.describe(p)


# ----------------------------------------------------------------------------- pseudo-arclength


class ParameterAxis:
    """What a branch is continued in, for both problems (``NaturalParameter`` steps along it, ``PseudoArclength``
    solves for its coordinate): ``name``, the key of ``BranchPoint.parameters`` it is (``"K"`` or ``"omega"``,
    also the events' ``parameter``); ``value(point)``; the coordinate c the steps are taken in (``of(value)``,
    ``value_of(c)``, ``coordinate(point)``); the chain and frequency at a value (``at``) or at a coordinate
    (``chain``, which refuses one the corrector should not have reached); dR/dc (``derivative``, for the
    arclength corrector's bordered Jacobian). A new axis (another parameter of the chain) is a subclass."""

    name: str

    def value(self, point) -> float:
        return float(point.value(self.name))

    def of(self, value: float) -> float:
        return float(value)

    def value_of(self, c: float) -> float:
        return float(c)

    def coordinate(self, point) -> float:
        return self.of(self.value(point))

    def at(self, value: float) -> tuple:
        raise NotImplementedError

    def chain(self, c: float) -> tuple:
        return self.at(self.value_of(c))

    def describe(self, p) -> str:
        return f"{self.name} = {self.value(p):.8g}: E = {p.energy:.8f}, max|l| = {p.max_modulus:.8f}"


class FrequencyAxis(ParameterAxis):
    """The arclength parameter w_b at fixed K (the chain's ``params``): the half period keeps its
    number of steps, so dt follows w, and dR/dw is read from the trajectory (module docstring)."""

    name = "omega"

    def __init__(self, params: ChainParams):
        self.params = params
        self.edges = band_edges(params.M, params.K)

    def at(self, value: float) -> tuple:
        return self.params, float(value)

    def chain(self, c: float) -> tuple:
        if not (math.isfinite(c) and c > 0):
            raise _BadParameter(f"the corrector left the positive frequencies (w = {c:.3g})")
        return self.at(c)

    def default_theta(self) -> float:
        return 1.0 / self.edges["gap_width"]

    def derivative(self, point, c: float, x0) -> np.ndarray:
        x_end = point.linearization.x_end
        return -(math.pi / c**2) * accelerations(self.params, x_end[None])[0].ravel()

    def description(self) -> str:
        return f"frequency continuation, K = {self.params.K:g}"

    def finished(self, problem, last) -> tuple:
        """(True, why) at the frequency floor or up in the optical band (contact loss ends it in the driver)."""
        edges = self.edges
        if last.omega < problem.omega_min:
            return True, f"w_b = {last.omega:.8g} < omega_min = {problem.omega_min:g}"
        if last.omega > edges["optical_bottom"] + 0.5 * edges["gap_width"]:
            return True, f"w_b = {last.omega:.8g} went up into the optical band"
        return False, ""

    def progress(self, problem, first, last) -> float:
        """Contact loss is the expected end, so progress is the fall of min contact towards 0 (or of w_b
        towards omega_min, whichever is further along)."""
        c0 = first.min_contact
        by_contact = (c0 - last.min_contact) / c0 if c0 > 0 else 0.0
        by_omega = (first.omega - last.omega) / max(first.omega - problem.omega_min, 1e-12)
        return max(by_contact, by_omega)

    def describe(self, p) -> str:
        return f"w = {p.omega:.8f}: E = {p.energy:.8f}, max|l| = {p.max_modulus:.8f}, min contact {p.min_contact:.4f}"


class CouplingAxis(ParameterAxis):
    """The parameter K at fixed w_b (``omega``), in the coordinate log10 K: dR/d(log10 K) by a central difference
    of two runs at K 10^(+-h) (R depends on K through the force only; h = 1e-6 keeps the truncation
    error ~1e-12 and the round-off ~1e-10 relative, below the corrector's tolerance)."""

    name = "K"
    STEP = 1e-6

    def __init__(self, params: ChainParams, omega: float):
        self.params, self.omega = params, float(omega)

    def of(self, value: float) -> float:
        return math.log10(value)

    def value_of(self, c: float) -> float:
        return 10.0**c

    def at(self, value: float) -> tuple:
        return self.params.replace(K=value), self.omega

    def chain(self, c: float) -> tuple:
        if not (math.isfinite(c) and -12.0 < c < 12.0):
            raise _BadParameter(f"the corrector left the couplings 1e-12 < K < 1e12 (log10 K = {c:.3g})")
        return self.at(self.value_of(c))

    def default_theta(self) -> float:
        return 1.0

    def derivative(self, point, c: float, x0) -> np.ndarray:
        pmap, h = point.pmap, self.STEP
        ends = [
            pmap.flow.run(self.params.replace(K=10.0 ** (c + d)), x0[None], pmap.nsteps, pmap.dt).x_end[0]
            for d in (h, -h)
        ]
        return (ends[0][2:] - ends[1][2:]).ravel() / (2.0 * h)

    def description(self) -> str:
        return f"arclength in K, w_b = {self.omega:g}"

    def finished(self, problem, last) -> tuple:
        """(True, why) once K leaves the problem's ``K_range``."""
        lo, hi = problem.K_range
        if not lo <= last.K <= hi:
            return True, f"K = {last.K:.8g} left [{lo:g}, {hi:g}]"
        return False, ""

    def progress(self, problem, first, last) -> float:
        """The fraction of the K range in log10 K, from the first point to the nearer end."""
        lo, hi = (math.log10(k) for k in problem.K_range)
        k0, k1 = math.log10(first.K), math.log10(last.K)
        return abs(k1 - k0) / max(max(hi - k0, k0 - lo), 1e-12)


def _pack(state, c) -> np.ndarray:
    return np.concatenate([np.asarray(state)[:2].ravel(), [c]])


def _state_of(params: ChainParams, y) -> np.ndarray:
    state = np.zeros((4, params.N))
    state[:2] = y[:-1].reshape(2, params.N)
    return state


class _BorderedPoint:
    """One Newton point of the arclength corrector (one trajectory; Jacobian on request)."""

    def __init__(self, corrector, y, y_pred, tau):
        self.c, self.y = corrector, y
        self.value = float(y[-1])
        self.params, self.omega = corrector.axis.chain(self.value)
        self.point = PeriodMap(self.params, self.omega, corrector.flow).evaluate(y[:-1])
        self.linearization = self.point.linearization
        self.row = corrector.W * tau
        self.residual = np.append(self.point.residual, np.sum(self.row * (y - y_pred)))
        self._dparameter = None

    def dparameter(self) -> np.ndarray:
        """dR/d(parameter) at this point (the axis says how)."""
        if self._dparameter is None:
            self._dparameter = self.c.axis.derivative(self.point, self.value, self.point.x0)
        return self._dparameter

    def jacobian(self) -> np.ndarray:
        n2 = len(self.y) - 1
        J = np.zeros((n2 + 1, n2 + 1))
        J[:n2, :n2] = self.point.jacobian()
        J[:n2, -1] = self.dparameter()
        J[-1] = self.row
        return J


def _bordered_chord(J0, row):
    """Chord solver for [[J0, b], [row]] with J0 (the neighbour's 2N x 2N block) factored once and
    b = dR/d(parameter) taken from each trajectory, by block elimination; None when J0 is singular."""
    solve0 = chord_solver(J0)
    if solve0 is None:
        return None
    c, d = row[:-1], row[-1]

    def solve(ev, r):
        y = solve0(ev, r[:-1])
        z = solve0(ev, ev.dparameter())
        denom = d - float(c @ z)
        x2 = (r[-1] - float(c @ y)) / denom if denom != 0.0 else 0.0
        return np.append(y - z * x2, x2)

    return solve


class _BadParameter(ValueError):
    pass


class ArclengthCorrector:
    """Newton on [R(q, c) = 0; <tau, y - y_pred>_W = 0] for y = (q, c), c the axis' coordinate.

    Args:
        axis: ``FrequencyAxis`` or ``CouplingAxis``.
        flow: the integrator.
        W: weights of the inner product (2N ones, then theta^2).
        settings: NewtonSettings.
        symmetric: project every iterate onto mirror-symmetric profiles.
    """

    def __init__(self, axis, flow: Flow, W, settings: NewtonSettings, symmetric: bool = False):
        self.axis, self.flow, self.W, self.settings = axis, flow, W, settings
        self.project = mirror_projector(axis.params.N) if symmetric else None

    def correct(self, y_pred, tau, hint=None):
        """A NewtonOutcome (``.unknowns`` = (q, c)), or a Failure when the parameter left its range."""
        row = self.W * tau
        try:
            return newton(
                y_pred,
                lambda y: _BorderedPoint(self, y, y_pred, tau),
                self.settings,
                project=self.project,
                chord=None if hint is None else _bordered_chord(hint, row),
            )
        except _BadParameter as exc:
            return Failure(str(exc))

    def solution(self, outcome, s) -> Solution | Failure:
        """The Solution of a converged outcome (a Failure otherwise)."""
        if isinstance(outcome, Failure):
            return outcome
        if not outcome.success:
            return Failure(f"{outcome.status.value}: {outcome.message}")
        y = outcome.unknowns
        params, omega = self.axis.chain(float(y[-1]))
        return Solution(
            params,
            omega,
            _state_of(params, y),
            outcome.iterations,
            outcome.history,
            outcome.evaluation.linearization,
            s,
        )


class PseudoArclength(_JacobianMemory):
    """Pseudo-arclength continuation in (q, c), c the coordinate of ``axis``: w_b at fixed K
    (``FrequencyAxis``, the default: from the eigenmode until contact is lost or w_b < omega_min) or
    log10 K at fixed w_b (``CouplingAxis``: through folds in K, until K leaves [K_min, K_max] or
    ``until`` says the branch ended).

    Args:
        params: the chain (the first point's, for the coupling axis).
        flow: the integrator.
        start_points: two (state, c, iterations, residual history[, linearization]) tuples that set
            the direction (None: ``start_from_eigenmode``, frequency axis only).
        omega_min: the frequency branch's floor (an end, reached only if contact holds until there).
        theta: the parameter's weight in the norm (default: 1 / gap width for w_b, 1 for log10 K).
        eigenmode_amplitude: amplitude of the first eigenmode point (when start_points is None).
        symmetric: project iterates onto mirror-symmetric profiles (None: when the start is).
        axis: ``FrequencyAxis(params)`` (None) or ``CouplingAxis(params, omega)``.
        K_range: (K_min, K_max) for the coupling axis: the branch ends when it leaves it.
        until: optional (previous point, point) -> reason or None: the branch ends there (an event
            such as joining another family).
    """

    def __init__(
        self,
        params: ChainParams,
        flow: Flow,
        start_points=None,
        *,
        omega_min: float = 0.5,
        theta: float | None = None,
        eigenmode_amplitude: float = 0.03,
        symmetric: bool | None = None,
        axis=None,
        K_range: tuple = (1e-3, 1e3),
        until=None,
    ):
        self.params, self.flow, self.start_points = params, flow, start_points
        self.axis = FrequencyAxis(params) if axis is None else axis
        self.parameter = self.axis.name
        if start_points is None and not isinstance(self.axis, FrequencyAxis):
            raise ValueError("a branch in K needs two start points (e.g. from bifurcation.switch_branch)")
        self.symmetric = symmetric
        self.omega_min, self.eigenmode_amplitude = float(omega_min), eigenmode_amplitude
        self.theta = self.axis.default_theta() if theta is None else float(theta)
        self.W = np.concatenate([np.ones(2 * params.N), [self.theta**2]])
        self.edges = band_edges(params.M, params.K)
        self.K_range = tuple(float(k) for k in K_range)
        self.until = until
        self.description = self.axis.description()

    def _norm(self, d) -> float:
        return math.sqrt(float(np.sum(self.W * d * d)))

    def _y(self, point) -> np.ndarray:
        return _pack(point.state, self.axis.coordinate(point))

    def prepare(self, settings: ContinuationSettings, resume=None, walk=None) -> None:
        self._settings = settings
        if walk and len(walk) >= 2:  # where ``finished`` stood after the last completed step
            self._previous = walk[-2]
        if self.symmetric is None:  # the eigenmode start is symmetric; a resumed branch says itself
            first = resume[-1].state if resume else (self.start_points[-1][0] if self.start_points else None)
            self.symmetric = first is None or is_mirror_symmetric(first, 1e-9)
        self.corrector = ArclengthCorrector(
            self.axis,
            self.flow,
            self.W,
            NewtonSettings(tol=settings.newton_tol, max_iterations=settings.max_newton),
            symmetric=self.symmetric,
        )

    def revisit(self, point: BranchPoint) -> Solution:
        """As ``NaturalParameter.revisit``."""
        return _revisit(self.params.replace(K=point.K), point.omega, point, self.flow)

    def start(self):
        settings = self._settings
        if self.start_points is None:
            try:
                self.start_points = start_from_eigenmode(
                    self.params, self.eigenmode_amplitude, flow=self.flow, theta=self.theta, tol=settings.newton_tol
                )
            except RuntimeError as exc:
                return [Failure(str(exc))]
        out, s = [], 0.0
        for k, (state, c, it, hist, *rest) in enumerate(self.start_points):
            if k:
                s += self._norm(_pack(state, c) - _pack(*self.start_points[k - 1][:2]))
            params, omega = self.axis.chain(float(c))
            lin = rest[0] if rest else self.flow.linearize(params, state, *self.flow.grid(omega))
            out.append(Solution(params, omega, state, it, hist, lin, s))
        return out

    def step(self, points, h: float):
        y1, y0 = self._y(points[-1]), self._y(points[-2])
        d = y1 - y0
        tau = d / self._norm(d)
        return self.corrector.solution(
            self.corrector.correct(y1 + h * tau, tau, self.hint(points[-1])), points[-1].s + h
        )

    def between(self, a: BranchPoint, b: BranchPoint, t: float = 0.5):
        ya, yb = self._y(a), self._y(b)
        d = yb - ya
        tau = d / self._norm(d)
        return self.corrector.solution(
            self.corrector.correct((1.0 - t) * ya + t * yb, tau, self.hint(a)), (1.0 - t) * a.s + t * b.s
        )

    def is_between(self, a, m, b) -> bool:
        ya, ym, yb = (self._y(p) for p in (a, m, b))
        d = yb - ya
        t = float(np.sum(self.W * (ym - ya) * d)) / float(np.sum(self.W * d * d))
        return 0.0 < t < 1.0

    def is_forward(self, points, new) -> bool:
        y1, y0 = self._y(points[-1]), self._y(points[-2])
        return float(np.sum(self.W * (self._y(new) - y1) * (y1 - y0))) > 0

    def clip_step(self, last, h: float) -> float:
        return h

    def finished(self, last: BranchPoint):
        previous, self._previous = getattr(self, "_previous", None), last
        if self.until is not None and previous is not None and previous is not last:
            why = self.until(previous, last)
            if why:
                return True, why
        return self.axis.finished(self, last)

    def progress(self, first: BranchPoint, last: BranchPoint) -> float:
        return self.axis.progress(self, first, last)

    def describe(self, p: BranchPoint) -> str:
        return self.axis.describe(p)


def start_from_eigenmode(
    params: ChainParams,
    amplitude: float = 0.03,
    *,
    flow: Flow | None = None,
    method=None,
    steps_per_period=None,
    theta=None,
    tol: float = 1e-10,
    device=None,
    log=None,
) -> tuple:
    """Two small-amplitude points of the breather branch that bifurcates from the lowest optical
    eigenmode, with max |u - v| = ``amplitude`` and 2 ``amplitude``.

    Fixed-frequency Newton is nearly singular next to the linear mode (the finite chain's optical
    modes are ~1e-4 apart), so these points come from the arclength corrector itself: the
    constraint fixes the projection on the mode, the frequency is an unknown, and its predictor is
    the single-mode Lindstedt estimate dw / w = (1/24) A^2 sum(phi^4) / sum(phi^2) for z = A phi.

    Returns:
        two (state, omega, iterations, residual history, linearization) tuples.
    """
    flow = make_flow(flow, method=method, steps_per_period=steps_per_period, device=device)
    w_lin, shape = lowest_optical_mode(params)
    z = shape[0] - shape[1]
    shape = shape / np.max(np.abs(z))
    phi = z / np.max(np.abs(z))
    ratio = np.sum(phi**4) / np.sum(phi**2)
    axis = FrequencyAxis(params)
    W = np.concatenate([np.ones(2 * params.N), [(axis.default_theta() if theta is None else theta) ** 2]])
    corrector = ArclengthCorrector(
        axis, flow, W, NewtonSettings(tol=tol, max_iterations=30), symmetric=is_mirror_symmetric(shape, 1e-9)
    )
    direction = np.concatenate([shape[:2].ravel(), [0.0]])
    tau = direction / math.sqrt(np.sum(W * direction * direction))
    out = []
    for A in (amplitude, 2.0 * amplitude):
        y_pred = np.concatenate([A * shape[:2].ravel(), [w_lin * (1.0 - A * A * ratio / 24.0)]])
        res = corrector.correct(y_pred, tau)
        if isinstance(res, Failure) or not res.success:
            why = res.message if isinstance(res, Failure) else res.message
            raise RuntimeError(f"could not start the frequency branch from the eigenmode at amplitude {A}: {why}")
        if log:
            log(
                f"start at mode amplitude {A:g}: w = {res.unknowns[-1]:.8f}, converged in {res.iterations} "
                f"iterations (residual {res.history[-1]:.2e})"
            )
        out.append(
            (
                _state_of(params, res.unknowns),
                float(res.unknowns[-1]),
                res.iterations,
                res.history,
                res.evaluation.linearization,
            )
        )
    return tuple(out)


# ----------------------------------------------------------------------------- entry points


def continue_in_coupling(
    params: ChainParams,
    omega: float,
    seed,
    K_end: float,
    *,
    targets=(),
    settings: ContinuationSettings | None = None,
    flow: Flow | None = None,
    method: str | None = None,
    steps_per_period: int | None = None,
    device: str | None = None,
    resume: list | None = None,
    on_point=None,
    on_event=None,
    progress: bool = False,
    log=None,
) -> Branch:
    """Continuation in K at fixed omega from ``params.K`` to ``K_end`` (``NaturalParameter``).

    Default settings: steps of 0.15 in log10 K (at most 0.3), resolution 1e-4 in log10 K.
    """
    settings = settings or ContinuationSettings(ds=0.15, ds_min=1e-4, ds_max=0.3, resolution=1e-4)
    flow = make_flow(flow, method=method, steps_per_period=steps_per_period, device=device)
    problem = NaturalParameter(params, omega, seed, K_end, flow, targets=targets)
    return continuation(
        problem, settings, resume=resume, on_point=on_point, on_event=on_event, log=log, progress=progress
    )


def continue_in_frequency(
    params: ChainParams,
    start_points=None,
    *,
    omega_min: float = 0.5,
    theta: float | None = None,
    settings: ContinuationSettings | None = None,
    flow: Flow | None = None,
    method: str | None = None,
    steps_per_period: int | None = None,
    device: str | None = None,
    resume: list | None = None,
    on_point=None,
    on_event=None,
    progress: bool = False,
    log=None,
) -> Branch:
    """Pseudo-arclength continuation in (q, w_b) at fixed K (``PseudoArclength``), from two points
    (``start_from_eigenmode`` when None) until contact is lost or w_b < omega_min.

    Default settings: arclength steps 0.05 (at most 0.6) in the weighted norm, Newton up to 8
    iterations, resolution 1e-3 in arclength (about 2e-5 in w_b for the paper chain).
    """
    settings = settings or ContinuationSettings(ds=0.05, ds_min=1e-4, ds_max=0.6, grow=1.3, resolution=1e-3)
    flow = make_flow(flow, method=method, steps_per_period=steps_per_period, device=device)
    problem = PseudoArclength(params, flow, start_points, omega_min=omega_min, theta=theta)
    return continuation(
        problem, settings, resume=resume, on_point=on_point, on_event=on_event, log=log, progress=progress
    )
