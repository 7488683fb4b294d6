"""Events along a branch: why it stopped, where stability changed, where multipliers crossed.

Detectors compare two consecutive points of a branch; the driver (``continuation.driver``) bisects
any step across which one fires, with the multipliers recomputed at every trial point, until the
bracket is below the settings' resolution.

* **Stability signature**: the number of unstable multipliers of each kind (real pair through +1,
  pair through -1, Krein quadruplet). A change between two points is a stability change.
* **Krein order**: the sequence of Krein signatures of the elliptic multipliers (mu in (-1, 1)),
  sorted by mu, within each parity class. Two elliptic multipliers of opposite signature (and equal
  or unknown parity) that pass each other change this sequence; only such pairs can collide and
  leave the unit circle (Krein's theorem), so a step across which the sequence changes may hide an
  instability bubble and is bisected like a stability change. Same-signature crossings cannot.
* **Contact**: min over the orbit of 1 + u - v <= 0 stops a branch.
* **Harmonics**: n w_b entering a phonon band (flagged; resonances of the breather with phonons).
* **Unresolved bubbles**: a final step of the branch in which ``continuation.bubbles`` predicts
  bubbles narrower than the driver's chase width, which nobody solved for (``bubble_foam``).
  ``unresolved_bubbles`` merges such steps into stretches, where the branch's verdict between its
  points is "stable outside bubbles covering the predicted fraction", not "stable".
"""

from __future__ import annotations

import enum
import math

import numpy as np

from warpchain.model import band_edges

from .bubbles import covered_fraction
from .floquet import KINDS


class StopReason(enum.Enum):
    """Why a branch stopped; ``.explanation`` says what it means and what to do."""

    END_REACHED = "end_reached"
    CONTACT_LOST = "contact_lost"
    NEWTON_FAILED = "newton_failed"
    STEP_UNDERFLOW = "step_underflow"
    MAX_POINTS = "max_points"
    TIME_BUDGET = "time_budget"

    @property
    def explanation(self) -> str:
        return {
            "end_reached": "the branch reached its end parameter",
            "contact_lost": "a resonator lost contact (min over the orbit of 1 + u - v <= 0): the model's smooth "
            "branch ends here",
            "newton_failed": "Newton failed at the first point: check the seed and that the frequency lies in a gap",
            "step_underflow": "Newton kept failing and the step fell below its minimum: lower ds_min, raise "
            "max_newton, or look for a fold or a bifurcation near the last point",
            "max_points": "the requested number of points was reached: raise max_points or resume the branch",
            "time_budget": "the opt-in time budget was spent: resume the branch from its store to go on",
        }[self.value]

    @property
    def physical(self) -> bool:
        """Whether the branch ended on physics (end parameter or contact loss)."""
        return self in (StopReason.END_REACHED, StopReason.CONTACT_LOST)


def stability_signature(point) -> tuple:
    """(real pairs, period doublings, quadruplets) unstable at a point."""
    counts = {k: 0 for k in KINDS}
    for inst in point.instabilities:
        counts[inst.kind] += 1
    return tuple(counts[k] for k in KINDS)


def krein_order(point) -> dict | None:
    """Signatures of the elliptic, nontrivial mu sorted by mu, per parity class (None without mu)."""
    if point.mu is None or point.signature is None:
        return None
    t = elliptic_table(point)
    parity = t["parity"] if np.all(t["parity"] != 0) else np.zeros(len(t["mu"]), int)  # unresolved: one class
    out = {}
    for cls in np.unique(parity):
        sel = parity == cls
        out[int(cls)] = t["sig"][sel][np.argsort(t["mu"][sel])]
    return out


def krein_crossings(a, b) -> int:
    """How many opposite-signature passes the Krein order shows between a and b (0 when equal;
    -1 when the orders cannot be compared, e.g. the number of elliptic multipliers changed)."""
    oa, ob = krein_order(a), krein_order(b)
    if oa is None or ob is None:
        return 0
    if set(oa) != set(ob) or any(len(oa[k]) != len(ob[k]) for k in oa):
        return -1
    total = 0
    for k in oa:
        # count inversions via the positions of the +1 signatures: each opposite pass moves one
        pa, pb = np.flatnonzero(oa[k] > 0), np.flatnonzero(ob[k] > 0)
        if len(pa) != len(pb):
            return -1
        total += int(np.sum(np.abs(pa - pb)))
    return total


def localized_krein_crossings(a, b) -> int:
    """How many times a localized elliptic mode (participation < LOCALIZED_FRACTION N) passed an
    elliptic multiplier of opposite signature (same or unknown parity) between a and b."""
    from .floquet import LOCALIZED_FRACTION

    if a.mu is None or b.mu is None or a.participation is None or b.participation is None:
        return 0
    total = 0
    ca, cb = elliptic_table(a), elliptic_table(b)
    N = np.shape(a.state)[-1]  # sites (len(mu) is 2N only on the dense path)
    for sig in (1, -1):
        for par in set(ca["parity"]) | set(cb["parity"]):
            la = np.sort(ca["mu"][(ca["sig"] == sig) & (ca["parity"] == par) & (ca["pr"] < LOCALIZED_FRACTION * N)])
            lb = np.sort(cb["mu"][(cb["sig"] == sig) & (cb["parity"] == par) & (cb["pr"] < LOCALIZED_FRACTION * N)])
            if len(la) != len(lb) or not len(la):
                continue
            oa = np.sort(ca["mu"][(ca["sig"] == -sig) & ((ca["parity"] == par) | (ca["parity"] == 0) | (par == 0))])
            ob = np.sort(cb["mu"][(cb["sig"] == -sig) & ((cb["parity"] == par) | (cb["parity"] == 0) | (par == 0))])
            total += int(np.sum(np.abs(np.searchsorted(oa, la) - np.searchsorted(ob, lb))))
    return total


def elliptic_table(point) -> dict:
    """The elliptic, nontrivial mu (signature +1/-1) of a point: their real parts, signatures,
    parities (0 where unknown) and participation ratios (None when the point has none)."""
    keep = point.signature != 0
    parity = point.parity if point.parity is not None else np.zeros(len(point.mu), int)
    return {
        "mu": np.real(point.mu)[keep],
        "sig": point.signature[keep],
        "parity": parity[keep],
        "pr": None if point.participation is None else point.participation[keep],
    }


#: max |l| - 1 below which a point's instability is weak (``weak_extended``, ``weak_extended_instability``)
WEAK_INSTABILITY = 1e-3


def _weak(point) -> bool:
    return point.max_modulus - 1.0 < WEAK_INSTABILITY


#: two unstable multipliers at the two ends of a step are taken for the same one when their mu (of the same
#: kind and parity) differ by at most this much; otherwise one left and another arrived in the step
IDENTITY_TOL = 0.02


def instability_set(point, significant: bool = False) -> dict:
    """The unstable multipliers of a point by (kind, parity), each class sorted by mu (imaginary part folded
    to >= 0, so that a quadruplet's two mu are one). ``significant``: without the weak extended ones
    (``weak_extended_instability``)."""
    out: dict = {}
    for inst in point.instabilities:
        if not (significant and weak_extended_instability(inst)):
            out.setdefault((inst.kind, int(inst.parity)), []).append(inst)
    return {key: sorted(v, key=lambda i: (i.mu.real, abs(i.mu.imag))) for key, v in out.items()}


def _same_instabilities(a, b, significant: bool = False) -> bool:
    """The same unstable multipliers at both ends: the same kinds, parities and counts, each (in mu order)
    with mu near its counterpart's (``IDENTITY_TOL``) and, where both are known, its Floquet vector's
    participation within a factor 2 (two weak quadruplets near one mu can be different modes: 121 and 49
    sites on either side of a stable window of the paper's frequency branch); ``significant``: of those
    that are not weak and extended."""
    sa, sb = instability_set(a, significant), instability_set(b, significant)
    if sa.keys() != sb.keys():
        return False
    return all(len(sa[k]) == len(sb[k]) and all(_alike(x, y) for x, y in zip(sa[k], sb[k])) for k in sa)


def _folded(mu: complex) -> complex:
    """mu with its imaginary part folded to >= 0 (a quadruplet's two mu are one)."""
    return complex(mu.real, abs(mu.imag))


def _same_extent(x, y) -> bool:
    """Floquet vectors' participations within a factor 2 (NaN, on the full path: not compared)."""
    px, py = x.participation, y.participation
    return not (px > 0 and py > 0) or 0.5 <= px / py <= 2.0


def _alike(x, y) -> bool:
    """Two instabilities that can be one multiplier at the two ends of a step (``_same_instabilities``)."""
    return abs(_folded(x.mu) - _folded(y.mu)) <= IDENTITY_TOL and _same_extent(x, y)


def kinds_present(point) -> tuple:
    return tuple(k for k, n in zip(KINDS, stability_signature(point)) if n)


#: a step whose ends carry the same unstable multipliers is examined when one of them moved further than
#: this fraction of its summed distances to the critical set at the two ends (``near_critical``)
TOUCH_FRACTION = 0.5


def _critical_distance(kind: str, mu: complex) -> float:
    """How far an unstable multiplier is from turning stable or changing kind: a quadruplet's |Im mu| (it
    lands on the unit circle, or on the real axis, when that vanishes), a real pair's mu - 1, a period
    doubling's -1 - mu."""
    if kind == "complex_quadruplet":
        return abs(mu.imag)
    return abs(mu.real - 1.0) if kind == "real_pair" else abs(mu.real + 1.0)


def near_critical(a, b) -> bool:
    """Whether an unstable multiplier matched across the step (same kind and parity, in mu order) moved far
    enough to have touched the critical set inside it and come back: |mu_b - mu_a| above ``TOUCH_FRACTION``
    of the sum of its distances to the critical set at the two ends (a quadruplet that closes onto the
    unit circle and opens again within one step leaves a stable window and the same set at both ends).
    Weak extended instabilities (the phonon foam, stated as fractions by ``unresolved_bubbles``) are left
    out."""
    sa, sb = instability_set(a, significant=True), instability_set(b, significant=True)
    return any(_touches(key[0], x.mu, y.mu) for key in sa.keys() & sb.keys() for x, y in zip(sa[key], sb[key]))


def _touches(kind: str, mu_a: complex, mu_b: complex) -> bool:
    """An instability moved further than ``TOUCH_FRACTION`` of its summed distances to the critical set."""
    ma, mb = _folded(mu_a), _folded(mu_b)
    return abs(mb - ma) > TOUCH_FRACTION * (_critical_distance(kind, ma) + _critical_distance(kind, mb))


def weak_extended_instability(inst) -> bool:
    """A weak (|l| - 1 < ``WEAK_INSTABILITY``) instability of an extended (phonon) Floquet vector: the foam of
    finite-size resonances inside and near the acoustic band, which changes at nearly every step there."""
    return inst.modulus - 1.0 < WEAK_INSTABILITY and not inst.localized


def persistent(a, b) -> bool:
    """Whether one significant instability (not weak and extended) holds across the step: of the same kind,
    parity and extent at both ends, with log |l| changed by less than ``TOUCH_FRACTION`` of its smaller
    value, its participation within a factor 2, and not ``near_critical``. No stable window can then sit
    inside the step, whatever else comes and goes (along the paper's K branch a localized real pair of
    |l| - 1 ~ 3e-4 holds while extended quadruplets at |l| - 1 ~ 1e-3 come and go at nearly every step;
    examining those changes took the branch from 203 to 1423 points).

    The stated limit: the test reads the two ends only. An instability that dips through the unit circle and
    comes back within the step with a similar |l| at both ends (for a real pair near +1 the mu test is weak:
    mu - 1 grows like (|l| - 1)^2 / 2) is taken for one that held, and a window inside that step, if every
    other instability closed there too, goes unseen. Any instability is matched with any of its class."""
    sa, sb = instability_set(a, significant=True), instability_set(b, significant=True)
    for key in sa.keys() & sb.keys():
        for x in sa[key]:
            for y in sb[key]:
                lx, ly = math.log(x.modulus), math.log(y.modulus)
                if (
                    x.localized == y.localized
                    and _same_extent(x, y)
                    and abs(ly - lx) < TOUCH_FRACTION * min(lx, ly)
                    and not _touches(key[0], x.mu, y.mu)
                ):
                    return True
    return False


def changed(a, b) -> str | None:
    """What changed between two consecutive points, in this order:

    1. ``"stability"``: the verdict or the kinds present changed.
    2. ``"count"`` (recorded, not examined) or None: one significant instability holds across the step
       (``persistent``), so that no stable window can sit inside it.
    3. ``"stability"``: the significant unstable multipliers (all but the weak extended ones) differ: a
       parity, a count, or one that left while another arrived (``IDENTITY_TOL``). Between two unstable
       points whose unstable multipliers differ one instability may close before the other opens, leaving
       a stable window inside the step (measured on a chain checked against AUTO: windows 3e-4 and 1.4e-3
       wide in w_b between points with max |l| - 1 of 4e-3 to 2e-2, stepped over when only weakly
       unstable ends were examined).
    4. ``"suspect"``: the same significant multipliers at both ends, but one moved far enough to have
       closed and opened again inside the step (``near_critical``).
    5. Only weak extended instabilities at both ends (the foam of finite-size phonon resonances): a change
       is ``"stability"`` when the same counts are different multipliers, or when the end with fewer has at
       most one (one closing is enough for a window: the paper's frequency branch has one 2.4e-5 wide in
       w_b between one weak quadruplet and two); other count changes are ``"count"`` (recorded as
       ``instability_count``, not examined): a window there needs several to close together, and the
       foam's windows are its own bubbles, which ``unresolved_bubbles`` states as fractions. Examining
       every count change took the paper's K branch from 203 to 1812 points.
    6. ``"krein"``: elliptic multipliers of opposite signature passed each other; else None.
    """
    if a.stable != b.stable or kinds_present(a) != kinds_present(b):
        return "stability"
    if not a.stable and persistent(a, b):
        return None if stability_signature(a) == stability_signature(b) else "count"
    if not _same_instabilities(a, b, significant=True):
        return "stability"
    if instability_set(a, significant=True):  # the same significant ones at both ends: a window needs them to close
        if near_critical(a, b):
            return "suspect"
    elif not _same_instabilities(a, b):  # only weak extended ones at both ends: the foam
        fewer = min(len(a.instabilities), len(b.instabilities))
        return "count" if stability_signature(a) != stability_signature(b) and fewer > 1 else "stability"
    if krein_crossings(a, b) != 0:
        return "krein"
    return None


def _change_word(a, b) -> str:
    if a.stable and not b.stable:
        return "lost"
    return "regained" if b.stable and not a.stable else "changed"


def stability_change_event(a, b, parameter: str) -> dict:
    pa, pb = a.value(parameter), b.value(parameter)
    unstable = b if not b.stable else a
    lead = unstable.instabilities[0] if unstable.instabilities else None
    return {
        "type": "stability_change"
        if (a.stable != b.stable or kinds_present(a) != kinds_present(b))
        else "instability_count",
        "parameter": parameter,
        "bracket": [pa, pb],
        "from_stable": bool(a.stable),
        "to_stable": bool(b.stable),
        "from": list(stability_signature(a)),
        "to": list(stability_signature(b)),
        "kinds": sorted({i.kind for i in unstable.instabilities}),
        "localized": None if lead is None else bool(lead.localized),
        "message": f"stability {_change_word(a, b)} between {parameter} = {pa:.8g} and {pb:.8g}",
    }


def krein_event(a, b, parameter: str, bisected: bool = True) -> dict:
    pa, pb = a.value(parameter), b.value(parameter)
    return {
        "type": "krein_crossing",
        "parameter": parameter,
        "bracket": [pa, pb],
        "bisected": bisected,
        "crossings": krein_crossings(a, b),
        "message": None
        if not bisected
        else f"elliptic multipliers of opposite Krein signature passed each other between {parameter} = "
        f"{pa:.8g} and {pb:.8g} with no instability seen at this resolution",
    }


def bubble_event(a, b, fraction: float, m, parameter: str, predicted=()) -> dict:
    """A solve inside the step (a, b) where ``continuation.bubbles`` predicted an instability bubble:
    what was predicted (strongest member of the group), and what the solve at its centre ``m`` found."""
    pa, pb, at = a.value(parameter), b.value(parameter), m.value(parameter)
    best = max(predicted, key=lambda x: x.modulus) if predicted else None
    confirmed = not m.stable
    return {
        "type": "bubble_probe",
        "parameter": parameter,
        "bracket": [pa, pb],
        "at": at,
        "fraction": float(fraction),
        "predicted_modulus": None if best is None else best.modulus,
        "predicted_width": None if best is None else 2.0 * best.half_width * abs(pb - pa),
        "confirmed": confirmed,
        "modulus": float(m.max_modulus),
        "message": f"predicted instability bubble at {parameter} = {at:.8g}"
        + ("" if best is None else f" (|l| ~ {best.modulus:.6f})")
        + (f": confirmed, max|l| = {m.max_modulus:.6f}" if confirmed else ": not seen there (stable)"),
    }


def foam_event(a, b, parameter: str, narrow, step: float) -> dict:
    """The bubbles predicted in the final step (a, b) that are narrower than the chase width
    (``narrow``: ``continuation.bubbles.Bubble``; ``step``: the step's length in the continuation
    coordinate, which their widths are fractions of)."""
    pa, pb = a.value(parameter), b.value(parameter)
    widest = max(narrow, key=lambda x: x.half_width)
    return {
        "type": "bubble_foam",
        "parameter": parameter,
        "bracket": [pa, pb],
        "predicted": len(narrow),
        "unstable_fraction": covered_fraction(narrow),
        "max_modulus": float(max(x.modulus for x in narrow)),
        "max_im": float(max(abs(x.mu.imag) for x in narrow)),
        "widest": float(2.0 * widest.half_width * step),
        "message": None,
    }


#: orders n of the parametric resonances w_k + w_k' = n w_b that ``parametric_orders`` looks for
PARAMETRIC_ORDERS = 6


def parametric_orders(M: float, K: float, omega: float, n_max: int = PARAMETRIC_ORDERS) -> frozenset:
    """The orders n <= n_max for which two phonons of the infinite chain can be in parametric resonance
    through the breather, w_k + w_k' = n w_b, with w_k and w_k' in the acoustic [0, top] or optical
    [bottom, top] bands: n w_b inside one of the sum sets A + A, A + O, O + O.

    That is the condition for two extended Floquet multipliers of opposite Krein signature to meet
    (e^{i w_k T} = e^{-i w_k' T}), i.e. for the finite chain's phonon-phonon bubbles (the foam) to be
    possible at all. Closed form, no solve: e.g. at w_b = 1.01, M = 30 the first order (two acoustic
    phonons at w_b / 2) opens where the acoustic top passes w_b / 2, K = 1.99827. Returns the orders as
    (n, bands) pairs, bands among "AA", "AO", "OO"."""
    e = band_edges(M, K)
    ac, op = (0.0, e["acoustic_top"]), (e["optical_bottom"], e["optical_top"])
    sums = {"AA": (2 * ac[0], 2 * ac[1]), "AO": (ac[0] + op[0], ac[1] + op[1]), "OO": (2 * op[0], 2 * op[1])}
    return frozenset((n, name) for n in range(1, n_max + 1) for name, (lo, hi) in sums.items() if lo < n * omega < hi)


def parametric_event(a, b, parameter: str, M: float) -> dict | None:
    """Where the parametric-resonance orders (``parametric_orders``) change inside the step (a, b),
    located by bisection on the straight line between the two points' (K, w_b) (closed form, no solve)."""
    oa, ob = (parametric_orders(M, p.K, p.omega) for p in (a, b))
    if oa == ob:
        return None
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        om = parametric_orders(M, a.K + mid * (b.K - a.K), a.omega + mid * (b.omega - a.omega))
        lo, hi = (mid, hi) if om == oa else (lo, mid)
    pa, pb = a.value(parameter), b.value(parameter)
    at = pa + 0.5 * (lo + hi) * (pb - pa)
    opened, closed = sorted(ob - oa), sorted(oa - ob)
    words = [f"n = {n} ({bands}) opened" for n, bands in opened] + [f"n = {n} ({bands}) closed" for n, bands in closed]
    return {
        "type": "parametric_resonance",
        "parameter": parameter,
        "bracket": [pa, pb],
        "at": at,
        "opened": [list(x) for x in opened],
        "closed": [list(x) for x in closed],
        "message": f"phonon-phonon parametric resonance w_k + w_k' = n w_b: {', '.join(words)} "
        f"at {parameter} = {at:.8g}",
    }


def weak_extended(point) -> bool:
    """Unstable only through weak instabilities of extended (phonon) Floquet vectors."""
    return point.stable is False and _weak(point) and not any(i.localized for i in point.instabilities)


def unresolved_bubbles(points, events, parameter: str) -> list:
    """Stretches of the branch where bubbles narrower than the chase width were predicted and not
    solved for: maximal runs of consecutive steps carrying a ``bubble_foam`` event, joined across steps
    whose two ends are both weakly unstable through extended vectors (the foam's own bubbles caught by
    a branch point; a stable window between two of them is as likely as in the rest of the foam). A
    stretch whose preceding step holds a ``parametric_resonance`` event that opened an order starts
    there (``onset``): phonon-phonon bubbles become possible at that parameter, and the first-order
    model, over a step that long, does not see the first of them.

    Returns a list of ``{start, end, onset, steps, predicted, unstable_fraction, max_predicted_modulus,
    max_predicted_im, widest, points, unstable_points, max_modulus}``: ``max_predicted_im`` is the largest
    predicted Im mu (NaN from events stored before it was recorded), which says how far the stretch's
    strongest bubble is above ``continuation.bubbles.FLOOR``; ``unstable_fraction`` is the share of the foam
    steps that the predicted bubbles cover (length-weighted), ``widest`` the widest predicted bubble
    (continuation coordinate), ``points``/``unstable_points`` the solved points inside the stretch.
    """
    foam = {tuple(e["bracket"]): e for e in events if e.get("type") == "bubble_foam"}
    resonances: dict = {}
    for e in events:
        if e.get("type") == "parametric_resonance":
            resonances.setdefault(tuple(e["bracket"]), []).append(e)
    if not foam or len(points) < 2:
        return []
    vals = [p.value(parameter) for p in points]
    n = len(points) - 1
    kind = [foam.get((vals[i], vals[i + 1])) for i in range(n)]
    member = [k is not None for k in kind]
    weak = [weak_extended(points[i]) and weak_extended(points[i + 1]) for i in range(n)]
    for order in (range(n), range(n - 1, -1, -1)):  # spread into weakly unstable steps next to foam
        prev = False
        for i in order:
            member[i] = member[i] or (weak[i] and prev)
            prev = member[i]
    out, i = [], 0
    while i < n:
        if not member[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and member[j + 1]:
            j += 1
        start, onset = vals[i], None
        if i > 0 and not member[i - 1]:  # the foam's first bubbles can sit before the first step that shows them
            opened = [e for e in resonances.get((vals[i - 1], vals[i]), ()) if e["opened"]]
            if opened:
                start, onset = opened[-1]["at"], opened[-1]["message"]
        recorded = [k for k in range(i, j + 1) if kind[k] is not None]  # the steps with a foam event
        found = [kind[k] for k in recorded]
        lengths = np.array([abs(vals[k + 1] - vals[k]) for k in recorded])
        fractions = np.array([e["unstable_fraction"] for e in found])
        inside = points[i : j + 2]
        out.append(
            {
                "start": start,
                "end": vals[j + 1],
                "onset": onset,
                "steps": j - i + 1,
                "predicted": int(sum(e["predicted"] for e in found)),
                "unstable_fraction": float(fractions @ lengths / lengths.sum()) if lengths.sum() > 0 else 0.0,
                "max_predicted_modulus": float(max(e["max_modulus"] for e in found)),
                "max_predicted_im": _max_im(found),
                "widest": float(max(e["widest"] for e in found)),
                "points": len(inside),
                "unstable_points": int(sum(p.stable is False for p in inside)),
                "max_modulus": float(max(p.max_modulus for p in inside)),
            }
        )
        i = j + 1
    return out


def _max_im(foam: list) -> float:
    ims = [e.get("max_im") for e in foam]
    return float(max(ims)) if all(_is_number(v) for v in ims) else float("nan")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def contact_event(prev, point, parameter: str) -> dict:
    a, b = prev.value(parameter), point.value(parameter)
    ca, cb = prev.min_contact, point.min_contact
    at = a + (b - a) * ca / (ca - cb) if ca != cb else b
    return {
        "type": "contact_lost",
        "parameter": parameter,
        "bracket": [a, b],
        "estimate": at,
        "message": f"contact lost between {parameter} = {a:.6g} and {b:.6g} (interpolated {at:.6g})",
    }


def harmonic_event(prev, point, parameter: str) -> dict | None:
    new = sorted(set(point.harmonics_in_bands) - set(prev.harmonics_in_bands))
    if not new:
        return None
    at = point.value(parameter)
    return {
        "type": "harmonic_in_band",
        "harmonics": new,
        "at": at,
        "message": f"harmonic(s) {new} of w_b = {point.omega:.6g} entered a phonon band at {parameter} = {at:.6g}",
    }


def unstable_intervals(points, parameter: str) -> list:
    """Maximal runs of unstable points as ``{start, end, kinds, localized, localized_kinds,
    max_modulus, points}``. An interval's ends are the midpoints of the brackets where stability
    changed (or the branch's end); ``localized`` is the leading unstable Floquet vector's at the most
    unstable point (participation below ``floquet.LOCALIZED_FRACTION`` N), ``localized_kinds`` the
    kinds that are localized at any point of the interval."""
    out, run = [], []

    def close(i0, run, after):
        first, last = run[0], run[-1]
        start = first.value(parameter) if i0 == 0 else 0.5 * (points[i0 - 1].value(parameter) + first.value(parameter))
        end = last.value(parameter) if after is None else 0.5 * (last.value(parameter) + after.value(parameter))
        worst = max(run, key=lambda p: p.max_modulus)
        lead = worst.instabilities[0] if worst.instabilities else None
        out.append(
            {
                "start": start,
                "end": end,
                "kinds": sorted({i.kind for p in run for i in p.instabilities}),
                "localized": None if lead is None else bool(lead.localized),
                "localized_kinds": sorted({i.kind for p in run for i in p.instabilities if i.localized}),
                "max_modulus": float(worst.max_modulus),
                "points": len(run),
            }
        )

    for i, p in enumerate(points):  # positions, not points.index: points hold arrays, and may repeat
        if p.stable is False:  # undecided points (stable None) are not unstable
            if not run:
                i0 = i
            run.append(p)
        elif run:
            close(i0, run, p)
            run = []
    if run:
        close(i0, run, None)
    return out
