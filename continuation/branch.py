"""Branches of breathers: the two continuation problems the driver walks, and short entry points.

* ``NaturalParameter`` (continuation in the coupling K at fixed w_b): the coordinate is log10 K (or
  K); secant predictor on the states; corrector: fixed-K Newton shooting (reversible formulation);
  lands exactly on requested ``targets``.
* ``PseudoArclength`` (continuation in the frequency at fixed K): unknowns y = (q, w_b), secant
  tangent tau, corrector Newton on [R(q, w); <tau, y - y_pred>_W = 0] with the weighted inner product
  <a, b>_W = a_q . b_q + theta^2 a_w b_w, theta = 1 / (gap width), so that crossing the gap counts
  like a unit change of the profile. The half period keeps a fixed number of steps (dt follows w).
  dR/dw is read from the same trajectory: R is the velocity at T/2 = n dt, so
  dR/dw = -(pi / w^2) a(q(T/2)) up to the integrator's error in the modified flow (O(dt^8) for kahan8),
  which leaves Newton's convergence unchanged at the tolerances used; no extra trajectory is run.

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

from .driver import Branch, BranchPoint, ContinuationSettings, Failure, Solution, continuation
from .newton import NewtonSettings, newton
from .shooting import PeriodMap, chord_solver, find_breather, is_mirror_symmetric, make_flow, mirror_projector

__all__ = [
    "Branch",
    "BranchPoint",
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


class NaturalParameter(_JacobianMemory):
    """Continuation in K at fixed omega from ``params.K`` to ``K_end`` (natural parameter).

    Args:
        params: the chain at the first K.
        omega: the breather frequency.
        seed: a (4, N) state near the solution at params.K (e.g. the anti-continuum seed).
        K_end: the end of the branch.
        flow: the integrator.
        targets: K values the branch must land on exactly.
        log_spacing: the coordinate (and the steps) is log10 K, else K.
    """

    parameter = "K"

    def __init__(
        self, params: ChainParams, omega: float, seed, K_end: float, flow: Flow, *, targets=(), log_spacing: bool = True
    ):
        if not (isinstance(K_end, (int, float, np.integer, np.floating)) and math.isfinite(K_end) and K_end > 0):
            raise ValueError(f"K_end must be a finite number > 0, got {K_end!r}")
        self.params, self.omega, self.seed, self.K_end, self.flow = params, float(omega), seed, float(K_end), flow
        self.log_spacing = log_spacing
        self.direction = 1.0 if K_end >= params.K else -1.0
        self.targets = sorted(
            {float(t) for t in targets if (t - params.K) * self.direction > 0 and (K_end - t) * self.direction > 0}
            | {float(K_end)},
            reverse=self.direction < 0,
        )
        self.description = f"K-continuation, w_b = {omega:g}"

    def coord(self, K: float) -> float:
        return math.log10(K) if self.log_spacing else K

    def inverse(self, s: float) -> float:
        return 10.0**s if self.log_spacing else s

    def _solve(self, K: float, guess, s: float, max_newton: int, tol: float, hint=None):
        pr = self.params.replace(K=K)
        res = find_breather(
            pr, self.omega, guess, flow=self.flow, tol=tol, max_iterations=max_newton, jacobian_hint=hint
        )
        if not res.success:
            return Failure(res.message)
        return Solution(pr, self.omega, res.state, res.iterations, res.residual_history, res.linearization(), s)

    def prepare(self, settings: ContinuationSettings, resume=None) -> None:
        self._settings = settings

    def start(self):
        settings = self._settings
        return [
            self._solve(
                self.params.K, self.seed, self.coord(self.params.K), 3 * settings.max_newton, settings.newton_tol
            )
        ]

    def _next_target(self, K: float) -> float:
        return next(t for t in self.targets if (t - K) * self.direction > 1e-12 * max(1.0, abs(t)))

    def clip_step(self, last: BranchPoint, h: float) -> float:
        return min(h, abs(self.coord(self._next_target(last.K)) - self.coord(last.K)))

    def step(self, points, h: float):
        last = points[-1]
        s_last = self.coord(last.K)
        s_new = s_last + self.direction * h
        target = self._next_target(last.K)
        K_new = target if abs(s_new - self.coord(target)) <= 1e-12 * max(1.0, abs(s_new)) else self.inverse(s_new)
        if len(points) >= 2 and points[-2].K != last.K:
            s_prev = self.coord(points[-2].K)
            guess = last.state + (last.state - points[-2].state) * (s_new - s_last) / (s_last - s_prev)
        else:
            guess = last.state
        return self._solve(K_new, guess, s_new, self._settings.max_newton, self._settings.newton_tol, self.hint(last))

    def between(self, a: BranchPoint, b: BranchPoint):
        s = 0.5 * (self.coord(a.K) + self.coord(b.K))
        return self._solve(
            self.inverse(s),
            0.5 * (a.state + b.state),
            s,
            self._settings.max_newton,
            self._settings.newton_tol,
            self.hint(a),
        )

    def is_between(self, a, m, b) -> bool:
        return (m.K - a.K) * (b.K - m.K) > 0

    def is_forward(self, points, new) -> bool:
        return (new.K - points[-1].K) * self.direction > 0

    def finished(self, last: BranchPoint):
        if abs(last.K - self.K_end) <= 1e-12 * max(1.0, abs(self.K_end)):
            return True, f"K = {last.K:.8g}"
        return False, ""

    def progress(self, first: BranchPoint, last: BranchPoint) -> float:
        total = self.coord(self.K_end) - self.coord(first.K)
        return (self.coord(last.K) - self.coord(first.K)) / total if total else 1.0

    def describe(self, p: BranchPoint) -> str:
        return f"K = {p.K:.8g}: E = {p.energy:.8f}, max|l| = {p.max_modulus:.8f}"


# ----------------------------------------------------------------------------- continuation in frequency


def _weights(params: ChainParams, theta):
    edges = band_edges(params.M, params.K)
    theta = (1.0 / edges["gap_width"]) if theta is None else theta
    return np.concatenate([np.ones(2 * params.N), [theta**2]])


def _pack(state, omega) -> np.ndarray:
    return np.concatenate([np.asarray(state)[:2].ravel(), [omega]])


def _state_of(params: ChainParams, y) -> np.ndarray:
    state = np.zeros((4, params.N))
    state[:2] = y[:-1].reshape(2, params.N)
    return state


class _BorderedPoint:
    """One Newton point of the arclength corrector (one trajectory; Jacobian on request)."""

    def __init__(self, corrector, y, y_pred, tau):
        self.c, self.y = corrector, y
        params = corrector.params
        self.omega = float(y[-1])
        if not (math.isfinite(self.omega) and self.omega > 0):
            raise _BadFrequency(self.omega)
        self.point = PeriodMap(params, self.omega, corrector.flow).evaluate(y[:-1])
        self.linearization = self.point.linearization
        self.row = corrector.W * tau
        self.residual = np.append(self.point.residual, np.sum(self.row * (y - y_pred)))

    def domega(self) -> np.ndarray:
        """dR/dw from this trajectory: -(pi / w^2) a(q(T/2)) (module docstring)."""
        x_end = self.linearization.x_end
        return -(math.pi / self.omega**2) * accelerations(self.c.params, x_end[None])[0].ravel()

    def jacobian(self) -> np.ndarray:
        n2 = 2 * self.c.params.N
        J = np.zeros((n2 + 1, n2 + 1))
        J[:n2, :n2] = self.point.jacobian()
        J[:n2, -1] = self.domega()
        J[-1] = self.row
        return J


def _bordered_chord(J0, row):
    """Chord solver for [[J0, b], [row]] with J0 (the neighbour's 2N x 2N block) factored once and
    b = dR/dw taken from each trajectory, by block elimination; None when J0 is singular."""
    solve0 = chord_solver(J0)
    if solve0 is None:
        return None
    c, d = row[:-1], row[-1]

    def solve(ev, r):
        y = solve0(ev, r[:-1])
        z = solve0(ev, ev.domega())
        denom = d - float(c @ z)
        x2 = (r[-1] - float(c @ y)) / denom if denom != 0.0 else 0.0
        return np.append(y - z * x2, x2)

    return solve


class _BadFrequency(ValueError):
    pass


class _ArclengthCorrector:
    def __init__(self, params: ChainParams, flow: Flow, W, settings: NewtonSettings, symmetric: bool = False):
        self.params, self.flow, self.W, self.settings = params, flow, W, settings
        self.project = mirror_projector(params.N) if symmetric else None

    def correct(self, y_pred, tau, hint=None):
        row = self.W * tau
        try:
            return newton(
                y_pred,
                lambda y: _BorderedPoint(self, y, y_pred, tau),
                self.settings,
                project=self.project,
                chord=None if hint is None else _bordered_chord(hint, row),
            )
        except _BadFrequency as exc:
            return Failure(f"the corrector left the positive frequencies (w = {exc.args[0]:.3g})")


class PseudoArclength(_JacobianMemory):
    """Pseudo-arclength continuation in (q, w_b) at fixed K, until contact is lost or w_b < omega_min.

    Args:
        params: the chain.
        flow: the integrator.
        start_points: two (state, omega, iterations, residual history) tuples that set the direction
            (None: ``start_from_eigenmode``).
        omega_min: the branch's floor in frequency (an end, reached only if contact holds until there).
        theta: the frequency's weight (default 1 / gap width).
        eigenmode_amplitude: amplitude of the first eigenmode point (when start_points is None).
    """

    parameter = "omega"

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
    ):
        self.params, self.flow, self.start_points = params, flow, start_points
        self.symmetric = symmetric
        self.omega_min, self.theta, self.eigenmode_amplitude = float(omega_min), theta, eigenmode_amplitude
        self.W = _weights(params, theta)
        self.edges = band_edges(params.M, params.K)
        self.description = f"frequency continuation, K = {params.K:g}"

    def _norm(self, d) -> float:
        return math.sqrt(float(np.sum(self.W * d * d)))

    def prepare(self, settings: ContinuationSettings, resume=None) -> None:
        self._settings = settings
        if self.symmetric is None:  # the eigenmode start is symmetric; a resumed branch says itself
            first = resume[-1].state if resume else (self.start_points[-1][0] if self.start_points else None)
            self.symmetric = first is None or is_mirror_symmetric(first, 1e-9)
        self.corrector = _ArclengthCorrector(
            self.params,
            self.flow,
            self.W,
            NewtonSettings(tol=settings.newton_tol, max_iterations=settings.max_newton),
            symmetric=self.symmetric,
        )

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
        for k, (state, omega, it, hist, *rest) in enumerate(self.start_points):
            if k:
                s += self._norm(_pack(state, omega) - _pack(*self.start_points[k - 1][:2]))
            lin = rest[0] if rest else self.flow.linearize(self.params, state, *self.flow.grid(omega))
            out.append(Solution(self.params, omega, state, it, hist, lin, s))
        return out

    def _solution(self, outcome, s) -> Solution | Failure:
        if isinstance(outcome, Failure):
            return outcome
        if not outcome.success:
            return Failure(f"{outcome.status.value}: {outcome.message}")
        y = outcome.unknowns
        return Solution(
            self.params,
            float(y[-1]),
            _state_of(self.params, y),
            outcome.iterations,
            outcome.history,
            outcome.evaluation.linearization,
            s,
        )

    def step(self, points, h: float):
        y1, y0 = _pack(points[-1].state, points[-1].omega), _pack(points[-2].state, points[-2].omega)
        d = y1 - y0
        tau = d / self._norm(d)
        return self._solution(self.corrector.correct(y1 + h * tau, tau, self.hint(points[-1])), points[-1].s + h)

    def between(self, a: BranchPoint, b: BranchPoint):
        ya, yb = _pack(a.state, a.omega), _pack(b.state, b.omega)
        d = yb - ya
        tau = d / self._norm(d)
        return self._solution(self.corrector.correct(0.5 * (ya + yb), tau, self.hint(a)), 0.5 * (a.s + b.s))

    def is_between(self, a, m, b) -> bool:
        ya, ym, yb = (_pack(p.state, p.omega) for p in (a, m, b))
        d = yb - ya
        t = float(np.sum(self.W * (ym - ya) * d)) / float(np.sum(self.W * d * d))
        return 0.0 < t < 1.0

    def is_forward(self, points, new) -> bool:
        y1, y0 = _pack(points[-1].state, points[-1].omega), _pack(points[-2].state, points[-2].omega)
        return float(np.sum(self.W * (_pack(new.state, new.omega) - y1) * (y1 - y0))) > 0

    def clip_step(self, last, h: float) -> float:
        return h

    def finished(self, last: BranchPoint):
        if last.omega < self.omega_min:
            return True, f"w_b = {last.omega:.8g} < omega_min = {self.omega_min:g}"
        if last.omega > self.edges["optical_bottom"] + 0.5 * self.edges["gap_width"]:
            return True, f"w_b = {last.omega:.8g} went up into the optical band"
        return False, ""

    def progress(self, first: BranchPoint, last: BranchPoint) -> float:
        # contact loss is the expected end, so progress is the fall of min contact towards 0 (or of
        # w_b towards omega_min, whichever is further along)
        c0 = first.min_contact
        by_contact = (c0 - last.min_contact) / c0 if c0 > 0 else 0.0
        by_omega = (first.omega - last.omega) / max(first.omega - self.omega_min, 1e-12)
        return max(by_contact, by_omega)

    def describe(self, p: BranchPoint) -> str:
        return f"w = {p.omega:.8f}: E = {p.energy:.8f}, max|l| = {p.max_modulus:.8f}, min contact {p.min_contact:.4f}"


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
    W = _weights(params, theta)
    corrector = _ArclengthCorrector(
        params, flow, W, NewtonSettings(tol=tol, max_iterations=30), symmetric=is_mirror_symmetric(shape, 1e-9)
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
    log_spacing: bool = True,
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
    problem = NaturalParameter(params, omega, seed, K_end, flow, targets=targets, log_spacing=log_spacing)
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
