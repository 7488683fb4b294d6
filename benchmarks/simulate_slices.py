"""``simulate()`` without recording on a GPU: the state moved in S lattice slices (overlapped with the
kernels; a short run queued slice after slice) against the whole batch at once, beside the kernel's own time
(``time_steps``), Verlet, N = 201, 2000 steps: the data behind ``ensemble._slice_bounds``,
``_SLICED_MIN_VALUES`` and the two chunks of a short sliced run. Best of ``--repeats`` calls after one untimed
call; ``stats`` of the best call (ms); each variant's end state against the first's, bit for bit.

Variants: ``whole``: no slices, the default chunk count (from the work, at most 10); ``whole, 2 chunks``;
``S slices``: S slices, two chunks; ``S slices, 1 chunk`` (``--one-chunk S``); ``S slices, no prefault``
(``--no-prefault S``): the final state's host array not touched in advance; ``auto``: what ``simulate`` does
(the final state in page-locked memory lent by ``leases``); ``auto, plain results``: the same with
``ensemble._LEASE_RESULTS`` off (a fresh pageable result, touched in advance, as before the leases);
``auto, x0 page-locked``: x0 given as ``page_locked(x0)`` (as a continued run passes a lent result);
``on the device``: x0 a ``DeviceState`` and ``keep_on_device=True`` (a run continued on the device);
``auto, driver's pageable upload``: a whole-batch x0 copied by the driver from pageable memory
(``_UPLOAD_PAGEABLE``), not through our pinned staging buffer.
``--record K``: also ``simulate(save_every=K)``, lent frames against plain ones, with the frames' rate.
``--ends F``: also ``auto`` with ``ensemble._SLICED_ENDS = F`` (sliced first and last chunks of F of the run
each, the middle on the whole batch), with x0 plain and page-locked.

Command (GPU): ``python benchmarks/simulate_slices.py [--batch 805 8192 32768] [--slices 2 4 8 16]
[--one-chunk 4 8] [--no-prefault 8] [--record 20] [--ends 0.125 0.25]
[--record 20 --pool-gib 24]``
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpchain import ChainParams, DeviceState, lowest_optical_mode, page_locked, simulate  # noqa: E402
from warpchain import ensemble, leases  # noqa: E402
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
    ap.add_argument("--ends", type=float, nargs="*", default=[], help="also: auto with these _SLICED_ENDS")
    ap.add_argument("--pool-gib", type=float, default=None, help="with --record: also lent frames, pool limit G GiB")
    args = ap.parse_args()
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    dt = 0.1
    whole, sliced = dict(_SLICED_MIN_VALUES=1 << 62, _SLICES=None), lambda n: dict(_SLICED_MIN_VALUES=1, _SLICES=n)
    # (name, ensemble attributes to set, simulate keywords, x0: False plain, True page-locked, "device")
    variants = [("whole", whole, {}, False), ("whole, 2 chunks", whole, dict(chunks=2), False)]
    variants += [(f"{n} slices", sliced(n), {}, False) for n in args.slices]
    variants += [(f"{n} slices, 1 chunk", sliced(n), dict(chunks=1), False) for n in args.one_chunk]
    no_prefault = dict(_PREFAULT_MIN_VALUES=1 << 62, _LEASE_RESULTS=False)
    variants += [(f"{n} slices, no prefault", {**sliced(n), **no_prefault}, {}, False) for n in args.no_prefault]
    variants += [("auto", {}, {}, False), ("auto, plain results", dict(_LEASE_RESULTS=False), {}, False)]
    variants += [("auto, x0 page-locked", {}, {}, True)]
    variants += [("on the device", {}, dict(keep_on_device=True), "device")]
    variants += [("auto, driver's pageable upload", dict(_UPLOAD_PAGEABLE=True), {}, False)]
    for f in args.ends:
        variants += [(f"auto, ends {f:g}", dict(_SLICED_ENDS=f), {}, False)]
        variants += [(f"auto, ends {f:g}, x0 page-locked", dict(_SLICED_ENDS=f), {}, True)]
    variants += [(f"auto, copy {c}", dict(_COPY_SLICE=c), {}, False) for c in args.copy_slice]
    if args.record:
        record = dict(save_every=args.record)
        variants += [
            ("auto, record", {}, record, False),
            ("auto, record, plain", dict(_LEASE_RESULTS=False), record, False),
        ]
        if args.pool_gib:
            pool = dict(LIMIT_BYTES=int(args.pool_gib * (1 << 30)))
            variants += [(f"auto, record, pool {args.pool_gib:g} GiB", pool, record, False)]
    names = {name for _, settings, _, _ in variants for name in settings}
    owner = lambda name: leases if name == "LIMIT_BYTES" else ensemble  # noqa: E731
    defaults = {name: getattr(owner(name), name) for name in names}
    print(f"# {args.steps} Verlet steps, N = {p.N}; best of {args.repeats}; ratio = kernel / simulate()", flush=True)
    for batch in args.batch:
        x0 = np.repeat(one[None], batch, 0)
        kernel = time_steps(p, x0, args.steps, dt, device=args.device, repeats=3)
        print(f"\nbatch {batch}: kernel {1e3 * kernel:.3f} ms", flush=True)
        first = None  # the first variant's end state: every other must have the same bits
        for name, settings, keywords, locked in variants:
            for attr, value in {**defaults, **settings}.items():
                setattr(owner(attr), attr, value)
            start = page_locked(x0, device=args.device) if locked else x0
            if locked == "device":
                start = DeviceState.of(x0, device=args.device)
            kw = dict(device=args.device, **keywords)
            simulate(p, start, args.steps * dt, dt, **kw)
            walls, stats = [], []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                run = simulate(p, start, args.steps * dt, dt, **kw)
                walls.append(time.perf_counter() - t0)
                stats.append(run.stats)
            best = int(np.argmin(walls))
            x = np.asarray(run.x)  # a DeviceState's host copy, outside the timed calls
            first = x if first is None else first
            same = "same bits" if np.array_equal(x, first) else f"DIFFERS by {np.max(np.abs(x - first)):.3g}"
            st = {k: round(1e3 * v, 3) if isinstance(v, float) else v for k, v in stats[best].items()}
            lent = "on the device" if isinstance(run.x, DeviceState) else "plain"
            lent = "lent" if lent == "plain" and ensemble._pinned_view(run.x) is not None else lent
            rate = f", frames {2 * run.u.nbytes / walls[best] / 1e9:.1f} GB/s" if run.u is not None else ""
            print(
                f"  {name:32s} best {1e3 * walls[best]:8.3f} ms ({kernel / walls[best]:.2f}x kernel{rate}), "
                f"median {1e3 * np.median(walls):8.3f} ms; {same}; x {lent}; stats {st}",
                flush=True,
            )
            del run, start
        for attr, value in defaults.items():
            setattr(owner(attr), attr, value)


if __name__ == "__main__":
    main()
