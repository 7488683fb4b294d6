"""The monodromy's kernels, variant by variant: the paper breather's base run (one lattice, kahan8, 64 steps,
recording the contact stiffness) and its tangent columns (804 for the monodromy, 402 for a Newton iteration),
for every (columns per block, history prefetch, register cap) of ``block_kernels``' tangent kernel; each
checked bit for bit against the first variant and against the numpy reference. Kernel time best of
``--repeats`` (device synchronised before and after each launch).

Command (GPU): ``python benchmarks/tangent_variants.py [--repeats 20]``
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from continuation import nls_seed  # noqa: E402
from scenarios._common import (  # noqa: E402
    BREATHER_METHOD,
    BREATHER_STEPS_PER_PERIOD,
    PAPER_K,
    PAPER_M,
    PAPER_N,
    PAPER_OMEGA,
)
from warpchain import ChainParams, ensemble, reference  # noqa: E402
from warpchain.integrators import get_method  # noqa: E402

VARIANTS = [  # (columns per block, prefetch, min blocks per SM of the two-column kernel)
    (1, False, None),
    (1, True, None),
    (2, False, 4),
    (2, True, 4),
    (2, True, 3),
    (2, True, 0),
]


def best(fn, wp, device, repeats):
    times = []
    for _ in range(repeats):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--repeats", type=int, default=50)
    args = ap.parse_args()
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    x0 = nls_seed(params, PAPER_OMEGA)[None]
    period = 2 * np.pi / PAPER_OMEGA
    nsteps, dt = BREATHER_STEPS_PER_PERIOD, period / BREATHER_STEPS_PER_PERIOD
    meth = get_method(BREATHER_METHOD)
    M, K = np.array([PAPER_M]), np.array([PAPER_K])
    print(f"{BREATHER_METHOD}, N = {params.N}, {nsteps} steps (one period), {args.device}; best / median ms")
    for one_site_group in (None, True):
        ensemble._GROUP_ONE_SITE = one_site_group
        runner = ensemble._Runner(meth, params, x0, M, K, args.device, record_stiffness_steps=nsteps)
        wp = runner.wp

        def base():
            runner.launch(nsteps, dt, record_stiffness=True)  # a period further along the (near) breather

        b, bm = best(base, wp, args.device, args.repeats)
        label = "site-group kernel" if one_site_group else "default kernel"
        print(f"base run ({label}): {1e3 * b:.3f} / {1e3 * bm:.3f}")
    ensemble._GROUP_ONE_SITE = None
    runner.load(x0, M, K)
    base()
    for ncols in (4 * params.N, 2 * params.N):
        eye = np.eye(4 * params.N)[:ncols].reshape(ncols, 4, params.N)
        eye_device = wp.array(eye, dtype=wp.float64, device=args.device)
        dx = wp.empty(eye.shape, dtype=wp.float64, device=args.device)
        column_base = wp.zeros(ncols, dtype=wp.int32, device=args.device)
        first = None
        exact = reference.integrate(BREATHER_METHOD, params, x0, dt, nsteps, dx0=eye[None])["dx"][0]
        for columns, prefetch, cap in VARIANTS:
            ensemble._TANGENT_COLUMNS, ensemble._TANGENT_PREFETCH = columns, prefetch
            if cap is not None:
                ensemble._TANGENT_PAIR_MIN_BLOCKS = {True: cap, False: 0}

            def tangent():
                wp.copy(dx, eye_device)
                runner.launch_tangent(dx, column_base, nsteps, dt)

            tangent()  # compile
            out = dx.numpy().copy()
            first = out if first is None else first
            same = "same bits" if np.array_equal(out, first) else f"DIFFERS by {np.max(np.abs(out - first)):.3g}"
            same += f", reference rel diff {np.max(np.abs(out - exact)) / np.max(np.abs(exact)):.2g}"
            copy, _ = best(lambda: wp.copy(dx, eye_device), wp, args.device, args.repeats)
            t, tm = best(tangent, wp, args.device, args.repeats)
            print(
                f"{ncols} columns, {columns} per block, prefetch {prefetch!s:5s}, cap {cap}: "
                f"{1e3 * (t - copy):.3f} / {1e3 * (tm - copy):.3f} (less the {1e3 * copy:.3f} ms device copy); {same}"
            )


if __name__ == "__main__":
    main()
