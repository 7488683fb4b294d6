"""Where a sliced ``simulate()`` call spends its host time: the host-side phases of one call (uploads'
host copies, launches, the prefault of the result, waits, takes), timed by wrapping ``ensemble``'s functions,
printed as a timeline in ms from the call's start, with the kernel time (``time_steps``) beside it. Verlet,
N = 201, 2000 steps, after one untimed call. With ``--device-events`` the device's side too: CUDA events
recorded around every launch (main stream) and every slice transfer (its own stream), in ms from an event
recorded just before the call, marked ``[device]``.

Command (GPU): ``python benchmarks/simulate_timeline.py [--batch 32768] [--slices 0 8] [--chunks 1]
[--page-locked | --on-device] [--device-events] [--detail]``

``--on-device``: x0 a ``DeviceState`` and ``keep_on_device=True`` (a run continued on the device: no transfer).
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

EVENTS = []
DEVICE_EVENTS = []  # (label, CUDA event before, CUDA event after)


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


def wrap_device(owner, name, label, stream_of):
    """Record CUDA events before and after every call of owner.name on the stream ``stream_of(self)``."""
    import warp as wp

    original = getattr(owner, name)

    def timed(self, *args, **kwargs):
        stream = stream_of(self)
        before = wp.Event(enable_timing=True)
        stream.record_event(before)
        try:
            return original(self, *args, **kwargs)
        finally:
            after = wp.Event(enable_timing=True)
            stream.record_event(after)
            DEVICE_EVENTS.append((label, before, after))

    setattr(owner, name, timed)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[32768])
    ap.add_argument("--slices", type=int, nargs="+", default=[0], help="0: simulate's own slices; 1: whole")
    ap.add_argument("--chunks", type=int, default=None)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--page-locked", action="store_true", help="x0 given as page_locked(x0)")
    ap.add_argument("--on-device", action="store_true", help="x0 a DeviceState, keep_on_device=True")
    ap.add_argument("--device-events", action="store_true", help="also CUDA events around launches, transfers")
    ap.add_argument("--detail", action="store_true", help="also every host copy (_copy) and wp.copy call")
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
    wrap(ensemble._Runner, "enqueue_download", "final copy (queue)")
    wrap(ensemble, "_fill_zero", "prefault fill (thread)")
    wrap(ensemble._GuardReader, "wait", "guard wait")
    if args.detail:
        import warp

        wrap(ensemble, "_copy", "  host copy (_copy)")
        wrap(warp, "copy", "  wp.copy (queue)")
        for owner, name in [
            (ensemble, "_as_state"),
            (ensemble, "per_lattice_parameters"),
            (ensemble, "_check_step"),
            (ensemble, "_pooled_runner"),
            (ensemble._Runner, "set_damping"),
            (leases, "lend"),
            (ensemble._GuardReader, "__init__"),
            (ensemble._SlicedTransfers, "__init__"),
        ]:
            wrap(owner, name, f"  set-up: {getattr(owner, '__name__', '')}.{name}")
    if args.device_events:
        import warp as wp

        main_stream = lambda self: wp.get_stream(args.device)  # noqa: E731
        wrap_device(ensemble._Runner, "launch", "kernel", main_stream)
        wrap_device(ensemble._Runner, "guard", "guard kernel", main_stream)
        wrap_device(ensemble._SlicedTransfers, "upload", "slice upload", lambda self: self.up_stream)
        wrap_device(ensemble._SlicedTransfers, "download", "slice download", lambda self: self.down_stream)
    defaults = ensemble._SLICED_MIN_VALUES, ensemble._SLICES
    for batch in args.batch:
        x0 = np.repeat(one[None], batch, 0)
        kernel = time_steps(p, x0, 2000, 0.1, device=args.device, repeats=3)
        if args.page_locked:
            x0 = page_locked(x0, device=args.device)
        if args.on_device:
            x0 = DeviceState.of(x0, device=args.device)
        kw = dict(device=args.device, chunks=args.chunks, keep_on_device=args.on_device)
        for slices in args.slices:
            ensemble._SLICED_MIN_VALUES, ensemble._SLICES = defaults
            if slices:  # 1: the whole batch at once; S > 1: S equal slices
                ensemble._SLICED_MIN_VALUES, ensemble._SLICES = (1, slices) if slices > 1 else (1 << 62, None)
            simulate(p, x0, 200.0, 0.1, **kw)
            best = None
            for _ in range(3):
                EVENTS.clear()
                DEVICE_EVENTS.clear()
                origin = None
                if args.device_events:
                    origin = wp.Event(enable_timing=True)
                    wp.get_stream(args.device).record_event(origin)
                t0 = time.perf_counter()
                run = simulate(p, x0, 200.0, 0.1, **kw)
                wall = time.perf_counter() - t0
                device_rows = []
                if origin is not None:
                    wp.synchronize_device(args.device)
                    for label, a, b in DEVICE_EVENTS:
                        start = wp.get_event_elapsed_time(origin, a) * 1e-3
                        device_rows.append((f"[device] {label}", start, start + wp.get_event_elapsed_time(a, b) * 1e-3))
                if best is None or wall < best[0]:
                    lent = "lent" if run.stats.get("lent") else "plain"
                    best = (wall, t0, [(label, a - t0, b - t0) for label, a, b in EVENTS] + device_rows, lent)
                del run
            wall, t0, events, lent = best
            start = "on the device" if args.on_device else "page-locked" if args.page_locked else "plain"
            print(
                f"\n=== batch {batch}, {slices or 'auto'} slice(s): kernel {1e3 * kernel:.2f} ms, "
                f"call {1e3 * wall:.2f} ms (x0 {start}, result {'on the device' if args.on_device else lent})"
            )
            for label, a, b in sorted(events, key=lambda e: e[1]):
                print(f"  {1e3 * a:8.3f} .. {1e3 * b:8.3f}  ({1e3 * (b - a):7.3f})  {label}")


if __name__ == "__main__":
    main()
