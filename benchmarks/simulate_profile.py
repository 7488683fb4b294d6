"""Where ``simulate()``'s wall time goes beyond the kernel: cProfile of default calls (Verlet, N = 201,
2000 steps) at 805 and 32768 lattices, after one untimed call, with the kernel time (``time_steps``) and a
timeline of the call's phases beside it. Prints the top functions by cumulative and by own time.

Command (GPU): ``python benchmarks/simulate_profile.py [--batch 805 32768] [--save-every 20] [--slices S]
[--page-locked]``
"""

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpchain import ChainParams, lowest_optical_mode, page_locked, simulate  # noqa: E402
from warpchain import ensemble  # noqa: E402
from warpchain.ensemble import time_steps  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[805, 32768])
    ap.add_argument("--save-every", type=int, default=None)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--slices", type=int, default=None, help="force this many lattice slices (the sliced path)")
    ap.add_argument("--page-locked", action="store_true", help="x0 given as page_locked(x0)")
    args = ap.parse_args()
    if args.slices is not None:
        ensemble._SLICED_MIN_VALUES, ensemble._SLICES = 1, args.slices
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    for batch in args.batch:
        x0 = np.repeat(one[None], batch, 0)
        if args.page_locked:
            x0 = page_locked(x0, device=args.device)
        kernel = time_steps(p, x0, 2000, 0.1, device=args.device, repeats=3)
        simulate(p, x0, 200.0, 0.1, device=args.device, save_every=args.save_every)
        walls, stats = [], []
        for _ in range(3):
            t0 = time.perf_counter()
            run = simulate(p, x0, 200.0, 0.1, device=args.device, save_every=args.save_every)
            walls.append(time.perf_counter() - t0)
            stats.append({k: round(1e3 * v, 3) if isinstance(v, float) else v for k, v in run.stats.items()})
            del run
        print(
            f"\n=== batch {batch}: kernel {1e3 * kernel:.2f} ms, simulate best {1e3 * min(walls):.2f} ms "
            f"({kernel / min(walls):.2f}x), all {[round(1e3 * w, 2) for w in walls]}",
            flush=True,
        )
        for st in stats:
            print("stats (ms):", st)
        prof = cProfile.Profile()
        prof.enable()
        for _ in range(5):
            simulate(p, x0, 200.0, 0.1, device=args.device, save_every=args.save_every)
        prof.disable()
        stats = pstats.Stats(prof)
        stats.sort_stats("cumulative").print_stats(args.top)
        stats.sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
