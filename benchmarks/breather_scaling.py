"""The N-scaling table of issues #36 and #48: the paper breather from the NLS seed plus its complete verdict.

The paper breather (w_b = 1.01, K = 160, M = 30, kahan8, 32 steps per period) at each N: Newton
(``find_breather(solver="auto")``: matrix-free from 1025 sites), then every multiplier (``floquet(solver=...)``,
default ``auto``: dense below 1601 sites, from there the probed sparse Mu by a dense eig per block on a GPU with
CuPy, else by shift-invert slices, either certified by a count: ``continuation.slicing``), and up to ``--dense-max``
the dense Floquet analysis of the same orbit (4N tangent columns), which it is checked against: the largest modulus
of each, the largest distance between the two sets of mu (each mu to the nearest of the other set, both ways), the
kinds. Each size is solved once untimed first (kernels compile per shape on a GPU; the first sliced call also starts
the worker processes). Per size: seconds of each step, energy, verdicts, the count per parity block.

With ``--lattice square`` or ``triangular`` the same for the monolayer's site breather (w_b = 1.014, K = 1, M = 30,
fixed walls, the anti-continuum seed, Newton ``auto``: matrix-free from 1024 sites) on n x n patches, ``--sizes``
giving n and ``--dense-max`` sites (issue #51: breather plus complete verdict on 51 x 51 <= 10 s); ``--solver none``
times the breather alone (201 x 201 <= 30 s).

Command: ``python benchmarks/breather_scaling.py [--device cpu] [--lattice chain] [--sizes 201 ... 12801]
[--dense-max 1601] [--solver auto] [--warm all|newton] [--json FILE]``.
"""

import argparse
import json
import os
import time

import numpy as np

import continuation as ct
import warpchain as wc
from warpchain.lattice import LatticeParams, square, triangular

BUILDERS = {"square": square, "triangular": triangular}


def distance(a: np.ndarray, b: np.ndarray) -> float:
    """max over each mu of either set of its distance to the nearest of the other (sorted by real part, a window)."""
    worst = 0.0
    for x, y in ((a, b), (b, a)):
        order = np.argsort(y.real)
        ys = y[order]
        idx = np.searchsorted(ys.real, x.real)
        best = np.full(len(x), np.inf)
        for shift in range(-3, 4):
            j = np.clip(idx + shift, 0, len(ys) - 1)
            best = np.minimum(best, np.abs(ys[j] - x))
        worst = max(worst, float(best.max()))
    return worst


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--sizes", type=int, nargs="+", default=[201, 401, 801, 1601, 3201, 6401, 12801])
    ap.add_argument("--dense-max", type=int, default=1601, help="largest N analysed densely too")
    ap.add_argument("--solver", default="auto", choices=("auto", "sliced", "probed", "dense", "none"))
    ap.add_argument(
        "--warm", default="all", choices=("all", "newton"),
        help="untimed first solve per size: Newton and Floquet (all), or Newton alone (a long lattice's Floquet twice "
        "costs a minute on a GPU)",
    )  # fmt: skip
    ap.add_argument("--lattice", default="chain", choices=("chain", "square", "triangular"))
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = []
    for size in args.sizes:
        if args.lattice == "chain":
            p, omega, newton = wc.ChainParams(30.0, 160.0, size), 1.01, "auto"
            seed = ct.nls_seed(p, omega)
        else:
            p, omega, newton = LatticeParams(30.0, 1.0, BUILDERS[args.lattice](size, size, "fixed")), 1.014, "auto"
            seed = ct.anticontinuum_seed(p, omega)
        N = p.N

        def solve():
            return ct.require(ct.find_breather(p, omega, seed, device=args.device, solver=newton))

        warm = solve()  # warm-up
        if args.solver != "none" and args.warm == "all":
            ct.floquet(warm, solver=args.solver)
        t0 = time.perf_counter()
        b = solve()
        t1 = time.perf_counter()
        if args.solver == "none":
            row = {"lattice": args.lattice, "size": size, "N": N, "newton_solver": b.stats["solver"]}
            row |= {"newton_seconds": t1 - t0, "energy": b.energy, "residual": b.residual}
            row |= {"gmres_products": b.stats.get("krylov_iterations")}
            rows.append(row)
            print(json.dumps(row), flush=True)
            continue
        fl = ct.floquet(b, solver=args.solver)
        t2 = time.perf_counter()
        row = {
            "lattice": args.lattice,
            "size": size,
            "N": N,
            "newton_solver": b.stats["solver"],
            "newton_seconds": t1 - t0,
            "floquet_seconds": t2 - t1,
            "total_seconds": t2 - t0,
            "energy": b.energy,
            "path": fl.path,
            "complete": fl.complete,
            "stable": fl.stable,
            "max_modulus": fl.max_modulus,
            "kinds": list(fl.kinds),
            "mu_count": len(fl.mu),
            "tangent_runs": fl.stats["tangent_columns"],
        }
        if fl.coverage is not None:
            keys = ("method", "eig", "segments", "shifts", "strip_half_height", "closed", "counts")
            row |= {k: fl.coverage[k] for k in keys if k in fl.coverage}
            row["floquet_parts"] = fl.stats.get("seconds")
        if N <= args.dense_max and fl.path != "reduced":
            t3 = time.perf_counter()
            fd = ct.floquet(b, solver="dense")
            row["dense_floquet_seconds"] = time.perf_counter() - t3
            row["dense_max_modulus"] = fd.max_modulus
            row["dense_stable"] = fd.stable
            row["dense_kinds"] = list(fd.kinds)
            row["max_modulus_difference"] = abs(fd.max_modulus - fl.max_modulus)
            row["mu_set_distance"] = distance(fd.mu, fl.mu)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"device": args.device, "cores": os.cpu_count(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
