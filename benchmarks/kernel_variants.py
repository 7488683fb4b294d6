"""Where the block kernels' time goes: the stage-specialised splitting kernels (Verlet and kahan8;
without and with ``__launch_bounds__`` minimum blocks per SM, which caps registers) against a
hand-reduced Verlet-only Warp kernel (no recording branches), at 1, 805 and 32768 lattices, in one
run; then registers per kernel.

Command (GPU): ``python benchmarks/kernel_variants.py [--profile] [--quick]``; ``--profile`` runs one
launch of Verlet and kahan8 as simulate() compiles them, and of the hand-reduced kernel, for ``ncu``;
``--quick`` times Verlet and kahan8 alone.
"""

import sys
import time

import numpy as np
import warp as wp


from warpchain import ChainParams, lowest_optical_mode
from warpchain.engine import block_kernels as bk
from warpchain.engine.site import Lattice, Observer, Recording
from warpchain.engine.block_kernels import (
    load_site,
    neighbour_or_wall,
    site_acceleration,
    site_neighbours,
    store_site,
)

BLOCK = bk.block_size(201)
HALVES = 2 * BLOCK


@wp.func
def exchange(buf: wp.tile[wp.float64, HALVES], u: wp.float64, parity: int, nbr: wp.vec4i, boundary: int) -> wp.vec2d:
    offset = parity * BLOCK
    wp.tile_assign(buf, wp.tile(u), offset=(offset,))
    return wp.vec2d(
        neighbour_or_wall(buf[offset + nbr[0]], u, nbr[2], boundary),
        neighbour_or_wall(buf[offset + nbr[1]], u, nbr[3], boundary),
    )


@wp.kernel(enable_backward=False, module="unique", grid_stride=False, launch_bounds=BLOCK)
def verlet_only(
    x: wp.array3d(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    coupling: wp.array(dtype=wp.float64),
    boundary: int,
    half: wp.float64,
    dt: wp.float64,
    nsteps: int,
):
    b, j = wp.tid()
    n = x.shape[2]
    active = j < n
    start = load_site(x, b, j, active)
    u = start[0]
    v = start[1]
    pu = start[2]
    pv = start[3]
    m = mass[b]
    k = coupling[b]
    nbr = site_neighbours(j, n, boundary)
    buf = wp.tile_zeros(shape=(HALVES,), dtype=wp.float64, storage="shared")
    parity = int(0)
    nb = exchange(buf, u, parity, nbr, boundary)
    a = site_acceleration(u, v, nb[0], nb[1], m, k)
    for _step in range(nsteps):
        pu = pu + half * a[0]
        pv = pv + half * a[1]
        u = u + dt * pu
        v = v + dt * pv
        parity = 1 - parity
        nb = exchange(buf, u, parity, nbr, boundary)
        a = site_acceleration(u, v, nb[0], nb[1], m, k)
        pu = pu + half * a[0]
        pv = pv + half * a[1]
    store_site(x, b, j, active, wp.vec4d(u, v, pu, pv))


def main():
    profile = "--profile" in sys.argv
    quick = "--quick" in sys.argv  # Verlet and kahan8 only
    wp.init()
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    f64 = wp.float64
    from warpchain.integrators import get_method

    variants = {}
    for min_blocks in (0, 5) if profile else (0, 5, 6, 7):
        kernels = bk.block_kernels(BLOCK, min_blocks)
        for name in ("verlet", "kahan8") if quick else ("verlet", "yoshida4", "kahan8"):
            if profile and min_blocks != bk.min_blocks_per_sm(get_method(name).stages):
                continue  # profile what simulate() launches
            m = get_method(name)
            variants[f"{name} min_blocks={min_blocks}"] = (kernels.splitting(m.stages), m)
    for batch in (1, 805, 32768):
        x = wp.array(np.repeat(one[None], batch, 0), dtype=f64, device="cuda")
        mass = wp.array(np.full(batch, 1.0 / 30.0), dtype=f64, device="cuda")  # the kernels take 1/M
        cpl = wp.array(np.full(batch, 160.0), dtype=f64, device="cuda")
        rec = wp.zeros((1, 1, 1), dtype=f64, device="cuda")
        hist = wp.zeros((1, 1, 1), dtype=f64, device="cuda")
        lattice = Lattice()  # M = 30, K = 160, fixed ends, no losses
        lattice.mass = wp.array(np.full(batch, 30.0), dtype=f64, device="cuda")
        lattice.inv_mass, lattice.coupling, lattice.boundary = mass, cpl, 0
        lattice.lossy = wp.zeros(batch, dtype=wp.int32, device="cuda")
        lattice.damp = wp.zeros((1, 1, 8), dtype=f64, device="cuda")
        nothing = Recording()  # nothing recorded
        no_base = wp.zeros(1, dtype=wp.int32, device="cuda")  # base runs: no tangent columns
        nothing.u, nothing.v, nothing.hist = rec, rec, hist

        def runner(kernel, m):
            step = 0.1 if m.stages == 1 else 0.5
            scheme = bk.pack_scheme(m.drifts, m.kicks, step)
            return lambda n: wp.launch(
                kernel,
                dim=(batch, BLOCK),
                block_dim=BLOCK,
                device="cuda",
                inputs=[x, no_base, lattice, scheme, n, nothing, Observer()],
            )

        def run_verlet(n):
            wp.launch(
                verlet_only,
                dim=(batch, BLOCK),
                block_dim=BLOCK,
                device="cuda",
                inputs=[x, mass, cpl, 0, f64(0.05), f64(0.1), n],
            )

        runs = [("verlet-only", run_verlet, 1)] + [(k, runner(kern, m), m.stages) for k, (kern, m) in variants.items()]
        for name, fn, evals in runs:
            if profile:  # one launch of 200 steps (Verlet) or 40 (kahan8) per kernel and batch, for ncu
                fn(200 // evals + 1)
                wp.synchronize()
                continue
            fn(10)
            wp.synchronize()
            steps = (20000 if batch < 1000 else 2000) // evals
            best = 1e9
            for _ in range(3):
                t0 = time.perf_counter()
                fn(steps)
                wp.synchronize()
                best = min(best, time.perf_counter() - t0)
            print(
                f"{name:24s} batch {batch:6d}: {1e9 * best / steps / evals:8.1f} ns per force evaluation, "
                f"{batch * p.N * steps / best:.3g} site-steps/s",
                flush=True,
            )
    if not profile:
        for min_blocks in (0, 5, 6, 7):
            for key, kern in bk.block_kernels(BLOCK, min_blocks).built().items():
                print(min_blocks, key, wp.get_cuda_kernel_properties(kern, "cuda", block_dim=BLOCK))


if __name__ == "__main__":
    main()
