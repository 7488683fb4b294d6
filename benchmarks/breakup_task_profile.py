"""Where a breakup-statistics task's time goes, in-process vs inside a one-worker Dask cluster (one GPU).

Command (on a GPU machine): ``python benchmarks/breakup_task_profile.py > profile.json``. Times four
(A, damping) tasks of the full grid each way, after a warm-up task: initial states, ``observe`` (kernels
and transfers) and the host's peak tracking; the zarr write is not included (the sweep's own
``task_seconds`` include it).
"""

import dataclasses
import json
import time


def timed_task(index: dict, device: str, config: dict) -> dict:
    import numpy as np

    from scenarios.breakup_statistics import Parameters, grid, initial_states
    from warpchain import ChainParams
    from warpchain.losses import Damping
    from warpchain.observe import Observation, observe, peak_tracks

    P = Parameters(**config)
    A_values, widths, damping_cases, R = grid(P)
    gc, gs = damping_cases[index["damping"]]
    t = {}
    t0 = time.perf_counter()
    params = ChainParams(30.0, 160.0, 201)
    x0 = initial_states(201, float(A_values[index["A"]]), widths, R, P)
    t["initial_states"] = time.perf_counter() - t0
    T = 2 * np.pi / 1.01
    ob = Observation(
        frame_every=32,
        threshold=P.threshold,
        radius=P.radius,
        contrast=P.contrast,
        spot=np.repeat(widths, R),
        lag_frames=P.velocity_lag,
    )
    t1 = time.perf_counter()
    run = observe(
        params, x0, P.periods * T, T / 32, observation=ob, method=P.method, damping=Damping(gc, gs), device=device
    )
    t["observe"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    peak_tracks(run.envelope_lag, run.envelope, run.t[-1] - run.t_lag, ob, P.max_speed, max_peaks=P.max_peaks)
    t["tracks"] = time.perf_counter() - t2
    t["total"] = time.perf_counter() - t0
    return t


def main() -> None:
    from distributed import Client, LocalCluster

    from scenarios.breakup_statistics import Parameters

    config = dataclasses.asdict(Parameters(grid="full"))
    out = {}
    timed_task({"A": 5, "damping": 0}, "cuda:0", config)  # warm-up: Warp, CUDA context, kernels
    out["in_process"] = [timed_task({"A": i, "damping": 0}, "cuda:0", config) for i in (5, 6, 7, 8)]
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True)
    client = Client(cluster)
    client.submit(timed_task, {"A": 5, "damping": 0}, "cuda:0", config, pure=False).result()
    futures = [client.submit(timed_task, {"A": i, "damping": 0}, "cuda:0", config, pure=False) for i in (5, 6, 7, 8)]
    out["dask_worker"] = [f.result() for f in futures]
    client.close()
    cluster.close()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
