"""Several host threads driving Flows on one GPU give the bits of the same solves run in sequence.

Four threads, each with its own ``Flow`` (as site-bond's workers), each run ``--solves`` Newton solves of the
paper chain (N = 201, M = 30, K = 160) at frequencies spread over the gap, each followed by its Floquet
analysis; a ``simulate`` call runs on the main thread meanwhile. The same solves run first one after the
other. Every state, energy, residual and multiplier must be equal bit for bit (graphs are captured and
replayed on every thread; ``warpchain.ensemble.device_lock`` keeps one thread at a time on the device). The
host BLAS runs on one thread throughout, as site-bond's workers run it: with several threads in LAPACK at
once and a process-wide thread limit that Floquet changes around its blocks, a factorisation's rounding
depended on which thread ran when (593 of 600 solves differed, by ~1e-15, on an H100 before).
Exit 1 on any difference or error; writes a JSON summary.

Command: ``python benchmarks/thread_check.py [--device cuda] [--threads 4] [--solves 50] [--out check.json]``
(about a minute on an H100).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

import numpy as np


import continuation as ct
from continuation.hostblas import blas_threads
from warpchain import ChainParams, simulate
from warpchain.flow import Flow


def solves(device: str, params: ChainParams, omegas) -> list:
    """Newton (from the NLS seed) and Floquet at each frequency on a Flow of this thread's own."""
    flow = Flow("kahan8", 32, device=device)
    out = []
    for omega in omegas:
        b = ct.require(ct.find_breather(params, omega, ct.nls_seed(params, omega), flow=flow))
        fl = ct.floquet(b, flow=flow)
        out.append([b.state, np.array([b.energy, b.residual]), fl.multipliers])
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--threads", type=int, default=4)
    parser.add_argument("--solves", type=int, default=50)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    with blas_threads(1):
        return check(args)


def check(args) -> int:
    params = ChainParams(30.0, 160.0, 201)
    grids = [np.linspace(1.004, 1.016, args.solves) + 1e-5 * t for t in range(args.threads)]
    start = time.perf_counter()
    sequential = [solves(args.device, params, g) for g in grids]
    t_seq = time.perf_counter() - start

    results, errors = [None] * args.threads, []
    barrier = threading.Barrier(args.threads)

    def work(i):
        try:
            barrier.wait()
            results[i] = solves(args.device, params, grids[i])
        except BaseException as exc:  # reported below
            errors.append(f"thread {i}: {type(exc).__name__}: {exc}")

    x0 = np.zeros((64, 4, params.N))
    x0[:, 1, params.N // 2] = -np.linspace(0.1, 0.6, 64)
    alone = simulate(params, x0, 200 * 0.05, 0.05, method="kahan8", device=args.device).x
    start = time.perf_counter()
    threads = [threading.Thread(target=work, args=(i,)) for i in range(args.threads)]
    for t in threads:
        t.start()
    beside = [simulate(params, x0, 200 * 0.05, 0.05, method="kahan8", device=args.device).x for _ in range(20)]
    for t in threads:
        t.join()
    t_par = time.perf_counter() - start
    differing = []
    if not errors:
        for i, (got, want) in enumerate(zip(results, sequential)):
            for k, (a, b) in enumerate(zip(got, want)):
                for name, x, y in zip(("state", "energy/residual", "multipliers"), a, b):
                    if not np.array_equal(x, y):
                        differing.append(f"thread {i}, solve {k}: {name} differs by {np.max(np.abs(x - y)):.3g}")
    differing += [f"simulate beside the threads, call {k}" for k, x in enumerate(beside) if not (x == alone).all()]
    summary = {
        "device": args.device,
        "threads": args.threads,
        "solves_per_thread": args.solves,
        "sequential_seconds": t_seq,
        "threaded_seconds": t_par,
        "errors": errors,
        "differences": differing,
        "same_bits": not errors and not differing,
    }
    print(json.dumps(summary, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(summary, indent=1))
    return 0 if summary["same_bits"] else 1


if __name__ == "__main__":
    sys.exit(main())
