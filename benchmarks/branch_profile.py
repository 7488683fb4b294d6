"""Where a branch point's time goes: the paper's frequency branch under cProfile.

Runs the frequency branch of the paper chain (M = 30, K = 160, N = 201, the scene's default settings)
to contact loss under cProfile on the given device, prints the functions with the largest own and
cumulative times, and writes OUT/branch-profile-DEVICE.txt (that table) and .json (totals).

    python benchmarks/branch_profile.py --device cuda --out results/profile
    python benchmarks/branch_profile.py --device cpu --max-points 60 --out results/profile
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import time
from pathlib import Path


from continuation.branch import continue_in_frequency
from scenarios.continuation_omega import Parameters
from warpchain import ChainParams


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--max-points", type=int, default=None)
    ap.add_argument("--top", type=int, default=35)
    ap.add_argument("--out", type=Path, default=Path("results/profile"))
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    P = Parameters()
    if args.max_points is not None:
        P = Parameters(max_points=args.max_points)
    flow = P.flow(args.device)
    params = ChainParams(P.M, P.K, P.N)
    # warm-up: compile the kernels outside the profile
    continue_in_frequency(params, None, omega_min=P.omega_min, settings=P.settings().replace(max_points=3), flow=flow)
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    br = continue_in_frequency(params, None, omega_min=P.omega_min, settings=P.settings(), flow=flow)
    prof.disable()
    wall = time.perf_counter() - t0
    text = io.StringIO()
    st = pstats.Stats(prof, stream=text)
    print(f"{len(br.points)} points in {wall:.1f} s ({wall / len(br.points):.3f} s per point); {br.message}", file=text)
    st.sort_stats("tottime").print_stats(args.top)
    st.sort_stats("cumulative").print_stats(args.top)
    name = f"branch-profile-{args.device or 'default'}"
    (args.out / f"{name}.txt").write_text(text.getvalue())
    (args.out / f"{name}.json").write_text(
        json.dumps(
            {"device": str(flow.device), "points": len(br.points), "wall_seconds": wall, "stats": br.stats}, indent=1
        )
    )
    print(text.getvalue()[:6000])


if __name__ == "__main__":
    main()
