"""What a host copy into page-locked staging costs on the GPU machine's host, at the sizes ``simulate`` copies
(a state slice of 1024-4096 lattices and the whole 805-lattice state): one thread (numpy), the copy pool
(``ensemble._copy``) at its default and other thread counts, and the pool's round trip for an empty job (what
waking its threads costs). Best and median of 20 after 3 untimed, ms and GB/s; sources and destinations
touched before.

Command (GPU host): ``python benchmarks/host_copy_probe.py``
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpchain import ensemble  # noqa: E402


def timed(f, reps=20):
    for _ in range(3):
        f()
    walls = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        walls.append(time.perf_counter() - t0)
    return min(walls), float(np.median(walls))


def main():
    import warp as wp

    wp.init()
    device = "cuda" if wp.is_cuda_available() else "cpu"
    values_per_lattice = 4 * 201
    biggest = 4096 * values_per_lattice
    pinned = wp.empty(biggest, dtype=wp.float64, device="cpu", pinned=device != "cpu").numpy()
    pinned[:] = 1.0
    source = np.random.default_rng(0).random(biggest)
    pool = ensemble._copy_pool(ensemble._MAX_COPY_THREADS)
    a, m = timed(lambda: pool.submit(int).result())
    print(f"pool round trip, empty job: best {a * 1e6:.1f} us, median {m * 1e6:.1f} us")
    a, m = timed(lambda: [f.result() for f in [pool.submit(int) for _ in range(8)]])
    print(f"pool round trip, 8 empty jobs: best {a * 1e6:.1f} us, median {m * 1e6:.1f} us")
    for lattices in (805, 1024, 2048, 4096):
        n = lattices * values_per_lattice
        dst, src = pinned[:n], source[:n]
        rows = [("one thread", lambda: np.copyto(dst, src))]
        rows.append((f"pool, default ({ensemble._workers(n)} threads)", lambda: ensemble._copy(dst, src)))
        for threads in (2, 4, 8, 16):
            saved = ensemble._COPY_SLICE
            ensemble._COPY_SLICE = max(1, n // threads)
            best, median = timed(lambda: ensemble._copy(dst, src))
            ensemble._COPY_SLICE = saved
            rows.append((f"pool, {threads} threads", (best, median)))
        print(f"\n{lattices} lattices ({8 * n / 1e6:.1f} MB):")
        for label, f in rows:
            best, median = f if isinstance(f, tuple) else timed(f)
            rate = 8 * n / best / 1e9
            print(f"  {label:32s} best {best * 1e3:7.3f} ms ({rate:5.1f} GB/s), median {median * 1e3:7.3f} ms")


if __name__ == "__main__":
    main()
