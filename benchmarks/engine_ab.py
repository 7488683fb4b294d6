"""A/B of the engine in whichever tree ``PYTHONPATH`` puts first: the kernel rows (``time_steps``, best of 5,
site-steps per second; Verlet and kahan8, N = 201, dt 0.1, the lowest optical mode at 0.3; 1, 805, 4096 and 32768
lattices) and the monodromy as Floquet gets it (``Flow("kahan8", 32).linearize`` + ``unit_columns("all")``: 804
columns, wall ms, best of 10 after 2 warm-ups). Prints one line: ``LABEL {json}``.

Command (GPU), alternating the trees on one machine, e.g. ``git archive OLD warpchain continuation`` unpacked in
``abold/``: ``PYTHONPATH=$WARP_SITE:abold python3 -P benchmarks/engine_ab.py old1`` then ``PYTHONPATH=$WARP_SITE:.
python3 -P benchmarks/engine_ab.py new1``, and again (``-P``: the script's folder is not put first on the path).
Results: ``benchmarks/results/h200-2026-11-28b.json``.
"""

import json
import sys
import time

import numpy as np

import warpchain as wc
from warpchain.ensemble import time_steps

label = sys.argv[1]
p = wc.ChainParams(30.0, 160.0, 201)
_, shape = wc.lowest_optical_mode(p)
one = np.zeros((4, p.N))
one[:2] = 0.3 * shape / np.max(np.abs(shape))
out = {"tree": wc.__file__}
for method in ("verlet", "kahan8"):
    for batch in (1, 805, 4096, 32768):
        x0 = np.repeat(one[None], batch, 0)
        n = 20000 if batch == 1 else 2000
        if method == "kahan8":
            n //= 10
        sec = time_steps(p, x0, n, 0.1, method=method, device="cuda", repeats=5)
        out[f"{method}/{batch}"] = batch * p.N * n / sec
flow = wc.Flow("kahan8", 32, device="cuda")
best = []
for r in range(12):
    t = time.perf_counter()
    lin = flow.linearize(p, one, 32, 0.19)
    cols = lin.unit_columns("all")
    best.append(time.perf_counter() - t)
out["monodromy_ms"] = 1e3 * min(best[2:])
out["monodromy_sum"] = float(np.sum(cols))
print(label, json.dumps(out), flush=True)
