"""Branch vs dense fixed-step scan: does the continuation see every stability change?

Runs a branch (K or frequency) of the paper chain with the default continuation settings, then a
dense scan at fixed parameter steps inside the given windows (fixed-parameter Newton from the
nearest branch point, reduced Floquet), and reports every scan point whose verdict disagrees with
the branch's (the verdict between two branch points is theirs when they agree; scan points inside a
located bracket are skipped as undecided at the branch's resolution). Inside a stretch of unresolved
bubbles (``Branch.unresolved_bubbles``: bubbles predicted narrower than the chase width) the branch
states a predicted unstable fraction instead of a verdict: the scan's unstable fraction there is
reported beside it, per stretch, and those points are not counted as disagreements.

    python benchmarks/branch_check.py omega --window 1.0125 1.0166 --step 1e-4 --out results/check
    python benchmarks/branch_check.py K --window 1.9 4.2 --step 2e-3 --out results/check

Writes OUT/check-PARAM.json with the branch's stats, its stability changes and the disagreements.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


import continuation as ct
from continuation.branch import continue_in_coupling, continue_in_frequency
from warpchain import ChainParams, Flow
from warpchain.store import jsonable


def in_foam(foam, value):
    """The index of the unresolved-bubble stretch (``Branch.unresolved_bubbles``) holding ``value``, or None."""
    for k, st in enumerate(foam):
        if min(st["start"], st["end"]) <= value <= max(st["start"], st["end"]):
            return k
    return None


def branch_verdict(points, par, value):
    """The branch's verdict at ``value``: True/False, or None inside a bracket where it changes."""
    vals = np.array([getattr(p, par) for p in points])
    out = []
    for i in range(len(points) - 1):
        lo, hi = sorted((vals[i], vals[i + 1]))
        if lo <= value <= hi:
            a, b = points[i], points[i + 1]
            out.append(a.stable if a.stable == b.stable else None)
    if not out:
        return "outside"
    return out[0] if all(o == out[0] for o in out) else None


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("parameter", choices=["K", "omega"])
    ap.add_argument("--window", nargs=2, type=float, action="append", default=[])
    ap.add_argument("--step", type=float, default=1e-4)
    ap.add_argument("--N", type=int, default=201)
    ap.add_argument("--device", default=None)
    ap.add_argument("--resolution", type=float, default=None)
    ap.add_argument("--out", type=Path, default=Path("results/check"))
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    flow = Flow("kahan8", 32, args.device)
    t0 = time.perf_counter()

    def log(m):
        print(f"{time.perf_counter() - t0:8.1f} {m}", flush=True)

    if args.parameter == "K":
        p = ChainParams(30.0, 0.01, args.N)
        settings = ct.driver.ContinuationSettings(ds=0.15, ds_min=1e-4, ds_max=0.3, resolution=args.resolution or 1e-3)
        br = continue_in_coupling(
            p, 1.01, ct.anticontinuum_seed(p, 1.01), 160.0, targets=(5.0, 20.0), flow=flow, settings=settings, log=log
        )
    else:
        p = ChainParams(30.0, 160.0, args.N)
        settings = ct.driver.ContinuationSettings(
            ds=0.05, ds_min=1e-4, ds_max=0.6, grow=1.3, resolution=args.resolution or 1e-3
        )
        br = continue_in_frequency(p, None, omega_min=0.8, flow=flow, settings=settings, log=log)
    branch_seconds = time.perf_counter() - t0
    log(f"branch: {br.message}; {br.stats}")
    par = args.parameter
    disagreements, scanned, scan = [], 0, []
    vals = np.array([getattr(q, par) for q in br.points])
    foam = br.unresolved_bubbles()
    foam_scan = [{"scanned": 0, "unstable": 0} for _ in foam]
    for lo, hi in args.window:
        for value in np.arange(lo, hi + 0.5 * args.step, args.step):
            verdict = branch_verdict(br.points, par, value)
            stretch = in_foam(foam, value)
            if verdict == "outside" or (verdict is None and stretch is None):
                continue
            near = br.points[int(np.argmin(np.abs(vals - value)))]
            pr = p.replace(K=float(value)) if par == "K" else p
            w = 1.01 if par == "K" else float(value)
            res = ct.find_breather(pr, w, near.state, flow=flow)
            if not res.success:
                disagreements.append({"value": float(value), "problem": "newton failed"})
                continue
            fl = ct.floquet(res)
            scanned += 1
            scan.append({"value": float(value), "stable": fl.stable, "max_modulus": fl.max_modulus})
            if stretch is not None:
                foam_scan[stretch]["scanned"] += 1
                foam_scan[stretch]["unstable"] += int(not fl.stable)
                continue
            if fl.stable != verdict:
                disagreements.append(
                    {
                        "value": float(value),
                        "scan_stable": fl.stable,
                        "branch_stable": verdict,
                        "scan_max_modulus": fl.max_modulus,
                    }
                )
                log(f"DISAGREE at {par} = {value:.6f}: scan {fl.stable}, branch {verdict}")
    out = {
        "parameter": par,
        "N": args.N,
        "device": str(args.device),
        "branch_seconds": branch_seconds,
        "stop_reason": br.stop_reason.value,
        "message": br.message,
        "stats": br.stats,
        "stability_changes": br.stability_changes(),
        "unstable_intervals": br.unstable_intervals(),
        "krein_crossings": sum(1 for e in br.events if e["type"] == "krein_crossing"),
        "scan_step": args.step,
        "windows": args.window,
        "scanned": scanned,
        "disagreements": disagreements,
        "unresolved_bubbles": [dict(st, scan=sc) for st, sc in zip(foam, foam_scan)],
        "foam_steps": [
            {k: e[k] for k in ("bracket", "predicted", "unstable_fraction", "max_modulus", "widest")}
            for e in br.events
            if e["type"] == "bubble_foam"
        ],
        "scan": scan,
        "points": [{par: getattr(q, par), "stable": q.stable, "max_modulus": q.max_modulus} for q in br.points],
        "scan_seconds": time.perf_counter() - t0 - branch_seconds,
    }
    (args.out / f"check-{par}.json").write_text(json.dumps(jsonable(out), indent=1))
    log(f"scan: {scanned} points, {len(disagreements)} disagreements outside unresolved-bubble stretches")
    for st, sc in zip(foam, foam_scan):
        if sc["scanned"]:
            log(
                f"  unresolved bubbles in [{st['start']:.6g}, {st['end']:.6g}]: {st['predicted']} predicted, "
                f"predicted unstable fraction {st['unstable_fraction']:.3f}; scan {sc['unstable']} of "
                f"{sc['scanned']} unstable ({sc['unstable'] / sc['scanned']:.3f})"
            )


if __name__ == "__main__":
    main()
