"""Sites per thread: the block splitting kernels with one site per thread (``block_kernels``) against
``site_group_kernels`` with 2, 3, 4 and 7 consecutive sites per thread, and the hand-written CUDA kernel
in the same two shapes (``scenarios/_baselines.py``: ``verlet`` and ``verlet_sites``), in one process,
velocity Verlet, float64, N = 201, fixed ends, at 1, 64, 805, 4096 and 32768 lattices.

Warp kernels are timed by ``time_steps`` (host clock around one launch, device synchronised, best of 3);
the hand kernels by CUDA events (best of 3) with their host-timed rate beside it. Each Warp variant is
first checked against the numpy reference on the device (max |x - reference| after 400 steps), each
hand variant too.

Command (GPU; the hand kernels need CuPy): ``python benchmarks/sites_per_thread.py [--quick]``

``--variants`` instead times Warp's site-group kernel with and without ``scalar_ends`` (one float64 per
thread in the shared tile when a thread owns one site) and without ``carry`` (the accelerations carried
across steps) against the hand kernel, interleaved over ``--rounds`` rounds (best of all), at the sites per
thread each runs at that batch; ``--sites`` adds forced sites per thread for both. (At commit 162cc50 it
also timed a ``force_first`` option of both, the contact force computed before the exchange's barrier:
slower in both, ``benchmarks/h200-2026-11-22k/sites-variants-first.txt``, and removed.)
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scenarios._baselines import cupy_verlet_runner  # noqa: E402
from warpchain import ChainParams, ensemble, lowest_optical_mode, reference  # noqa: E402
from warpchain.ensemble import simulate, time_steps  # noqa: E402

#: "1g": one site per thread through ``site_group_kernels`` (fixed walls compiled in, no carried acceleration)
WARP_SITES = (1, "1g", 2, 4, 7)
HAND_SITES = (1, 7)


def setup():
    """The chain, dt, the timed state (lowest optical mode, amplitude 0.3), a 3-lattice check batch and its
    numpy reference after 400 Verlet steps."""
    p = ChainParams(30.0, 160.0, 201)
    dt = 0.1
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    check = np.repeat(one[None], 3, 0)
    check[1, 0] *= 0.5
    return p, dt, one, check, reference.integrate("verlet", p, check, dt, 400)["x"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--json", default=None, help="write the rows here")
    ap.add_argument("--variants", action="store_true", help="compare the kernels' options (see the docstring)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64, 805, 4096, 32768], help="with --variants")
    ap.add_argument("--sites", type=int, nargs="*", default=[], help="with --variants: also these sites per thread")
    args = ap.parse_args()
    if args.variants:
        return variants(args)
    p, dt, one, check, ref = setup()
    batches = (1, 805, 32768) if args.quick else (1, 64, 805, 1600, 2400, 4096, 32768)
    rows = []

    def use(label, min_blocks=0):
        """Force the Warp variant ``label``: 1, 2, 4, 7 sites per thread, or "1g" (one site per thread through
        the site-group kernels), with ``min_blocks`` blocks per SM as their launch bound; its error against
        the reference after 400 steps."""
        ensemble._SITES_FORCED = 1 if label == "1g" else label
        ensemble._GROUP_ONE_SITE = label == "1g"
        ensemble._GROUP_MIN_BLOCKS = {1: min_blocks} if min_blocks else {}
        run = simulate(p, check, 400 * dt, dt, device=args.device, layout="block", max_energy_error=None)
        return float(np.max(np.abs(run.x - ref)))

    def measure(name, batch, steps, method="verlet", err=None):
        x0 = np.repeat(one[None], batch, 0)
        best = time_steps(p, x0, steps, dt, method=method, device=args.device, layout="block")
        rate = batch * p.N * steps / best
        impl = "warp" if method == "verlet" else f"warp-{method}"
        rows.append({"impl": impl, "sites": name, "batch": batch, "rate": rate, "ns_per_step": 1e9 * best / steps})
        line = (
            f"{impl} sites/thread {name} batch {batch:6d}: {rate:.3g} site-steps/s ({1e9 * best / steps:.1f} ns/step)"
        )
        print(line + (f"; max |x - reference| after 400 steps {err:.2g}" if err is not None else ""), flush=True)

    for label in WARP_SITES:
        err = use(label)
        for batch in batches:
            measure(label, batch, 20000 if batch <= 64 else 2000 if batch < 32768 else 4000, err=err)
    for min_blocks in (6, 7, 8):  # one site per thread, registers capped so that 805 lattices need fewer waves
        err = use("1g", min_blocks)
        for batch in (1, 805, 1600):
            measure(f"1g-minb{min_blocks}", batch, 20000 if batch <= 64 else 2000, err=err)
    for method in ("yoshida4", "kahan8"):  # many-stage methods: one site per thread against a warp per lattice
        for label in (1, "1g", 7):
            use(label)
            for batch in (805, 4096, 32768):
                measure(label, batch, 400 if batch < 32768 else 200, method=method)
    ensemble._SITES_FORCED = ensemble._GROUP_ONE_SITE = None
    ensemble._GROUP_MIN_BLOCKS = {}
    for sites in HAND_SITES:
        run = cupy_verlet_runner(p.M, p.K, sites=sites)
        if run is None:
            print("CuPy not importable: no hand-written kernels")
            break
        err = float(np.max(np.abs(run(check, 400, dt)[0] - ref)))
        for batch in batches:
            x0 = np.repeat(one[None], batch, 0)
            steps = 20000 if batch <= 64 else 2000 if batch < 32768 else 4000
            times = [(run(x0, steps, dt)[1], run.wall_seconds) for _ in range(3)]
            best, wall = min(times)
            rate = batch * p.N * steps / best
            rows.append(
                {"impl": "hand", "sites": sites, "batch": batch, "rate": rate, "ns_per_step": 1e9 * best / steps}
            )
            print(
                f"hand sites/thread {sites} batch {batch:6d}: {rate:.3g} site-steps/s "
                f"({1e9 * best / steps:.1f} ns/step;"
                f" host-timed {batch * p.N * steps / wall:.3g}); max |x - reference| after 400 steps {err:.2g}",
                flush=True,
            )
    for batch in batches:
        best = {
            impl: max(
                (r for r in rows if r["impl"] == impl and r["batch"] == batch), key=lambda r: r["rate"], default=None
            )
            for impl in ("warp", "hand")
        }
        line = f"best at {batch}: " + ", ".join(
            f"{k} {v['sites']} sites/thread {v['rate']:.3g}" for k, v in best.items() if v
        )
        if best["hand"] and best["warp"]:
            line += f"; warp / hand {best['warp']['rate'] / best['hand']['rate']:.2f}"
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


#: Warp site-group options compared by ``--variants`` (the first is the default)
WARP_OPTIONS = {"default": {}, "no scalar_ends": {"scalar_ends": False}, "no carry": {"carry": False}}


def variants(args):
    """Each option set of the Warp site-group kernel and of the hand kernel, per batch, interleaved."""
    p, dt, one, check, ref = setup()
    batches = args.batches
    steps = {1: 200000, 64: 50000, 805: 4000, 4096: 2000, 32768: 1000}
    best: dict = {}
    for name, options in WARP_OPTIONS.items():
        ensemble._GROUP_OPTIONS = options
        for sites in (1, 7):
            ensemble._SITES_FORCED, ensemble._GROUP_ONE_SITE = sites, True
            run = simulate(p, check, 400 * dt, dt, device=args.device, layout="block", max_energy_error=None)
            print(
                f"warp {name}, {sites} sites/thread: max |x - reference| after 400 steps "
                f"{float(np.max(np.abs(run.x - ref))):.2g}",
                flush=True,
            )
    hand = cupy_verlet_runner(p.M, p.K)
    if hand is None:
        print("CuPy not importable: no hand-written kernel")
    forced_hands = {sites: cupy_verlet_runner(p.M, p.K, sites=sites) for sites in args.sites}
    for sites in sorted({1, 7, *args.sites}) if hand is not None else ():
        r = forced_hands.get(sites) or cupy_verlet_runner(p.M, p.K, sites=sites)
        print(
            f"hand, {sites} sites/thread: max |x - reference| after 400 steps "
            f"{float(np.max(np.abs(r(check, 400, dt)[0] - ref))):.2g}",
            flush=True,
        )
    for rnd in range(args.rounds):
        for batch in batches:
            x0 = np.repeat(one[None], batch, 0)
            n = steps.get(batch, 1000) if args.device != "cpu" else 20
            for name, options in WARP_OPTIONS.items():
                ensemble._GROUP_OPTIONS = options
                ensemble._SITES_FORCED, ensemble._GROUP_ONE_SITE = None, None
                seconds = time_steps(p, x0, n, dt, device=args.device, layout="block", repeats=3)
                key = ("warp", name, batch)
                best[key] = min(best.get(key, np.inf), seconds / n)
            ensemble._GROUP_OPTIONS = {}
            for forced in args.sites:
                ensemble._SITES_FORCED, ensemble._GROUP_ONE_SITE = forced, True
                seconds = time_steps(p, x0, n, dt, device=args.device, layout="block", repeats=3)
                key = ("warp", f"{forced} sites/thread", batch)
                best[key] = min(best.get(key, np.inf), seconds / n)
            ensemble._SITES_FORCED, ensemble._GROUP_ONE_SITE = None, None
            if hand is not None:
                seconds = hand(x0, n, dt, repeats=3)[1]
                best["hand", "default", batch] = min(best.get(("hand", "default", batch), np.inf), seconds / n)
                for forced in args.sites:
                    seconds = forced_hands[forced](x0, n, dt, repeats=3)[1]
                    key = ("hand", f"{forced} sites/thread", batch)
                    best[key] = min(best.get(key, np.inf), seconds / n)
        print(f"round {rnd + 1} done", flush=True)
    ensemble._GROUP_OPTIONS = {}
    ensemble._SITES_FORCED = ensemble._GROUP_ONE_SITE = None
    rows = []
    for batch in batches:
        sites = ensemble.sites_per_thread(batch, p.N, 1, args.device)
        for (impl, name, b), per_step in best.items():
            if b == batch:
                rate = batch * p.N / per_step
                rows.append(
                    {"impl": impl, "variant": name, "batch": batch, "rate": rate, "ns_per_step": 1e9 * per_step}
                )
                print(
                    f"{impl:4s} {name:20s} batch {batch:6d} (warp {sites} sites/thread): {rate:.4g} site-steps/s "
                    f"({1e9 * per_step:.1f} ns/step)"
                )
        warp = best[("warp", "default", batch)]
        if ("hand", "default", batch) in best:
            print(f"  warp default / hand at {batch}: {best['hand', 'default', batch] / warp:.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
