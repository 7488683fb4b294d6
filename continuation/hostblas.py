"""How many threads the host's BLAS/LAPACK may use while a branch is walked.

The host linear algebra of continuation is small: LU solves of 402 (or 804) unknowns, products of
201- or 402-square blocks, and eigen-decompositions of 201-square parity blocks. How many BLAS threads
pay depends on what else wants the cores:

- **On the CPU device** one thread. OpenBLAS's worker threads spin after every call, on the cores that
  Warp's CPU kernels, the tangent launches' threads and the host copy threads need. On this project's
  2-core CPU the paper's frequency branch took 51.3 s with OpenBLAS's default 2 threads and 24.7 s with 1
  (``benchmarks/branch_profile.py``; the LU of 402 unknowns went from 15 to 1.7 ms per call, the Floquet
  products from 32 to 11 ms).
- **On a GPU** the process's own setting (``None``): the kernels need no host cores, and on the H200
  machines' hosts one thread factors the 402 x 402 Newton Jacobian in 9 ms against 2-4 ms on several
  (``benchmarks/results/h200-2026-11-22g.json``).
- **The parity blocks' eigs** (``floquet.parity_blocks``: two, or four on a patch with a mirror) always run on
  one BLAS thread each, on host threads at once: LAPACK's ``dgeev`` is not threaded at these sizes, and two
  calls that each start OpenBLAS threads contend (2-core CPU: 27.6 ms for both on 2 BLAS threads, 13.3 ms on 1).

``blas_threads(n)`` limits every loaded BLAS (numpy's and scipy's OpenBLAS, MKL, ...) to n threads for
the duration of a ``with`` block, through one cached ``threadpoolctl.ThreadpoolController`` (11 us per
block, against 1.5 ms for a fresh ``threadpool_limits``). ``None`` leaves them alone. The limit is the
process's, not the calling thread's, so blocks are counted: while any is open (two branches walked at once on
two threads of one process, two Floquet analyses) the BLAS runs at the smallest limit asked, and the limits
from before the first come back when the last one ends, whichever order they end in.
"""

from __future__ import annotations

import contextlib
import os
import threading
import weakref

_CONTROLLER = None
_LOCK = threading.Lock()


def threads_for(device: str | None) -> int | None:
    """The BLAS threads for a walk on this device (module docstring): 1 on the CPU (and for the numpy
    reference flow), None (the process's setting) on a GPU. None picks the device as Warp would."""
    if device is None:
        from warpchain import resolve_device

        device = resolve_device(None)
    return 1 if str(device) in ("cpu", "numpy") else None


def _controller():
    global _CONTROLLER
    with _LOCK:
        if _CONTROLLER is None:
            from threadpoolctl import ThreadpoolController

            _CONTROLLER = ThreadpoolController()  # the BLAS libraries loaded by now: numpy's and scipy's
    return _CONTROLLER


@contextlib.contextmanager
def blas_threads(threads: int | None = 1):
    """Limit the host BLAS to ``threads`` threads inside the block (None: no change)."""
    if threads is None:
        yield
        return
    if int(threads) < 1:
        raise ValueError(f"BLAS threads must be a whole number >= 1 or None, got {threads!r}")
    global _ORIGINAL
    limit = int(threads)
    libraries = _controller().select(user_api="blas").lib_controllers
    with _LOCK:
        if not _OPEN:
            _ORIGINAL = [library.get_num_threads() for library in libraries]
            _set(libraries, [limit] * len(libraries))
        elif limit < min(_OPEN):
            _set(libraries, [limit] * len(libraries))
        _OPEN.append(limit)
    try:
        yield
    finally:
        with _LOCK:
            _OPEN.remove(limit)
            if not _OPEN:
                _set(libraries, _ORIGINAL)
            elif limit < min(_OPEN):
                _set(libraries, [min(_OPEN)] * len(libraries))


#: the limits of the open ``blas_threads`` blocks, and each library's limit from before the first
_OPEN: list = []
_ORIGINAL: list = []


def _set(libraries, limits) -> None:
    """Set each library's limit (under ``_LOCK``), from whichever thread. threadpoolctl (3.8 on) lets one thread
    alone set a process-wide OpenBLAS pool, the first to set it, until a ``with`` block of its own ends; these
    blocks keep their own count, so control is cleared before each set and after (``OpenBLASController``)."""
    from threadpoolctl import OpenBLASController

    clear = getattr(OpenBLASController, "clear_controlling_thread", None)
    for library, limit in zip(libraries, limits):
        if clear is not None:
            clear(force=True)
        library.set_num_threads(limit)
    if clear is not None:
        clear(force=True)


class HostPool:
    """Host threads for one kind of work (``ThreadPoolExecutor`` of ``size`` threads named ``name``), made on the first
    call and kept; made afresh in a forked child, which has none of its parent's threads (a pool carried over would
    wait for them for ever). Work handed to a pool must never wait on the same pool."""

    def __init__(self, size: int, name: str):
        self.size, self.name = int(size), name
        self._pool, self._lock = None, threading.Lock()
        _POOLS.add(self)

    def __call__(self):
        with self._lock:
            if self._pool is None:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(max_workers=self.size, thread_name_prefix=self.name)
        return self._pool

    def _forget(self) -> None:
        self._pool, self._lock = None, threading.Lock()


_POOLS: "weakref.WeakSet[HostPool]" = weakref.WeakSet()


def _after_fork_in_child() -> None:
    for pool in list(_POOLS):
        pool._forget()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


#: the host threads for chunked work whose tasks hand no work on (one per core, at most 16): the probed problem's sparse
#: products (``krylov_floquet._products``), the eigenvectors' measures (``slicing._measures``), the blocks' inertia
#: counts (``slicing._start_counts``)
host_pool = HostPool(min(16, os.cpu_count() or 1), "warpchain-host")
