"""Worker processes for the host eigensolves: ARPACK holds the GIL while it orthogonalises, so the independent
eigensolves of a long lattice (the window's ends, the slices of a complete spectrum) run in Python processes.

**What a worker is.** ``python -P -c _WORKER DIR``: a stub package named ``continuation`` whose ``__path__`` is this
folder, so a task's module (``continuation.krylov_floquet``, ``continuation.slicing``) is imported with its relative
imports but without ``continuation/__init__.py`` (no warpchain, no Warp: ~0.3 s to start), with one BLAS thread,
in a session of its own (a terminal's Ctrl-C or Ctrl-Z reaches the caller, not the workers) and with SIGINT ignored.
Workers start on first use and are kept for the process's life, so a branch pays their start once; they end when
their stdin closes (the caller's exit, or ``close``).

**A task** is (module, function, args): args may hold ``Shared`` objects, which a worker keeps (the last
``CACHE_SIZE``), so a slice's 40 MB operator travels to each worker once, not once per slice. The reply is the
function's result, or its error: raised here as a ``WorkerError`` whose message is one line (the error's last
line; the worker's traceback is its ``detail``), and that worker is replaced.

**Nothing hangs.** While a task runs, its caller's thread looks at the worker every ``POLL_SECONDS``: a worker that
exited, or that was stopped (SIGSTOP: state T), fails the task at once with a ``WorkerError`` naming it; a task
past ``TASK_TIMEOUT_SECONDS`` (a hang: far beyond any solve's time) too. Ctrl-C in ``map`` kills the busy workers and
raises ``KeyboardInterrupt`` at once. Timings never change a result: a slow worker is waited for, a stuck one is
an error.
"""

from __future__ import annotations

import collections
import itertools
import logging
import os
import pickle
import queue
import select
import signal
import subprocess
import sys
import threading
import time
import traceback
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait

#: worker processes at most (the caller's available cores bound it too)
PROCESS_COUNT = 16

#: shared objects a worker keeps (first in, first out; the caller mirrors the rule to know what each holds)
CACHE_SIZE = 8

#: how often a waiting caller looks at its worker (exited? stopped?) and at Ctrl-C, seconds
POLL_SECONDS = 0.25

#: a task still running after this long fails (a hung worker): the slowest solve seen takes a few seconds
TASK_TIMEOUT_SECONDS = 1800.0


class WorkerError(RuntimeError):
    """A task that failed in a worker, or a worker that died, was stopped or hung. ``detail``: the worker's
    traceback (or what was seen)."""

    def __init__(self, message: str, detail: str = ""):
        super().__init__(message)
        self.detail = detail


class Shared:
    """An argument that a worker keeps under ``key`` once sent (``Workers.map``): it travels as itself the first
    time, as a ``_Ref`` to its key after."""

    _keys = itertools.count()

    def __init__(self, value, key=None):
        self.value = value
        self.key = key if key is not None else f"{os.getpid()}-{next(Shared._keys)}"


class _Ref:
    def __init__(self, key):
        self.key = key


def _state(pid: int) -> str:
    """The process's state letter from /proc (R, S, T, Z, ...), '' where /proc is not there."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0].decode()
    except (OSError, IndexError):
        return ""


class _Worker:
    def __init__(self):
        command = [sys.executable, *(["-P"] if sys.version_info >= (3, 11) else []), "-c", _WORKER]
        command.append(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
        self.process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, start_new_session=True
        )
        self.held = collections.deque()  # the Shared keys it keeps, oldest first (its own rule, mirrored)

    def send(self, module: str, function: str, args: tuple) -> None:
        out = []
        for a in args:
            if isinstance(a, Shared):
                if a.key in self.held:
                    a = _Ref(a.key)
                else:
                    self.held.append(a.key)
                    if len(self.held) > CACHE_SIZE:
                        self.held.popleft()
            out.append(a)
        payload = pickle.dumps((module, function, tuple(out)), protocol=pickle.HIGHEST_PROTOCOL)
        self.process.stdin.write(len(payload).to_bytes(8, "little") + payload)
        self.process.stdin.flush()

    def receive(self, cancelled: threading.Event, what: str):
        """The reply, waited for while the worker lives, runs and is within the time limit."""
        start, out, pid = time.monotonic(), self.process.stdout, self.process.pid
        while not select.select([out], [], [], POLL_SECONDS)[0]:
            if cancelled.is_set():
                raise KeyboardInterrupt
            if self.process.poll() is not None:
                raise WorkerError(f"eigensolver worker {pid} exited ({self.process.returncode}) during {what}")
            if _state(pid) in ("T", "t"):
                raise WorkerError(f"eigensolver worker {pid} was stopped (SIGSTOP) during {what}: killed it")
            if time.monotonic() - start > TASK_TIMEOUT_SECONDS:
                raise WorkerError(
                    f"eigensolver worker {pid} gave no answer in {TASK_TIMEOUT_SECONDS:.0f} s during {what} (hung): "
                    "killed it"
                )
        head = out.read(8)
        if len(head) < 8:
            raise WorkerError(f"eigensolver worker {pid} exited during {what}")
        size = int.from_bytes(head, "little")
        body = out.read(size)
        if len(body) < size:
            raise WorkerError(f"eigensolver worker {pid} exited during {what} (half a reply)")
        status, value = pickle.loads(body)
        if status == "error":
            last = value.strip().splitlines()[-1] if value.strip() else "no message"
            raise WorkerError(f"{what} failed in eigensolver worker {pid}: {last}", value)
        return value

    def kill(self) -> None:
        try:
            self.process.kill()
        except OSError:
            pass
        self.process.wait()
        for pipe in (self.process.stdin, self.process.stdout):
            try:
                pipe.close()
            except OSError:
                pass


class Workers:
    """A pool of worker processes (module docstring)."""

    _shared = None
    _lock = threading.Lock()

    @classmethod
    def shared(cls) -> "Workers":
        """The process's pool (a forked child starts its own)."""
        with cls._lock:
            if cls._shared is None or cls._shared.pid != os.getpid():
                cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
                cls._shared = cls(min(PROCESS_COUNT, cores or 1))
            return cls._shared

    def __init__(self, count: int):
        import atexit

        self.pid, self.count, self.idle, self.started = os.getpid(), int(count), queue.SimpleQueue(), []
        for _ in range(self.count):
            self.idle.put(None)  # started when first taken
        atexit.register(self.close)

    def call(self, module: str, function: str, args: tuple, *, what: str = "a task", cancelled=None):
        """``module.function(*args)`` in an idle worker (a fresh one in place of any that failed)."""
        cancelled = cancelled or threading.Event()
        worker = self.idle.get()
        try:
            if worker is not None and worker.process.poll() is not None:  # it died while idle
                self._forget(worker)
                worker = None
            if worker is None:
                worker = self._start()
                self.started.append(worker)
            worker.send(module, function, args)
            value = worker.receive(cancelled, what)
        except BaseException:  # failed, stuck or interrupted mid-task: this worker is not reused
            self._discard(worker)
            raise
        self.idle.put(worker)
        return value

    def map(self, module: str, tasks: list, *, what: str = "task") -> list:
        """``call`` of each task, (function, args), on all workers at once; the results in order. The first error
        is raised (the other tasks are stopped); Ctrl-C kills the busy workers and raises ``KeyboardInterrupt`` at
        once."""
        cancelled = threading.Event()
        pool = ThreadPoolExecutor(min(self.count, max(1, len(tasks))), thread_name_prefix="eigensolver-worker")
        futures = [
            pool.submit(self.call, module, f, args, what=f"{what} {i + 1} of {len(tasks)}", cancelled=cancelled)
            for i, (f, args) in enumerate(tasks)
        ]
        try:
            start = time.monotonic()
            while True:  # a line every PROGRESS_SECONDS on long maps (a 12801-site verdict on 2 cores: minutes)
                done, pending = wait(futures, timeout=PROGRESS_SECONDS, return_when=FIRST_EXCEPTION)
                if not pending or any(f.exception() is not None for f in done):
                    break
                logging.getLogger("continuation").info(
                    "[workers] %s: %d of %d done (%.0f s)", what, len(done), len(futures), time.monotonic() - start
                )
            return [f.result() for f in futures]
        except BaseException:
            cancelled.set()  # the busy workers' waits raise and kill them
            raise
        finally:
            pool.shutdown(wait=False, cancel_futures=True)

    @staticmethod
    def _start() -> _Worker:
        return _Worker()

    def _discard(self, worker) -> None:
        if worker is not None:
            worker.kill()
            self._forget(worker)
        self.idle.put(None)

    def _forget(self, worker) -> None:
        if worker in self.started:
            self.started.remove(worker)

    def close(self) -> None:
        """End the workers: close their stdin, so that each leaves its loop, and wait for them."""
        if self.pid != os.getpid():
            return
        for worker in list(self.started):
            self._forget(worker)
            try:
                worker.process.stdin.close()
                worker.process.wait(timeout=5)
            except Exception:
                worker.kill()


#: seconds between the progress lines of a long ``Workers.map``
PROGRESS_SECONDS = 30.0


#: a worker's command line: the stub package, then ``_serve``
_WORKER = (
    "import importlib, sys, types; p = types.ModuleType('continuation'); p.__path__ = [sys.argv[1]]; "
    "sys.modules['continuation'] = p; importlib.import_module('continuation.workers')._serve()"
)


def _serve() -> None:
    """A worker's loop: per task an 8-byte length and a pickle in, ("ok", result) or ("error", traceback) out the
    same way; it ends when its stdin closes."""
    import importlib

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller handles Ctrl-C and kills what it must
    read, write = sys.stdin.buffer.read, sys.stdout.buffer
    held = collections.OrderedDict()
    while head := read(8):
        try:
            module, function, args = pickle.loads(read(int.from_bytes(head, "little")))
            values = []
            for a in args:
                if isinstance(a, Shared):
                    held[a.key] = a.value
                    if len(held) > CACHE_SIZE:
                        held.popitem(last=False)
                    a = a.value
                elif isinstance(a, _Ref):
                    a = held[a.key]
                values.append(a)
            reply = ("ok", getattr(importlib.import_module(module), function)(*values))
        except Exception:
            reply = ("error", traceback.format_exc())
        out = pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL)
        write.write(len(out).to_bytes(8, "little") + out)
        write.flush()
