"""Sites per thread: the block splitting kernels with one site per thread (``block_kernels``) against
``site_group_kernels`` with 2, 3, 4 and 7 consecutive sites per thread, and the hand-written CUDA kernel
in the same two shapes (``benchmarks/_baselines.py``: ``verlet`` and ``verlet_sites``), in one process,
velocity Verlet, float64, N = 201, fixed ends, at 1, 64, 805, 4096 and 32768 lattices.

Warp kernels are timed by ``time_steps`` (host clock around one launch, device synchronised, best of 3);
the hand kernels by CUDA events (best of 3) with their host-timed rate beside it. Each Warp variant is
first checked against the numpy reference on the device (max |x - reference| after 400 steps), each
hand variant too.

Command (GPU; the hand kernels need CuPy): ``python benchmarks/sites_per_thread.py [--quick]``

(Until commit 956cfc8 a ``--variants`` mode also timed the site-group kernel without one float64 per thread in
the tile and without accelerations carried across steps, and register caps of the one-site kernel: all slower,
``benchmarks/results/h200-2026-11-22k.json``; those options were removed from the kernels.)
"""

import argparse
import json
from pathlib import Path

import numpy as np


from _baselines import cupy_verlet_runner  # beside this script
from warpchain import Guard, Placement
from warpchain import ChainParams, lowest_optical_mode, reference
from warpchain.engine import tuning
from warpchain.ensemble import simulate, time_steps

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
    args = ap.parse_args()
    p, dt, one, check, ref = setup()
    batches = (1, 805, 32768) if args.quick else (1, 64, 805, 1600, 2400, 4096, 32768)
    rows = []

    def use(label):
        """The Warp variant ``label``: 1, 2, 4, 7 sites per thread, or "1g" (one site per thread through the
        site-group kernels), as engine settings."""
        return tuning.active().replace(sites_per_thread=1 if label == "1g" else label, group_one_site=label == "1g")

    def error(label):
        """The variant's error against the reference after 400 steps."""
        with tuning.override(use(label)):
            run = simulate(
                p,
                check,
                400 * dt,
                dt,
                device=args.device,
                placement=Placement(layout="block"),
                guard=Guard(max_energy_error=None),
            )
        return float(np.max(np.abs(run.x - ref)))

    def measure(name, batch, steps, method="verlet", err=None):
        x0 = np.repeat(one[None], batch, 0)
        with tuning.override(use(name)):
            best = time_steps(p, x0, steps, dt, method=method, device=args.device, layout="block")
        rate = batch * p.N * steps / best
        impl = "warp" if method == "verlet" else f"warp-{method}"
        rows.append({"impl": impl, "sites": name, "batch": batch, "rate": rate, "ns_per_step": 1e9 * best / steps})
        line = (
            f"{impl} sites/thread {name} batch {batch:6d}: {rate:.3g} site-steps/s ({1e9 * best / steps:.1f} ns/step)"
        )
        print(line + (f"; max |x - reference| after 400 steps {err:.2g}" if err is not None else ""), flush=True)

    for label in WARP_SITES:
        err = error(label)
        for batch in batches:
            measure(label, batch, 20000 if batch <= 64 else 2000 if batch < 32768 else 4000, err=err)
    for method in ("yoshida4", "kahan8"):  # many-stage methods: one site per thread against a warp per lattice
        for label in (1, "1g", 7):
            for batch in (805, 4096, 32768):
                measure(label, batch, 400 if batch < 32768 else 200, method=method)
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


if __name__ == "__main__":
    main()
