"""Reduced Floquet of the paper breather: the whole 2N problem against its even and odd blocks.

    python benchmarks/parity_blocks.py

Solves the w_b = 1.01 breather (M = 30, K = 160, N = 201) on the CPU and times, best of 7 each in one
process, under one BLAS thread (``continuation.hostblas``) and under the process's default:
- whole: ``reduced_products`` on the 4N x 4N half-period map and numpy's eig of the 2N x 2N Mu;
- blocks: ``floquet.parity_blocks`` (products and eigs of the even and odd blocks, on two threads);
and prints the times and the largest distance between the two spectra.
"""

from __future__ import annotations

import time

import numpy as np


import continuation as ct
from continuation.floquet import half_period_map, parity_blocks, reduced_products
from continuation.hostblas import blas_threads
from warpchain import ChainParams


def best(fn, repeat=7):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main():
    p = ChainParams(30.0, 160.0, 201)
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01)))
    A = half_period_map(b.linearization(b.flow))

    def whole():
        Mu = reduced_products(A, p.M)[0]
        return np.linalg.eig(Mu)[0]

    for label, threads in (("1 BLAS thread", 1), ("default BLAS threads", None)):
        with blas_threads(threads):
            t_whole, mu_full = best(whole)
            t_blocks, blocks = best(lambda: parity_blocks(A, p.M))
        mu = np.concatenate([x.mu for x in blocks])
        gap = max(np.min(np.abs(mu_full[:, None] - mu[None, :]), axis=1))
        sizes = " + ".join(str(len(x.mu)) for x in blocks)
        print(
            f"{label}: whole ({len(mu_full)}) products + eig {1e3 * t_whole:.1f} ms; "
            f"even/odd blocks ({sizes}) {1e3 * t_blocks:.1f} ms; spectra differ by {gap:.1e}"
        )


if __name__ == "__main__":
    main()
