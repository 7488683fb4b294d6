"""The monodromy's kernels, variant by variant: the paper breather's base run (one lattice, kahan8, 64 steps,
recording the contact stiffness) and its tangent columns (804 for the monodromy, 402 for a Newton iteration),
for every (columns per block, history prefetch, register cap) of ``block_kernels``' tangent kernel; each
checked bit for bit against the first variant and against the numpy reference. Kernel time best of
``--repeats`` (device synchronised before and after each launch).

With ``--monodromy`` it also times the 804-column monodromy end to end, its launches issued one by one against
replayed as a CUDA graph (``ensemble._Replay``): through ``propagate_tangent`` and through the Flow.

Command (GPU): ``python benchmarks/tangent_variants.py [--repeats 20] [--monodromy] [--base-only]``
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

BASE_VARIANTS = [  # (label, ensemble settings, register cap forced on the default kernel, stiffness recorded)
    ("history stored per force evaluation, capped (before)", {"_RECORD_PER_STEP": False}, None, True),
    ("history stored per force evaluation, uncapped", {"_RECORD_PER_STEP": False}, 0, True),
    ("history stored per step, uncapped (default)", {}, None, True),
    ("history stored per step, capped", {"_RECORD_UNCAPPED_MAX_BATCH": 0}, None, True),
    ("no history", {}, None, False),
    ("site-group kernel", {"_GROUP_ONE_SITE": True}, None, True),
]
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
    ap.add_argument("--base-only", action="store_true", help="the base runs only (e.g. under ncu)")
    ap.add_argument("--monodromy", action="store_true", help="also the monodromy end to end, eager against graphs")
    args = ap.parse_args()
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    x0 = nls_seed(params, PAPER_OMEGA)[None]
    period = 2 * np.pi / PAPER_OMEGA
    nsteps, dt = BREATHER_STEPS_PER_PERIOD, period / BREATHER_STEPS_PER_PERIOD
    meth = get_method(BREATHER_METHOD)
    M, K = np.array([PAPER_M]), np.array([PAPER_K])
    defaults = dict(ensemble._TANGENT_PAIR_MIN_BLOCKS)
    print(f"{BREATHER_METHOD}, N = {params.N}, {nsteps} steps (one period), {args.device}; best / median ms")
    from warpchain import block_kernels

    first_end = None
    for label, settings, cap, record in BASE_VARIANTS:
        saved = {name: getattr(ensemble, name) for name in settings}
        for name, value in settings.items():
            setattr(ensemble, name, value)
        runner = ensemble._Runner(meth, params, x0, M, K, args.device, record_stiffness_steps=nsteps, layout="block")
        if cap is not None:
            runner.bk = block_kernels.block_kernels(runner.block, cap)
        wp = runner.wp

        def base():
            runner.launch(nsteps, dt, record_stiffness=record)  # a period further along the (near) breather

        b, bm = best(base, wp, args.device, args.repeats)
        runner.load(x0, M, K)
        base()
        end = runner.x.numpy().copy()
        first_end = end if first_end is None else first_end
        same = "same bits" if np.array_equal(end, first_end) else f"DIFFERS by {np.max(np.abs(end - first_end)):.3g}"
        print(f"base run ({label}): {1e3 * b:.3f} / {1e3 * bm:.3f}; {same}", flush=True)
        for name, value in saved.items():
            setattr(ensemble, name, value)
    if args.base_only:
        return
    runner = ensemble._Runner(meth, params, x0, M, K, args.device, record_stiffness_steps=nsteps, layout="block")
    base = lambda: runner.launch(nsteps, dt, record_stiffness=True)  # noqa: E731
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
    ensemble._TANGENT_COLUMNS, ensemble._TANGENT_PREFETCH = None, None
    ensemble._TANGENT_PAIR_MIN_BLOCKS = defaults
    if args.monodromy:
        monodromy(params, x0[0], nsteps, dt, args)


def monodromy(params, x0, nsteps, dt, args):
    """The 804-column monodromy end to end, launched one by one against replayed as a graph: through
    ``propagate_tangent`` (device time between its events, host time of the launches) and as Floquet gets it
    (``Flow.linearize`` + ``unit_columns("all")``, wall time)."""
    from warpchain import Flow, propagate_tangent

    n = 4 * params.N
    eye = np.eye(n).reshape(n, 4, params.N)
    for after in (None, 1):
        ensemble._GRAPH_AFTER = after
        label = "graphs" if after is not None else "eager "
        runs = [
            propagate_tangent(params, x0, eye, nsteps, dt, method=BREATHER_METHOD, device=args.device)
            for _ in range(args.repeats)
        ]
        kernel = [r.kernel_seconds for r in runs]
        launch = [r.launch_seconds for r in runs]
        wall = [r.wall_seconds for r in runs]
        print(
            f"propagate_tangent, {label}: kernel {1e3 * min(kernel):.3f} / {1e3 * np.median(kernel):.3f}, launches "
            f"{1e3 * min(launch):.3f} / {1e3 * np.median(launch):.3f}, wall {1e3 * min(wall):.3f} / "
            f"{1e3 * np.median(wall):.3f}; columns rel diff to the first {rel(runs[-1].columns, runs[0].columns):.1e}",
            flush=True,
        )
        flow = Flow(BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, device=args.device)
        times, cols = [], []
        for _ in range(args.repeats + 2):
            t0 = time.perf_counter()
            cols.append(flow.linearize(params, x0, nsteps, dt).unit_columns("all"))
            times.append(time.perf_counter() - t0)
        times = times[2:]
        print(
            f"Flow.linearize + unit_columns('all'), {label}: wall {1e3 * min(times):.3f} / "
            f"{1e3 * np.median(times):.3f}; same bits as propagate_tangent: "
            f"{np.array_equal(cols[-1], runs[0].columns.reshape(n, -1).T)}",
            flush=True,
        )
    ensemble._GRAPH_AFTER = 1


def rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


if __name__ == "__main__":
    main()
