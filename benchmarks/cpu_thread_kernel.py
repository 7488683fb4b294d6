"""Warp's CPU path (thread layout: one thread per lattice) against the numpy reference, velocity Verlet.

Command: ``python benchmarks/cpu_thread_kernel.py [--warp-only] [--method NAME] [--batches 1,64,805]
[--seconds 0.5] [--rounds 1] [--device cpu]``

Measures site-steps per second of ``warpchain.ensemble.time_steps`` (kernel time alone: one launch of
``nsteps`` steps on a batch already on the device, best of 3; compilation excluded; the batch is split
into one concurrent launch per core, as ``simulate`` does) for layout ``"thread"`` on device ``"cpu"``,
and of ``reference.integrate`` (numpy, whole run, best of 3) at the same batches, on the paper's chain
(M = 30, K = 160, N = 201, dt = 0.1, the lowest optical mode at amplitude 0.3), each run sized to
about ``--seconds``; prints both rates and their ratio. ``--rounds`` repeats the whole table (the machine
may be shared: compare rounds before trusting a difference of a few percent). ``--device cuda`` times the
same thread-layout kernels on a GPU (where they serve lattices too long for a thread block).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


from warpchain import ChainParams, lowest_optical_mode, reference
from warpchain.ensemble import time_steps

M, K, N, DT = 30.0, 160.0, 201, 0.1


def sized(run, seconds: float) -> tuple[int, float]:
    """(steps, best seconds) of ``run(steps, repeats)`` with steps grown until a run takes ~``seconds``."""
    steps = 4
    while True:
        took = run(steps, 1)
        if took >= seconds / 4:
            break
        steps = int(steps * min(64.0, max(2.0, seconds / 4 / max(took, 1e-7))))
    steps = max(1, int(steps * seconds / took))
    return steps, run(steps, 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", default="1,64,805")
    ap.add_argument("--method", default="verlet")
    ap.add_argument("--seconds", type=float, default=0.5)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--warp-only", action="store_true")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    params = ChainParams(M, K, N)
    _, shape = lowest_optical_mode(params)
    one = np.zeros((4, N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    batches = [int(b) for b in args.batches.split(",")]
    where = "the CPU" if args.device == "cpu" else args.device
    print(f"method {args.method}, N = {N}, thread layout on {where}; site-steps/s, best of 3, runs ~{args.seconds} s")
    print(f"{'batch':>6} {'warp':>10} {'numpy':>10} {'ratio':>7}")
    for _ in range(args.rounds):
        for batch in batches:
            x0 = np.repeat(one[None], batch, axis=0)

            def warp_run(n, repeats):
                return time_steps(
                    params, x0, n, DT, method=args.method, device=args.device, layout="thread", repeats=repeats
                )

            def numpy_run(n, repeats):
                best = float("inf")
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    reference.integrate(args.method, params, x0, DT, n)
                    best = min(best, time.perf_counter() - t0)
                return best

            steps, sec = sized(warp_run, args.seconds)
            warp = batch * N * steps / sec
            if args.warp_only:
                print(f"{batch:>6} {warp:>10.3e} {'-':>10} {'-':>7}", flush=True)
                continue
            steps, sec = sized(numpy_run, args.seconds)
            ref = batch * N * steps / sec
            print(f"{batch:>6} {warp:>10.3e} {ref:>10.3e} {warp / ref:>6.2f}x", flush=True)


if __name__ == "__main__":
    main()
