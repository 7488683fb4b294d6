"""Reduced Floquet of the paper breather: the whole 2N x 2N eig against its even and odd blocks.

    python benchmarks/parity_blocks.py

Solves the w_b = 1.01 breather (M = 30, K = 160, N = 201) on the CPU, builds its reduced matrix Mu, and
times numpy's eig of the whole Mu and ``floquet.parity_blocks`` (best of 5 each, same process);
prints both times and the largest distance between the two spectra.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import continuation as ct  # noqa: E402
from continuation.floquet import half_period_map, parity_blocks, reduced_matrix  # noqa: E402
from warpchain import ChainParams  # noqa: E402


def best(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main():
    p = ChainParams(30.0, 160.0, 201)
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01)))
    Mu = reduced_matrix(half_period_map(b.linearization(b.flow)), p.M)
    t_full, (mu_full, _) = best(lambda: np.linalg.eig(Mu))
    t_blocks, blocks = best(lambda: parity_blocks(Mu))
    mu = blocks[0]
    gap = max(np.min(np.abs(mu_full[:, None] - mu[None, :]), axis=1))
    print(f"whole Mu ({Mu.shape[0]} x {Mu.shape[0]}) eig: {1e3 * t_full:.1f} ms")
    print(f"even/odd blocks ({blocks[3][0][2].shape[0]} + {blocks[3][1][2].shape[0]}): {1e3 * t_blocks:.1f} ms")
    print(f"largest distance between the two spectra: {gap:.1e}")


if __name__ == "__main__":
    main()
