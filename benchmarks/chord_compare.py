"""Continuation in K of the paper chain with and without chord Newton steps: points, solves, time.

python benchmarks/chord_compare.py [--N 201] [--device cuda]
"""

import argparse
import time


import continuation as ct
from continuation.branch import continue_in_coupling
from continuation.driver import ContinuationSettings
from warpchain import ChainParams, Flow


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--N", type=int, default=201)
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    p = ChainParams(30.0, 0.01, args.N)
    for chord in (False, True):
        t0 = time.perf_counter()
        br = continue_in_coupling(
            p,
            1.01,
            ct.anticontinuum_seed(p, 1.01),
            160.0,
            targets=(5.0, 20.0),
            flow=Flow("kahan8", 32, args.device),
            settings=ContinuationSettings(ds=0.15, ds_min=1e-4, ds_max=0.3, resolution=1e-3, chord=chord),
        )
        newton = sum(q.iterations for q in br.points) / len(br.points)
        print(
            f"chord={chord}: {br.stop_reason.value}, {br.stats}, {time.perf_counter() - t0:.1f} s, "
            f"mean Newton iterations {newton:.2f}, changes {len(br.stability_changes())}",
            flush=True,
        )


if __name__ == "__main__":
    main()
