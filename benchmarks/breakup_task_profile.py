"""Where a breakup-statistics task's time goes, in-process and inside a Dask worker, with and without the
sweep's host allocator setting (one GPU).

Command (on a GPU machine): ``python benchmarks/breakup_task_profile.py > profile.json``. Times four
(A, damping) tasks of the full grid in each of four settings, after a warm-up task in each: initial
states, ``observe`` (kernels and transfers), the host's peak tracking and the zarr write of the task's
region (``sweep.store._write_result`` into a scratch store of the full grid's layout). The settings:
in-process, in-process after :func:`sweep.host_allocator`, a one-worker ``LocalCluster``
as Dask starts it (``MALLOC_TRIM_THRESHOLD_=65536``), and the same worker after ``host_allocator``.
Prints the median of each phase per setting and the worker/in-process ratio of the totals.
``python benchmarks/breakup_task_profile.py cpu quick`` is a smoke test of the script on a CPU.
"""

import dataclasses
import json
import os
import sys
import tempfile
import time

STORE = os.path.join(tempfile.gettempdir(), "breakup-profile.zarr")


def timed_task(index: dict, device: str, config: dict, allocator: bool) -> dict:
    import numpy as np

    from sweep import host_allocator
    from sweep.store import _layout, _open_root, _write_result
    from scenarios.breakup_statistics import GROUP, grid, initial_states
    from scenarios.breakup_statistics import Parameters as P_
    from warpchain import ChainParams
    from warpchain.losses import Damping
    from warpchain.observe import OBSERVABLES, Observation, observe, peak_tracks

    if allocator:
        host_allocator()
    P = P_(**config)
    A_values, widths, damping_cases, R = grid(P)
    gc, gs = damping_cases[index["damping"]]
    t = {}
    t0 = time.perf_counter()
    params = ChainParams(30.0, 160.0, 201)
    x0 = initial_states(201, float(A_values[index["A"]]), widths, R, P)
    t["initial_states"] = time.perf_counter() - t0
    T = 2 * np.pi / 1.01
    ob = Observation(
        frame_every=P.steps_per_period,
        threshold=P.threshold,
        radius=P.radius,
        contrast=P.contrast,
        spot=np.repeat(widths, R),
        lag_frames=P.velocity_lag,
    )
    t1 = time.perf_counter()
    run = observe(
        params,
        x0,
        P.periods * T,
        T / P.steps_per_period,
        observation=ob,
        method=P.method,
        damping=Damping(gc, gs),
        device=device,
    )
    t["observe"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    shape = (len(widths), R)
    out = {name: run[name].T.reshape(*shape, -1) for name in OBSERVABLES}
    tracks = peak_tracks(run.envelope_lag, run.envelope, run.t[-1] - run.t_lag, ob, P.max_speed, max_peaks=P.max_peaks)
    for name, values in zip(("peak_position", "peak_amplitude", "peak_velocity"), tracks):
        out[name] = values.reshape(*shape, P.max_peaks)
    out["contact_loss_time"] = run.first_contact_loss().reshape(shape)
    t["tracks"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    from scenarios.breakup_statistics import sweep_spec

    group = _open_root(STORE, "r+")[GROUP]
    _write_result(group, _layout(sweep_spec(P)), (index["A"], index["damping"]), out)
    t["write"] = time.perf_counter() - t3
    t["total"] = time.perf_counter() - t0
    return t


def medians(runs: list[dict]) -> dict:
    import numpy as np

    return {k: float(np.median([r[k] for r in runs])) for k in runs[0]}


def main() -> None:
    from distributed import Client, LocalCluster

    from sweep import open_sweep
    from scenarios.breakup_statistics import Parameters, sweep_spec

    device, grid_name = (sys.argv[1:] + ["cuda:0", "full"][len(sys.argv) - 1 :])[:2]
    config = dataclasses.asdict(Parameters(grid=grid_name))
    open_sweep(STORE, sweep_spec(Parameters(**config)))
    tasks = [{"A": i % 3 if grid_name == "quick" else i, "damping": 0} for i in (5, 6, 7, 8)]
    out = {}
    for allocator in (False, True):  # in-process: without, then with (the setting cannot be undone)
        timed_task(tasks[0], device, config, allocator)  # warm-up: Warp, CUDA context, kernels
        out[f"in_process{'_allocator' if allocator else ''}"] = [
            timed_task(index, device, config, allocator) for index in tasks
        ]
    for allocator in (False, True):
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            with Client(cluster) as client:
                client.submit(timed_task, tasks[0], device, config, allocator, pure=False).result()
                futures = [client.submit(timed_task, i, device, config, allocator, pure=False) for i in tasks]
                out[f"dask_worker{'_allocator' if allocator else ''}"] = [f.result() for f in futures]
    summary = {name: medians(runs) for name, runs in out.items()}
    summary["worker_over_in_process_total"] = summary["dask_worker"]["total"] / summary["in_process"]["total"]
    summary["worker_allocator_over_in_process_allocator_total"] = (
        summary["dask_worker_allocator"]["total"] / summary["in_process_allocator"]["total"]
    )
    print(json.dumps({"medians": summary, "runs": out}, indent=1))


if __name__ == "__main__":
    main()
