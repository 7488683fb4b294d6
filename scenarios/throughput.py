"""Throughput: site-steps per second (batch x N x steps / seconds) of the Warp integrators against the
numpy reference over batch sizes 1 to 32768 (4096 on the CPU, capped by time), all measured in one
run on the current device; on a GPU also JAX (vmap + fori_loop) and a hand-written CUDA kernel through
CuPy, when importable. Each result is also given as a fraction of the best at its batch size.

Command: ``python -m scenarios run throughput`` (about 1-2 minutes on a 2-core CPU; ``--quick`` ~20 s).
The device, CPU or GPU model and package versions are recorded in summary.json.
"""

from __future__ import annotations

import time

import numpy as np

from warpchain import METHODS, ChainParams, lowest_optical_mode, reference, simulate
from warpchain.ensemble import cpu_threads
from warpchain.store import device_description, open_store, provenance, read_group, write_table

from ._baselines import cupy_verlet_runner, jax_verlet_runner
from ._common import PAPER_K, PAPER_M, PAPER_N, Context, pyplot, read_summary, save_figure

# parameters
BATCHES_CPU = (1, 4, 16, 64, 256, 805, 4096)        # 32768 would take minutes per method on 2 cores
BATCHES_GPU = (1, 16, 64, 256, 805, 4096, 32768)
BATCHES_QUICK = (1, 64, 805)
DT = 0.1
SECONDS_PER_MEASUREMENT = 0.5    # each measurement is sized from a short probe to take about this long
PROBE_STEPS = 2
NUMPY_MAX_BATCH = 4096


def _measure(run_steps, seconds):
    """Time run_steps(n) -> seconds for a step count sized (from a probe) to take ``seconds``."""
    probe = run_steps(PROBE_STEPS)
    steps = int(np.clip(PROBE_STEPS * seconds / max(probe, 1e-9), PROBE_STEPS, 500000))
    return steps, run_steps(steps)


def run(ctx: Context) -> dict:
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    _, shape = lowest_optical_mode(params)
    one = np.zeros((4, params.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    gpu = ctx.device.startswith("cuda")
    batches = BATCHES_QUICK if ctx.quick else (BATCHES_GPU if gpu else BATCHES_CPU)
    seconds = SECONDS_PER_MEASUREMENT * (0.3 if ctx.quick else 1.0)
    results = []

    def record(impl, method, batch, steps, seconds, **extra):
        rate = batch * params.N * steps / seconds
        results.append({"implementation": impl, "method": method, "batch": batch, "steps": steps,
                        "seconds": seconds, "site_steps_per_second": rate, **extra})
        ctx.log("%-6s %-8s batch %6d: %.3g site-steps/s", impl, method, batch, rate)

    jax_run = jax_verlet_runner(PAPER_M, PAPER_K) if gpu else None
    cupy_run = cupy_verlet_runner(PAPER_M, PAPER_K) if gpu else None
    for batch in batches:
        x0 = np.repeat(one[None], batch, axis=0)
        for name in METHODS:
            simulate(params, x0, 2 * DT, DT, method=name, device=ctx.device, chunks=1)  # warm-up / compile

            def warp_run(n, name=name):
                return simulate(params, x0, n * DT, DT, method=name, device=ctx.device, chunks=1,
                                max_energy_error=None).wall_seconds

            steps, sec = _measure(warp_run, seconds)
            record("warp", name, batch, steps, sec)
        if batch <= NUMPY_MAX_BATCH:
            def numpy_run(n):
                t0 = time.perf_counter()
                reference.integrate("verlet", params, x0, DT, n)
                return time.perf_counter() - t0

            steps, sec = _measure(numpy_run, seconds)
            record("numpy", "verlet", batch, steps, sec)
        for impl, runner in (("jax", jax_run), ("cupy", cupy_run)):
            if runner is not None:
                steps, sec = _measure(lambda n: runner(x0, n, DT)[1], seconds)
                record(impl, "verlet", batch, steps, sec)
    # fraction of the best Verlet implementation at each batch size
    for batch in batches:
        same = [r for r in results if r["batch"] == batch and r["method"] == "verlet"]
        best = max(r["site_steps_per_second"] for r in same)
        for r in same:
            r["fraction_of_best"] = r["site_steps_per_second"] / best
    ratios = {}
    for batch in batches:
        w = [r for r in results if r["batch"] == batch and r["implementation"] == "warp" and r["method"] == "verlet"]
        n = [r for r in results if r["batch"] == batch and r["implementation"] == "numpy"]
        if w and n:
            ratios[str(batch)] = w[0]["site_steps_per_second"] / n[0]["site_steps_per_second"]
    root = open_store(ctx.out / "data.zarr", params=params.as_dict(), provenance_info=provenance(ctx.device))
    impls = sorted({r["implementation"] for r in results})
    methods = sorted({r["method"] for r in results})
    write_table(root, "results", {
        "implementation": [impls.index(r["implementation"]) for r in results],
        "method": [methods.index(r["method"]) for r in results], "batch": [r["batch"] for r in results],
        "site_steps_per_second": [r["site_steps_per_second"] for r in results]}, dim="result",
        attrs={"implementation_names": impls, "method_names": methods})
    prov = provenance(ctx.device)
    return {"device": device_description(ctx.device), "cpu": prov["cpu"], "packages": prov["packages"],
            "cpu_threads": cpu_threads() if not gpu else None, "N": params.N, "dt": DT,
            "results": results, "warp_verlet_over_numpy": ratios}


def plot(out) -> None:
    s = read_summary(out)
    d, attrs = read_group(out / "data.zarr", "results")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    for i, impl in enumerate(attrs["implementation_names"]):
        for k, method in enumerate(attrs["method_names"]):
            m = (d["implementation"] == i) & (d["method"] == k)
            if m.any():
                style = {"warp": "o-", "numpy": "s--", "jax": "^-", "cupy": "D-"}.get(impl, "x-")
                ax.loglog(d["batch"][m], d["site_steps_per_second"][m], style, ms=4, label=f"{impl} {method}")
    ax.set_xlabel("lattices in the batch")
    ax.set_ylabel("site-steps per second")
    ax.set_title(f"throughput, N = {s['N']}, float64 - {s['device']}", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    save_figure(fig, out, "throughput")
