"""Independent solves of one scene on a few host threads (``site-bond``'s branch points and finite-size checks,
``finite-size``'s sizes and foam).

Each thread keeps a Flow of its own (a Flow holds device buffers and captured graphs between calls, so threads
never share one). The solves spend most of their time in LAPACK and in waits for the device, which release the
GIL. From the first task to ``close`` the host BLAS runs on one thread (``continuation.hostblas``): the thread
limit is the process's, and with several threads in LAPACK at once, each changing it around its Floquet blocks,
how many BLAS threads a factorisation got, hence its rounding, would depend on which thread ran when
(``benchmarks/thread_check.py``). One BLAS thread per solve gives every solve the bits it has alone, whatever the
number of workers and on every device; the workers keep the cores busy instead.

A task that raises is retried once on a fresh Flow (new buffers and graphs); a second failure is raised by the
Future's ``result()`` as a ``TaskError`` naming the task, so that it fails the scene (never a log line). Exceptions
listed as ``outcomes`` (a mathematical answer, such as ``bifurcation.NotLocated``) pass through untouched.
"""

from __future__ import annotations

import contextlib
import threading
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout

from warpchain.engine.devices import usable_cores


class TaskError(RuntimeError):
    """A scene's task that raised twice: the scene fails (it is never a log line)."""


def default_workers(count: int, most: int = 4) -> int:
    """``count`` threads, or for 0 one per two usable cores, at least 1 and at most ``most``."""
    if count < 0:
        raise ValueError(f"workers must be >= 0 (0: one per two CPU cores), got {count}")
    return count or max(1, min(most, usable_cores() // 2))


class Workers:
    """``count`` host threads (``default_workers``) running ``fn(flow, *args)`` tasks, each thread with its own
    Flow from ``make_flow()`` (``count`` 0: one per two usable cores, at most ``most``); ``name`` prefixes the
    threads' names; ``log(message, *args)`` hears retries; ``retry=False``: a failure is not retried (a long task
    whose errors are the mathematics', e.g. a chain of solves). ``stopping`` is set when ``close`` begins or a task
    fails: a task that loops over many solves polls it, so that an error or Ctrl-C elsewhere does not wait for the
    loop's end."""

    def __init__(
        self, count: int, make_flow, log=None, *, name: str = "scene", outcomes: tuple = (), most: int = 4,
        retry: bool = True, shared: "Workers | None" = None,
    ):  # fmt: skip
        self.make_flow, self.log, self.outcomes, self.retry = make_flow, log, tuple(outcomes), retry
        # set by ``close`` or by the first task that fails: long tasks poll it; ``shared``: another pool's, so that
        # a failure in either stops both
        self.stopping = shared.stopping if shared is not None else threading.Event()
        self.errors = shared.errors if shared is not None else []  # the failures, first first
        self.blas = None  # the one-thread BLAS limit while tasks run
        self._lock = threading.Lock()
        self.local = threading.local()
        self.count = default_workers(count, most)
        self.pool = ThreadPoolExecutor(max_workers=self.count, thread_name_prefix=name)

    def _flow(self):
        if getattr(self.local, "flow", None) is None:
            self.local.flow = self.make_flow()
        return self.local.flow

    def submit(self, what: str, fn, *args):
        """fn(flow, *args) on a worker thread; returns its Future (``what`` names the task in a ``TaskError``). A
        task that raises (an outcome too) sets ``stopping`` and is kept in ``errors``, so that ``result`` raises it
        at once, whatever else is awaited."""

        def attempt():
            try:
                return fn(self._flow(), *args)
            except self.outcomes:
                raise
            except Exception as first:
                if not self.retry:
                    raise TaskError(f"{what} failed: {type(first).__name__}: {first}") from first
                if self.log:
                    self.log("%s raised %s: %s; retrying once", what, type(first).__name__, first)
                self.local.flow = None  # new buffers and graphs for the retry
                del first  # not kept alive (with the failed attempt's frames and Flow) through the retry
                try:
                    return fn(self._flow(), *args)
                except self.outcomes:
                    raise
                except Exception as exc:
                    raise TaskError(f"{what} failed twice: {type(exc).__name__}: {exc}") from exc

        def failed(future) -> None:
            if not future.cancelled() and future.exception() is not None:
                self.errors.append(future.exception())
                self.stopping.set()

        with self._lock:  # submitted from several threads at once (a chain thread hands its analyses here)
            if self.blas is None:
                from continuation.hostblas import blas_threads

                self.blas = contextlib.ExitStack()
                self.blas.enter_context(blas_threads(1))
            future = self.pool.submit(attempt)
        future.add_done_callback(failed)
        return future

    def result(self, future):
        """``future.result()``, or the first failure of any task of this pool (or the pool it shares), as soon as
        there is one: an error elsewhere does not wait for this task's end."""
        while True:
            if self.errors:
                raise self.errors[0]
            try:
                return future.result(timeout=0.25)
            except FutureTimeout:
                continue

    def close(self) -> None:
        """Set ``stopping``, cancel what has not started (after success nothing is left), let a running solve finish,
        then give the host BLAS its thread count back (a solve still running would otherwise restore the one-thread
        limit it found, after this, for the rest of the process; given back even when a second Ctrl-C interrupts
        the wait)."""
        self.stopping.set()
        try:
            self.pool.shutdown(wait=True, cancel_futures=True)
        finally:
            if self.blas is not None:
                self.blas.close()
                self.blas = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
