"""GPU checks and rates of the loss + observation engine (``warpchain.observe``), in one process.

Command (on a GPU machine): ``python benchmarks/breakup_gpu.py OUT_DIR``. Writes ``breakup-gpu.json``.

1. Agreement on the GPU: ``observe`` (damped, block kernels) against ``reference.observe`` (numpy),
   and damped ``simulate`` against ``reference.integrate``; zero-damping ``observe`` against ``simulate``.
2. Rates, site-steps per second, best of 3, the same batch: the plain Verlet block kernel
   (``time_steps``), ``observe`` without losses and with losses (one frame per 32 steps, end to end:
   launches, the per-chunk copies of the observables, the final envelope copies).
"""

import json
import sys
import time
from pathlib import Path

import numpy as np

from warpchain import ChainParams, reference, simulate
from warpchain.ensemble import time_steps
from warpchain.losses import Damping
from warpchain.observe import Observation, observe

N = 201
PARAMS = ChainParams(30.0, 160.0, N)
T = 2 * np.pi / 1.01
DT = T / 32


def spots(batch, A=0.4, W=20.0, seed=0):
    j = np.arange(N)
    rng = np.random.default_rng(seed)
    x = np.zeros((batch, 4, N))
    x[:, 2] = A * np.exp(-0.5 * ((j - N // 2) / W) ** 2) * (1 + 0.02 * rng.standard_normal((batch, N)))
    return x


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    result = {"device": "cuda:0"}
    import warp as wp

    result["gpu"] = wp.get_device("cuda:0").name
    result["warp"] = wp.config.version
    # 1. agreement
    x0 = spots(8)
    damping = Damping(np.linspace(0.0, 0.01, 8), np.r_[np.zeros(4), np.full(4, 0.005)])
    ob = Observation(frame_every=32, threshold=0.1, radius=10, contrast=0.5, spot=20.0, lag_frames=2)
    run = observe(PARAMS, x0, 10 * T, DT, observation=ob, damping=damping, device="cuda:0")
    values, env, x = reference.observe("verlet", PARAMS, x0, run.dt, run.nsteps, ob, damping=damping)
    scale = np.abs(values).max(axis=(0, 1))
    result["observe_vs_reference"] = {
        "state_max_abs": float(np.abs(run.x - x).max()),
        "observables_max_rel": (np.abs(run.values - values).max(axis=(0, 1)) / np.maximum(scale, 1e-300)).tolist(),
        "peaks_equal": bool(np.array_equal(run["peaks"], values[..., 0])),
        "envelope_max_abs": float(np.abs(run.envelope - env).max()),
    }
    sim = simulate(PARAMS, x0, 10 * T, DT, method="kahan6", device="cuda:0", damping=damping)
    ref = reference.integrate("kahan6", PARAMS, x0, sim.dt, sim.nsteps, damping=damping)["x"]
    result["damped_simulate_vs_reference_max_abs"] = float(np.abs(sim.x - ref).max())
    zero = observe(PARAMS, x0, 10 * T, DT, observation=ob, method="kahan8", damping=(0.0, 0.0), device="cuda:0")
    plain = simulate(PARAMS, x0, zero.t[-1], zero.dt, method="kahan8", device="cuda:0")
    result["zero_damping_observe_vs_simulate_bitwise"] = bool(np.array_equal(zero.x, plain.x))
    result["zero_damping_observe_vs_simulate_max_abs"] = float(np.abs(zero.x - plain.x).max())
    print(json.dumps(result, indent=1), flush=True)
    # 2. rates
    rates = []
    steps = 3200  # 100 periods
    for batch in (2432, 8192, 32768):
        x0 = spots(batch)
        kernel = time_steps(PARAMS, x0, steps, DT, method="verlet", device="cuda:0")
        row = {"batch": batch, "kernel_site_steps_per_s": batch * N * steps / kernel}
        for label, damp in (("observe_lossless", None), ("observe_damped", (1e-3, 1e-3))):  # Verlet, as the kernel
            obs = Observation(frame_every=32, threshold=0.1, radius=10, contrast=0.5, spot=20.0, lag_frames=10)
            observe(PARAMS, x0, 2 * T, DT, observation=obs, damping=damp, device="cuda:0")  # compile, warm
            best = np.inf
            for _ in range(3):
                t0 = time.perf_counter()
                observe(PARAMS, x0, steps * DT, DT, observation=obs, damping=damp, device="cuda:0", chunks=10)
                best = min(best, time.perf_counter() - t0)
            row[f"{label}_site_steps_per_s"] = batch * N * steps / best
            row[f"{label}_vs_kernel"] = kernel / best
        rates.append(row)
        print(json.dumps(row), flush=True)
    result["rates"] = rates
    (out / "breakup-gpu.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "."))
