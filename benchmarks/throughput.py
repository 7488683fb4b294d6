"""Throughput: how fast the Warp kernels step ensembles of lattices and monodromy batches, against the
numpy reference and (on a GPU, when importable) JAX (vmap + fori_loop) and a hand-written CUDA kernel
through CuPy - all measured in one run on the current device and reported as ratios.

Three parts:

* **ensemble**: site-steps per second (batch x N x steps / seconds) of velocity Verlet for batch sizes
  1 to 32768, every implementation, each also as a fraction of the best at its batch size; every
  Warp method in the block layout (the GPU default) as force evaluations per second relative to
  Verlet; a single lattice as nanoseconds per Verlet step.
* **monodromy**: the paper breather (w_b = 1.01, K = 160, kahan8, 32 steps per period): the full
  804-column monodromy (``propagate_tangent``'s kernel time and wall time, and the Flow's wall time as
  Floquet gets it) and one Newton iteration end to end (tangent batch of the half-period map,
  transfers, linear solve).
* **kernels** (GPU): registers per thread, local memory and theoretical occupancy of each kernel.
* **simulate**: ``simulate()`` end to end as users call it (validation, upload, chunks, the guard,
  the final state back on the host), with default arguments, continued on the device (``DeviceState`` x0,
  ``keep_on_device``), and recording a frame every
  ``record_every`` steps, beside the kernel's own rate on the same batch (``time_steps``), all Verlet
  over ``simulate_steps`` steps; recording also as GB/s of frames reaching host memory. Measured first,
  before the baselines load JAX and CuPy into the process (which slow ``simulate()`` on small batches).

Timings are kernel time (device synchronised before and after, transfers excluded; best of 3), with
the step count sized so that a measurement takes about ``seconds`` s.

Command: ``python benchmarks/throughput.py [--device cuda] [--out results]`` (about 2 minutes on a 2-core
CPU, about 1 minute on an H200; ``--quick`` ~20 s), writing OUT/throughput/ (summary.json, figures) as a scene
does. Device, CPU/GPU model and package versions are recorded in summary.json.
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from warpchain import (
    METHODS,
    ChainParams,
    DeviceState,
    frame_buffers,
    lowest_optical_mode,
    propagate_tangent,
    reference,
    simulate,
)
from warpchain.engine.devices import cpu_threads
from warpchain.engine.plans import sites_per_thread
from warpchain.ensemble import time_steps
from warpchain.integrators import SplittingMethod
from warpchain.store import device_description, provenance, read_group, write_table

from scenarios._common import PAPER_K, PAPER_M, PAPER_N, Context, paper_breather, pyplot, read_summary, save_figure
from scenarios._params import Rule, number, param, stability_dt

#: an H100/H200-class SM: registers, resident threads, resident blocks (for the theoretical occupancy)
CUDA_SM_REGISTERS, CUDA_SM_THREADS, CUDA_SM_BLOCKS = 65536, 2048, 32


def _shortest_limit() -> float:
    """The smallest linear stability limit on dt over the registry's methods, on the paper chain: every
    method is timed at ``dt``."""
    return min(stability_dt(name, PAPER_M, PAPER_K) for name in METHODS)


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    batches_cpu: tuple[int, ...] = param(
        (1, 16, 64, 256, 805, 4096), "lattices per batch, on a CPU", ge=1, length=(1, None)
    )
    batches_gpu: tuple[int, ...] = param(
        (1, 16, 64, 256, 805, 4096, 32768), "lattices per batch, on a GPU", ge=1, length=(1, None)
    )
    all_methods_at: tuple[int, ...] = param(
        (805, 32768), "batches where every method is timed, those present; the last batch always", ge=1
    )
    thread_layout_max_batch_gpu: int = param(
        4096, "largest batch timed in the thread-per-lattice layout on a GPU, slow there", ge=0
    )
    numpy_max_batch: int = param(805, "largest batch the numpy reference is timed at", ge=0)
    dt: float = param(0.1, "time step of every timed run", gt=0)
    seconds: float = param(0.4, "target duration of one timed run", gt=0)
    max_steps: int = param(2_000_000, "most steps of one timed run", ge=1)
    repeats: int = param(3, "best of, for the ensemble timings", ge=1)
    monodromy: bool = param(True, "time the monodromy and a Newton iteration; needs the paper breather")
    monodromy_repeats: int = param(3, "best of, for those", ge=1)
    simulate_batches_cpu: tuple[int, ...] = param((64, 805), "batches of simulate() end to end, on a CPU", ge=1)
    simulate_batches_gpu: tuple[int, ...] = param(
        (805, 8192, 32768), "batches of simulate() end to end, on a GPU", ge=1
    )
    simulate_steps: int = param(2000, "steps of each simulate() run", ge=1)
    record_every: int = param(20, "steps between recorded frames of simulate()", ge=1)
    simulate_repeats: int = param(3, "best of, after one untimed call", ge=1)

    RULES = (
        Rule(
            ("dt",),
            lambda P: (
                f"dt < {number(_shortest_limit())}, the smallest linear stability limit of the methods on the "
                "paper chain: every method is timed"
            ),
            lambda P: P.dt < _shortest_limit(),
        ),
        Rule(
            ("record_every", "simulate_steps"),
            "record_every <= simulate_steps: a frame is recorded within the run",
            lambda P: P.record_every <= P.simulate_steps,
        ),
    )


QUICK = {
    "batches_cpu": (1, 64, 805),
    "batches_gpu": (1, 64, 805),
    "seconds": 0.12,
    "monodromy": False,
    "monodromy_repeats": 1,
    "simulate_batches_cpu": (64,),
    "simulate_batches_gpu": (805,),
    "simulate_steps": 400,
    "simulate_repeats": 1,
}


def _measure(run_steps, seconds, max_steps):
    """(steps, seconds) of run_steps(steps) -> seconds, with steps grown until a run takes about
    ``seconds`` (short runs are dominated by launch latency and clock ramp-up)."""
    steps = 8
    while True:
        took = run_steps(steps)
        if took >= seconds / 4 or steps >= max_steps:
            break
        steps = int(min(max_steps, steps * min(64.0, max(2.0, seconds / 4 / max(took, 1e-7)))))
    final = int(np.clip(steps * seconds / max(took, 1e-9), 1, max_steps))
    return final, run_steps(final)


def _occupancy(registers: int, block: int, shared_bytes: int = 0) -> float:
    """Theoretical occupancy (resident threads / 2048 per SM) on an H100/H200-class SM."""
    warps = -(-block // 32)
    regs_per_warp = -(-registers * 32 // 256) * 256
    by_regs = CUDA_SM_REGISTERS // max(regs_per_warp * warps, 1)
    by_threads = CUDA_SM_THREADS // (warps * 32)
    by_smem = (228 * 1024) // shared_bytes if shared_bytes else CUDA_SM_BLOCKS
    blocks = min(by_regs, by_threads, by_smem, CUDA_SM_BLOCKS)
    return blocks * warps * 32 / CUDA_SM_THREADS


def _ensemble(ctx, P: Parameters, params, one, gpu):
    batches = tuple(int(batch) for batch in (P.batches_gpu if gpu else P.batches_cpu))
    all_methods_at = tuple(int(batch) for batch in P.all_methods_at)
    seconds = P.seconds
    results = []

    def record(impl, method, batch, steps, sec, evals=1, sites=None):
        rate = batch * params.N * steps / sec
        results.append(
            {
                "implementation": impl,
                "method": method,
                "batch": batch,
                "steps": steps,
                "seconds": sec,
                "site_steps_per_second": rate,
                "force_evals_per_second": rate * evals,
                "ns_per_step": 1e9 * sec / steps,
                "sites_per_thread": sites,
            }
        )
        ctx.log(
            "%-11s %-8s batch %6d: %.3g site-steps/s (%.3g ns/step%s)",
            impl,
            method,
            batch,
            rate,
            1e9 * sec / steps,
            f", {sites} sites per thread" if sites else "",
        )

    from _baselines import cupy_verlet_runner, jax_verlet_runner  # beside this script

    jax_run = jax_verlet_runner(PAPER_M, PAPER_K) if gpu else None
    cupy_run = cupy_verlet_runner(PAPER_M, PAPER_K) if gpu else None
    layouts = ["block", "thread"] if gpu else ["thread", "block"]
    for batch in batches:
        x0 = np.repeat(one[None], batch, axis=0)
        for layout in layouts:
            if gpu and layout == "thread" and batch > P.thread_layout_max_batch_gpu:
                continue
            if not gpu and layout == "block" and batch > 64:
                continue  # CPU fibers: a correctness path, not a fast one; one point shows it
            main = layout == ("block" if gpu else "thread")
            every = main and (batch in all_methods_at or batch == batches[-1])
            names = [n for n, m in sorted(METHODS.items()) if isinstance(m, SplittingMethod)] if every else ["verlet"]
            for name in names:

                def warp_run(n, name=name, layout=layout):
                    return time_steps(
                        params, x0, n, P.dt, method=name, device=ctx.device, layout=layout, repeats=P.repeats
                    )

                steps, sec = _measure(warp_run, seconds, P.max_steps)
                sites = None
                if layout == "block":
                    sites = sites_per_thread(batch, params.N, METHODS[name].stages, ctx.device)
                record(f"warp-{layout}", name, batch, steps, sec, METHODS[name].force_evaluations, sites)
        if batch <= P.numpy_max_batch:

            def numpy_run(n):
                t0 = time.perf_counter()
                reference.integrate("verlet", params, x0, P.dt, n)
                return time.perf_counter() - t0

            steps, sec = _measure(numpy_run, seconds, P.max_steps)
            record("numpy", "verlet", batch, steps, sec)
        for impl, runner in (("jax", jax_run), ("cupy", cupy_run)):
            if runner is not None:
                steps, sec = _measure(lambda n: runner(x0, n, P.dt, repeats=P.repeats)[1], seconds, P.max_steps)
                record(impl, "verlet", batch, steps, sec, sites=getattr(runner, "sites", None))
    for batch in batches:
        same = [r for r in results if r["batch"] == batch and r["method"] == "verlet"]
        best = max(r["site_steps_per_second"] for r in same)
        for r in same:
            r["fraction_of_best"] = r["site_steps_per_second"] / best
    return batches, results


def _ratios(batches, results, gpu):
    """Headline ratios, each from numbers of this one run."""

    def rate(impl, batch, method="verlet"):
        hit = [r for r in results if r["implementation"] == impl and r["batch"] == batch and r["method"] == method]
        return hit[0]["site_steps_per_second"] if hit else None

    main = "warp-block" if gpu else "warp-thread"
    out = {
        "main_layout": main,
        "over_numpy": {},
        "over_jax": {},
        "over_cupy": {},
        "over_thread_layout": {},
        "force_eval_cost_over_verlet": {},
    }
    for batch in batches:
        w = rate(main, batch)
        for key, other in (("over_numpy", "numpy"), ("over_jax", "jax"), ("over_cupy", "cupy")):
            o = rate(other, batch)
            if w and o:
                out[key][str(batch)] = w / o
        if gpu and rate("warp-thread", batch):
            out["over_thread_layout"][str(batch)] = w / rate("warp-thread", batch)
        per_method = {}
        for name, meth in METHODS.items():
            r = rate(main, batch, name)
            if r and name != "verlet":
                # cost per force evaluation relative to Verlet's (1.0: no overhead beyond the evaluations)
                per_method[name] = w / (r * meth.force_evaluations)
        if per_method:
            out["force_eval_cost_over_verlet"][str(batch)] = per_method
    single = [r for r in results if r["implementation"] == main and r["batch"] == 1 and r["method"] == "verlet"]
    out["single_lattice_ns_per_step"] = single[0]["ns_per_step"] if single else None
    return out


def _simulate_end_to_end(ctx, P: Parameters, params, one, gpu):
    """simulate() as users call it against the kernel rate on the same batch, in one run."""
    rows = []
    steps = int(P.simulate_steps)
    t_final = steps * P.dt
    for batch in P.simulate_batches_gpu if gpu else P.simulate_batches_cpu:
        batch = int(batch)
        x0 = np.repeat(one[None], batch, axis=0)
        kernel = time_steps(params, x0, steps, P.dt, device=ctx.device, repeats=P.repeats)
        site_steps = batch * params.N * steps
        row = {"batch": batch, "steps": steps, "kernel_seconds": kernel, "kernel_rate": site_steps / kernel}
        every = int(P.record_every)
        shape = (1 + steps // every, batch, params.N)
        variants = (
            ("default", lambda: {}),
            # a run continued on the device: x0 an earlier result's DeviceState (keep_on_device), no transfer
            ("on_device", lambda: {"x0": DeviceState.of(x0, device=ctx.device), "keep_on_device": True}),
            ("recording", lambda: {"save_every": every}),
            # an ensemble study's frame arrays, allocated once: plain, and page-locked by frame_buffers (which
            # simulate copies the frames into straight from the device)
            ("recording_reused", lambda: {"save_every": every, "frames_out": (np.zeros(shape), np.zeros(shape))}),
            (
                "recording_pinned",
                lambda: {"save_every": every, "frames_out": frame_buffers(params, batch, t_final, P.dt, every)},
            ),
        )
        for name, make in variants:
            kwargs = make()
            start = kwargs.pop("x0", x0)
            simulate(params, start, t_final, P.dt, device=ctx.device, **kwargs)  # compile, pinned buffers
            walls = []
            for _ in range(int(P.simulate_repeats)):
                t0 = time.perf_counter()
                run = simulate(params, start, t_final, P.dt, device=ctx.device, **kwargs)
                walls.append(time.perf_counter() - t0)
                del run
            wall = min(walls)
            row[f"{name}_seconds"] = wall
            row[f"{name}_rate"] = site_steps / wall
            row[f"{name}_over_kernel"] = kernel / wall
            del kwargs, start
        frames = 1 + steps // int(P.record_every)
        row["recorded_frames"] = frames
        row["frame_bytes"] = 2 * frames * batch * params.N * 8
        for name in ("recording", "recording_reused", "recording_pinned"):
            row[f"{name}_gb_per_second"] = row["frame_bytes"] / row[f"{name}_seconds"] / 1e9
        rows.append(row)
        ctx.log(
            "simulate() batch %6d, %d steps: kernel %.3g site-steps/s; default %.3g (%.2fx kernel); "
            "on the device %.3g (%.2fx); "
            "recording every %d steps %.3g (%.2fx kernel, %.3g GB/s of frames; into reused arrays %.3g GB/s, "
            "into reused page-locked arrays %.3g GB/s)",
            batch,
            steps,
            row["kernel_rate"],
            row["default_rate"],
            row["default_over_kernel"],
            row["on_device_rate"],
            row["on_device_over_kernel"],
            P.record_every,
            row["recording_rate"],
            row["recording_over_kernel"],
            row["recording_gb_per_second"],
            row["recording_reused_gb_per_second"],
            row["recording_pinned_gb_per_second"],
        )
    return rows


def _monodromy(ctx, repeats):
    """Monodromy and Newton-iteration timings on the paper breather (best of ``repeats``)."""
    from continuation.shooting import PeriodMap, solve_linear

    breather = paper_breather(ctx.device, log=ctx.log)
    params = breather.params
    n = 4 * params.N
    eye = np.eye(n).reshape(n, 4, params.N)
    period_steps = 2 * breather.nsteps
    runs = [
        propagate_tangent(
            params, breather.state, eye, period_steps, breather.dt, method=breather.method, device=ctx.device
        )
        for _ in range(repeats)
    ]
    kernel = min(r.kernel_seconds for r in runs)
    launches = min(r.launch_seconds for r in runs)
    wall = min(r.wall_seconds for r in runs)
    ctx.log(
        "monodromy (%d columns, %d steps of %s): kernel %.3g ms (launches, host-timed %.3g ms), wall %.3g ms",
        n,
        period_steps,
        breather.method,
        1e3 * kernel,
        1e3 * launches,
        1e3 * wall,
    )
    # the same monodromy as Floquet gets it: the Flow's base run and unit columns (replayed as CUDA graphs from
    # the second call), transfers included, wall time
    flow = breather.flow.replace()
    flow_wall = []
    for _ in range(max(5, repeats) + 1):
        t0 = time.perf_counter()
        flow.linearize(params, breather.state, period_steps, breather.dt).unit_columns("all")
        flow_wall.append(time.perf_counter() - t0)
    flow_wall = min(flow_wall[1:])
    ctx.log("monodromy through the Flow (as Floquet gets it, columns on the host): %.3g ms wall", 1e3 * flow_wall)
    pmap = PeriodMap(params, breather.omega, breather.flow)
    unknowns = pmap.from_state(breather.state)
    iteration = []
    for _ in range(max(20, repeats)):  # a 5 ms operation: best and median of 20
        t0 = time.perf_counter()
        point = pmap.evaluate(unknowns)
        r, J = point.residual, point.jacobian()
        step, _ = solve_linear(J, r)
        iteration.append(time.perf_counter() - t0)
    solves = []
    for _ in range(max(5, repeats)):  # best of several: a single call can catch a BLAS thread wake-up
        t0 = time.perf_counter()
        solve_linear(J, r)
        solves.append(time.perf_counter() - t0)
    solve = min(solves)
    ctx.log(
        "Newton iteration (%d columns, half period): %.3g ms end to end (median %.3g ms), of which linear solve "
        "%.3g ms",
        J.shape[1],
        1e3 * min(iteration),
        1e3 * float(np.median(iteration)),
        1e3 * solve,
    )
    return {
        "columns": n,
        "period_steps": period_steps,
        "method": breather.method,
        "force_evaluations": period_steps * METHODS[breather.method].force_evaluations,
        "monodromy_kernel_seconds": kernel,
        "monodromy_launch_seconds": launches,
        "monodromy_wall_seconds": wall,
        "monodromy_flow_wall_seconds": flow_wall,
        "newton_columns": int(J.shape[1]),
        "newton_iteration_seconds": min(iteration),
        "newton_iteration_median_seconds": float(np.median(iteration)),
        "newton_linear_solve_seconds": solve,
        "layout": runs[0].layout,
    }


def _kernel_properties(ctx, params):
    """Registers, local memory and theoretical occupancy of the kernels that ran (CUDA only)."""
    import warp as wp

    from warpchain.engine import block_kernels, site_group_kernels
    from warpchain.engine import thread_kernels as kernels

    block = block_kernels.block_size(params.N)
    rows = []
    built, blocks = {}, {}
    caps = {block_kernels.min_blocks_per_sm(method.stages) for method in METHODS.values()}
    for min_blocks in sorted(caps | {0}):
        for key, kernel in block_kernels.block_kernels(block, min_blocks).built().items():
            name = "/".join(str(part) for part in key) + f" (min blocks {min_blocks})"
            built[name], blocks[name] = kernel, (block, 2 * block * 8)  # threads, shared: two halves of a row
    for (threads, sites, _, min_blocks), group in site_group_kernels.SITE_GROUPS.items():
        for key, kernel in group.built().items():
            name = "/".join(str(part) for part in key) + f" ({sites} sites/thread, min blocks {min_blocks})"
            entry_bytes = 8 if sites == 1 else 16  # one float64 per thread with one site, else a pair
            built[name], blocks[name] = kernel, (threads, 2 * (threads + 2) * entry_bytes)
    for name, kernel in sorted(built.items()):
        block, smem = blocks[name]
        try:
            props = wp.get_cuda_kernel_properties(kernel, ctx.device, block_dim=block)
        except Exception as exc:  # not loaded in this run, or the query is unsupported
            ctx.log("kernel properties of %s unavailable: %s", name, exc)
            continue
        rows.append(
            {
                "kernel": f"block/{name}",
                "block": block,
                **props,
                "shared_bytes": smem,
                "occupancy": _occupancy(props["register_count"], block, smem),
            }
        )
    for name, module in (("splitting_kernel", kernels),):
        try:
            props = wp.get_cuda_kernel_properties(getattr(module, name), ctx.device)
            rows.append(
                {
                    "kernel": f"thread/{name}",
                    "block": 256,
                    **props,
                    "occupancy": _occupancy(props["register_count"], 256),
                }
            )
        except Exception as exc:
            ctx.log("kernel properties of %s unavailable: %s", name, exc)
    for row in rows:
        ctx.log(
            "%-44s %4d registers, %4d B local, occupancy %.2f",
            row["kernel"],
            row["register_count"],
            row["local_memory_size"],
            row["occupancy"],
        )
    return rows


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    _, shape = lowest_optical_mode(params)
    one = np.zeros((4, params.N))
    one[:2] = 0.3 * shape / np.max(np.abs(shape))
    gpu = ctx.device.startswith("cuda")
    # simulate() first, as users call it: in a process that has not loaded JAX and CuPy (the baselines). With
    # both loaded, simulate() at 805 lattices took 4.6 ms against 2.5 ms
    # (benchmarks/results/h200-2026-11-22l.json, preload.txt)
    end_to_end = _simulate_end_to_end(ctx, P, params, one, gpu)
    batches, results = _ensemble(ctx, P, params, one, gpu)
    ratios = _ratios(batches, results, gpu)
    # the monodromy part needs the paper breather (Newton, ~10 s on a CPU): skipped by --quick
    monodromy = _monodromy(ctx, P.monodromy_repeats) if P.monodromy else None
    props = _kernel_properties(ctx, params) if gpu else []

    root = ctx.store(params)
    impls = sorted({r["implementation"] for r in results})
    methods = sorted({r["method"] for r in results})
    write_table(
        root,
        "results",
        {
            "implementation": [impls.index(r["implementation"]) for r in results],
            "method": [methods.index(r["method"]) for r in results],
            "batch": [r["batch"] for r in results],
            "site_steps_per_second": [r["site_steps_per_second"] for r in results],
            "force_evals_per_second": [r["force_evals_per_second"] for r in results],
        },
        dim="result",
        attrs={"implementation_names": impls, "method_names": methods},
    )
    if end_to_end:
        names = ("kernel", "default", "on_device", "recording", "recording_reused", "recording_pinned")
        write_table(
            root,
            "simulate",
            {"batch": [r["batch"] for r in end_to_end]}
            | {f"{n}_rate": [r[f"{n}_rate"] for r in end_to_end] for n in names},
            dim="row",
            attrs={
                "units": "site-steps per second (velocity Verlet)",
                "record_every": P.record_every,
                "steps": int(P.simulate_steps),
            },
        )
    prov = provenance(ctx.device)
    return {
        "device": device_description(ctx.device),
        "cpu": prov["cpu"],
        "packages": prov["packages"],
        "cpu_threads": cpu_threads() if not gpu else None,
        "N": params.N,
        "dt": P.dt,
        "timing": f"kernel time, best of {P.repeats}, runs sized to ~{P.seconds:g} s",
        "results": results,
        "ratios": ratios,
        "monodromy": monodromy,
        "simulate": {
            "what": "simulate() wall time end to end (best of repeats after one untimed call) against "
            "time_steps() kernel time on the same batch; velocity Verlet",
            "record_every": P.record_every,
            "rows": end_to_end,
        },
        "kernel_properties": props,
        "hand_cuda_variant": _hand_variant() if gpu else None,
    }


def plot(out) -> None:
    s = read_summary(out)
    d, attrs = read_group(out / "data.zarr", "results")
    plt = pyplot()
    fig, (ax, bx, cx) = plt.subplots(1, 3, figsize=(19, 5))
    styles = {"warp-block": "o-", "warp-thread": "o:", "numpy": "s--", "jax": "^-", "cupy": "D-"}
    labels = {"cupy": "hand CUDA (CuPy)"}
    verlet = attrs["method_names"].index("verlet")
    for i, impl in enumerate(attrs["implementation_names"]):
        m = (d["implementation"] == i) & (d["method"] == verlet)
        if m.any():
            rate = d["site_steps_per_second"][m]
            ax.loglog(d["batch"][m], rate, styles.get(impl, "x-"), ms=4, label=labels.get(impl, impl))
    ax.set_xlabel("lattices in the batch")
    ax.set_ylabel("site-steps per second (velocity Verlet)")
    ax.set_title(f"ensemble throughput, N = {s['N']}, float64\n{s['device']}", fontsize=9)
    ax.legend(fontsize=8)
    main = attrs["implementation_names"].index(s["ratios"]["main_layout"])
    for k, method in enumerate(attrs["method_names"]):
        m = (d["implementation"] == main) & (d["method"] == k)
        if m.sum() > 0:
            bx.loglog(d["batch"][m], d["force_evals_per_second"][m], "o-", ms=4, label=method)
    mono = s["monodromy"]
    bx.set_xlabel("lattices in the batch")
    bx.set_ylabel("site force evaluations per second")
    title = f"{s['ratios']['main_layout']}, every method"
    if mono:
        title += (
            f"; monodromy ({mono['columns']} columns) {1e3 * mono['monodromy_kernel_seconds']:.3g} ms,\n"
            f"Newton iteration {1e3 * mono['newton_iteration_seconds']:.3g} ms"
        )
    bx.set_title(title, fontsize=9)
    bx.legend(fontsize=8)
    _plot_simulate(cx, out, s)
    save_figure(fig, out, "throughput")


def _plot_simulate(cx, out, summary) -> None:
    """simulate() end to end against the kernel's own rate, per batch (from the store's simulate table)."""
    if not (summary.get("simulate") or {}).get("rows"):
        cx.set_axis_off()
        cx.set_title("simulate(): not measured in this run", fontsize=9)
        return
    d, attrs = read_group(out / "data.zarr", "simulate")  # raises on a damaged store
    every = attrs["record_every"]
    curves = (
        ("kernel_rate", "o-", "kernel alone (time_steps)"),
        ("default_rate", "s-", "simulate(), default"),
        ("on_device_rate", "P-", "simulate(), continued on the device"),
        ("recording_pinned_rate", "^--", f"save_every={every}, into frame_buffers"),
        ("recording_rate", "v:", f"save_every={every}, default arrays"),
    )
    for key, style, label in curves:
        if key in d:  # a store written before the on-device variant has no such column
            cx.loglog(d["batch"], d[key], style, ms=5, label=label)
    # the ratios as a small table in the empty band between the end-to-end and the recording curves (labels
    # beside the points collide where two variants run at nearly the same rate)
    rows = [("default", "default_rate"), ("on the device", "on_device_rate")]
    lines = ["simulate() / kernel " + "".join(f"{int(b):>8d}" for b in d["batch"])]
    for name, key in rows:
        if key in d:
            lines.append(f"{name:19s} " + "".join(f"{r / k:7.2f}x" for k, r in zip(d["kernel_rate"], d[key])))
    cx.text(
        0.97,
        0.42,
        "\n".join(lines),
        transform=cx.transAxes,
        ha="right",
        va="center",
        fontsize=8,
        family="monospace",
        bbox=dict(boxstyle="round", facecolor="white", edgecolor="0.7"),
    )
    cx.set_xlabel("lattices in the batch")
    cx.set_ylabel("site-steps per second, end to end")
    title = f"simulate() as users call it ({attrs['steps']} Verlet steps) against its kernel;"
    cx.set_title(title + "\non the device: a DeviceState x0 (keep_on_device)", fontsize=9)
    cx.set_xlim(min(d["batch"]) / 1.6, max(d["batch"]) * 1.6)
    cx.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)  # below: clear of the curves


def _hand_variant():
    from _baselines import cupy_variant  # beside this script

    return cupy_variant()


def main(argv=None) -> int:
    import argparse
    import shlex
    import sys
    from pathlib import Path

    from scenarios._common import parse_overrides, run_scene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results", type=Path, help="output root (default: results/)")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: cuda when Warp sees a GPU)")
    parser.add_argument("--quick", action="store_true", help="reduced variant for smoke tests")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    args = parser.parse_args(argv)
    try:
        overrides = parse_overrides(args.set)
        words = argv if argv is not None else sys.argv[1:]
        line = " ".join(["python benchmarks/throughput.py", *(shlex.quote(w) for w in words)])  # as scenarios does
        run_scene(
            "throughput", args.out, args.device, args.quick, overrides, command_line=line, module=sys.modules[__name__]
        )
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    import logging

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    raise SystemExit(main())
