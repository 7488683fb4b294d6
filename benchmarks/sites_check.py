"""The ``"sites"`` layout on a device against the numpy reference (a GPU's rounding: ~1e-13 relative) and
against the thread layout on the same device: base runs with frames, and tangent columns.

Command: ``python benchmarks/sites_check.py --device cuda [--sizes 1500 3201]`` (seconds).
"""

import argparse
import json

import numpy as np

import continuation as ct
import warpchain as wc
from warpchain import Placement, Record, reference


def relative(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1500, 3201])
    args = ap.parse_args()
    worst = 0.0
    for N in args.sizes:
        for boundary in wc.BOUNDARIES:
            p = wc.ChainParams(30.0, 160.0, N, boundary=boundary)
            x0 = np.stack([ct.nls_seed(p, 1.01), 1.5 * ct.nls_seed(p, 1.01)])
            for method in ("verlet", "kahan8"):
                run = wc.simulate(
                    p, x0, 40 * 0.05, 0.05, method=method, device=args.device, record=Record(every=10),
                    placement=Placement(layout="sites"),
                )  # fmt: skip
                ref = reference.integrate(method, p, x0, 0.05, run.nsteps, save_every=10)
                d = {"x": relative(run.x, ref["x"]), "u": relative(run.u, ref["u"])}
                dx0 = np.random.default_rng(1).normal(size=(3, 4, N))
                base = np.array([0, 1, 0], dtype=np.int32)
                out = {
                    layout: wc.propagate_tangent(
                        p, x0, dx0, 8, 0.05, method=method, column_base=base, device=args.device, layout=layout
                    )
                    for layout in ("sites", "thread")
                }
                refs = [
                    reference.integrate(method, p, x0[b : b + 1], 0.05, 8, dx0=dx0[None, c : c + 1])["dx"][0, 0]
                    for c, b in enumerate(base)
                ]
                d["columns_vs_reference"] = relative(out["sites"].columns, np.stack(refs))
                d["columns_vs_thread"] = relative(out["sites"].columns, out["thread"].columns)
                worst = max(worst, *d.values())
                print(json.dumps({"N": N, "boundary": boundary, "method": method, "layout": run.layout, **d}))
    print(json.dumps({"worst_relative_difference": worst}))


if __name__ == "__main__":
    main()
