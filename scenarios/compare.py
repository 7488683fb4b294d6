"""``python -m scenarios compare A B``: do two result folders hold the same science?

Only the scenes' ``summary.json`` files are read, so a folder may hold summaries alone (the kept CPU reference,
``benchmarks/results/cpu-2core-2026-11-25b.json``, unpacks into one: ``benchmarks/results/compact.py compare``).
A scene is a subfolder with ``summary.json`` or named like a known
scene (a scene that raised leaves its folder with ``failed.json`` and no summary); one missing from a folder,
without ``summary.json`` (it failed), unreadable, or marked failed (``"failed": true`` or ``"status":
"failed"``) is a difference, also when so in both. ``--scenes a,b``
compares those only. Calibration below: "22g" is ``benchmarks/results/cpu-2core-2026-11-22g.json`` against
``benchmarks/results/h200-2026-11-22g.json`` (the same scenes on a CPU and on an H200).

Ignored at any depth: provenance and timing (``IGNORED``: command line, device, CPU, versions, dates, paths,
worker / job / thread / GPU counts; ``IGNORED_RE``: ``*seconds*``, ``*_per_second``, ``*_rate``,
``*_over_kernel``, ``fraction_of_best``); solver effort (``EFFORT``: Newton iterations, residual histories,
solve and secant-evaluation counts, an adaptive integrator's force evaluations (``ADAPTIVE_EFFORT``, in a record
with a numeric ``rtol``): how hard a solver worked, not what it found); per scene
(``SCENE_IGNORED``): throughput's measurements (a benchmark: its configuration is compared),
work-precision's ``cheapest`` (picked by wall time) and ``speedup_at_1e-9`` (a ratio of wall times),
breakup-statistics' sweep report and ``breakup_interval_95`` (derived from the probabilities, compared through
their intervals below).

Everything else is compared by the first rule that applies to its key, looking from the value's own key up
to the root (``fit.M`` is a fit value, ``relative_max_difference.kahan8/32`` a magnitude):

* default: ints, strings, bools, None exactly (stop reasons, kinds, flags, counts of points, bubbles, foam
  steps, Krein crossings; parameters); floats to ``|a - b| <= REL max(|a|, |b|) + ABS`` with REL = 1e-8
  (energies, multipliers, frequencies) and ABS = 1e-10: the model is dimensionless with states of order 1,
  solved to Newton residuals of ~1e-10, so differences of order-1 numbers (min contact near contact loss,
  K - K*) are known to ~1e-10 absolute (22g: 4e-12 on a min contact of 2.6e-4). No floor for dispersion
  (SI units, ``SCENE_ABS``). NaN equals NaN. Lists of different lengths: one difference, the counts.
* fit (``FIT_RE``: ``fit*``, ``sensitivity``, ``*_slope``, ``*exponent``, square-root-law parameters,
  observed orders): relative FIT_REL = 1e-6, no floor: fits stop at their solvers' tolerances, and 1e-6
  is far below any use of them. ``KEY_REL``: the square-root-law exponent at 1e-2 and its curvature at 1e-3,
  fitted to K - K* of 1e-8..5e-7 known to ~1e-10, i.e. to 1 % (22g: 0.4813 vs 0.4808); an observed order with contact
  loss at 1e-3 (its DOP853 reference is accurate to ~1e-9 past the kink, and that moves with the host's rounding).
* absolute (``KEY_ABS``): a multiplier's modulus to 1e-6 (near a Krein collision |l| - 1 moves like the square
  root of the monodromy's rounding), K - K* to 1e-9.
* predicted (``PREDICTED_KEYS``: the bubble predictions of ``continuation.bubbles``, extrapolated, not
  solved, and counted against a width threshold): counts within 1 % (at least 1), values within 5 %. The
  verdicts they accompany (stability changes, unstable intervals, points) keep the strict rules.
* magnitude (``ERROR_RE``, ``MAGNITUDE``: residuals, errors, tolerances, deviations, pairing and
  symplecticity errors, finite-difference and step-halving differences, relative distances, a branch
  point's test value and secant slope): they say how accurate something is and sit at rounding level when
  small. Equal when both are <= ERROR_FLOOR = 1e-9 (below the 1e-8 resolution above) or, of one sign,
  within ERROR_FACTOR = 10.
* text (``TEXT``: message, note, onset...): the same words, numbers masked (compared under their own keys).
* ``parameters`` (the run's inputs): the default rule, whatever the keys' names.

Specific rules:

* Brackets (``bracket``; ``start``/``end`` of unstable intervals and unresolved bubbles) overlap or lie at
  most the wider one's width apart: a correct bracket holds its change, so two must overlap; the slack (a
  bracket is bisected down to the branch's resolution, its width is the resolution reached) admits a
  borderline multiplier that one run counts a step earlier.
* Unresolved-bubble stretches (``unresolved_bubbles``): every stretch of one run overlaps one of the other,
  except marginal ones (``MARGINAL_IM``: all their predicted bubbles within a factor 3 of the floor at which a
  bubble counts, ``continuation.bubbles.FLOOR``); stretches with the same ends pair and compare by the rules.
* Branch points (``bifurcation_points``): the numbers located and not located agree; records pair by
  family, kind, located or not, and K: located ``|K_a - K_b| <= K_error_a + K_error_b + K_SLACK |K|``
  (K_SLACK = 1e-12) or their final brackets overlap (each holds the zero); not located (K is the bracket's
  geometric mean) by their brackets. A not-located record marked ``test_function_jump`` (a sign change of a
  test function at rounding level next to another mode: ``continuation.bifurcation.JUMP_RATIO``) is a remark
  whose presence depends on rounding (22: present on the CPU, absent in a GPU paper run): left out of
  the counts and the pairing. Pairs compare the
  rest with REL widened by ``(K_error_a + K_error_b) / K`` (energy, participation are stated at a K known to
  that much), the critical mode's central weight as a magnitude (ill-defined on the bond-centred families:
  0.89 vs 0.98 in 22g), the errors not at all. Unpaired records are reported one by one.
* Points along a branch (``points`` with K, omega, energy): the counts agree; points pair where K and omega
  agree (default rule), the unpaired are one difference, pairs compare energy, max |multiplier|,
  stability, kinds, min contact.
* Breakup probabilities (``breakup_probability*``): the 95 % Wilson score intervals of the two estimates
  (n = the grid's realisations, times its widths for the W-averaged ``*_by_A``) overlap. Overlap, not each
  estimate inside the other's interval: chaotic filamentation turns rounding differences between devices
  into different lattices, and over a grid's hundreds of cells the stricter test raises false alarms.

Exit status: 0 the same science; 1 differences (a line each: scene, key path, both values, the rule; then
a count); 2 bad input (a folder that does not exist or holds no scene, an unknown scene).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import sys
from pathlib import Path

REL, ABS = 1e-8, 1e-10
SCENE_ABS = {"dispersion": 0.0}  # SI units: no absolute floor
FIT_REL = 1e-6
ERROR_FLOOR, ERROR_FACTOR = 1e-9, 10.0
K_SLACK = 1e-12
WILSON_Z = 1.96

IGNORED = frozenset(
    "command_line device devices cpu cpu_threads packages version versions git git_commit commit hostname host "
    "platform python date created timestamp path paths provenance workers jobs threads scheduler gpus fresh "
    "timing".split()
)
IGNORED_RE = re.compile(r"seconds|_per_second$|_rate$|_over_kernel$|^fraction_of_best$")
EFFORT = frozenset(
    "iterations newton_iterations evaluations solves failed_solves bisection_solves rejected_backwards "
    "bubble_solves residual_history newton_residual_history chord_steps jacobians tangent_columns".split()
)
#: an adaptive integrator's force evaluations (a record with a numeric ``rtol``) are effort too: work-precision's
#: DOP853 took 1394 / 1406 and 14102 / 13658 on the 2-core CPU and on the H100 host (2026-11-26, numpy of another
#: build: the step sequences part at rounding level), its errors within the magnitude rule. A fixed-step point's
#: count (steps times evaluations per step) is compared: it is the record of how many steps the run took
ADAPTIVE_EFFORT = "force_evaluations"
SCENE_IGNORED = {
    "throughput": frozenset({"results", "ratios", "simulate", "monodromy", "kernel_properties", "hand_cuda_variant"}),
    "work-precision": frozenset({"cheapest", "speedup_at_1e-9"}),
    "breakup-statistics": frozenset({"sweep", "breakup_interval_95"}),
}
#: relative tolerances of single keys: ill-conditioned fits (the square-root law's exponent and curvature,
#: fitted to K - K* of 1e-8..5e-7 known to ~1e-10)
#: and a mode's central weight (an eigenvector's: conditioned by the gap to the nearest multiplier, not by the
#: multiplier's own accuracy; H100 x2 against CPU, 2026-11-25: 2.9e-8 apart at site-bond's N = 401 table)
#: and the observed order with contact loss (stability-limits: three errors of 1e-4..1e-3 against a DOP853 reference
#: that its kink leaves accurate to ~1e-9, which moves with the host's rounding: 2.631653 vs 2.631647 for kahan8,
#: 2.50414 vs 2.50422 for rk4, 2-core CPU against the H100 host, 2026-11-26)
KEY_REL = {"sqrt_law_exponent": 1e-2, "sqrt_law_curvature": 1e-3, "central_weight": 1e-6, "order_contact_loss": 1e-3}
#: absolute tolerances of single keys: a multiplier's modulus (near a Krein collision a pair splits like the
#: square root of a perturbation: monodromies that differ by rounding, ~1e-14, give |l| - 1 apart by ~1e-7;
#: H100 against CPU: 6.15e-7 vs 6.30e-7 at a bubble's edge) and K - K* (K* located to ~1e-9)
#: 2026-11-25 H100 x2 against CPU: 1.00000065 vs 1.0 (the pair not yet split) at a point both call stable;
#: 1e-6 stays below the verdict's tolerance (|l| - 1 of 5.5e-6 for a real pair), and the verdicts are compared
KEY_ABS = {"max_floquet_modulus": 1e-6, "max_modulus": 1e-6, "K_offset": 1e-9}
#: the bubble predictions (``continuation.bubbles``: extrapolated from the multipliers at a step's two ends, not
#: solved): a predicted width is compared with the chase width, so one borderline bubble moves between the
#: counts (H100 against CPU: 596 vs 597 predicted, 115 vs 116 foam steps) and shifts a stretch's predicted
#: fraction by a few per cent. Counts agree within PREDICTED_COUNT (at least one), values within PREDICTED_REL.
#: Krein crossings recorded along a branch count the same way: a pair at the edge of a collision is counted
#: or not by rounding (H100 x2 against CPU, 2026-11-25: 117 vs 116)
PREDICTED_KEYS = frozenset(
    "bubbles_predicted bubbles_below_width foam_steps predicted unstable_fraction widest max_predicted_modulus"
    " krein_crossings_recorded".split()
)
PREDICTED_COUNT, PREDICTED_REL = 0.01, 0.05
#: an unresolved-bubble stretch whose strongest predicted bubble has Im mu <= MARGINAL_IM is marginal: a bubble
#: counts above ``continuation.bubbles.FLOOR`` (1e-10), and the prediction's rounding (the CPU against the H100:
#: a stretch at 1.2e-11 in |l| - 1 present on one only, when the threshold was the measured tolerance) decides
#: near it; such a stretch may be present in one run only
MARGINAL_IM = 3e-10
FIT_RE = re.compile(
    r"^fit(_|$)|^sensitivity$|^paper_slope_difference$|_slope$|exponent$|^sqrt_law_(K0|curvature)$|^order_"
)
ERROR_RE = re.compile(r"(^|_)(errors?|residuals?|tolerance|symplecticity)(_|$)|deviation$")
MAGNITUDE = frozenset(
    "test_mu_minus_1 slope relative_difference max_abs_difference relative_max_difference max_state_difference "
    "max_modulus_difference_to_reduced step_halving_difference_final step_halving_difference_max "
    "relative_distance".split()
)
TEXT = frozenset("message note finding onset what interval gamma_rule rule".split())
BRACKET_TEXT = "intervals overlap or lie within the wider one's width"
MAGNITUDE_TEXT = f"both <= {ERROR_FLOOR:g} or within a factor {ERROR_FACTOR:g}"
NUMBER_RE = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


@dataclasses.dataclass(frozen=True)
class Difference:
    """One disagreement: the scene, where in its summary, the two values and the rule they fail."""

    scene: str
    path: str
    a: object
    b: object
    rule: str

    def line(self) -> str:
        return f"{self.scene}: {self.path or '(scene)'}: {_short(self.a)} vs {_short(self.b)} [{self.rule}]"


def _short(value, width: int = 70) -> str:
    text = value if isinstance(value, str) and value.startswith("<") else json.dumps(value, default=str)
    return text if len(text) <= width else text[: width - 3] + "..."


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _close(a: float, b: float, rel: float, floor: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a) or math.isinf(b):  # a relative slack of an infinity is infinite: only itself is close
        return a == b
    return a == b or abs(a - b) <= rel * max(abs(a), abs(b)) + floor


def _same_magnitude(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a) or math.isinf(b):
        return a == b
    big, small = max(abs(a), abs(b)), min(abs(a), abs(b))
    return big <= ERROR_FLOOR or (a * b > 0 and big <= ERROR_FACTOR * small)


def _intervals_agree(a, b) -> bool:
    """Brackets overlap, or lie at most the wider one's width apart (module docstring)."""
    (a0, a1), (b0, b1) = sorted(a), sorted(b)
    slack = REL * max(map(abs, (a0, a1, b0, b1))) + ABS
    gap = max(a0, b0) - min(a1, b1)
    return gap <= max(a1 - a0, b1 - b0) + slack


def wilson(p: float, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """The Wilson score interval of a proportion p out of n trials (as the breakup-statistics scene's)."""
    p = min(max(p, 0.0), 1.0)
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def _path_text(path: tuple) -> str:
    return "".join(f"[{k}]" if isinstance(k, int) or "=" in k else (f".{k}" if i else k) for i, k in enumerate(path))


def _rule(path: tuple) -> tuple[str, float]:
    """The rule of a value and its relative tolerance, from its own key up to the root (module docstring)."""
    if "parameters" in path:
        return "default", REL  # the run's inputs, whatever their names
    if path[-1:] == ("central_weight",) and "bifurcation_points" in path:
        return "magnitude", 0.0  # the critical mode's, ill-defined on bond-centred families (module docstring)
    for key in reversed([k for k in path if isinstance(k, str)]):
        if key in TEXT:
            return "text", 0.0
        if key in PREDICTED_KEYS:
            return "predicted", PREDICTED_REL
        if key in KEY_ABS:
            return "absolute", KEY_ABS[key]
        if key in KEY_REL:
            return "fit", KEY_REL[key]
        if key in MAGNITUDE or ERROR_RE.search(key):
            return "magnitude", 0.0
        if FIT_RE.search(key):
            return "fit", FIT_REL
    return "default", REL


class _Comparer:
    """Walks two summaries of one scene side by side and collects the differences."""

    def __init__(self, scene: str, a: dict, b: dict):
        self.scene, self.root, self.out = scene, a, []
        self.ignored = IGNORED | EFFORT | SCENE_IGNORED.get(scene, frozenset())
        self.floor = SCENE_ABS.get(scene, ABS)
        self.widen = 0.0  # relative tolerance added at a located branch point: its K error bars, relative

    def differ(self, path: tuple, a, b, rule: str) -> None:
        self.out.append(Difference(self.scene, _path_text(path), a, b, rule))

    def skip(self, key) -> bool:
        return isinstance(key, str) and (key in self.ignored or bool(IGNORED_RE.search(key)))

    def walk(self, a, b, path: tuple = ()) -> None:
        key = path[-1] if path else None
        if isinstance(key, str) and key.startswith("breakup_probability") and isinstance(a, list):
            return self.probabilities(a, b, path)
        if isinstance(a, dict) and isinstance(b, dict):
            return self.record(a, b, path)
        if isinstance(a, list) and isinstance(b, list):
            if key == "bracket" and len(a) == len(b) == 2 and all(map(_number, a + b)):
                if not _intervals_agree(a, b):
                    self.differ(path, a, b, BRACKET_TEXT)
            elif key == "bifurcation_points" and _records(a) and _records(b):
                self.branch_points(a, b, path)
            elif key == "points" and _records(a, "energy") and _records(b, "energy"):
                self.branch(a, b, path)
            elif key == "unresolved_bubbles" and _stretches(a) and _stretches(b):
                self.stretches(a, b, path)
            elif len(a) != len(b) and any(isinstance(x, (dict, list)) for x in a + b):
                self.differ(path, len(a), len(b), "same count")
            elif len(a) != len(b):
                self.differ(path, a, b, "equal")
            else:
                for i, (x, y) in enumerate(zip(a, b)):
                    self.walk(x, y, path + (i,))
            return
        self.leaf(a, b, path)

    def record(self, a: dict, b: dict, path: tuple) -> None:
        done = set()
        if all(_number(r.get(k)) for r in (a, b) for k in ("start", "end")):
            done = {"start", "end"}
            if not _intervals_agree((a["start"], a["end"]), (b["start"], b["end"])):
                self.differ(path + ("start..end",), [a["start"], a["end"]], [b["start"], b["end"]], BRACKET_TEXT)
        for k in sorted(set(a) | set(b), key=str):
            if k in done or self.skip(k):
                continue
            if k == ADAPTIVE_EFFORT and _number(a.get("rtol")) and _number(b.get("rtol")):
                continue
            if k not in a or k not in b:
                self.differ(path + (k,), a.get(k, "<missing>"), b.get(k, "<missing>"), "present in both")
            else:
                self.walk(a[k], b[k], path + (k,))

    def leaf(self, a, b, path: tuple) -> None:
        rule, rel = _rule(path)
        if _number(a) and _number(b):
            if rule == "magnitude":
                ok, text = _same_magnitude(a, b), MAGNITUDE_TEXT
            elif rule == "absolute":
                ok, text = abs(a - b) <= rel or (math.isnan(a) and math.isnan(b)), f"absolute {rel:g}"
            elif rule == "predicted" and isinstance(a, int) and isinstance(b, int):
                slack = max(1, PREDICTED_COUNT * max(abs(a), abs(b)))
                ok, text = abs(a - b) <= slack, f"predicted count: within {PREDICTED_COUNT:.0%} or 1"
            elif rule == "predicted":
                ok, text = _close(a, b, rel, 0.0), f"predicted: relative {rel:g}"
            elif rule == "fit":
                ok, text = _close(a, b, rel, 0.0), f"fit: relative {rel:g}"
            elif isinstance(a, int) and isinstance(b, int):
                ok, text = a == b, "equal"
            else:
                tol = REL + self.widen
                ok, text = _close(a, b, tol, self.floor), f"relative {tol:.3g} + absolute {self.floor:g}"
        elif rule == "text" and isinstance(a, str) and isinstance(b, str):
            ok, text = NUMBER_RE.sub("#", a) == NUMBER_RE.sub("#", b), "same words (numbers masked)"
        else:
            ok, text = a == b, "equal"
        if not ok:
            self.differ(path, a, b, text)

    def branch(self, a: list, b: list, path: tuple) -> None:
        """Points along a branch: counts, then each point of A against B's point at the same K and omega."""
        if len(a) != len(b):
            self.differ(path, len(a), len(b), "same point count")
        param = "K" if len({p.get("K") for p in a}) > 1 else "omega"
        pairs, left_a, left_b = _pair(a, b, _same_point)
        for i, j in pairs:
            self.walk(_without(a[i]), _without(b[j]), path + (f"{param}={a[i].get(param):.10g}",))
        if left_a or left_b:
            first = f", the first at {param} = {a[left_a[0]].get(param):.10g}" if left_a else ""
            self.differ(
                path + (f"matched by {param}",),
                f"<{len(pairs)} of {len(a)} points matched{first}>",
                f"<{len(pairs)} of {len(b)} points matched>",
                "every point at the same K and omega",
            )

    def stretches(self, a: list, b: list, path: tuple) -> None:
        """Unresolved-bubble stretches: each one of A overlaps one of B and the other way round, unless it is
        marginal (its strongest predicted bubble within MARGINAL of ``continuation.bubbles.FLOOR``, where
        rounding decides whether a bubble counts, and so whether a step joins, splits or makes a stretch);
        stretches with the same ends (the default rule: branch points of both runs) pair, and pairs compare
        by the rules above."""
        for x, y, side in ((a, b, 0), (b, a, 1)):
            for r in x:
                if not any(_overlap(r, o) for o in y) and not _marginal(r):
                    where = [r["start"], r["end"]]
                    pair = (where, "<none>") if side == 0 else ("<none>", where)
                    self.differ(path + ("stretch",), *pair, f"in both unless marginal (max Im mu <= {MARGINAL_IM:g})")
        same = lambda x, y: all(_close(x[k], y[k], REL, ABS) for k in ("start", "end"))  # noqa: E731
        for i, j in _pair(a, b, same)[0]:
            self.record(a[i], b[j], path + (i,))

    def branch_points(self, a: list, b: list, path: tuple) -> None:
        """Branch points matched by family, kind, located or not, and K (located: within the stated errors;
        not located: brackets that agree); the rest of a matched pair by the rules above."""
        a, b = ([r for r in x if not (isinstance(r, dict) and r.get("test_function_jump"))] for x in (a, b))
        counts = [[sum(map(_located, x)), sum(not _located(r) for r in x)] for x in (a, b)]
        if counts[0] != counts[1]:
            self.differ(path + ("(located, not located)",), counts[0], counts[1], "same counts")
        pairs, left_a, left_b = _pair(a, b, _same_branch_point)
        for i, j in pairs:  # K and its stated errors are judged by the pairing
            x, y = (_without(r, ("K", "K_error", "relative_error")) for r in (a[i], b[j]))
            if _located(a[i]) and all(_number(r.get(k)) for r in (a[i], b[j]) for k in ("K", "K_error")):
                self.widen = (a[i]["K_error"] + b[j]["K_error"]) / max(abs(a[i]["K"]), abs(b[j]["K"]), ABS)
            self.record(x, y, path + (i,))
            self.widen = 0.0
        near, left_a, left_b = _pair(a, b, lambda x, y: _identity(x) == _identity(y), left_a, left_b)
        for x, y in [(a[i], b[j]) for i, j in near]:
            rule = "|K_a - K_b| <= K_error_a + K_error_b" if _located(x) else BRACKET_TEXT
            self.differ(path + (_label(x),), _where(x), _where(y), rule)
        for i in left_a:
            self.differ(path + (_label(a[i]),), _where(a[i]), "<none>", "a branch point in both")
        for j in left_b:
            self.differ(path + (_label(b[j]),), "<none>", _where(b[j]), "a branch point in both")

    def probabilities(self, a: list, b: list, path: tuple) -> None:
        grid = self.root.get("grid", {})
        n = int(grid.get("realisations", 0)) * (len(grid.get("W", [])) if path[-1].endswith("_by_A") else 1)
        if n <= 0:
            return self.walk(a, b, path + ("values",))

        def cells(x, y, p):
            if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
                for i, (u, v) in enumerate(zip(x, y)):
                    cells(u, v, p + (i,))
            elif _number(x) and _number(y) and (math.isnan(x) or math.isnan(y)):
                if not (math.isnan(x) and math.isnan(y)):
                    self.differ(p, x, y, "NaN on one side")
            elif _number(x) and _number(y):
                (la, ha), (lb, hb) = wilson(x, n), wilson(y, n)
                if la > hb + ABS or lb > ha + ABS:
                    self.differ(p, x, y, f"95 % Wilson intervals (n = {n}) overlap")
            elif x != y:
                self.differ(p, x, y, "same shape")

        cells(a, b, path)


def _stretches(items: list) -> bool:
    return all(isinstance(r, dict) and _number(r.get("start")) and _number(r.get("end")) for r in items)


def _overlap(x: dict, y: dict) -> bool:
    (a0, a1), (b0, b1) = sorted((x["start"], x["end"])), sorted((y["start"], y["end"]))
    return max(a0, b0) <= min(a1, b1) + REL * max(map(abs, (a0, a1, b0, b1))) + ABS


def _marginal(stretch: dict) -> bool:
    im = stretch.get("max_predicted_im")
    return _number(im) and im <= MARGINAL_IM


def _records(items: list, field: str | None = None) -> bool:
    return bool(items) and all(isinstance(r, dict) and (field is None or field in r) for r in items)


def _located(record: dict) -> bool:
    """A branch point record is located when it says so, or (site-bond's records) when it states its K error."""
    return bool(record["located"]) if "located" in record else "K_error" in record


def _identity(r: dict) -> tuple:
    return r.get("family"), r.get("kind"), _located(r)


def _label(r: dict) -> str:
    return f"{r.get('family')} {r.get('kind')} {'located' if _located(r) else 'not located'}"


def _where(r: dict) -> list:
    return [r.get("K"), r.get("K_error")] if _located(r) else r.get("bracket")


def _same_branch_point(x: dict, y: dict) -> bool:
    if _identity(x) != _identity(y):
        return False
    if _located(x) and all(_number(r.get(k)) for r in (x, y) for k in ("K", "K_error")):
        if abs(x["K"] - y["K"]) <= x["K_error"] + y["K_error"] + K_SLACK * max(abs(x["K"]), abs(y["K"])):
            return True
        # or their final brackets (each holds the zero) overlap: the K reported is the bracket's end nearer the
        # zero, and K_error its distance to the secant's zero, which can be less than the bracket (H100 against
        # CPU: K 2.0e-7 apart with errors 1.4e-8 and 1.7e-7, brackets overlapping over 1.8e-7)
        brackets = [r.get("bracket") for r in (x, y)]
        if all(isinstance(br, list) and len(br) == 2 and all(map(_number, br)) for br in brackets):
            (a0, a1), (b0, b1) = sorted(brackets[0]), sorted(brackets[1])
            return max(a0, b0) <= min(a1, b1) + K_SLACK * max(abs(a1), abs(b1))
        return False
    if all(isinstance(r.get("bracket"), list) and len(r["bracket"]) == 2 for r in (x, y)):
        return _intervals_agree(x["bracket"], y["bracket"])
    return _number(x.get("K")) and _number(y.get("K")) and _close(x["K"], y["K"], REL, ABS)


def _pair(a: list, b: list, same, ia=None, ib=None) -> tuple[list, list, list]:
    """Greedy pairs (i, j) with same(a[i], b[j]), in order, over the indices ia of a and ib of b (default all);
    and the indices of a and of b left over."""
    ia, ib = range(len(a)) if ia is None else ia, range(len(b)) if ib is None else ib
    pairs, used = [], set()
    for i in ia:
        j = next((j for j in ib if j not in used and same(a[i], b[j])), None)
        if j is not None:
            pairs.append((i, j))
            used.add(j)
    paired = {i for i, _ in pairs}
    return pairs, [i for i in ia if i not in paired], [j for j in ib if j not in used]


def _without(record: dict, keys=("K", "omega")) -> dict:
    return {k: v for k, v in record.items() if k not in keys}


def _same_point(p: dict, q: dict) -> bool:
    return all(_number(p.get(k)) and _number(q.get(k)) and _close(p[k], q[k], REL, ABS) for k in ("K", "omega"))


def compare_summaries(scene: str, a: dict, b: dict) -> list[Difference]:
    """The differences between two summaries of one scene (module docstring for the rules)."""
    comparer = _Comparer(scene, a, b)
    comparer.walk(a, b)
    return comparer.out


def _scenes(root: Path, known) -> set[str]:
    return {d.name for d in root.iterdir() if d.is_dir() and ((d / "summary.json").is_file() or d.name in known)}


def _load(folder: Path) -> tuple[dict | None, str | None]:
    """A scene's summary, or None and why there is none."""
    if not folder.is_dir():
        return None, "<missing>"
    try:
        summary = json.loads((folder / "summary.json").read_text())
    except FileNotFoundError:
        try:  # a scene that raised says why (scenarios._common)
            return None, f"<failed: {json.loads((folder / 'failed.json').read_text())['error']}>"
        except (OSError, ValueError, KeyError, TypeError):
            return None, "<failed: no summary.json>"
    except (OSError, ValueError) as exc:
        return None, f"<failed: unreadable summary.json: {exc}>"
    except RecursionError:
        return None, "<failed: unreadable summary.json: nested too deeply to be a scene's summary>"
    if not isinstance(summary, dict) or summary.get("failed") is True or summary.get("status") == "failed":
        return None, "<failed: marked failed in summary.json>"
    return summary, None


def compare_folders(a: Path, b: Path, scenes: list[str] | None = None) -> tuple[list[Difference], list[str]]:
    """The differences between result folders a and b, and the scenes compared. ValueError on bad input."""
    from ._common import SCENES

    a, b = Path(a), Path(b)
    for folder in (a, b):
        if not folder.is_dir():
            raise ValueError(f"{folder} is not a folder")
    found = {folder: _scenes(folder, SCENES) for folder in (a, b)}
    for folder, names in found.items():
        if not names:
            raise ValueError(f"{folder} holds no scenes (no subfolder with a summary.json)")
    names = sorted(found[a] | found[b], key=lambda n: (list(SCENES).index(n) if n in SCENES else len(SCENES), n))
    if scenes:
        unknown = [s for s in scenes if s not in SCENES and s not in names]
        if unknown:
            raise ValueError(f"unknown scene(s) {', '.join(unknown)}; known: {', '.join(SCENES)}")
        names = list(scenes)
    out = []
    for name in names:
        (sa, why_a), (sb, why_b) = _load(a / name), _load(b / name)
        if sa is None or sb is None:
            out.append(Difference(name, "", why_a or "<finished>", why_b or "<finished>", "must finish in both"))
        else:
            out.extend(compare_summaries(name, sa, sb))
    return out, names


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def main(a: Path, b: Path, scenes: str | None = None, json_path: Path | None = None) -> int:
    """The command: one line per difference and a verdict; exit 0 same, 1 different, 2 bad input."""
    try:
        chosen = [s.strip() for s in scenes.split(",") if s.strip()] if scenes else None
        differences, names = compare_folders(a, b, chosen)
        if json_path is not None:
            rows = [dataclasses.asdict(d) for d in differences]
            Path(json_path).write_text(json.dumps(rows, indent=1, default=str) + "\n")
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RecursionError:
        print(f"error: a summary under {a} or {b} is nested too deeply to compare", file=sys.stderr)
        return 2
    for d in differences:
        print(d.line())
    if not differences:
        print(f"same science: {_count(len(names), 'scene')}")
        return 0
    print(f"{_count(len(differences), 'difference')} in {_count(len({d.scene for d in differences}), 'scene')}")
    return 1
