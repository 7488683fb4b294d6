"""Host <-> GPU and host memory bandwidths that bound simulate()'s transfers: 1 GiB device -> host into
pageable memory (first touch and touched), into pinned memory, the cost of pinning, and host copies
with one and eight threads (first touch and touched).

Command (GPU): ``python benchmarks/transfer_probe.py``
"""

import threading
import time

import numpy as np
import warp as wp


def main():
    wp.init()
    n = 1 << 27  # 1 GiB of float64
    d = wp.zeros(n, dtype=wp.float64, device="cuda")
    wp.synchronize()

    def best(f, label, reps=3):
        t = np.inf
        for _ in range(reps):
            wp.synchronize()
            t0 = time.perf_counter()
            f()
            wp.synchronize()
            t = min(t, time.perf_counter() - t0)
        print(f"{label:55s} {t * 1e3:8.1f} ms  {8 * n / t / 1e9:6.1f} GB/s", flush=True)

    host = np.empty(n)
    hw = wp.array(host, dtype=wp.float64, device="cpu", copy=False)
    t0 = time.perf_counter()
    wp.copy(hw, d)
    wp.synchronize()
    print(f"D2H pageable first touch {8 * n / (time.perf_counter() - t0) / 1e9:.1f} GB/s")
    best(lambda: wp.copy(hw, d), "D2H pageable (touched)")
    t0 = time.perf_counter()
    pin = wp.empty(n, dtype=wp.float64, device="cpu", pinned=True)
    print(f"pinned alloc 1 GiB {time.perf_counter() - t0:.3f} s")
    best(lambda: wp.copy(pin, d), "D2H pinned")
    pn = pin.numpy()
    host2 = np.empty(n)
    t0 = time.perf_counter()
    np.copyto(host2, pn)
    print(f"host memcpy first touch {8 * n / (time.perf_counter() - t0) / 1e9:.1f} GB/s")
    best(lambda: np.copyto(host2, pn), "host memcpy pinned->pageable (touched)")

    def parallel(dst):
        k, ch = 8, n // 8
        threads = [
            threading.Thread(target=np.copyto, args=(dst[i * ch : (i + 1) * ch], pn[i * ch : (i + 1) * ch]))
            for i in range(k)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

    best(lambda: parallel(host2), "host memcpy 8 threads")
    host3 = np.empty(n)
    t0 = time.perf_counter()
    parallel(host3)
    print(f"host memcpy 8 threads first touch {8 * n / (time.perf_counter() - t0) / 1e9:.1f} GB/s")


if __name__ == "__main__":
    main()
