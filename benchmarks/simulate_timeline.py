"""Where a sliced ``simulate()`` call spends its host time: the host-side phases of one call (uploads'
host copies, launches, the prefault of the result, waits, takes), timed by wrapping ``ensemble``'s functions,
printed as a timeline in ms from the call's start, with the kernel time (``time_steps``) beside it. Verlet,
N = 201, 2000 steps, after one untimed call.

Command (GPU): ``python benchmarks/simulate_timeline.py [--batch 32768] [--slices 8] [--chunks 1]``
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpchain import ChainParams, lowest_optical_mode, simulate  # noqa: E402
from warpchain import ensemble  # noqa: E402
from warpchain.ensemble import time_steps  # noqa: E402

EVENTS = []


def wrap(owner, name, label):
    """Record (label, start, end) of every call of owner.name."""
    original = getattr(owner, name)

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            EVENTS.append((label, t0, time.perf_counter()))

    setattr(owner, name, timed)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[32768])
    ap.add_argument("--slices", type=int, nargs="+", default=[8])
    ap.add_argument("--chunks", type=int, default=None)
    ap.add_argument("--device", default="cuda")
    args = ap.parse_args()
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    wrap(ensemble._SlicedTransfers, "upload", "upload (host copy + queue)")
    wrap(ensemble._SlicedTransfers, "take", "take (wait + host copy)")
    wrap(ensemble._Runner, "launch", "launch")
    wrap(ensemble._Runner, "guard", "guard launch")
    wrap(ensemble._Runner, "upload", "whole upload")
    wrap(ensemble._Runner, "download", "whole download")
    wrap(ensemble, "_fill_zero", "prefault fill (thread)")
    wrap(ensemble._GuardReader, "wait", "guard wait")
    for batch in args.batch:
        x0 = np.repeat(one[None], batch, 0)
        kernel = time_steps(p, x0, 2000, 0.1, device=args.device, repeats=3)
        for slices in args.slices:
            ensemble._SLICED_MIN_VALUES, ensemble._SLICES = (1, slices) if slices > 1 else (1 << 62, None)
            simulate(p, x0, 200.0, 0.1, device=args.device, chunks=args.chunks)
            best = None
            for _ in range(3):
                EVENTS.clear()
                t0 = time.perf_counter()
                simulate(p, x0, 200.0, 0.1, device=args.device, chunks=args.chunks)
                wall = time.perf_counter() - t0
                if best is None or wall < best[0]:
                    best = (wall, t0, list(EVENTS))
            wall, t0, events = best
            print(f"\n=== batch {batch}, {slices} slice(s): kernel {1e3 * kernel:.2f} ms, call {1e3 * wall:.2f} ms")
            for label, a, b in sorted(events, key=lambda e: e[1]):
                print(f"  {1e3 * (a - t0):8.3f} .. {1e3 * (b - t0):8.3f}  ({1e3 * (b - a):7.3f})  {label}")


if __name__ == "__main__":
    main()
