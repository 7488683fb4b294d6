"""One tangent product of a 201 x 201 patch over half a period (issue #51: <= 5 ms), on the Warp Flow of a GPU.

The base run (``Flow.linearize``: kahan8, 16 steps, the contact stiffness recorded) and then one tangent column
(``Linearization.columns`` of one direction: the linearised step replaying that history), wall time with the device
synchronised, best and median of 6 after 2 warm-ups; square and triangular patches, M = 30, K = 1, a small
centred bump.

Command (GPU): ``python benchmarks/lattice_tangent.py OUT.json``. Results: ``benchmarks/results/h200-2026-11-28d/``.
"""

import json
import sys
import time

import numpy as np
import warp as wp

from warpchain.flow import Flow
from warpchain.lattice import LatticeParams, square, triangular

out = {}
for name, build in (("triangular", triangular), ("square", square)):
    p = LatticeParams(30.0, 1.0, build(201, 201))
    x0 = np.zeros((1, 4, p.N))
    x0[0, 1, p.lattice.centre] = 0.3
    flow = Flow("kahan8", 32, device="cuda")
    dt = np.pi / 1.014 / 16
    lin = flow.linearize(p, x0, 16, dt)
    d = np.random.default_rng(0).normal(size=(1, 4, p.N))
    times = []
    for _ in range(8):
        wp.synchronize()
        t0 = time.perf_counter()
        lin.columns(d)
        wp.synchronize()
        times.append(time.perf_counter() - t0)
    tl = []
    for _ in range(4):
        wp.synchronize()
        t0 = time.perf_counter()
        flow.linearize(p, x0, 16, dt)
        wp.synchronize()
        tl.append(time.perf_counter() - t0)
    out[name] = {
        "one_column_ms_best": 1e3 * min(times[2:]),
        "one_column_ms_median": 1e3 * float(np.median(times[2:])),
        "base_run_ms_best": 1e3 * min(tl[1:]),
    }
    print(name, out[name], flush=True)
json.dump(out, open(sys.argv[1], "w"), indent=1)
