"""``python -m scenarios paper --jobs J``: the paper's scenes in J processes at once.

The paper scenes are independent (each reads only its own folder), and the three branch scenes are
bound by host work (Newton's LU and the Floquet eigs of 201 x 201 blocks, on one or two cores each)
while the GPU sits mostly idle: on a machine with many cores they run side by side. Each scene is a
child ``python -m scenarios run NAME`` with the same --out, --device and --quick, so its store, summary
and figures are exactly those of a run on its own; the command line recorded in their provenance is
the ``paper`` command as typed.

Scheduling: the longest scenes start first (``COST_ORDER``), a new one starts whenever one ends.
Each child gets ``max(1, cores // J)`` Warp CPU threads and BLAS/OpenMP threads (the scenes use one
BLAS thread themselves, ``continuation.hostblas``), no progress bars, and its log lines pass through
unchanged (they carry the scene's name). A failing scene does not stop the others; the run ends with a
list of what failed and the last lines each printed. A Ctrl-C (or any error) in this process sends each
running child one SIGINT, so that it marks its stores as interrupted, and kills what is left after 30 s.
"""

from __future__ import annotations

import collections
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from warpchain.engine.devices import count_from_text, usable_cores

log = logging.getLogger("scenarios")

#: the paper scenes, longest first (2-core CPU and H200 runs of 2026-11-22: site-bond 55-70 s,
#: continuation-omega 50-60 s, continuation-k 41-49 s, the others 1-7 s)
COST_ORDER = (
    "site-bond",
    "continuation-omega",
    "continuation-k",
    "breather",
    "direct-simulation",
    "nls",
    "dispersion",
    "anticontinuum",
)
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_TAIL_LINES = 25


def auto_jobs(n_scenes: int, cores: int | None = None) -> int:
    """Scenes at once by default: one per 2 usable cores (a branch scene's host work is mostly one
    thread of Python and LAPACK, plus a second for the other parity block), at most 4 and the scene
    count; 1 on a 2-core machine, where one scene's Warp CPU kernels already use both cores."""
    cores = cores or usable_cores()
    return max(1, min(4, n_scenes, cores // 2))


def parse_jobs(value: str, n_scenes: int) -> int:
    """--jobs: ``auto`` or a whole number >= 1."""
    if str(value).strip().lower() == "auto":
        return auto_jobs(n_scenes)
    return count_from_text(value, "--jobs takes a whole number >= 1 or 'auto'")


def child_environment(jobs: int, environ=None, cores: int | None = None) -> tuple[dict, int]:
    """The environment of each child and its thread count: the cores (or the caller's explicit thread
    count) shared out among the jobs, no progress bars."""
    env = dict(os.environ if environ is None else environ)
    cores = cores or usable_cores()
    given = [int(env[k]) for k in _THREAD_VARIABLES if env.get(k, "").strip().isdigit()]
    threads = max(1, (max(given) if given else cores) // jobs)
    for key in _THREAD_VARIABLES:
        env[key] = str(threads)
    env["WARPCHAIN_CPU_THREADS"] = str(max(1, cores // jobs))  # Warp's CPU launches (``ensemble.cpu_threads``)
    env["TQDM_DISABLE"] = "1"  # a child's bar would interleave with the others' log lines
    env["PYTHONUNBUFFERED"] = "1"
    return env, threads


class _Child:
    """One scene's process, with a thread that passes its output lines on and keeps the last few."""

    def __init__(self, name: str, argv: list[str], env: dict):
        self.name = name
        self.start = time.perf_counter()
        self.tail = collections.deque(maxlen=_TAIL_LINES)
        self.proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=env,
            text=True,
            errors="replace",
            bufsize=1,
            start_new_session=True,  # a Ctrl-C reaches this process only, which passes one SIGINT on (_stop)
        )
        self.reader = threading.Thread(target=self._pump, daemon=True)
        self.reader.start()

    def _pump(self) -> None:
        """Pass the child's lines on; keep draining its pipe even when our stderr is gone (a full pipe
        would block the child)."""
        for line in self.proc.stdout:
            self.tail.append(line.rstrip("\n"))
            try:
                sys.stderr.write(line)
                sys.stderr.flush()
            except (OSError, ValueError):
                pass

    def finished(self) -> int | None:
        code = self.proc.poll()
        if code is not None:
            self.reader.join()
        return code


def run_parallel(
    names: list[str],
    out: Path,
    device: str | None,
    quick: bool,
    jobs: int,
    command_line: str,
    poll_seconds: float = 0.1,
) -> list[tuple[str, int, list[str]]]:
    """Run the scenes ``names`` in up to ``jobs`` child processes; returns the failures as
    (name, exit code, last output lines), empty when every scene succeeded."""
    order = sorted(names, key=lambda n: COST_ORDER.index(n) if n in COST_ORDER else len(COST_ORDER))
    jobs = max(1, min(jobs, len(order)))
    env, _ = child_environment(jobs)
    log.info(
        "paper: %d scenes, %d at a time in separate processes (%s Warp CPU threads each), longest first",
        len(order),
        jobs,
        env["WARPCHAIN_CPU_THREADS"],
    )
    pending = collections.deque(order)
    running: list[_Child] = []
    failures = []
    done = 0
    start = time.perf_counter()
    try:
        while pending or running:
            while pending and len(running) < jobs:
                name = pending.popleft()
                argv = [sys.executable, "-m", "scenarios", "run", name, "--out", str(out)]
                argv += ["--device", device] if device else []
                argv += ["--quick"] if quick else []
                argv += ["--provenance-command", command_line]
                running.append(_Child(name, argv, env))
            time.sleep(poll_seconds)
            for child in list(running):
                code = child.finished()
                if code is None:
                    continue
                running.remove(child)
                done += 1
                took = time.perf_counter() - child.start
                if code == 0:
                    log.info("paper: %s finished in %.1f s (%d of %d)", child.name, took, done, len(order))
                else:
                    code = 128 - code if code < 0 else code  # killed by signal n: the shell's 128 + n
                    log.info(
                        "paper: %s FAILED (exit %d) after %.1f s (%d of %d)", child.name, code, took, done, len(order)
                    )
                    failures.append((child.name, code, list(child.tail)))
    finally:
        _stop(running)
    log.info(
        "paper: %d scenes in %.1f s, %d failed; results in %s",
        len(order),
        time.perf_counter() - start,
        len(failures),
        out,
    )
    return failures


def _stop(running: list, grace_seconds: float = 30.0) -> None:
    """Interrupt the children still running (an interrupt or error in this process; the children
    mark their stores as interrupted, as on a Ctrl-C of their own), wait for them until one shared
    deadline, then kill and reap what is left."""
    for child in running:
        if child.proc.poll() is None:
            try:
                child.proc.send_signal(signal.SIGINT)
            except OSError:
                pass
    deadline = time.monotonic() + grace_seconds
    for child in running:
        try:
            child.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.proc.kill()
            child.proc.wait()
