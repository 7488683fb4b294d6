"""Multi-site breathers of the monolayer in and out of phase: complete verdicts over K, and the K where the
out-of-phase bond loses stability, bisected on two patch sizes (docs/findings/scenes.md, "The monolayer").

    python benchmarks/monolayer_families.py scan --sizes 15 --K 0.1 0.25 0.5 1.0      # ~3 min on 2 cores
    python benchmarks/monolayer_families.py bisect --sizes 15 21                      # ~10 min on 2 cores

The seeds are the ``monolayer`` scene's (``scenarios.monolayer._seed``: ``bond``, ``bond-out``, ``triangle``,
``triangle-out``); Newton from the anti-continuum seed at each K, the verdict ``floquet(solver="auto")`` (dense on
these patches), fixed walls, M = 30, w_b = 1.014.
"""

from __future__ import annotations

import argparse

import numpy as np

import continuation as ct
from scenarios.monolayer import _seed
from warpchain.lattice import LatticeParams, square, triangular

BUILDERS = {"square": square, "triangular": triangular}
M, OMEGA = 30.0, 1.014


def analyse(lattice: str, n: int, K: float, family: str):
    p = LatticeParams(M, K, BUILDERS[lattice](n, n, "fixed"))
    b = ct.require(ct.find_breather(p, OMEGA, _seed(p, OMEGA, family), device="cpu"))
    fl = ct.floquet(b, solver="auto")
    if not fl.complete:
        raise RuntimeError(f"{lattice} {n} x {n} {family} K = {K}: the count did not close")
    return b, fl


def describe(fl) -> str:
    kinds = [i.kind for i in fl.instabilities]
    participation = [round(float(i.participation), 1) for i in fl.instabilities]
    return f"{fl.verdict:8s} max|l|-1 = {fl.max_modulus - 1:.3e} {kinds} participation {participation}"


def scan(sizes, couplings) -> None:
    for lattice in BUILDERS:
        families = ["bond", "bond-out"] + (["triangle", "triangle-out"] if lattice == "triangular" else [])
        for n in sizes:
            for family in families:
                for K in couplings:
                    b, fl = analyse(lattice, n, K, family)
                    print(
                        f"{lattice:10s} {n}x{n} {family:12s} K = {K:<5g} E = {b.energy:.6f} {describe(fl)}", flush=True
                    )


def bisect(sizes, steps: int) -> None:
    brackets = {"square": (0.5, 1.0), "triangular": (0.25, 0.5)}  # stable at the first, not at the second
    for lattice, (lo, hi) in brackets.items():
        for n in sizes:
            assert analyse(lattice, n, lo, "bond-out")[1].stable and not analyse(lattice, n, hi, "bond-out")[1].stable
            for _ in range(steps):
                mid = 0.5 * (lo + hi)
                if analyse(lattice, n, mid, "bond-out")[1].stable:
                    lo = mid
                else:
                    hi = mid
            print(f"{lattice} {n}x{n}: bond-out stable up to K in ({lo:.4f}, {hi:.4f}); at {hi:.4f}: "
                  f"{describe(analyse(lattice, n, hi, 'bond-out')[1])}", flush=True)  # fmt: skip
            lo, hi = brackets[lattice]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("scan", "bisect"))
    parser.add_argument("--sizes", type=int, nargs="+", default=[15])
    parser.add_argument("--K", type=float, nargs="+", default=[0.1, 0.25, 0.5, 1.0])
    parser.add_argument("--steps", type=int, default=7, help="bisection steps")
    args = parser.parse_args()
    np.set_printoptions(precision=4)
    if args.what == "scan":
        scan(args.sizes, args.K)
    else:
        bisect(args.sizes, args.steps)


if __name__ == "__main__":
    main()
