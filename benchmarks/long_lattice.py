"""One long lattice on each kernel layout, in one run: the base run and tangent columns over half a period.

The paper breather's NLS seed (w_b = 1.01, K = 160, M = 30, kahan8, 32 steps per period) at each N:
``Flow.linearize`` over half a period (the base run, recording f'(z)), then ``Linearization.columns`` with 1,
8 and 64 random directions, and the 2N position columns (``unit_columns``) up to ``--unit-max``; best of
``--repeat`` after an untimed call (compilation, graph capture). Layouts: ``auto`` (on a GPU: ``block`` up to
1024 sites, ``sites`` beyond) and ``thread`` (one thread per lattice: what long lattices ran on before the
sites layout). The columns of the two layouts are compared (largest difference relative to the largest
entry). Where the issue's table came from (#36: 120 ms per column at N = 3201 on an H100).

Command: ``python benchmarks/long_lattice.py --device cuda [--sizes 201 3201 12801] [--json FILE]``.
"""

import argparse
import json
import time

import numpy as np

import continuation as ct
import warpchain as wc
from warpchain.flow import Flow


def best(fn, repeat):
    fn()  # untimed: compilation, the graph's capture
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--sizes", type=int, nargs="+", default=[201, 3201, 12801])
    ap.add_argument("--layouts", nargs="+", default=["auto", "thread"])
    ap.add_argument("--thread-max", type=int, default=12801, help="largest N timed on the thread layout")
    ap.add_argument("--unit-max", type=int, default=3201, help="largest N whose 2N position columns are timed")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = []
    for N in args.sizes:
        p = wc.ChainParams(30.0, 160.0, N)
        x0 = ct.nls_seed(p, 1.01)
        rng = np.random.default_rng(0)
        directions = {c: rng.normal(size=(c, 4, N)) for c in (1, 8, 64)}
        results = {}
        for layout in args.layouts:
            if layout == "thread" and N > args.thread_max:
                continue
            flow = Flow("kahan8", 32, device=args.device, layout=layout)
            nsteps, dt = flow.grid(1.01)
            t_base, lin = best(lambda: flow.linearize(p, x0, nsteps, dt), args.repeat)
            row = {"N": N, "layout": layout, "base_seconds": t_base}
            runner = next(iter(flow._pool.values()))["runners"][0]
            row["ran_on"] = runner.layout
            for c, d in directions.items():
                t, cols = best(lambda d=d: lin.columns(d), args.repeat)
                row[f"columns_{c}_seconds"] = t
                results.setdefault(c, {})[layout] = cols
            if N <= args.unit_max:
                t0 = time.perf_counter()
                lin.unit_columns("positions")
                row["position_columns_seconds_first_call"] = time.perf_counter() - t0
            rows.append(row)
            print(json.dumps(row), flush=True)
        if len(results.get(64, {})) == 2:
            a, b = results[64].values()
            diff = float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
            rows.append({"N": N, "columns_64_relative_difference_between_layouts": diff})
            print(json.dumps(rows[-1]), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"device": args.device, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    main()
