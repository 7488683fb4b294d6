"""Scaling of ``breakup-statistics`` over GPUs through Dask, and its resume, in one session.

Command (on a machine with two GPUs): ``python benchmarks/breakup_dask.py OUT_DIR``. Runs the full grid
(``--set grid=full``, 100 320 lattices x 200 periods) three times: in-process on one GPU, through a local
Dask cluster with one worker on one GPU, and with two workers on two GPUs; then interrupts a two-worker
run after a few seconds (SIGINT) and runs the same command again (the resume), and the same after a SIGKILL of
the client (whose threads are the workers on a GPU). Compares the stores array by array
and writes ``breakup-dask.json`` (sweep wall seconds from each summary, throughput ratios, equality).
"""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import zarr

BASE = [sys.executable, "-m", "scenarios", "run", "breakup-statistics", "--set", "grid=full", "--set", "fields=false"]
BASE += ["--set", "checks=false"]


def run(out: str, *sets: str, timeout: float | None = None, kill: bool = False) -> dict:
    cmd = BASE + [a for s in sets for a in ("--set", s)] + ["--out", out]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        output, _ = proc.communicate(timeout=timeout)
        rc = proc.returncode
    except subprocess.TimeoutExpired:  # interrupt it as Ctrl-C would, or kill it (SIGKILL: no handler runs)
        proc.send_signal(signal.SIGKILL if kill else signal.SIGINT)
        output, _ = proc.communicate()
        rc = f"{'killed (SIGKILL' if kill else 'interrupted (SIGINT'} after {timeout} s), exit {proc.returncode}"
    tail = output.replace("\r", "\n")[-1500:]
    wall = time.perf_counter() - t0
    summary = Path(out) / "breakup-statistics" / "summary.json"
    info = {"command": " ".join(cmd[1:]), "rc": rc, "process_seconds": wall}
    if rc == 0:
        s = json.loads(summary.read_text())
        info["sweep"] = s["sweep"]
    else:
        info["tail"] = tail
    print(json.dumps(info), flush=True)
    return info


def same_store(a: str, b: str) -> dict:
    ga = zarr.open_group(f"{a}/breakup-statistics/data.zarr", mode="r")["observables"]
    gb = zarr.open_group(f"{b}/breakup-statistics/data.zarr", mode="r")["observables"]
    out = {}
    for name in sorted(ga.array_keys()):
        x, y = ga[name][...], gb[name][...]
        out[name] = bool(x.shape == y.shape and np.array_equal(x, y, equal_nan=True))
    return out


def main(out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {
        "in_process": run("/tmp/d0"),
        "dask_1gpu": run("/tmp/d1", "workers=1", "gpus=1"),
        "dask_2gpu": run("/tmp/d2", "workers=2", "gpus=2"),
    }
    lp = {k: v["sweep"]["lattice_periods_per_second"] for k, v in result.items() if "sweep" in v}
    result["throughput_ratio_2gpu_vs_in_process"] = lp.get("dask_2gpu", 0) / lp["in_process"]
    result["throughput_ratio_2gpu_vs_dask_1gpu"] = lp.get("dask_2gpu", 0) / lp["dask_1gpu"]
    result["store_dask_2gpu_equals_in_process"] = same_store("/tmp/d0", "/tmp/d2")
    result["interrupted"] = run("/tmp/d3", "workers=2", "gpus=2", timeout=15)
    result["resumed"] = run("/tmp/d3", "workers=2", "gpus=2")
    result["store_resumed_equals_in_process"] = same_store("/tmp/d0", "/tmp/d3")
    # the client killed outright (SIGKILL: with thread workers, the workers die with it), then the same command
    result["killed"] = run("/tmp/d4", "workers=2", "gpus=2", timeout=8, kill=True)
    result["resumed_after_kill"] = run("/tmp/d4", "workers=2", "gpus=2")
    result["store_resumed_after_kill_equals_in_process"] = same_store("/tmp/d0", "/tmp/d4")
    (out_dir / "breakup-dask.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "."))
