"""A grid of independent tasks written into one zarr v3 group, in-process or through Dask, resumable.

A sweep is described by a :class:`SweepSpec`: coordinates of every dimension, the *task dims* (one task
per index combination of them) and the variables (each with dims that start with the task dims). For
example ``breakup-statistics`` has dims ``(A, damping, W, realisation, frame)`` and one task per
``(A, damping)``: a task integrates every W and realisation of its (A, damping) and returns arrays of
shape ``(W, realisation, frame)`` (or whatever its variables hold after the task dims).

Layout of the group (``spec.group`` inside the store; the root and its other groups are left alone)::

    <group>/                     attrs: spec.attrs, task_dims, sweep (the grid's signature)
      <variable>  dims as given  chunks 1 along each task dim, whole along the others; NaN fill (floats)
      <dim>       (dim,)         one 1-D coordinate array per dim, single chunk
      completed   task dims      int8, fill 0; 1 once the task's region is written

Design:

* Disjoint chunks, no locks. Each task's region of each variable is exactly one chunk, and so is its
  ``completed`` element, so workers never touch the same chunk and write concurrently without locks.
  The worker that runs a task writes its region itself: only a few timing numbers travel back to the
  client, never the data.
* ``completed`` is written last. A task sets its flag only after all its variables are written, so an
  interrupted task (killed worker, Ctrl-C, a failure) is never counted as done; its partly written
  chunks are overwritten whole when it runs again.
* Resume. :func:`run_sweep` opens (or creates) the group, reads ``completed`` and runs only the tasks
  not yet done: rerunning the same command after an interruption finishes the sweep. A group that holds
  a different grid (coords, task dims, variables, or ``spec.attrs`` such as parameters and seeds)
  raises :class:`SweepMismatchError` instead of mixing two grids: use a new output folder.
* Determinism. The runner never reorders data: each task writes at its own index, and a task is expected
  to derive its random seeds from its index (``np.random.default_rng((seed, *index.values()))``), so a
  task gives the same bytes whichever path (in-process, any worker) runs it.
* Devices. A task is called as ``task(index, device)``. ``device`` is ``"cpu"`` when ``gpus == 0``;
  otherwise ``f"cuda:{k % gpus}"`` with ``k`` the ordinal of the worker running it (``LocalCluster``
  names its workers 0..N-1; in-process runs use ``cuda:0``). With ``workers == gpus`` each worker owns
  one GPU; with more workers than GPUs several share one. For an external cluster whose workers are
  not named by integers, ``k`` is the worker's rank among the workers of its host (sorted by name and
  address, taken when the sweep starts). Workers started with ``CUDA_VISIBLE_DEVICES`` set to one GPU
  each should be given ``gpus=1`` (every worker then uses its ``cuda:0``).
* Dask is optional (``pip install -e ".[dask]"``); importing this module never imports it and the
  in-process path (``workers=0``, no scheduler) works without it. ``workers=N`` starts a
  ``distributed.LocalCluster`` of N worker processes (threads of this process with ``processes=False``, for GPU
  tasks: no start cost) for the sweep and closes it at the
  end; ``scheduler="tcp://host:8786"`` uses a running cluster instead (a scene passes it through, e.g.
  ``python -m scenarios run breakup-statistics --set scheduler=tcp://host:8786``). Workers of an
  external cluster must see the store at the same path (shared file system) and be able to import
  ``scenarios``, ``sweep`` and ``warpchain`` (an editable install does it; the client's ``sys.path`` entries
  are also appended on every worker where they exist).
* Tasks must be picklable top-level callables; ``functools.partial(module_level_function, **params)``
  is the expected form. The task is sent to each worker once (scattered), not once per task.
* Consolidated metadata is written once, at the end of :func:`run_sweep`, by the client.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import sys
import time
import traceback

import numpy as np

from sweep.store import (
    SweepSpec,
    _layout,
    _open_root,
    _write_result,
    completed,
    damaged_tasks,
    open_sweep,
)
from warpchain.store import consolidate

DASK_HINT = 'pip install -e ".[dask]"'


class SweepTaskError(RuntimeError):
    """A task failed; the message names its index. ``report`` is set when the sweep went on (fail_fast=False)."""

    def __init__(self, message: str, failed=(), report=None):
        super().__init__(message)
        self.failed = tuple(failed)
        self.report = report


@dataclasses.dataclass(frozen=True)
class SweepReport:
    """What a sweep did. ``task_seconds`` (task plus writing its region, measured where it ran) and
    ``task_indices`` cover the tasks that ran, in grid order."""

    tasks: int
    skipped: int
    ran: int
    workers: int
    mode: str
    wall_seconds: float
    task_seconds: list[float]
    task_indices: list[tuple[int, ...]] = dataclasses.field(default_factory=list)
    failed: list[tuple[int, ...]] = dataclasses.field(default_factory=list)
    start_seconds: float = 0.0  # from the call to the first task handed out (cluster start, warm-up)
    #: per worker (in-process: "main"): seconds between the first task handed out and the last task's end during
    #: which none of its tasks ran (uneven tasks, a worker waiting for the host or the scheduler)
    idle_seconds: dict = dataclasses.field(default_factory=dict)


def _call_task(task, group, layout, index: tuple[int, ...], device: str) -> dict:
    """Runs one task and writes its region: its seconds and its (start, end) on the wall clock (``time.time``, for
    the idle time per worker across processes of one host)."""
    t0, start = time.perf_counter(), time.time()
    result = task(dict(zip(layout["task_dims"], (int(i) for i in index))), device)
    _write_result(group, layout, index, result)
    return {"seconds": time.perf_counter() - t0, "span": (start, time.time())}


def _idle(spans: dict, begin: float, end: float) -> dict:
    """Per worker, the time in [begin, end] covered by none of its task spans (the union of overlapping spans:
    a worker runs several tasks at once)."""
    out = {}
    for worker, intervals in spans.items():
        busy, reach = 0.0, begin
        for a, b in sorted(intervals):
            a, b = max(a, reach), min(b, end)
            if b > a:
                busy, reach = busy + (b - a), b
        out[worker] = max(0.0, (end - begin) - busy)
    return out


def _device(ordinal: int, gpus: int) -> str:
    return "cpu" if gpus <= 0 else f"cuda:{int(ordinal) % int(gpus)}"


def _int_name(name) -> int | None:
    if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
        return int(name)
    if isinstance(name, str) and name.isdigit():
        return int(name)
    return None


def _worker_ordinals(workers: dict) -> dict[str, int]:
    """address -> ordinal from the scheduler's worker table: the integer name when workers have one
    (LocalCluster: 0..N-1), else the rank among the workers of the same host."""
    ordinals, by_host = {}, {}
    for address, info in workers.items():
        k = _int_name(info.get("name"))
        if k is not None:
            ordinals[address] = k
        else:
            by_host.setdefault(info.get("host", ""), []).append((str(info.get("name")), address))
    for members in by_host.values():
        for rank, (_, address) in enumerate(sorted(members)):
            ordinals[address] = rank
    return ordinals


def _worker_device(worker, ordinals: dict, gpus: int) -> str:
    """The device of a Dask worker: by its ordinal in the sweep's table, else its integer name, else 0."""
    ordinal = ordinals.get(worker.address)
    if ordinal is None:
        ordinal = _int_name(worker.name) or 0
    return _device(ordinal, gpus)


def _run_on_worker(store_path: str, layout: dict, task, index: tuple[int, ...], gpus: int, ordinals: dict) -> dict:
    """Runs on a Dask worker: the task, then its region written from here. Returns only timing/status."""
    from distributed import get_worker

    worker = get_worker()
    device = _worker_device(worker, ordinals, gpus)
    try:
        group = _open_root(store_path, "r+")[layout["group"]]
        ran = _call_task(task, group, layout, index, device)
        return {"index": index, "ok": True, **ran, "worker": str(worker.name), "device": device}
    except Exception as exc:
        return {
            "index": index,
            "ok": False,
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(),
            "worker": str(worker.name),
            "device": device,
        }


# ------------------------------------------------------------------------------------------ the sweep


def _index_text(spec: SweepSpec, index: tuple[int, ...]) -> str:
    return ", ".join(f"{d}={i}" for d, i in zip(spec.task_dims, index))


def _progress_bar(total: int, enabled: bool, desc: str):
    from tqdm.auto import tqdm

    return tqdm(total=total, disable=not enabled, desc=desc, unit="task", leave=False, dynamic_ncols=True)


@contextlib.contextmanager
def _quiet_distributed(level=logging.ERROR):
    """Silences distributed's INFO/WARNING chatter (worker start/stop, closing streams) while it runs."""
    names = ["distributed", *(n for n in logging.root.manager.loggerDict if n.startswith("distributed."))]
    names += ["bokeh", "tornado"]
    saved = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(level)
    try:
        yield
    finally:
        for n, lvl in saved.items():
            logging.getLogger(n).setLevel(lvl)


def _import_distributed():
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(
            f"workers=/scheduler= run the sweep through Dask, which is not installed: {DASK_HINT}"
        ) from exc
    return distributed


_ALLOCATOR: dict = {}  # what host_allocator set in this process


def host_allocator() -> None:
    """Lets glibc keep freed memory of this process for reuse (Linux; elsewhere nothing).

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which returns freed memory to the
    system at once and turns off glibc's adaptive mmap threshold: every array of more than 128 KiB then
    comes from fresh, zero-filled pages. A task's host work (reductions over arrays of a few MB) ran
    ~1.8x slower for it. Setting both thresholds here (mmap threshold 32 MiB, glibc's own adaptive
    maximum; trim threshold 128 MiB) gives the same steady state in every process, worker or not."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import ctypes.util

    with contextlib.suppress(OSError, AttributeError, TypeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        if libc.mallopt(-3, 32 << 20) and libc.mallopt(-1, 128 << 20):  # M_MMAP_, M_TRIM_THRESHOLD
            _ALLOCATOR["mmap_threshold"] = 32 << 20


def _worker_plugin(paths: list[str], ordinals: dict, gpus: int, warm_up):
    """A worker plugin (defined here so that cloudpickle sends it by value: a worker that cannot import
    ``scenarios`` yet can still unpickle it): appends the client's sys.path entries that exist there,
    sets the allocator as :func:`host_allocator` does, and runs ``warm_up(device)`` once."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class SweepWorker(WorkerPlugin):
        name = "warpchain-sweep-worker"

        def __init__(self, entries, ordinals, gpus, warm_up):
            self.entries, self.ordinals, self.gpus, self.warm_up = list(entries), ordinals, gpus, warm_up

        def setup(self, worker):
            import contextlib as _contextlib
            import os as _os
            import sys as _sys

            for entry in self.entries:
                if entry and entry not in _sys.path and _os.path.isdir(entry):
                    _sys.path.append(entry)
            from sweep.runner import _worker_device, host_allocator

            host_allocator()
            if self.warm_up is not None:
                with _contextlib.suppress(Exception):
                    self.warm_up(_worker_device(worker, self.ordinals, self.gpus))

    return SweepWorker(paths, ordinals, gpus, warm_up)


def run_sweep(
    store_path,
    spec: SweepSpec,
    task,
    *,
    workers: int = 0,
    scheduler: str | None = None,
    gpus: int = 0,
    progress: bool = True,
    log=None,
    fail_fast: bool = True,
    tasks_per_worker: int = 2,
    warm_up=None,
    cost=None,
    processes: bool = True,
) -> SweepReport:
    """Runs every task of ``spec`` not yet completed in ``store_path`` and writes its region.

    Args:
        store_path: the zarr store (a directory path); created if missing, its root left as it is.
        spec: the grid (:class:`SweepSpec`).
        task: ``task(index: dict[str, int], device: str) -> dict[str, np.ndarray]``; one array per
            variable, shaped like the variable without its task dims. A picklable top-level callable
            (``functools.partial`` of a module-level function) when run through Dask.
        workers: 0 (with no scheduler): in-process, tasks in grid order. N: a ``distributed.LocalCluster``
            of N workers (processes, or threads with ``processes=False``), closed at the end.
        scheduler: address of a running Dask scheduler (``tcp://host:8786``) to use instead.
        gpus: 0: every task gets ``"cpu"``; G: ``f"cuda:{worker ordinal % G}"`` (in-process: ``cuda:0``).
        progress: a tqdm bar over the tasks to run.
        log: ``log(message)`` for a start line (mode, workers, tasks to run and skipped) and an end line.
        tasks_per_worker: tasks in flight at once in each process (in-process: threads of this process;
            a local cluster: threads per worker; a running cluster: its workers' ``--nthreads``). Two
            overlap one task's kernels with another's host work and zarr write; results do not change.
        warm_up: ``warm_up(device)``, run once in each Dask worker when the sweep starts (loads kernels,
            fills memory pools) so that no task pays for it; its errors are left to the tasks to meet.
        cost: ``cost(index: dict[str, int]) -> float``, an estimate of each task's run time: tasks are handed out
            longest first (in-process in that order; through Dask as priorities), so that uneven tasks do not
            leave workers idle at the end. None: grid order.
        processes: the workers of a local cluster (``workers=N``) as processes (True) or as threads of this process
            (False): no start cost (the imports, CUDA contexts and loaded kernels are this process's; 3.2 s against
            0.8 s on two H200s) and each writes the shared store directly, for tasks whose time is on the GPU
            (``breakup-statistics``: 1.91x the in-process one-GPU sweep on two H200s against 1.60x with processes,
            the same store). Tasks that hold the GIL on the host (Newton, eigs: the stability atlas) belong in
            processes. A running cluster (``scheduler``) keeps its own kind.
        fail_fast: True: the first failing task raises :class:`SweepTaskError` naming its index, the
            others are cancelled (those already written stay completed). False: every task runs, then
            one :class:`SweepTaskError` names all that failed (its ``report`` holds the report).

    Returns:
        a :class:`SweepReport`. A rerun after an interruption or a failure runs only what is missing.
    """
    if workers < 0 or gpus < 0:
        raise ValueError("workers and gpus must be >= 0")
    if int(tasks_per_worker) < 1:
        raise ValueError(f"tasks_per_worker must be >= 1, got {tasks_per_worker}")
    if workers and scheduler:
        raise ValueError("give workers= (a local cluster) or scheduler= (a running one), not both")
    if not callable(task):
        raise TypeError("task must be callable")
    use_dask = bool(workers or scheduler)
    if use_dask:
        _import_distributed()  # fail before touching the store
    say = log or (lambda message: None)
    store_path = os.path.abspath(os.fspath(store_path))
    t_start = time.perf_counter()

    group = open_sweep(store_path, spec)
    done = completed(store_path, spec)
    if done.any():  # trust no flag without its data: a damaged task runs again
        for index, why in damaged_tasks(store_path, spec, done):
            done[index] = False
            say(f"sweep {spec.group}: task ({_index_text(spec, index)}) is flagged completed but {why}: it runs again")
    todo = [tuple(int(i) for i in index) for index in np.ndindex(*spec.task_shape) if not done[index]]
    if cost is not None:  # longest first (a stable sort: equal estimates keep grid order)
        todo.sort(key=lambda index: -float(cost(dict(zip(spec.task_dims, index)))))
    n_tasks, skipped = int(done.size), int(done.sum())
    layout = _layout(spec)
    mode = "dask" if use_dask else "in-process"
    seconds: dict[tuple, float] = {}
    spans: dict[str, list] = {}
    failures: list[tuple[tuple, str]] = []
    n_workers, t_ready = 0, t_start
    try:
        if not todo:
            say(f"sweep {spec.group}: all {n_tasks} tasks already completed, nothing to run")
        with contextlib.ExitStack() as stack:
            if todo and use_dask:
                n_workers, where, outcomes = _dask_outcomes(
                    stack, store_path, task, todo, layout, workers, scheduler, gpus, tasks_per_worker, warm_up,
                    processes,
                )  # fmt: skip
            elif todo:
                host_allocator()
                outcomes = _Pipeline(task, group, layout, todo, _device(0, gpus), tasks_per_worker, fail_fast)
                stack.push(lambda kind, *_: outcomes.close(wait=not (kind and issubclass(kind, KeyboardInterrupt))))
                where = f"on {_device(0, gpus)}, {len(outcomes._threads)} tasks in flight"
            else:
                outcomes = iter(())
            t_ready = time.perf_counter()
            if todo:
                say(f"sweep {spec.group}: {mode} {where}, {len(todo)} of {n_tasks} tasks to run, {skipped} skipped")
            bar = stack.enter_context(_progress_bar(len(todo), progress and bool(todo), spec.group))
            for out in outcomes:
                index = tuple(out["index"])
                if out["ok"]:
                    seconds[index] = out["seconds"]
                    spans.setdefault(str(out.get("worker", "main")), []).append(tuple(out["span"]))
                else:
                    where_ran = f" on worker {out['worker']} ({out['device']})" if out.get("worker") is not None else ""
                    message = f"sweep {spec.group}: task ({_index_text(spec, index)}) failed{where_ran}: {out['error']}"
                    if fail_fast:
                        detail = f"\n--- worker traceback ---\n{out['traceback']}" if out.get("traceback") else ""
                        raise SweepTaskError(message + detail, failed=[index]) from out.get("exception")
                    failures.append((index, message))
                    say(message)
                bar.update()
    finally:
        consolidate(store_path)

    ran_indices = [index for index in todo if index in seconds]
    ran_indices.sort()  # grid order, whatever order they ran in
    ends = [b for intervals in spans.values() for _, b in intervals]
    first = min((a for intervals in spans.values() for a, _ in intervals), default=0.0)
    idle = _idle(spans, first, max(ends)) if ends else {}
    report = SweepReport(
        tasks=n_tasks,
        skipped=skipped,
        ran=len(ran_indices),
        workers=n_workers,
        mode=mode,
        wall_seconds=time.perf_counter() - t_start,
        task_seconds=[seconds[index] for index in ran_indices],
        task_indices=ran_indices,
        failed=[index for index, _ in failures],
        start_seconds=t_ready - t_start,
        idle_seconds=idle,
    )
    say(
        f"sweep {spec.group}: {report.ran} tasks ran in {report.wall_seconds:.1f} s wall"
        f" ({sum(report.task_seconds):.1f} s in tasks), {report.skipped} skipped, {len(failures)} failed"
        + (f"; idle per worker: {', '.join(f'{w} {t:.1f} s' for w, t in sorted(idle.items()))}" if idle else "")
    )
    if failures:
        names = "; ".join(f"({_index_text(spec, index)})" for index, _ in failures)
        raise SweepTaskError(
            f"sweep {spec.group}: {len(failures)} of {len(todo)} tasks failed: {names}; first: {failures[0][1]}"
            " (rerun to retry only those)",
            failed=[index for index, _ in failures],
            report=report,
        )
    return report


class _Pipeline:
    """In-process tasks on ``in_flight`` daemon threads, in grid order, outcomes as they finish.

    With two in flight, one task's kernels run while the other's host work (reductions, its zarr write)
    proceeds; :func:`warpchain.ensemble.device_lock` keeps the kernels of one device from interleaving.
    With ``fail_fast`` a failure stops handing out tasks at once, and :meth:`close` does too; its
    ``wait=True`` also waits for the running ones (nothing writes into the store after the sweep returns
    or raises), ``wait=False`` (Ctrl-C) does not: a task cut off by the process's exit never set its
    completed flag and runs again on resume."""

    def __init__(self, task, group, layout, todo, device: str, in_flight: int, fail_fast: bool):
        import queue
        import threading

        self._todo = iter(todo)
        self._take = threading.Lock()
        self._stop = threading.Event()
        self._results = queue.Queue()
        self._n = len(todo)
        self._args = (task, group, layout)
        self._device = device
        self._fail_fast = fail_fast
        self._threads = [
            threading.Thread(target=self._work, name=f"sweep-task-{k}", daemon=True)
            for k in range(max(1, min(int(in_flight), len(todo))))
        ]
        for thread in self._threads:
            thread.start()

    def _work(self) -> None:
        task, group, layout = self._args
        while not self._stop.is_set():
            with self._take:
                index = next(self._todo, None)
            if index is None:
                return
            try:
                out = {
                    "index": index,
                    "ok": True,
                    **_call_task(task, group, layout, index, self._device),
                    "worker": "main",
                }
            except BaseException as exc:  # noqa: BLE001 - reported to the client, which decides
                out = {"index": index, "ok": False, "error": repr(exc), "exception": exc}
                if self._fail_fast:
                    self._stop.set()  # no new task after a failure
            self._results.put(out)

    def __iter__(self):
        for _ in range(self._n):
            yield self._results.get()

    def close(self, wait: bool = True) -> None:
        self._stop.set()
        if wait:
            for thread in self._threads:
                thread.join()


@contextlib.contextmanager
def _environment_kept():
    """This process's environment as it was before a ``LocalCluster`` started: distributed's nanny writes its workers'
    variables (OMP/MKL/OPENBLAS_NUM_THREADS=1, PYTHONHASHSEED, MALLOC_TRIM_THRESHOLD_=65536) into ``os.environ`` of
    the process that starts it, and every process started later inherited them: a test running two scenes as
    subprocesses after a Dask test took 135 s instead of 31 s (found in the test suite, whose conftest keeps every
    test's environment with this too)."""
    kept = dict(os.environ)
    try:
        yield
    finally:
        if dict(os.environ) != kept:
            os.environ.clear()
            os.environ.update(kept)


def _dask_outcomes(
    stack: contextlib.ExitStack,
    store_path,
    task,
    todo,
    layout,
    workers,
    scheduler,
    gpus,
    tasks_per_worker,
    warm_up,
    processes=True,
):
    """Starts (``workers``) or connects to (``scheduler``) a cluster, registered on ``stack`` for closing,
    submits every task and returns (number of workers, description, iterator of outcomes as they come).
    Leaving ``stack`` cancels what has not run (fail_fast) and closes the client and the local cluster."""
    distributed = _import_distributed()
    stack.enter_context(_quiet_distributed())
    if scheduler:
        client = stack.enter_context(distributed.Client(scheduler, set_as_default=False))
        where = f"scheduler {scheduler}"
    else:
        with _environment_kept():
            cluster = stack.enter_context(
                distributed.LocalCluster(
                    n_workers=int(workers),
                    threads_per_worker=int(tasks_per_worker),
                    processes=bool(processes),
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
            )
            client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
            where = "local cluster"
            client.wait_for_workers(int(workers), timeout=120)
    if not client.scheduler_info().get("workers"):
        client.wait_for_workers(1, timeout=120)
    info = client.scheduler_info().get("workers", {})
    paths = [os.path.abspath(p) for p in sys.path if p] + [os.getcwd()]
    ordinals = _worker_ordinals(info)
    client.register_plugin(_worker_plugin(list(dict.fromkeys(paths)), ordinals, gpus, warm_up))
    devices = sorted({_device(k, gpus) for k in ordinals.values()}) or [_device(0, gpus)]
    where = f"({where}, {len(info)} workers on {', '.join(devices)})"

    task_ref = client.scatter(task, broadcast=True, hash=False)  # the task travels once per worker
    futures = {  # todo's order as priorities (higher first): longest first when the sweep has a cost estimate
        client.submit(
            _run_on_worker, store_path, layout, task_ref, index, gpus, ordinals, pure=False, priority=len(todo) - rank
        ): index
        for rank, index in enumerate(todo)
    }
    stack.callback(client.cancel, list(futures))  # runs before the client closes (last in, first out)

    def outcomes():
        for future in distributed.as_completed(list(futures), loop=client.loop):
            try:
                yield future.result()
            except Exception as exc:  # the worker died, or the task could not be unpickled there
                yield {"index": futures[future], "ok": False, "error": repr(exc)}

    return len(info), where, outcomes()


__all__ = [
    "SweepReport",
    "SweepTaskError",
    "host_allocator",
    "run_sweep",
]
