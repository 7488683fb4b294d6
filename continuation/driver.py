"""One continuation driver with pluggable predictor/corrector.

``continuation(problem, settings, ...)`` walks a branch. The ``problem`` (``continuation.branch``:
``NaturalParameter`` in K, ``PseudoArclength`` in the frequency) knows the unknowns, the predictor
and the corrector; the driver owns the loop, the step control, the events, the stop reasons and
the hook through which a caller records points (``on_point``: continuation itself writes nothing).
What it hands around (``Solution``, ``Failure``, ``BranchPoint``, ``Branch``, ``WalkState``) is defined in
``continuation.results`` and imported here.

**Step control that cannot skip a stability change.**

1. After every accepted point the multipliers' motion over the last step is measured (the mu's of
   each Krein-signature and parity class matched in sorted order). The next step is limited so that
   no mu is predicted to move by more than ``settings.multiplier_fraction`` of its distance to the
   nearest critical place (+1, -1, or the nearest elliptic mu of opposite signature that it can
   interact with), with a floor of ``settings.multiplier_floor`` in mu so that near-collisions do
   not stall the branch.
2. A step across which the verdict (stable/unstable) changes, or across which it may hide a stable window
   between unstable ends, is bisected: the point in the middle of the step is solved and analysed, and
   both halves are examined again, until the bracket is below ``settings.resolution`` (in the
   continuation coordinate). Every trial point is a solved, analysed branch point and is kept. A window
   between unstable ends is possible when their significant unstable multipliers (all but the weak
   extended ones) differ, since one instability may close before another opens, or when the same one
   moved far enough to have closed and opened again; not when one significant instability holds across
   the step. ``events.changed`` states the rules, their order and what each cost on the paper's branches:
   a step examined only between weakly unstable ends stepped over windows 3e-4 and 1.4e-3 wide in w_b
   on a chain checked against AUTO. The stated limit: the rules read the step's two ends, so an
   instability that closes and opens again within one step, back near where it was, can hide a window
   (``events.persistent``; ``benchmarks/branch_check.py`` compares a branch with a dense scan).
3. A step across which elliptic multipliers of opposite Krein signature passed each other (the Krein
   order of ``events`` changed) with no instability at either end is where a bubble could hide. When
   a localized mode (participation below ``floquet.LOCALIZED_FRACTION`` N: an internal mode of the
   breather) took part, the step is bisected like a stability change (``settings.bisect_krein`` =
   ``"localized"`` or ``"predict"``). Passes among extended phonon multipliers cannot all be bisected:
   the finite chain's phonon multipliers crowd near +-1 at the band edges, where they pass each other
   every step (measured on the paper chain: ~10 passes per step of the frequency branch at N = 201),
   and the bubbles they can make shrink with the chain length (finite-size resonances). With
   ``"predict"`` (the default above AUTO_ALL_SITES sites) every step with both ends stable is
   screened by ``continuation.bubbles``, which predicts each bubble's centre, width and strength from
   the reduced matrices at the two ends (no solve); the driver solves at the centre of each predicted
   bubble at least ``settings.bubble_width`` wide and, if the solve is unstable, just outside both
   predicted edges, then bisects the stability changes this exposes as usual. A prediction that the
   solve does not confirm is re-screened on the two shorter steps it made (twice at most). ``"all"``
   bisects every pass (the default up to AUTO_ALL_SITES sites). The stated limit: a bubble narrower
   than ``bubble_width``, or one the first-order model misplaces by more than its width, can go
   unseen; ``benchmarks/branch_check.py`` compares a branch with a dense fixed-step scan. What is
   predicted but too narrow to chase is not dropped: each final step with such bubbles (and a stable
   end, or weakly unstable extended ends) records a ``bubble_foam`` event with their predicted
   unstable fraction, and ``Branch.unresolved_bubbles()`` merges them into the stretches where the
   branch states that fraction instead of a verdict.
4. Branches stop on physics by default (end parameter, contact lost) or on a stated number of
   points; a time budget is opt-in (``settings.max_seconds``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import numpy as np

from warpchain import energy
from warpchain.model import real_number, whole_number

from . import bubbles
from . import events as ev
from .events import StopReason
from .floquet import VERDICTS, FloquetResult, floquet_path, reduced_analysis
from .hostblas import blas_threads, threads_for
from .results import Branch, BranchPoint, Failure, Solution, WalkState
from .shooting import frequency_report

#: the Floquet paths a walk may take: those that give every point a complete verdict
COMPLETE_SOLVERS = ("dense", "sliced", "probed", "auto")


class IncompleteVerdict(RuntimeError):
    """A point's Floquet analysis could not account for every multiplier (the sliced path's count did not close):
    the walk stops rather than record a verdict it does not have."""


#: ``bisect_krein="auto"`` bisects every opposite-signature pass up to this many sites. Measured on
#: the paper's M = 30 chain, w_b = 1.01 / K = 160, 2-core CPU: at N = 41 "all" costs 12 s for the
#: frequency branch to contact loss (517 points, 15 stability changes; "localized": 71 points, 1
#: change) and 33 s for K = 0.01 .. 160 (1524 points, 152 changes; "localized": 464 points, 76); at
#: N = 201 the passes number ~1000-1500 per branch (minutes on an H200), so "predict" is used there.
AUTO_ALL_SITES = 64

KREIN_MODES = ("auto", "localized", "predict", "all", "none")

#: where a step under examination is split: its middle, or, when the middle's solve fails, a quarter from
#: either end
SPLITS = (0.5, 0.25, 0.75)

#: ``bubble_width`` defaults to resolution / BUBBLE_FRACTION. On the paper's frequency branch
#: (resolution 1e-3 in arclength, ~2e-5 in w_b) 46 of the 594 bubbles predicted in its stable steps are
#: that wide (~2e-6 in w_b or more) and are solved for (29 confirmed); each narrower one would be hit by
#: a 1e-4 scan with a chance below 2 %.
BUBBLE_FRACTION = 10.0


@dataclasses.dataclass(frozen=True)
class ContinuationSettings:
    """Everything a branch's walk is controlled by (the problem holds what is solved).

    Attributes:
        ds, ds_min, ds_max: initial, smallest and largest step in the continuation coordinate.
        grow: step growth after an easy Newton solve (<= 3 iterations).
        max_points: stop after this many points (None: no limit).
        newton_tol, max_newton: corrector tolerance and iterations.
        multiplier_fraction, multiplier_floor: the spectral step bound (module docstring).
        resolution: smallest bracket of a located change, in the continuation coordinate.
        bisect_krein: which passes of elliptic multipliers of opposite Krein signature (with no
            instability at either end) are bisected: ``"all"``, ``"localized"`` (those where a
            localized mode took part), ``"predict"`` (``"localized"``, and in every step with both
            ends stable the bubbles that ``continuation.bubbles`` predicts are solved for), ``"none"``,
            or ``"auto"`` (default: ``"all"`` for chains of at most AUTO_ALL_SITES sites, where it is
            affordable, ``"predict"`` above). Passes not bisected are recorded as ``krein_crossing``
            events.
        bubble_width: with ``"predict"``, predicted bubbles at least this wide (in the continuation
            coordinate) are solved for (default: resolution / BUBBLE_FRACTION); narrower ones are
            counted in the branch's ``stats`` (``bubbles_below_width``).
        chord: start each corrector with chord steps on the neighbouring point's Jacobian (from its
            Floquet analysis), forming true Jacobians only when they converge slowly.
        floquet: compute multipliers at every point (False: energies only, no stability).
        floquet_solver: ``"dense"`` (every multiplier from A's 4N tangent columns: the reference), ``"sliced"``
            (every multiplier from the probed sparse Mu by slices, counted: ``continuation.slicing``), ``"probed"``
            (the same Mu by a dense eig per parity block, on the GPU with CuPy, counted) or ``"auto"`` (from
            ``SLICED_MIN_SITES`` sites on: probed on a GPU with CuPy or below ``PROBED_HOST_MAX_SITES`` sites, else
            sliced). Every point's verdict is
            complete: a sliced or probed analysis whose count does not close fails the walk (``IncompleteVerdict``)
            rather than record a guess. The window near +-1
            (``floquet(solver="window")``) gives no verdict and is not offered here. On the sliced and probed
            paths the bubble predictor, which needs Mu's dense eigenvectors, is off (no predicted bubbles).
        max_seconds: opt-in time budget (None: stop only on physics or max_points).
        blas_threads: threads of the host BLAS during the walk: ``"auto"`` (default: one on the CPU
            device, the process's setting on a GPU; ``continuation.hostblas``), a whole number, or None
            (leave the process's setting alone).
    """

    ds: float = 0.05
    ds_min: float = 1e-4
    ds_max: float = 0.5
    grow: float = 1.5
    max_points: int | None = None
    newton_tol: float = 1e-10
    max_newton: int = 8
    multiplier_fraction: float = 0.5
    multiplier_floor: float = 0.05
    resolution: float = 1e-3
    bisect_krein: str = "auto"
    bubble_width: float | None = None
    chord: bool = True
    floquet: bool = True
    floquet_solver: str = "auto"
    max_seconds: float | None = None
    blas_threads: int | str | None = "auto"

    def __post_init__(self):
        for name in (
            "ds",
            "ds_min",
            "ds_max",
            "grow",
            "newton_tol",
            "multiplier_fraction",
            "multiplier_floor",
            "resolution",
        ):
            real_number(name, getattr(self, name), positive=True)
        if self.floquet_solver not in COMPLETE_SOLVERS:
            if self.floquet_solver == "krylov":
                floquet_path("krylov", 1)  # the message that says what it became
            raise ValueError(
                f"floquet_solver must be one of {', '.join(map(repr, COMPLETE_SOLVERS))} (a complete verdict at every "
                f"point); got {self.floquet_solver!r}"
            )
        if self.bisect_krein not in KREIN_MODES:
            raise ValueError(f"bisect_krein must be one of {', '.join(KREIN_MODES)}; got {self.bisect_krein!r}")
        if self.bubble_width is not None:
            real_number("bubble_width", self.bubble_width, positive=True)
        if not self.ds_min <= self.ds <= self.ds_max:
            raise ValueError(f"need ds_min <= ds <= ds_max, got {self.ds_min}, {self.ds}, {self.ds_max}")
        if self.grow < 1:
            raise ValueError(f"grow must be >= 1, got {self.grow}")
        if self.max_points is not None:
            whole_number("max_points", self.max_points, minimum=1)
        whole_number("max_newton", self.max_newton, minimum=1)
        if self.max_seconds is not None:
            real_number("max_seconds", self.max_seconds, nonnegative=True)
        if self.blas_threads is not None and self.blas_threads != "auto":
            whole_number("blas_threads", self.blas_threads, minimum=1)

    def replace(self, **changes) -> "ContinuationSettings":
        return dataclasses.replace(self, **changes)


def analyse(solution: Solution, with_floquet: bool = True, spectra: dict | None = None, settings=None) -> BranchPoint:
    """Energy, multipliers (reduced Floquet on the solution's own linearization: dense, sliced or probed as
    ``settings.floquet_solver`` says: ``floquet.reduced_analysis``), harmonics.

    ``spectra``: where to keep the point's reduced matrix and eigenvectors (``floquet.SpectralData``, dense path
    only), keyed by id(point), for predicting bubbles in the steps next to it."""
    params, lin = solution.params, solution.linearization
    settings = settings or ContinuationSettings()
    if with_floquet:
        fl: FloquetResult = reduced_analysis(
            lin, params.M, solution.state, solver=settings.floquet_solver, params=params
        )
        if not fl.complete:
            counts = "; ".join(
                f"parity {c['parity']}: inertia {c['inertia']}, found {c['found']}" for c in fl.coverage["counts"]
            )
            raise IncompleteVerdict(
                f"the Floquet count did not close at K = {params.K!r}, omega = {solution.omega!r} (N = {params.N}): "
                f"{counts}. No verdict is recorded for a point whose multipliers are not all accounted for: walk with "
                "floquet_solver='dense'"
            )
        fields = dict(
            multipliers=fl.multipliers,
            mu=fl.mu,
            signature=fl.signature,
            parity=fl.parity,
            participation=fl.participation,
            central_weight=fl.central_weight,
            max_modulus=fl.max_modulus,
            tolerance=fl.tolerance,
            stable=fl.stable,
            instabilities=fl.instabilities,
            complete=fl.complete,
        )
    else:
        n = 2 * params.N
        fields = dict(
            multipliers=np.full(2 * n, np.nan + 0j),
            mu=None,
            signature=None,
            parity=None,
            participation=None,
            central_weight=None,
            max_modulus=float("nan"),
            tolerance=float("nan"),
            stable=None,
            instabilities=(),
            complete=False,
        )
    point = BranchPoint(
        parameters={"K": float(params.K), "omega": float(solution.omega)},
        state=np.array(solution.state),
        energy=float(energy(params, solution.state)[0]),
        iterations=int(solution.iterations),
        residual_history=tuple(solution.residual_history),
        min_contact=float(lin.min_contact),
        harmonics_in_bands=tuple(frequency_report(params, solution.omega)["harmonics_in_bands"]),
        s=float(solution.s),
        **fields,
    )
    if with_floquet and spectra is not None and fl.spectral is not None:
        spectra[id(point)] = (point, fl.spectral)
    return point


# ----------------------------------------------------------------------------- spectral step bound


def _classes(point):
    """Elliptic nontrivial mu grouped by (signature, parity), each sorted."""
    t = ev.elliptic_table(point)
    keys = {(int(s), int(p)) for s, p in zip(t["sig"], t["parity"])}
    return {key: np.sort(t["mu"][(t["sig"] == key[0]) & (t["parity"] == key[1])]) for key in keys}


def spectral_step_factor(prev: BranchPoint, point: BranchPoint, fraction: float, floor: float) -> float:
    """How much longer (or shorter) than the last step the next one may be so that no elliptic mu
    moves by more than ``fraction`` of its distance to +-1 or to the nearest interacting mu of
    opposite signature (at least ``floor``); inf when the motion cannot be measured."""
    if prev.mu is None or point.mu is None:
        return math.inf
    a, b = _classes(prev), _classes(point)
    factor = math.inf
    for key, mu_b in b.items():
        mu_a = a.get(key)
        if mu_a is None or len(mu_a) != len(mu_b):
            continue
        moved = np.abs(mu_b - mu_a)
        dist = np.minimum(1.0 - mu_b, mu_b + 1.0)
        for other, mu_o in b.items():  # opposite signature, same or unknown parity
            if other[0] != key[0] and (other[1] == key[1] or 0 in (other[1], key[1])) and len(mu_o):
                idx = np.clip(np.searchsorted(mu_o, mu_b), 1, len(mu_o)) - 1
                near = np.minimum(np.abs(mu_o[idx] - mu_b), np.abs(mu_o[np.minimum(idx + 1, len(mu_o) - 1)] - mu_b))
                dist = np.minimum(dist, near)
        allowed = np.maximum(fraction * dist, floor)
        with np.errstate(divide="ignore"):
            ratio = np.where(moved > 0, allowed / moved, np.inf)
        factor = min(factor, float(np.min(ratio)) if ratio.size else math.inf)
    return factor


# ----------------------------------------------------------------------------- the driver


def continuation(
    problem,
    settings: ContinuationSettings = ContinuationSettings(),
    *,
    resume: list | None = None,
    resume_state: WalkState | None = None,
    on_point: Callable[[BranchPoint], None] | None = None,
    on_event: Callable[[dict], None] | None = None,
    on_step: Callable[[WalkState], None] | None = None,
    log: Callable[[str], None] | None = None,
    progress: bool = False,
) -> Branch:
    """Walk a branch of ``problem`` (``NaturalParameter`` or ``PseudoArclength``).

    Args:
        problem: predictor/corrector and the branch's end (``continuation.branch``).
        settings: ContinuationSettings.
        resume: points of a stored branch to continue from. With ``resume_state`` (what ``on_step``
            last reported for them) the walk continues exactly as it would have without the stop: the
            same points, events and counters (unless ``max_seconds`` stopped it); points after
            ``resume_state.points`` (a step cut off) are computed again. Without it, the last two
            points set the predictor and the step starts at ``settings.ds``.
        resume_state: the stored ``WalkState`` of ``resume``.
        on_point: called with every accepted point, in order (e.g. a store's ``append``).
        on_event: called with every event as it is found.
        on_step: called with the ``WalkState`` after the start and after every completed step (after
            that step's points went to ``on_point``), e.g. a store's record of how to resume.
        log: one line per point and per event.
        progress: a tqdm bar over the problem's progress measure.

    Returns:
        Branch (its ``stop_reason`` says why it stopped; see StopReason.explanation).
    """
    threads = settings.blas_threads
    if threads == "auto":
        threads = threads_for(getattr(getattr(problem, "flow", None), "device", "cpu"))
    with blas_threads(threads):
        return _Walk(problem, settings, on_point, on_event, on_step, log).run(resume, resume_state, progress)


class _Walk:
    """``continuation``'s body (under its BLAS thread limit): one walk along a branch, its state named.

    State: ``points`` (every accepted point, in order); ``walk`` (the points the driver stepped to, not the
    ones bisection and bubble solves put between them: their secant sets the next predictor, so refinement
    never steers the branch) and ``walk_index`` (where they are in ``points``, what ``on_step`` reports);
    ``events``; ``stats`` (counters); ``spectra`` (id(point) -> (point, SpectralData) of the points analysed
    since the last step finished: its refinement needs them all; cleared down to the last point after each
    step); ``predictions`` ((id(a), id(b)) -> predicted bubbles, for a step's chase and its record); ``h``
    (the next step).
    """

    def __init__(self, problem, settings, on_point, on_event, on_step, log):
        self.problem, self.settings = problem, settings
        self.on_point, self.on_event, self.on_step, self.log = on_point, on_event, on_step, log
        self.start = time.perf_counter()
        self.stats = {"solves": 0, "failed_solves": 0, "bisection_solves": 0, "rejected_backwards": 0}
        self.stats.update(
            bubbles_predicted=0, bubbles_below_width=0, bubble_solves=0, bubbles_confirmed=0, foam_steps=0
        )
        self.events: list = []
        self.par = problem.parameter
        self.points: list = []
        self.walk: list = []
        self.walk_index: list = []
        self.spectra: dict = {}
        self.predictions: dict = {}
        self.h = settings.ds
        self.bubble_width = None

    # -- bookkeeping

    def note(self, event):
        if event is None:
            return
        self.events.append(event)
        if self.on_event:
            self.on_event(event)
        if self.log and event.get("message"):
            self.log(event["message"])

    def accept(self, point, on_walk=True):
        self.points.append(point)
        if on_walk:
            self.walk.append(point)
            self.walk_index.append(len(self.points) - 1)
        if self.on_point:
            self.on_point(point)

    def stepped(self):
        """Report the walk's state after the start or a whole step (``on_step``)."""
        if self.on_step is not None:
            problem, points = self.problem, self.points
            chord = problem.age(points[-1]) if hasattr(problem, "age") else None
            state = WalkState(len(points), tuple(self.walk_index), self.h, tuple(self.events), dict(self.stats), chord)
            self.on_step(state)

    def branch(self, reason, text) -> Branch:
        return Branch(tuple(self.points), reason, text, tuple(self.events), self.par, self.stats)

    # -- solves

    @staticmethod
    def chord_jacobian(solution):
        """The residual Jacobian the next corrector's chord steps start from (Floquet formed it anyway)."""
        return solution.linearization.unit_columns("positions")[2 * solution.params.N :, :]

    def analysed(self, solution):
        point = analyse(solution, self.settings.floquet, self.spectra, self.settings)
        if self.settings.floquet and self.settings.chord and hasattr(self.problem, "remember"):
            self.problem.remember(point, self.chord_jacobian(solution))
        return point

    def solve(self, fn, *args):
        self.stats["solves"] += 1
        out = fn(*args)
        if isinstance(out, Failure):
            self.stats["failed_solves"] += 1
            return out
        return self.analysed(out)

    # -- the start

    def begin(self, resume, resume_state) -> Branch | None:
        """Restore a stored walk or solve the problem's start; a Branch when the start already failed."""
        problem, settings, stats = self.problem, self.settings, self.stats
        restored = None  # the walk's points of a resumed branch with its state
        if resume_state is not None:
            self.h = resume_state.h
        if resume and resume_state is not None:
            resume_state.check(len(resume))
            resume = list(resume[: resume_state.points])
            restored = [resume[i] for i in resume_state.walk]
            self.events.extend(resume_state.events)
            stats.update(resume_state.stats)  # the counters go on from where the stored walk left them
        problem.prepare(settings, resume, restored)
        if settings.bisect_krein == "auto":
            self.settings = settings = settings.replace(
                bisect_krein="all" if problem.params.N <= AUTO_ALL_SITES else "predict"
            )
        self.bubble_width = settings.bubble_width or settings.resolution / BUBBLE_FRACTION
        if resume:
            if len(resume) < 2 and hasattr(problem, "axis"):
                raise ValueError("resuming an arclength branch needs at least two stored points (they set the tangent)")
            self.points.extend(resume)
            self.walk.extend(resume if restored is None else restored)
            self.walk_index.extend(range(len(resume)) if restored is None else resume_state.walk)
            if restored is not None:  # the last point's spectra and chord Jacobian, as its first analysis left them
                last = self.points[-1]
                again = problem.revisit(last)
                fresh = analyse(again, settings.floquet, self.spectra, settings)
                if settings.floquet:
                    if id(fresh) in self.spectra:  # the dense path's (the window keeps none)
                        self.spectra[id(last)] = (last, self.spectra.pop(id(fresh))[1])
                    if settings.chord and hasattr(problem, "restore") and resume_state.chord is not None:
                        problem.restore(last, self.chord_jacobian(again), resume_state.chord)
            return None
        for sol in problem.start():
            if isinstance(sol, Failure):
                wall = time.perf_counter() - self.start
                stats.update(points=0, wall_seconds=wall, seconds_per_point=0.0)  # the same keys as a walked branch
                return Branch(
                    (),
                    StopReason.NEWTON_FAILED,
                    f"{StopReason.NEWTON_FAILED.explanation}: {sol.message}",
                    tuple(self.events),
                    self.par,
                    dict(stats),
                )
            stats["solves"] += 1
            self.accept(self.analysed(sol))
        return None

    # -- refinement of a step

    def predicted_in(self, a, b):
        """The bubbles ``continuation.bubbles`` predicts in the step (a, b); None without spectra."""
        key = (id(a), id(b))
        if key not in self.predictions:
            sa, sb = self.spectra.get(id(a)), self.spectra.get(id(b))
            if sa is None or sb is None or sa[0] is not a or sb[0] is not b:
                return None
            self.predictions[key] = bubbles.predict(a, b, sa[1], sb[1])
        return self.predictions[key]

    def leaf(self, a, b, h):
        """A final step (a, b) of length h: record the predicted bubbles in it too narrow to chase, and
        where the phonon-phonon parametric resonances that make them possible open or close."""
        self.note(ev.parametric_event(a, b, self.par, self.problem.params.M))
        # a step that is unstable at both ends through anything but weak extended vectors has a verdict
        # that narrow bubbles cannot change: no screening there (it was ~10 ms per step in the acoustic band)
        if self.settings.bisect_krein == "predict" and (
            a.stable or b.stable or (ev.weak_extended(a) and ev.weak_extended(b))
        ):
            narrow = [x for x in self.predicted_in(a, b) or () if 2.0 * x.half_width * h < self.bubble_width]
            if narrow:
                self.stats["foam_steps"] += 1
                self.note(ev.foam_event(a, b, self.par, narrow, h))
        return [b]

    def chase_bubbles(self, a, b, h, depth, misses):
        """Solve inside a step with both ends stable where ``bubbles`` predicts an instability
        bubble at least ``bubble_width`` wide; None when nothing is predicted there."""
        problem, stats = self.problem, self.stats
        predicted = self.predicted_in(a, b)
        if predicted is None:
            return None
        stats["bubbles_predicted"] += len(predicted)
        plan = bubbles.chase_fractions(predicted, h, self.bubble_width)
        stats["bubbles_below_width"] += len(predicted) - len(bubbles.wide(predicted, h, self.bubble_width))
        if not plan:
            return None
        inner = []  # (fraction, point)
        confirmed = 0
        for centre, (lo, hi) in plan:
            stats["bubble_solves"] += 1
            m = self.solve(problem.between, a, b, centre)
            if isinstance(m, Failure) or not problem.is_between(a, m, b):
                continue
            inner.append((centre, m))
            unstable = not m.stable
            confirmed += unstable
            self.note(ev.bubble_event(a, b, centre, m, self.par, predicted=[x for x in predicted if lo <= x.t <= hi]))
            if unstable:  # its edges: one solve just outside each predicted edge, then bisection
                for t in (lo, hi):
                    if any(abs(t - f) < 1e-9 for f, _ in inner):  # a neighbour's edge at the same place
                        continue
                    stats["bubble_solves"] += 1
                    e = self.solve(problem.between, a, b, t)
                    if not isinstance(e, Failure) and problem.is_between(a, e, b):
                        inner.append((t, e))
        stats["bubbles_confirmed"] += confirmed
        if not inner:
            return None
        inner.sort(key=lambda x: x[0])
        chain = [(0.0, a)] + inner + [(1.0, b)]
        out = []
        for (t0, x), (t1, y) in zip(chain[:-1], chain[1:]):
            out += self.refine(x, y, h * (t1 - t0), depth + 1, misses + (confirmed == 0))
        return out

    def refine(self, a, b, h, depth=0, misses=0):
        """Points strictly after a up to b, bisecting while a change sits in a bracket > resolution."""
        settings, par, note = self.settings, self.par, self.note
        what = ev.changed(a, b) if settings.floquet else None
        if (
            settings.bisect_krein == "predict"
            and what in (None, "krein")
            and a.stable
            and b.stable
            and misses < 2
            and depth <= 40
        ):
            chased = self.chase_bubbles(a, b, h, depth, misses)
            if chased is not None:
                return chased
        if what is None:
            return self.leaf(a, b, h)
        if what == "count":  # recorded, not examined (events.changed, rules 2 and 5)
            note(ev.stability_change_event(a, b, par))
            return self.leaf(a, b, h)
        if what == "krein" and not (
            settings.bisect_krein == "all"
            or (settings.bisect_krein in ("localized", "predict") and ev.localized_krein_crossings(a, b))
        ):
            note(ev.krein_event(a, b, par, bisected=False))
            return self.leaf(a, b, h)
        if h <= settings.resolution or depth > 40:
            if what != "suspect":  # a suspect step resolved down to here without a change holds none
                note(ev.krein_event(a, b, par) if what == "krein" else ev.stability_change_event(a, b, par))
            return self.leaf(a, b, h)
        outcomes = []
        for t in SPLITS:  # the middle, else nearer either end (a long step's middle may not converge)
            self.stats["bisection_solves"] += 1
            m = self.solve(self.problem.between, a, b, t)
            if not isinstance(m, Failure) and self.problem.is_between(a, m, b):
                return self.refine(a, m, t * h, depth + 1, misses) + self.refine(m, b, (1.0 - t) * h, depth + 1, misses)
            outcomes.append(f"at {t:g}: " + ("did not converge" if isinstance(m, Failure) else "outside the bracket"))
        if what != "suspect":
            e = ev.krein_event(a, b, par) if what == "krein" else ev.stability_change_event(a, b, par)
            e["message"] += " (not bisected further: the points " + "; ".join(outcomes) + ")"
            note(e)
        return self.leaf(a, b, h)

    # -- the walk

    def stop(self, last):
        """(reason, message) when the walk ends at ``last``, else None."""
        problem, settings, par = self.problem, self.settings, self.par
        points = self.points
        if last.min_contact <= 0:
            message = ""
            if len(points) > 1:
                # the bracket's other end: the last point with contact (a bisected last step can leave points
                # past the loss before ``last``, and interpolating between two of those lands outside)
                held = [p for p in points[:-1] if p.min_contact > 0]
                e = ev.contact_event(held[-1] if held else points[-2], last, par)
                self.note(e)
                message = e["message"]
            return StopReason.CONTACT_LOST, message
        done, why = problem.finished(last)
        if done:
            return StopReason.END_REACHED, why
        if settings.max_points is not None and len(points) >= settings.max_points:
            return StopReason.MAX_POINTS, f"{len(points)} points, at {par} = {last.value(par):.8g}"
        if settings.max_seconds is not None and time.perf_counter() - self.start > settings.max_seconds:
            return StopReason.TIME_BUDGET, f"after {settings.max_seconds:g} s at {par} = {last.value(par):.8g}"
        return None

    def step(self, last):
        """One step from ``last``: the predictor-corrector, then its refinement, its points accepted. Returns
        (reason, message) when a failed step ends the walk (the step underflowed), else None."""
        problem, settings, par = self.problem, self.settings, self.par
        points, stats = self.points, self.stats
        h_try = problem.clip_step(last, self.h)
        new = self.solve(problem.step, self.walk, h_try)
        if isinstance(new, Failure) or not problem.is_forward(self.walk, new):
            if not isinstance(new, Failure):
                stats["rejected_backwards"] += 1
            self.h *= 0.5
            why = new.message if isinstance(new, Failure) else "the corrector turned back along the branch"
            if self.log:
                self.log(f"step failed ({why}); step halved to {self.h:.3g}")
            if self.h < settings.ds_min:
                return StopReason.STEP_UNDERFLOW, f"{why} near {par} = {last.value(par):.8g}"
            return None
        whole = True  # every point of the step accepted (a stated point count may cut it)
        for p in self.refine(last, new, h_try):
            if settings.max_points is not None and len(points) >= settings.max_points:
                whole = False
                break  # a stated point count is exact, even inside a bisected step
            self.note(ev.harmonic_event(points[-1], p, par))
            self.accept(p, on_walk=p is new)
        kept = self.spectra.get(id(points[-1]))
        self.spectra.clear()
        self.predictions.clear()
        if kept is not None:
            self.spectra[id(points[-1])] = kept
        # next step: grow after an easy solve, bounded by the multipliers' motion and ds_max
        h_next = h_try * (settings.grow if new.iterations <= 3 else 1.0)
        if settings.floquet:
            h_next = min(
                h_next,
                h_try * spectral_step_factor(last, new, settings.multiplier_fraction, settings.multiplier_floor),
            )
        self.h = float(min(max(h_next, settings.ds_min), settings.ds_max))
        if whole:  # a cut step is not a state to resume from: a resume redoes it whole
            self.stepped()
        return None

    def run(self, resume, resume_state, progress: bool) -> Branch:
        failed = self.begin(resume, resume_state)
        if failed is not None:
            return failed
        problem, par = self.problem, self.par
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(
                total=1.0,
                desc=problem.description,
                leave=False,
                dynamic_ncols=True,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}] {postfix}",
            )
        if resume_state is None:
            self.stepped()
        reason, message = StopReason.END_REACHED, ""
        try:
            while True:
                last = self.points[-1]
                if self.log:
                    self.log(
                        problem.describe(last) + f", {VERDICTS[last.stable]}, "
                        f"newton {last.iterations}, step {self.h:.3g}"
                    )
                if bar is not None:
                    bar.n = min(max(problem.progress(self.points[0], last), 0.0), 1.0)
                    bar.set_postfix_str(f"{par} = {last.value(par):.6g}, {len(self.points)} points", refresh=True)
                ended = self.stop(last) or self.step(last)
                if ended is not None:
                    reason, message = ended
                    break
        except KeyboardInterrupt:
            if bar is not None:
                bar.close()
            raise
        if bar is not None:
            bar.close()
        wall = time.perf_counter() - self.start
        self.stats.update(points=len(self.points), wall_seconds=wall, seconds_per_point=wall / max(len(self.points), 1))
        return self.branch(reason, reason.explanation + (f": {message}" if message else ""))
