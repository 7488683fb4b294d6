"""breakup-statistics on a running Dask cluster (one worker per GPU), against the in-process run.

Command (on a machine with two GPUs): ``python benchmarks/breakup_dask_cluster.py OUT_DIR``. Starts a
scheduler and two workers of two threads (two tasks in flight), each seeing one GPU
(``CUDA_VISIBLE_DEVICES``), as a cluster that is already up would be; runs the quick grid once through
it (the workers import the packages, make their CUDA contexts and load the kernels), then the full grid
through it (``--set scheduler=...``, ``--set gpus=1``: every worker uses its own ``cuda:0``), and the
full grid in-process on one GPU. Writes ``breakup-dask-cluster.json`` with each run's sweep seconds and
the throughput ratio.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ADDRESS = "tcp://127.0.0.1:8786"
SCENE = [
    sys.executable,
    "-m",
    "scenarios",
    "run",
    "breakup-statistics",
    "--set",
    "fields=false",
    "--set",
    "checks=false",
]


def scene(out: str, *sets: str, quick: bool = False) -> dict:
    cmd = SCENE + (["--quick"] if quick else ["--set", "grid=full"]) + [a for s in sets for a in ("--set", s)]
    cmd += ["--out", out]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    info = {"command": " ".join(cmd[1:]), "rc": proc.returncode, "process_seconds": time.perf_counter() - t0}
    if proc.returncode == 0:
        info["sweep"] = json.loads((Path(out) / "breakup-statistics" / "summary.json").read_text())["sweep"]
    else:
        info["tail"] = (proc.stdout + proc.stderr)[-2000:]
    print(json.dumps(info), flush=True)
    return info


def main(out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", "8786"], env=env)]
    time.sleep(3)
    for gpu in (0, 1):
        worker_env = dict(env, CUDA_VISIBLE_DEVICES=str(gpu))
        cmd = [sys.executable, "-m", "distributed.cli.dask_worker", ADDRESS, "--nthreads", "2", "--name", f"gpu{gpu}"]
        procs.append(subprocess.Popen(cmd, env=worker_env))
    time.sleep(5)
    try:
        result = {
            "warm_up_quick": scene("/tmp/c0", f"scheduler={ADDRESS}", "gpus=1", quick=True),
            "cluster_2gpu": scene("/tmp/c1", f"scheduler={ADDRESS}", "gpus=1"),
            "in_process": scene("/tmp/c2"),
        }
    finally:
        for p in procs:
            p.terminate()
    lp = {
        k: v["sweep"]["lattice_periods_per_second"] for k, v in result.items() if "sweep" in v and k != "warm_up_quick"
    }
    if len(lp) == 2:
        result["throughput_ratio_running_cluster_2gpu_vs_in_process"] = lp["cluster_2gpu"] / lp["in_process"]
    (out_dir / "breakup-dask-cluster.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k.startswith("throughput")}))


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "."))
