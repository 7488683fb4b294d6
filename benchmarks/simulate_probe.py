"""simulate() on a GPU: the sliced transfer path against the plain one (identical results), the
two-lattices-per-block kernel against the numpy reference, the non-finite x0 error, and simulate() end
to end (default and recording every 20 steps) against the kernel rate at 805, 8192 and 32768 lattices
(Verlet, N = 201, 2000 steps, best of 3 after one untimed call). The throughput scene measures the
same; this is the quick look.

Command (GPU): ``python benchmarks/simulate_probe.py``
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpchain import ChainParams, ensemble, lowest_optical_mode, simulate  # noqa: E402
from warpchain.ensemble import time_steps  # noqa: E402


def main():
    p = ChainParams(30.0, 160.0, 201)
    _, shape = lowest_optical_mode(p)
    one = np.zeros((4, p.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    rng = np.random.default_rng(0)
    x0 = np.repeat(one[None], 8192, 0) * (1 + 0.1 * rng.standard_normal((8192, 1, 1)))
    default_min = ensemble._SLICED_MIN_VALUES
    ensemble._SLICED_MIN_VALUES = 1  # sliced
    a = simulate(p, x0, 50.0, 0.1, device="cuda", save_every=50)
    c = simulate(p, x0, 50.0, 0.1, device="cuda")
    ensemble._SLICED_MIN_VALUES = 1 << 60  # plain
    b = simulate(p, x0, 50.0, 0.1, device="cuda", save_every=50)
    d = simulate(p, x0, 50.0, 0.1, device="cuda")
    ensemble._SLICED_MIN_VALUES = default_min
    same = [
        np.array_equal(a.x, b.x),
        np.array_equal(a.u, b.u),
        np.array_equal(a.min_contact, b.min_contact),
        np.array_equal(c.x, d.x),
        np.array_equal(a.energy_trace, b.energy_trace),
    ]
    print("sliced == plain (x, u, min_contact, x without recording, energy trace):", same)
    # the two-lattices-per-block kernel (batches >= 4096) against the numpy reference, odd batch
    from warpchain import reference

    xs = x0[:4097].copy()
    run = simulate(p, xs, 200 * 0.1, 0.1, device="cuda", method="yoshida4", save_every=100)
    ref = reference.integrate("yoshida4", p, xs, 0.1, 200, save_every=100)
    scale = np.max(np.abs(ref["x"]))
    print(
        "two per block, 4097 lattices, 200 yoshida4 steps: max |x - reference| / max |x| =",
        f"{np.max(np.abs(run.x - ref['x'])) / scale:.2g}, frames {np.max(np.abs(run.u - ref['u'])) / scale:.2g}",
    )
    bad = x0.copy()
    bad[5000, 1, 3] = np.nan
    try:
        simulate(p, bad, 50.0, 0.1, device="cuda")
        print("no error for a non-finite x0!")
    except ValueError as exc:
        print("ValueError:", exc)
    for batch in (805, 8192, 32768):
        x0 = np.repeat(one[None], batch, 0)
        kernel = time_steps(p, x0, 2000, 0.1, device="cuda", repeats=3)
        site_steps = batch * p.N * 2000
        for name, kwargs in (("default", {}), ("save_every=20", {"save_every": 20})):
            simulate(p, x0, 200.0, 0.1, device="cuda", **kwargs)
            best = np.inf
            for _ in range(3):
                t0 = time.perf_counter()
                run = simulate(p, x0, 200.0, 0.1, device="cuda", **kwargs)
                best = min(best, time.perf_counter() - t0)
                del run
            print(
                f"batch {batch} {name}: kernel {site_steps / kernel:.3g} site-steps/s, simulate "
                f"{site_steps / best:.3g} ({kernel / best:.2f}x the kernel, {1e3 * best:.1f} ms)",
                flush=True,
            )


if __name__ == "__main__":
    main()
