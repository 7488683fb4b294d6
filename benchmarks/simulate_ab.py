"""``simulate()`` over the kernel's own rate in whichever tree Python imports, from a plain x0 and continued on the
device: run it once per tree on one machine to see what a change to the host side cost, with the kernel rows of
``benchmarks/throughput.py`` (Verlet, N = 201, 2000 steps of 0.1, the state of its simulate rows; best of
``--repeats`` after one untimed call). It passes ``keep_on_device`` as a flat keyword, so it runs on trees from
before the option objects too (e5baf0b).

Command (GPU): ``PYTHONPATH=TREE python benchmarks/simulate_ab.py LABEL [--device cuda] [--repeats 5]``, e.g. with
``git archive e5baf0b`` unpacked in /tmp/e5 and this tree in /tmp/head, alternating. Prints one line:
``LABEL batch: default continued; ...`` (each simulate() rate over the kernel's).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def arguments(argv, doc: str, *extra):
    """The command line shared with ``simulate_calls.py``: LABEL and --device (and ``extra`` (flags, options))."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("label", help="names the tree in the output line")
    parser.add_argument("--device", default="cuda")
    for flags, options in extra:
        parser.add_argument(*flags, **options)
    return parser.parse_args(argv)


def paper_state():
    """(warpchain, the paper's chain, one lattice's state: its lowest optical mode at amplitude 0.3), as
    ``throughput.py`` times ``simulate()``; keep_on_device passes as a flat keyword, on purpose."""
    warnings.simplefilter("ignore", DeprecationWarning)
    import warpchain as wc

    params = wc.ChainParams(30.0, 160.0, 201)
    _, shape = wc.lowest_optical_mode(params)
    one = np.zeros((4, params.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    return wc, params, one


def main(argv=None) -> None:
    args = arguments(
        argv,
        __doc__,
        (("--repeats",), {"type": int, "default": 5, "help": "best of, after one untimed call"}),
        (("--batches",), {"default": "805,8192,32768", "help": "comma-separated lattices per batch"}),
    )
    wc, params, one = paper_state()
    from warpchain.ensemble import time_steps

    dt, steps = 0.1, 2000
    rows = []
    for batch in (int(b) for b in args.batches.split(",")):
        x0 = np.repeat(one[None], batch, axis=0)
        kernel = time_steps(params, x0, steps, dt, device=args.device, repeats=3)
        ratios = []
        for continued in (False, True):
            start = wc.DeviceState.of(x0, device=args.device) if continued else x0
            kwargs = {"keep_on_device": True} if continued else {}
            wc.simulate(params, start, steps * dt, dt, device=args.device, **kwargs)
            best = np.inf
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                run = wc.simulate(params, start, steps * dt, dt, device=args.device, **kwargs)
                best = min(best, time.perf_counter() - t0)
                del run
            ratios.append(kernel / best)
        rows.append(f"{batch}: {ratios[0]:.3f} {ratios[1]:.3f}")
    print(args.label, "; ".join(rows), flush=True)


if __name__ == "__main__":
    main()
