"""Matrix-free Newton (``find_breather(solver="krylov")``) against the dense reference, in one run.

The paper breather (w_b = 1.01, K = 160, M = 30, kahan8, 32 steps per period) from the NLS seed at each N:
Newton's wall time on each path (after one untimed call per path and size: on a GPU the block kernels compile
per block size), the energies
and their difference, the largest difference of the states, Newton iterations and the GMRES matrix-vector
products per Newton step with the linear lattice's preconditioner and without it.

Command: ``python benchmarks/newton_krylov.py [--device cpu] [--sizes 201 401 801 1601] [--json FILE]``
(2-core CPU: about a minute up to N = 1601).
"""

import argparse
import json
import time

import numpy as np

import continuation as ct
import warpchain as wc
from continuation.krylov import KrylovSettings


def solve(p, seed, device, **kwargs):
    t0 = time.perf_counter()
    b = ct.find_breather(p, 1.01, seed, device=device, **kwargs)
    return b, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--sizes", type=int, nargs="+", default=[201, 401, 801, 1601])
    ap.add_argument("--dense-max", type=int, default=1601, help="largest N solved densely too")
    ap.add_argument("--plain-max", type=int, default=1601, help="largest N solved without the preconditioner too")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = []
    for N in args.sizes:
        p = wc.ChainParams(30.0, 160.0, N)
        seed = ct.nls_seed(p, 1.01)
        # one untimed call per path and size: on a GPU the block kernels compile per block size
        solve(p, seed, args.device, solver="krylov")
        if N <= args.dense_max:
            solve(p, seed, args.device, solver="dense")
        k, tk = solve(p, seed, args.device, solver="krylov")
        plain, tp = None, None
        if N <= args.plain_max:
            plain, tp = solve(p, seed, args.device, solver="krylov", krylov=KrylovSettings(preconditioner="none"))
        row = {
            "N": N,
            "krylov_seconds": tk,
            "krylov_status": k.status.value,
            "krylov_energy": k.energy,
            "newton_iterations": k.iterations,
            "gmres_products": k.stats["krylov_iterations"],
            "unpreconditioned_status": plain.status.value if plain else None,
            "unpreconditioned_products": plain.stats["krylov_iterations"] if plain else None,
            "unpreconditioned_seconds": tp,
        }
        if N <= args.dense_max:
            d, td = solve(p, seed, args.device, solver="dense")
            row.update(
                dense_seconds=td,
                dense_energy=d.energy,
                energy_difference=abs(d.energy - k.energy),
                state_difference=float(np.max(np.abs(d.state - k.state))),
                speedup=td / tk,
            )
        rows.append(row)
        print(
            f"N {N:6d}: krylov {tk:8.3f} s ({k.status.value}, {k.iterations} Newton, "
            f"GMRES {k.stats['krylov_iterations']}; "
            + (f"unpreconditioned {plain.stats['krylov_iterations']} {plain.status.value})" if plain else "not run)")
            + (
                f"; dense {row['dense_seconds']:8.3f} s: {row['speedup']:.1f}x; |dE| {row['energy_difference']:.2e}, "
                f"max |dx| {row['state_difference']:.2e}"
                if "dense_seconds" in row
                else ""
            ),
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"device": args.device, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    main()
