"""The N-scaling table of issue #36: the paper breather from the NLS seed plus its stability-deciding multipliers.

The paper breather (w_b = 1.01, K = 160, M = 30, kahan8, 32 steps per period) at each N: Newton
(``find_breather(solver="auto")``: matrix-free from 1025 sites), then the multipliers near +1 and -1
(``floquet(solver="krylov")``: the probed half-period map and shift-invert Arnoldi), and up to ``--dense-max``
the dense Floquet analysis of the same orbit, which the window is checked against (largest difference of a
reported mu from the dense one, and the instabilities inside the window). Each size is solved once untimed
first (kernels compile per shape on a GPU). Per size: seconds of each step, energy, the largest multiplier of
each path, the localized real pair's modulus and the pinning mode's mu - 1 (the odd mode near +1 with the
most central weight: a real pair when positive).

Command: ``python benchmarks/breather_scaling.py [--device cpu] [--sizes 201 ... 12801] [--dense-max 1601]
[--json FILE]`` (2-core CPU: ~3 min to 12801).
"""

import argparse
import json
import time

import numpy as np

import continuation as ct
import warpchain as wc


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--sizes", type=int, nargs="+", default=[201, 401, 801, 1601, 3201, 6401, 12801])
    ap.add_argument("--dense-max", type=int, default=1601, help="largest N analysed densely too")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = []
    for N in args.sizes:
        p = wc.ChainParams(30.0, 160.0, N)
        seed = ct.nls_seed(p, 1.01)
        ct.floquet(ct.require(ct.find_breather(p, 1.01, seed, device=args.device)), solver="krylov")  # warm-up
        t0 = time.perf_counter()
        b = ct.require(ct.find_breather(p, 1.01, seed, device=args.device))
        t1 = time.perf_counter()
        fk = ct.floquet(b, solver="krylov")
        t2 = time.perf_counter()
        localized = [i.modulus for i in fk.instabilities if i.localized and i.kind == "real_pair"]
        # the pinning mode: the odd mu near +1 with the most weight on the central sites (a real pair when > 1)
        odd = np.flatnonzero((fk.parity == -1) & (np.abs(fk.mu - 1.0) < 1e-5))
        pin = odd[np.argmax(fk.central_weight[odd])] if odd.size else None
        row = {
            "N": N,
            "newton_solver": b.stats["solver"],
            "newton_seconds": t1 - t0,
            "krylov_floquet_seconds": t2 - t1,
            "total_seconds": t2 - t0,
            "energy": b.energy,
            "krylov_max_modulus": fk.max_modulus,
            "real_pair_modulus": max(localized) if localized else None,
            "krylov_kinds": list(fk.kinds),
            "pinning_mu_minus_one": None if pin is None else float(fk.mu[pin].real - 1.0),
            "pinning_participation": None if pin is None else float(fk.participation[pin]),
            "covered": fk.coverage["covered"],
            "shifts": fk.coverage["shifts"],
            "tangent_runs": fk.stats["tangent_columns"],
        }
        if N <= args.dense_max:
            t3 = time.perf_counter()
            fd = ct.floquet(b, solver="dense")
            row["dense_floquet_seconds"] = time.perf_counter() - t3
            row["dense_max_modulus"] = fd.max_modulus
            row["dense_kinds"] = list(fd.kinds)
            row["mu_difference"] = float(max(np.min(np.abs(fd.mu - m)) for m in fk.mu))
            (_, hi_minus), (lo_plus, _) = fk.coverage["covered"]
            seen = [i for i in fd.instabilities if i.mu.real >= lo_plus or i.mu.real <= hi_minus]
            row["window_instabilities_equal"] = [(i.kind, i.parity) for i in seen] == [
                (i.kind, i.parity) for i in fk.instabilities
            ] and bool(np.allclose([i.modulus for i in seen], [i.modulus for i in fk.instabilities], atol=1e-9))
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"device": args.device, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
