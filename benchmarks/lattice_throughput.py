"""Throughput of lattices given as neighbour tables (the monolayer: ``warpchain.lattice.LatticeParams``, the sites
layout) beside the chain's block kernel, in one run on one device: site-steps per second of kernel time
(``warpchain.ensemble.time_steps``: the device synchronised before and after, best of ``repeats``).

Rows: the chain (N = 201, velocity Verlet, block layout) at 805, 4096 and 32768 lattices and one lattice (ns per
step); 163 square and 163 triangular 201 x 201 patches (as many sites as 32768 chains of 201) and one 512 x 512
triangular patch, Verlet and kahan8; the chain of 201 x 201 sites in the sites layout (the same kernel reading its
neighbours without a table). Ratios are against the chain's block kernel at 32768 lattices.

Command: ``python benchmarks/lattice_throughput.py [--device cuda]`` (about 30 s on an H100 with warm kernels;
on a CPU, ``--small`` runs 21 x 21 patches). Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from warpchain import ChainParams
from warpchain.ensemble import time_steps
from warpchain.lattice import LatticeParams, square, triangular


def main(device: str, small: bool, repeats: int = 3) -> dict:
    rng = np.random.default_rng(0)
    out = {"device": device}
    chain = ChainParams(30.0, 160.0, 201)
    batches = (8, 64) if small else (805, 4096, 32768)
    for batch in batches:
        x0 = 1e-3 * rng.normal(size=(batch, 4, 201))
        n = 200 if small else (2000 if batch < 30000 else 1000)
        t = time_steps(chain, x0, n, 0.02, method="verlet", device=device, layout="block", repeats=repeats)
        out[f"chain_block_{batch}"] = batch * 201 * n / t
    x0 = 1e-3 * rng.normal(size=(1, 4, 201))
    n = 2000 if small else 20000
    t = time_steps(chain, x0, n, 0.02, method="verlet", device=device, layout="block", repeats=repeats)
    out["chain_one_lattice_ns_per_step"] = t / n * 1e9
    side, batch = (21, 4) if small else (201, 163)
    for name, lattice, count in (
        ("square", square(side, side), batch),
        ("triangular", triangular(side, side), batch),
        ("triangular_512", triangular(64 if small else 512, 64 if small else 512), 1),
    ):
        params = LatticeParams(30.0, 1.0, lattice)
        x0 = 1e-3 * rng.normal(size=(count, 4, params.N))
        for method, n in (("verlet", 200), ("kahan8", 40)):
            t = time_steps(params, x0, n, 0.05, method=method, device=device, repeats=repeats)
            out[f"{name}_{method}"] = count * params.N * n / t
    long_chain = ChainParams(30.0, 160.0, side * side)
    x0 = 1e-3 * rng.normal(size=(batch, 4, long_chain.N))
    t = time_steps(long_chain, x0, 200, 0.02, method="verlet", device=device, layout="sites", repeats=repeats)
    out["chain_sites_verlet"] = batch * long_chain.N * 200 / t
    best = out[f"chain_block_{batches[-1]}"]
    out["ratios_to_the_chain_block"] = {
        k: v / best for k, v in out.items() if isinstance(v, float) and k.endswith(("verlet", "kahan8"))
    }
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--small", action="store_true", help="small sizes (a CPU)")
    args = parser.parse_args()
    from warpchain.engine.devices import resolve_device

    print(json.dumps(main(resolve_device(args.device), args.small), indent=1))
