"""The Floquet window (``floquet(solver="window")``) against the dense analysis at every point of a stored branch.

Each point of a ``continuation-k`` or ``continuation-omega`` store (every ``--every``-th) is solved again from its
stored state (Newton with the branch's integrator: 0 or 1 iteration) and analysed both ways on the CPU. Per point:
the dense verdict, the window's, the dense instabilities inside the window's covered intervals (or beyond them)
and those outside it (which a window cannot see, by construction), and the largest difference between a mu the
window reports and the nearest dense one. A point where the verdicts differ is a miss; the report says whether
each miss is an instability outside the window (what the window says it cannot see) or inside it (a fault).

Command: ``python benchmarks/window_along_branch.py STORE [--group branch] [--every 1] [--json FILE]``
(2-core CPU, N = 801: ~2.5 s a point).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import continuation as ct
from continuation.branch_store import load_branch
from warpchain import Flow


def inside(mu: complex, covered) -> bool:
    """Whether mu's real part lies in one of the window's covered intervals or beyond the outer ends."""
    (minus_outer, minus_inner), (plus_inner, plus_outer) = covered
    return mu.real <= minus_inner or mu.real >= plus_inner


def check_point(params, point, flow) -> dict:
    b = ct.require(ct.find_breather(params.replace(K=point.K), point.omega, point.state, flow=flow))
    t0 = time.perf_counter()
    dense = ct.floquet(b, solver="dense")
    t1 = time.perf_counter()
    window = ct.floquet(b, solver="window")
    t2 = time.perf_counter()
    covered = window.coverage["covered"]
    seen = [i for i in dense.instabilities if inside(i.mu, covered)]
    unseen = [i for i in dense.instabilities if not inside(i.mu, covered)]
    gap = max((float(np.min(np.abs(dense.mu - m))) for m in window.mu), default=0.0)
    return {
        "K": point.K,
        "omega": point.omega,
        "dense_stable": bool(dense.stable),
        "window_stable": bool(window.partial_stable),  # what the window saw: it gives no verdict
        "dense_kinds_in_window": sorted(i.kind for i in seen),
        "window_kinds": sorted(i.kind for i in window.instabilities),
        "unseen": [{"kind": i.kind, "mu": [i.mu.real, i.mu.imag], "modulus": i.modulus} for i in unseen],
        "largest_mu_difference": gap,
        "window_mu": len(window.mu),
        "covered": covered,
        "dense_seconds": t1 - t0,
        "window_seconds": t2 - t1,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("store")
    ap.add_argument("--group", default="branch")
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    params, points, attrs = load_branch(args.store, args.group)
    flow = Flow(method=attrs.get("method", "kahan8"), steps_per_period=attrs.get("steps_per_period", 32), device="cpu")
    rows = []
    for k, point in enumerate(points[:: args.every]):
        row = check_point(params, point, flow)
        rows.append(row)
        if row["dense_stable"] != row["window_stable"] or row["dense_kinds_in_window"] != row["window_kinds"]:
            print(f"point {k * args.every}: K = {row['K']:.8g}, w = {row['omega']:.8g}: {json.dumps(row)[:400]}")
    same = [r["dense_stable"] == r["window_stable"] for r in rows]
    misses = [r for r, s in zip(rows, same) if not s]
    unseen_misses = [r for r in misses if r["unseen"] and not r["dense_kinds_in_window"]]
    inside_faults = [r for r in rows if r["dense_kinds_in_window"] != r["window_kinds"]]
    summary = {
        "store": args.store,
        "N": params.N,
        "points_checked": len(rows),
        "same_verdict": int(sum(same)),
        "misses": len(misses),
        "misses_outside_the_window": len(unseen_misses),
        "instabilities_inside_the_window_that_differ": len(inside_faults),
        "largest_mu_difference": max((r["largest_mu_difference"] for r in rows), default=0.0),
        "unseen_kinds": sorted({u["kind"] for r in rows for u in r["unseen"]}),
        "largest_unseen_modulus": max((u["modulus"] for r in rows for u in r["unseen"]), default=None),
        "dense_seconds_median": float(np.median([r["dense_seconds"] for r in rows])) if rows else None,
        "window_seconds_median": float(np.median([r["window_seconds"] for r in rows])) if rows else None,
    }
    print(json.dumps(summary, indent=1))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"summary": summary, "points": rows}, fh, indent=1)


if __name__ == "__main__":
    main()
