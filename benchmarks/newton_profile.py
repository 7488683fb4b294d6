"""Where one Newton iteration of the paper breather (w_b = 1.01, K = 160, kahan8, reversible formulation,
402 unknowns) spends its time: base run (``PeriodMap.evaluate``: the Flow's linearize), the 402 tangent
columns, the Jacobian's rows and the LU solve, best of ``--repeats``, with the launches issued one by one and
then replayed as CUDA graphs (``engine.runner._Replay``, the default); then a cProfile of 10 iterations by own time.

Command (GPU): ``python benchmarks/newton_profile.py [--device cuda] [--top 25] [--blas 8,4,2]``
"""

import argparse
import cProfile
import pstats
import time

import numpy as np


from continuation.hostblas import blas_threads
from continuation.newton import solve_linear
from warpchain.engine import tuning
from continuation.shooting import PeriodMap
from scenarios._common import paper_breather


def iteration(pmap, unknowns, marks):
    t0 = time.perf_counter()
    point = pmap.evaluate(unknowns)
    t1 = time.perf_counter()
    cols = point.columns()
    t2 = time.perf_counter()
    J = point.jacobian()
    t3 = time.perf_counter()
    solve_linear(J, point.residual)
    t4 = time.perf_counter()
    for name, a, b in (("evaluate", t0, t1), ("columns", t1, t2), ("jacobian", t2, t3), ("solve", t3, t4)):
        marks.setdefault(name, []).append(b - a)
    marks.setdefault("total", []).append(t4 - t0)
    return cols


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--blas", default="", help="also time the iteration with these BLAS thread counts, e.g. 8,4,2")
    args = ap.parse_args()
    breather = paper_breather(args.device)
    columns = {}
    for after in (None, 1):  # launches issued one by one, then replayed as CUDA graphs (the default)
        with tuning.override(graph_after=after):
            pmap = PeriodMap(breather.params, breather.omega, breather.flow.replace())  # a new Flow: new buffers
            unknowns = pmap.from_state(breather.state)
            marks = {}
            for _ in range(3):
                iteration(pmap, unknowns, {})
            for _ in range(args.repeats):
                columns[after] = iteration(pmap, unknowns, marks)
        label = "launches one by one" if after is None else "replayed as graphs"
        print(f"Newton iteration, {args.device}, {label}, best / median of {args.repeats} (ms):")
        for name, values in marks.items():
            print(f"  {name:9s} {1e3 * min(values):7.3f} {1e3 * np.median(values):7.3f}")
    print("same columns both ways:", np.array_equal(columns[None], columns[1]))
    for threads in [int(t) for t in args.blas.split(",") if t]:  # the host BLAS threads, replayed launches
        with blas_threads(threads):
            marks = {}
            for _ in range(3):
                iteration(pmap, unknowns, {})
            for _ in range(args.repeats):
                iteration(pmap, unknowns, marks)
        print(f"Newton iteration, replayed, {threads} BLAS threads, best / median of {args.repeats} (ms):")
        for name, values in marks.items():
            print(f"  {name:9s} {1e3 * min(values):7.3f} {1e3 * np.median(values):7.3f}")
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(10):
        iteration(pmap, unknowns, {})
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
