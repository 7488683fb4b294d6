"""The Warp flow on a monolayer patch against scipy's DOP853: a site-centred breather (Newton on the Warp flow, M = 30,
K = 1, w_b = 1.012, fixed walls) advanced over one period by the Warp kernels (``simulate``, kahan8 at 32, 64 and 128
steps per period) and by DOP853 at rtol 1e-13 (``warpchain.reference.solve_ivp_reference``, the model's own
right-hand side on the lattice's Laplacian): the Warp error against DOP853, its observed order, and the orbit's
closure under DOP853 (the breather is periodic to the scheme's error, which DOP853 sees).

Command: ``python benchmarks/lattice_dop853.py [--device cuda] [--n 11]`` (about 20 s on the 2-core CPU at 11 x 11).
Prints one JSON object. Measured (CPU, 2026-11-28, 11 x 11): see docs/findings/scenes.md.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

import continuation as ct
import warpchain as wc
from warpchain.lattice import LatticeParams, square, triangular
from warpchain.reference import solve_ivp_reference


def main(device: str, n: int, omega: float = 1.012) -> dict:
    out = {"device": device, "n": n, "omega": omega}
    for name, build in (("square", square), ("triangular", triangular)):
        params = LatticeParams(30.0, 1.0, build(n, n, "fixed"))
        seed = ct.anticontinuum_seed(params, omega)
        b = ct.require(ct.find_breather(params, omega, seed, flow=wc.Flow("kahan8", 32, device=device), solver="dense"))
        period = 2.0 * math.pi / omega
        ref, sol = solve_ivp_reference(params, b.state, period)
        scale = np.abs(b.state).max()
        row = {"energy": float(b.energy), "dop853_steps": int(sol.t.size - 1)}
        row["dop853_closure"] = float(np.abs(ref - b.state).max() / scale)
        errors = []
        for steps in (32, 64, 128):
            run = wc.simulate(params, b.state[None], period, period / steps, method="kahan8", device=device)
            errors.append(float(np.abs(run.x[0] - ref).max() / scale))
        row["warp_error"] = dict(zip(("32", "64", "128"), errors))
        row["observed_order"] = [float(np.log2(errors[i] / errors[i + 1])) for i in range(2)]
        out[name] = row
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--n", type=int, default=11, help="the patch is n x n sites")
    args = parser.parse_args()
    from warpchain.engine.devices import resolve_device

    print(json.dumps(main(resolve_device(args.device), args.n), indent=1))
