"""Variants of the hand-written CUDA Verlet kernel (``benchmarks/_baselines.py``, CuPy), measured in one
run so that the throughput scene's baseline is the strongest of them: lattices per block,
``__launch_bounds__`` minimum blocks per SM, threads per lattice and idle threads held at zero, at 1,
805, 4096 and 32768 lattices (N = 201, float64; kernel time by CUDA events, best of 3, with the
host-timed rate beside it). Also checks each variant against the numpy reference (max |difference|).

Command (GPU, CuPy importable): ``python benchmarks/hand_cuda_variants.py``
"""

import numpy as np


from _baselines import cupy_verlet_runner  # beside this script
from warpchain import ChainParams, lowest_optical_mode, reference


def main():
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    check = np.repeat(one[None], 3, 0)
    ref = reference.integrate("verlet", p, check, 0.1, 500)["x"]
    rows = []
    variants = [(lpb, minb, None, False) for lpb in (1, 2) for minb in (0, 6, 8) if minb * lpb * 224 <= 2048]
    variants += [(1, 0, 256, False), (1, 0, None, True), (1, 6, None, True), (1, 0, 256, True)]
    for lpb, minb, threads, idle_zero in variants:
        run = cupy_verlet_runner(
            p.M, p.K, lattices_per_block=lpb, min_blocks=minb, threads=threads, idle_zero=idle_zero, sites=1
        )
        err = float(np.max(np.abs(run(check, 500, 0.1)[0] - ref)))
        for batch in (1, 805, 4096, 32768):
            x0 = np.repeat(one[None], batch, 0)
            steps = 20000 if batch == 1 else 2000 if batch < 32768 else 8000
            times = []
            for _ in range(3):
                times.append((run(x0, steps, 0.1)[1], run.wall_seconds))
            best, wall = min(times)
            rate = batch * p.N * steps / best
            rows.append((f"{lpb}/{minb}/{threads}/{idle_zero}", minb, batch, rate))
            print(
                f"lattices/block {lpb} min_blocks {minb} threads {threads} idle_zero {idle_zero} "
                f"batch {batch:6d}: {rate:.3g} site-steps/s "
                f"({1e9 * best / steps:.1f} ns/step; host-timed {batch * p.N * steps / wall:.3g}); "
                f"max |x - reference| after 500 steps {err:.2g}",
                flush=True,
            )
    for batch in (1, 805, 4096, 32768):
        best = max((r for r in rows if r[2] == batch), key=lambda r: r[3])
        print(f"best at {batch}: lattices/block/min_blocks/threads/idle_zero {best[0]}: {best[3]:.3g}")


if __name__ == "__main__":
    main()
