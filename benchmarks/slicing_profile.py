"""Where the sliced Floquet path's time goes: the paper breather's ``sliced_floquet`` twice (the first starts the
worker processes), with the probe, slices and count seconds, the slices' wall time against the sum of the tasks'
own seconds (how well the workers were used), and the slowest segments.

Command: ``python benchmarks/slicing_profile.py [--device cpu] [--sizes 1601 3201]``.
"""

import argparse
import os
import time

import continuation as ct
import warpchain as wc
from continuation import slicing, workers
from continuation.floquet import linear_mu


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1601, 3201])
    args = ap.parse_args()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"cores {cores}, workers {min(workers.PROCESS_COUNT, cores)}", flush=True)
    seen = {}
    plain = workers.Workers.map

    def map_(self, module, tasks, what="task"):
        start = time.perf_counter()
        out = plain(self, module, tasks, what=what)
        seen.update(wall=time.perf_counter() - start, tasks=tasks, reports=out)
        return out

    workers.Workers.map = map_
    for N in args.sizes:
        p = wc.ChainParams(30.0, 160.0, N)
        b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), device=args.device))
        lin = b.linearization()
        for _ in range(2):
            start = time.perf_counter()
            fl = slicing.sliced_floquet(lin, p.M, b.state, hint=linear_mu(p, lin), processes=True)
            total = time.perf_counter() - start
        own = [r.get("seconds", 0.0) for r in seen["reports"]]
        print(f"N {N}: {total:.2f} s, {fl.stats}, closed {fl.coverage['closed']}", flush=True)
        print(f"  slices wall {seen['wall']:.2f} s, tasks' own {sum(own):.2f} s over {len(own)} tasks", flush=True)
        ranked = sorted(zip(own, seen["tasks"], seen["reports"]), key=lambda t: -t[0])[:6]
        for sec, (name, task), report in ranked:
            where = f"({task[3]:.7f}, {task[4]:.7f}]" if name == "slice_task" else f"outliers sign {task[3]:+g}"
            print(f"  {sec:6.2f} s {name} {where}: {len(report['mu'])} mu, {report.get('shifts', '-')} shifts")


if __name__ == "__main__":
    main()
