"""Write the README's statements about the two branches from their summary.json fields.

    python benchmarks/branch_report.py results            # after python -m scenarios paper
    python benchmarks/branch_report.py benchmarks/h200-2026-11-22 --flat

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


def report(root: Path, flat: bool = False) -> str:
    k = _load(root, "continuation-k", flat)
    w = _load(root, "continuation-omega", flat)
    lines = []
    ivs = k["unstable_intervals"]
    short = [iv for iv in ivs if iv["max_modulus"] - 1 < 1e-4]
    long_ = [iv for iv in ivs if iv["max_modulus"] - 1 >= 1e-4]
    lines.append(
        f"- **Continuation in K** (`continuation-k`, N = {k['N']}): {len(k['points'])} points from K = "
        f"{k['points'][0]['K']:g} to K = {k['end_K']:g} (stop: `{k['stop_reason']}`), "
        f"E = {k['end_energy']:.8f} at the end; "
        f"{len(k['stability_changes'])} stability changes, each bracketed to the resolution "
        f"({k['parameters']['resolution']:g} in log10 K). Stable up to K = {ivs[0]['start']:.4g}, "
        f"then {len(short)} narrow bubbles of weak extended quadruplets (max |l| - 1 <= "
        f"{max((iv['max_modulus'] - 1 for iv in short), default=0):.0e}) between K = "
        f"{min((iv['start'] for iv in short), default=float('nan')):.4g} and "
        f"{max((iv['end'] for iv in short), default=float('nan')):.4g}, and unstable "
        + "; ".join(_interval(iv, ".4g") for iv in long_)
        + "."
    )
    wivs = w["unstable_intervals"]
    lines.append(
        f"- **Continuation in frequency** (`continuation-omega`, N = {w['N']}): {len(w['points'])} points from "
        f"w_b = {w['omega_range'][1]:.6f} until contact is lost (stop: `{w['stop_reason']}`; "
        f"{w['message'].split(': ')[-1]}); energy monotonic in w_b across the gap: "
        f"{w['energy_monotonic_in_frequency_in_gap']}; E(w_b = 1.01) = {w['energy_at_omega_1_01']:.10f}. "
        f"Stability changes at w_b in "
        + ", ".join(
            f"[{c['bracket'][1]:.6f}, {c['bracket'][0]:.6f}] ({'lost' if c['from_stable'] else 'regained'})"
            for c in w["stability_changes"]
        )
        + "; unstable "
        + "; ".join(_interval(iv, ".6f") for iv in wivs)
        + "."
    )
    for s, name in ((k, "K"), (w, "frequency")):
        st = s["branch_stats"]
        lines.append(
            f"  - {name} branch: {st['points']} points, {st['solves']} solves ({st['bisection_solves']} in "
            f"bisections, {st['failed_solves']} failed), {st['wall_seconds']:.1f} s "
            f"({st['seconds_per_point']:.2f} s per point); {s['krein_crossings_recorded']} steps with "
            f"unbisected Krein passes of phonon multipliers."
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
