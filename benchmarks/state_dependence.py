"""Does the per-step cost move with the state over a long run? One lattice (the throughput scene's state:
the lowest optical mode at amplitude 0.3), velocity Verlet, dt = 0.1: Warp's kernel (``time_steps``) and
the hand-written CUDA kernel (``benchmarks/_baselines.py``) each timed on consecutive segments of
``--steps`` steps, from the start and from the states the hand kernel reaches after 1, 2 and 4 segments.
Why: the throughput scene used to time the hand kernel on its second segment and Warp's best of its first
three; this shows whether that choice alone moves the ratio.

Command (GPU, CuPy): ``python benchmarks/state_dependence.py [--steps 2000000]``
"""

import argparse

import numpy as np


from _baselines import cupy_verlet_runner  # beside this script
from warpchain import ChainParams, lowest_optical_mode
from warpchain.ensemble import time_steps


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2_000_000)
    ap.add_argument("--device", default="cuda")
    args = ap.parse_args()
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    x = np.zeros((1, 4, p.N))
    x[0, :2] = 0.3 * shape / np.max(np.abs(shape))
    hand = cupy_verlet_runner(p.M, p.K)
    if hand is None:
        print("CuPy not importable")
        return
    n = args.steps
    done = 0
    for segment in range(5):
        if segment in (0, 1, 2, 4):
            warp = time_steps(p, x, n, 0.1, device=args.device, repeats=1) / n
            _, hand_seconds = hand(x, n, 0.1)
            print(
                f"from step {done:9d}: warp {1e9 * warp:.1f} ns/step, hand {1e9 * hand_seconds / n:.1f} ns/step, "
                f"min contact 1 + u - v = {np.min(1 + x[0, 0] - x[0, 1]):.3f}",
                flush=True,
            )
        x = hand(x, n, 0.1)[0]
        done += n


if __name__ == "__main__":
    main()
