"""Write the README's statements about the two branches from their summary.json fields.

    python benchmarks/branch_report.py results            # after python -m scenarios paper
    python benchmarks/results/compact.py unpack benchmarks/results/cpu-2core-2026-11-25b.json /tmp/cpu-ref
    python benchmarks/branch_report.py /tmp/cpu-ref   # the CPU reference's summaries

Prints Markdown bullets (stop reason, stability changes, unstable intervals with kinds and
localization, points and seconds) so that nothing in the README is typed by hand.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _load(root: Path, name: str, flat: bool) -> dict:
    path = root / f"{name}-summary.json" if flat else root / name / "summary.json"
    return json.loads(path.read_text())


def _interval(iv: dict, fmt: str) -> str:
    loc = ", ".join(iv.get("localized_kinds", [])) or "none"
    return (
        f"[{iv['start']:{fmt}}, {iv['end']:{fmt}}] ({'/'.join(k.replace('_', ' ') for k in iv['kinds'])}; "
        f"max |l| - 1 = {iv['max_modulus'] - 1:.1e}; localized: {loc})"
    )


def _bubbles(wide: list, narrow: list) -> str:
    """Bubbles of a stable stretch: the wide ones listed, the narrow ones counted with their range."""
    parts = [_interval(iv, ".6f") for iv in wide]
    if narrow:
        lo = min(min(iv["start"], iv["end"]) for iv in narrow)
        hi = max(max(iv["start"], iv["end"]) for iv in narrow)
        width = max(abs(iv["start"] - iv["end"]) for iv in narrow)
        top = max(iv["max_modulus"] - 1 for iv in narrow)
        kinds = sorted({k for iv in narrow for k in iv["kinds"]})
        parts.append(
            f"{len(narrow)} narrower bubbles between w_b = {lo:.6f} and {hi:.6f} (each < {width:.1e} wide; "
            f"{'/'.join(k.replace('_', ' ') for k in kinds)}; max |l| - 1 <= {top:.1e}; localized: "
            f"{', '.join(sorted({k for iv in narrow for k in iv.get('localized_kinds', [])})) or 'none'})"
        )
    return "; ".join(parts) if parts else "nothing"


def _unresolved(s: dict, symbol: str, fmt: str) -> str:
    """The stretches where bubbles were predicted too narrow to chase, in one sentence."""
    st = s.get("unresolved_bubbles", [])
    if not st:
        return ""
    lo = min(min(x["start"], x["end"]) for x in st)
    hi = max(max(x["start"], x["end"]) for x in st)
    span = sum(abs(x["end"] - x["start"]) for x in st)
    frac = sum(x["unstable_fraction"] * abs(x["end"] - x["start"]) for x in st) / span if span else 0.0
    big = max(st, key=lambda x: abs(x["end"] - x["start"]))
    return (
        f" Bubbles predicted narrower than the chase width were not solved for in {len(st)} stretches between "
        f"{symbol} = {lo:{fmt}} and {hi:{fmt}} ({sum(x['predicted'] for x in st)} bubbles, each < "
        f"{max(x['widest'] for x in st):.1e} wide in the continuation coordinate, predicted max |l| - 1 = "
        f"{max(x['max_predicted_modulus'] for x in st) - 1:.1e}, covering a predicted {frac:.1%} of them; the "
        f"longest [{big['start']:{fmt}}, {big['end']:{fmt}}], {big['unstable_fraction']:.1%}): there the branch "
        f"states that fraction, not a verdict."
    )


def report(root: Path, flat: bool = False) -> str:
    k = _load(root, "continuation-k", flat)
    w = _load(root, "continuation-omega", flat)
    lines = []
    ivs = k["unstable_intervals"]
    foam_k = min((min(x["start"], x["end"]) for x in k.get("unresolved_bubbles", [])), default=float("inf"))
    before = max((p["K"] for p in k["points"] if p["K"] < foam_k), default=float("nan"))
    onset = next((x.get("onset") for x in k.get("unresolved_bubbles", []) if x.get("onset")), None)
    short = [iv for iv in ivs if iv["max_modulus"] - 1 < 1e-4]
    long_ = [iv for iv in ivs if iv["max_modulus"] - 1 >= 1e-4]
    lines.append(
        f"- **Continuation in K** (`continuation-k`, N = {k['N']}): {len(k['points'])} points from K = "
        f"{k['points'][0]['K']:g} to K = {k['end_K']:g} (stop: `{k['stop_reason']}`), "
        f"E = {k['end_energy']:.8f} at the end; "
        f"{len(k['stability_changes'])} stability changes, each bracketed to the resolution "
        + f"({k['parameters']['resolution']:g} in log10 K). "
        + (
            f"Stable up to K = {foam_k:.6g}, where the first phonon-phonon parametric resonance w_k + w_k' = "
            "n w_b opens (closed form from the band edges); from there on the branch is in the stretch of "
            "unresolved bubbles below. The solved points show "
            if foam_k < ivs[0]["start"] and onset
            else f"Stable at every point up to K = {before:.4g}; the next step, to K = {foam_k:.4g}, is the last "
            "without predicted bubbles too narrow to chase (the foam below may begin inside it), "
            if foam_k < ivs[0]["start"]
            else f"Stable up to K = {ivs[0]['start']:.4g}, "
        )
        + ("" if foam_k < ivs[0]["start"] and onset else "then ")
        + f"{len(short)} narrow bubbles of weak extended quadruplets (max |l| - 1 <= "
        f"{max((iv['max_modulus'] - 1 for iv in short), default=0):.0e}) between K = "
        f"{min((iv['start'] for iv in short), default=float('nan')):.4g} and "
        f"{max((iv['end'] for iv in short), default=float('nan')):.4g}, and unstable "
        + "; ".join(_interval(iv, ".4g") for iv in long_)
        + "."
        + _unresolved(k, "K", ".4g")
    )
    wivs = w["unstable_intervals"]
    # bubbles inside the stable stretch: listed when wider than 1e-4 in w_b, else counted
    inner = wivs[:-1]
    wide_w = [iv for iv in inner if abs(iv["start"] - iv["end"]) >= 1e-4]
    narrow_w = [iv for iv in inner if abs(iv["start"] - iv["end"]) < 1e-4]
    lines.append(
        f"- **Continuation in frequency** (`continuation-omega`, N = {w['N']}): {len(w['points'])} points from "
        f"w_b = {w['omega_range'][1]:.6f} until contact is lost (stop: `{w['stop_reason']}`; "
        f"{w['message'].split(': ')[-1]}); energy monotonic in w_b across the gap: "
        f"{w['energy_monotonic_in_frequency_in_gap']}; E(w_b = 1.01) = {w['energy_at_omega_1_01']:.10f}. "
        f"{len(w['stability_changes'])} stability changes, each bracketed to the resolution. Stable from "
        f"w_b = {w['omega_range'][1]:.6f} down to {wivs[-1]['start']:.6f} except for "
        + _bubbles(wide_w, narrow_w)
        + "; unstable "
        + "; ".join(_interval(iv, ".6f") for iv in wivs[-1:])
        + "."
        + _unresolved(w, "w_b", ".6f")
    )
    for s, name in ((k, "K"), (w, "frequency")):
        st = s["branch_stats"]
        lines.append(
            f"  - {name} branch: {st['points']} points, {st['solves']} solves ({st['bisection_solves']} in "
            f"bisections, {st['failed_solves']} failed), {st['wall_seconds']:.1f} s "
            f"({st['seconds_per_point']:.2f} s per point); {s['krein_crossings_recorded']} steps with "
            f"unbisected Krein passes of phonon multipliers; {st.get('bubbles_predicted', 0)} bubbles predicted "
            f"in stable steps, {st.get('bubble_solves', 0)} solves for the "
            f"{st.get('bubbles_predicted', 0) - st.get('bubbles_below_width', 0)} wider than the chase width, "
            f"{st.get('bubbles_confirmed', 0)} confirmed."
        )
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("root", type=Path)
    ap.add_argument("--flat", action="store_true", help="NAME-summary.json files in one folder")
    args = ap.parse_args(argv)
    print(report(args.root, args.flat))


if __name__ == "__main__":
    main()
