"""``simulate()`` without recording on a GPU: the state moved in S lattice slices (overlapped with the
kernels; a short run queued slice after slice) against the whole batch at once, beside the kernel's own time
(``time_steps``), Verlet, N = 201, 2000 steps: the data behind ``ensemble._slice_count``,
``_SLICED_MIN_VALUES`` and the two chunks of a short sliced run. Best of ``--repeats`` calls after one untimed
call; ``stats`` of the best call (ms); each variant's end state against the first's, bit for bit.

Variants: ``whole``: no slices, the default chunk count (from the work, at most 10); ``whole, 2 chunks``;
``S slices``: S slices, two chunks; ``S slices, 1 chunk`` (``--one-chunk S``); ``S slices, no prefault``
(``--no-prefault S``): the final state's host array not touched in advance; ``auto``: what ``simulate`` does
(the final state in page-locked memory lent by ``leases``); ``auto, plain results``: the same with
``ensemble._LEASE_RESULTS`` off (a fresh pageable result, touched in advance, as before the leases);
``auto, x0 page-locked``: x0 given as ``page_locked(x0)`` (as a continued run passes a lent result).
``--record K``: also ``simulate(save_every=K)``, lent frames against plain ones, with the frames' rate.

Command (GPU): ``python benchmarks/simulate_slices.py [--batch 805 8192 32768] [--slices 2 4 8 16]
[--one-chunk 4 8] [--no-prefault 8] [--record 20]``
"""

import argparse
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
    ap.add_argument("--batch", type=int, nargs="+", default=[805, 2048, 8192, 32768])
    ap.add_argument("--slices", type=int, nargs="+", default=[2, 4, 8, 16])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--one-chunk", type=int, nargs="*", default=[], help="also: these slice counts in one chunk")
    ap.add_argument("--no-prefault", type=int, nargs="*", default=[], help="also: these slice counts, no prefault")
    ap.add_argument("--copy-slice", type=int, nargs="*", default=[], help="also: auto, values per copy thread")
    ap.add_argument("--record", type=int, default=None, help="also: save_every=K, lent and plain frames")
    args = ap.parse_args()
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    dt = 0.1
    defaults = (ensemble._SLICED_MIN_VALUES, ensemble._SLICES)
    variants = [("whole", 1 << 62, None, None), ("whole, 2 chunks", 1 << 62, None, 2)]
    variants += [(f"{s} slices", 1, s, None) for s in args.slices]
    variants += [(f"{s} slices, 1 chunk", 1, s, 1) for s in args.one_chunk]
    variants += [(f"{s} slices, no prefault", 1, s, None, None, False) for s in args.no_prefault]
    variants += [("auto", *defaults, None)]
    variants += [("auto, plain results", *defaults, None, None, True, False)]
    variants += [("auto, x0 page-locked", *defaults, None, None, True, True, True)]
    variants += [(f"auto, copy {c}", *defaults, None, c) for c in args.copy_slice]
    copy_slice, prefault = ensemble._COPY_SLICE, ensemble._PREFAULT_MIN_VALUES
    print(f"# {args.steps} Verlet steps, N = {p.N}; best of {args.repeats}; ratio = kernel / simulate()", flush=True)
    for batch in args.batch:
        x0 = np.repeat(one[None], batch, 0)
        kernel = time_steps(p, x0, args.steps, dt, device=args.device, repeats=3)
        print(f"\nbatch {batch}: kernel {1e3 * kernel:.3f} ms", flush=True)
        first = None  # the first variant's end state: every other must have the same bits
        runs = [(name, min_values, slices, chunks, *copy, None) for name, min_values, slices, chunks, *copy in variants]
        if args.record:
            runs += [("auto, record", *defaults, None, None, True, True, False, args.record)]
            runs += [("auto, record, plain", *defaults, None, None, True, False, False, args.record)]
        for name, min_values, slices, chunks, *copy, record in runs:
            ensemble._SLICED_MIN_VALUES, ensemble._SLICES = min_values, slices
            ensemble._COPY_SLICE = copy[0] if copy and copy[0] else copy_slice
            ensemble._PREFAULT_MIN_VALUES = prefault if len(copy) < 2 or copy[1] else 1 << 62
            ensemble._LEASE_RESULTS = len(copy) < 3 or copy[2]
            start = page_locked(x0, device=args.device) if len(copy) > 3 and copy[3] else x0
            kw = dict(device=args.device, chunks=chunks, save_every=record)
            simulate(p, start, args.steps * dt, dt, **kw)
            walls, stats = [], []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                run = simulate(p, start, args.steps * dt, dt, **kw)
                walls.append(time.perf_counter() - t0)
                stats.append(run.stats)
            best = int(np.argmin(walls))
            first = run.x if first is None else first
            same = "same bits" if np.array_equal(run.x, first) else f"DIFFERS by {np.max(np.abs(run.x - first)):.3g}"
            st = {k: round(1e3 * v, 3) if isinstance(v, float) else v for k, v in stats[best].items()}
            lent = "lent" if ensemble._pinned_view(run.x) is not None else "plain"
            rate = f", frames {2 * run.u.nbytes / walls[best] / 1e9:.1f} GB/s" if record else ""
            print(
                f"  {name:21s} best {1e3 * walls[best]:8.3f} ms ({kernel / walls[best]:.2f}x kernel{rate}), "
                f"median {1e3 * np.median(walls):8.3f} ms; {same}; x {lent}; stats {st}",
                flush=True,
            )
            del run, start
        ensemble._SLICED_MIN_VALUES, ensemble._SLICES = defaults
        ensemble._LEASE_RESULTS = True
        ensemble._COPY_SLICE, ensemble._PREFAULT_MIN_VALUES = copy_slice, prefault


if __name__ == "__main__":
    main()
