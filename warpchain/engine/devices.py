"""Warp devices: import and initialise Warp once, name and lock devices, count usable cores, and spread
CPU launches over threads (one slice of lattices per core)."""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from typing import Callable

import numpy as np

from ..options import LAYOUTS

_WARP_LOCK = threading.Lock()


def _warp():
    import warp as wp

    with _WARP_LOCK:
        if not getattr(_warp, "_initialised", False):
            if not wp.is_initialized() if hasattr(wp, "is_initialized") else True:
                # keep Warp's start-up banner and per-module compile lines out of scene logs (set here,
                # when warpchain first initialises Warp, not as a side effect of importing a module)
                if hasattr(wp, "LOG_WARNING") and hasattr(wp.config, "log_level"):
                    wp.config.log_level = wp.LOG_WARNING
                wp.config.quiet = True
            _quiet_init(wp)
            _warp._initialised = True
    return wp


_NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def _quiet_init(wp) -> None:
    """wp.init() with the native library's stderr captured: on a machine without a CUDA driver its
    warning becomes one info line in the log (CPU runs are the expected case there); anything else
    it printed is passed on unchanged."""
    import logging
    import sys
    import tempfile

    fd = 2  # the native library writes to file descriptor 2, whatever sys.stderr is (pytest, notebooks)
    try:
        os.fstat(fd)
    except OSError:  # no stderr at all: nothing to filter
        wp.init()
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            wp.init()
        finally:
            sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
        tmp.seek(0)
        text = tmp.read().decode(errors="replace")
    lines = [line for line in text.splitlines() if line.strip()]
    if any(_NO_DRIVER in line for line in lines):
        logging.getLogger("warpchain").info("Warp: no CUDA driver on this machine; running on the CPU")
    rest = [line for line in lines if _NO_DRIVER not in line]
    if rest:
        print("\n".join(rest), file=sys.stderr)


def available_devices() -> list[str]:
    """Warp devices on this machine, e.g. ``["cpu", "cuda:0"]``."""
    wp = _warp()
    return [str(d) for d in wp.get_devices()]


def resolve_device(device: str | None) -> str:
    """``None`` -> ``"cuda"`` when Warp sees a GPU, else ``"cpu"``; otherwise validated."""
    wp = _warp()
    if device is None:
        return "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"
    if not isinstance(device, str):
        raise ValueError(f"device must be a string such as 'cpu' or 'cuda', got {device!r}")
    name = device.strip().lower()
    if name == "cuda":
        name = "cuda:0"
    if name not in available_devices():
        raise ValueError(f"unknown or unavailable device {device!r}; available: {available_devices()}")
    return name


def record_on(wp, device: str, event=None):
    """Record ``event`` (an event of ``device``; None: a new one) on ``device``'s current stream and return it.

    Never ``wp.record_event(event)``: that records on the current stream of Warp's *current* device, which is
    process-wide (``cuda:0`` unless something set another) and not the device the work was queued on. In a process
    whose threads drive several GPUs (the Dask sweep's workers, one per GPU) an event of ``cuda:1`` went to
    ``cuda:0``'s stream and Warp refused it (issue #49). Every stream, event, capture and allocation in the engine
    names its device (``tests/test_devices.py`` checks the sources)."""
    return wp.get_stream(device).record_event(event)


_DEVICE_LOCKS: dict = {}


def device_lock(device: str) -> threading.RLock:
    """The lock that one thread holds while it issues work to ``device`` and waits for it.

    Warp keeps one current stream per device and one capture state per process (a CUDA graph is captured
    from the device's current stream; a CPU graph records every launch made anywhere while it is open), and
    refuses to synchronise a device while a capture is active on it. So a launch, copy, allocation or
    synchronisation from a second thread during one thread's capture breaks that capture, or enters it.
    Streams of our own per thread cannot help here: the current stream is per device, not per thread, and
    ``wp.synchronize_device`` waits on all of them. Every entry point that touches the device (``simulate``,
    ``observe``, ``propagate_tangent``, ``time_steps``, ``Flow.run``, ``Flow.linearize`` and its columns,
    ``DeviceState`` copies) holds this lock from its first launch to its last wait. Several threads can drive
    Flows on one device (site-bond's workers do): their host work (LAPACK, Python) runs in parallel, their
    device work in turn. Reentrant: a callback under
    the lock (``on_chunk``) may call the engine again. Work must never wait, under the lock, for another thread
    that needs it (the lock is held only inside the engine's own calls, so only a callback can do that)."""
    name = str(device)
    lock = _DEVICE_LOCKS.get(name)
    if lock is None:
        with _WARP_LOCK:
            lock = _DEVICE_LOCKS.setdefault(name, threading.RLock())
    return lock


def on_one_thread(fn):
    """``fn(params, x0, ..., device=...)`` under ``device_lock`` of its device (a ``DeviceState`` x0's own when
    ``device`` is None)."""

    @functools.wraps(fn)
    def wrapper(params, x0, *args, device: str | None = None, **kwargs):
        where = x0.device if isinstance(x0, DeviceState) and device is None else resolve_device(device)
        with device_lock(where):
            return fn(params, x0, *args, device=device, **kwargs)

    return wrapper


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity; os.cpu_count() counts the host's, which in a
    container can be twice as many: 16 against 8 on the H200 machine)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def count_from_text(text: str, requirement: str) -> int:
    """A whole number >= 1 written as ``text`` (an option, an environment variable); otherwise a ValueError
    that reads "<requirement>, got <text>"."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{requirement}, got {text!r}")
    return value


def cpu_threads() -> int:
    """Threads used for CPU launches: WARPCHAIN_CPU_THREADS, else the usable cores."""
    env = os.environ.get("WARPCHAIN_CPU_THREADS")
    if env:
        return count_from_text(env, "WARPCHAIN_CPU_THREADS must be a positive integer")
    return usable_cores()


def _even_slices(n: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` (at least one) contiguous near-equal ranges (lo, hi) covering 0..n, empty ones left out."""
    bounds = np.linspace(0, n, max(int(parts), 1) + 1).astype(int)
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def _slices(n: int, device: str) -> list[tuple[int, int]]:
    """Contiguous slices of n lattices: one per CPU thread (Warp runs a CPU launch on one core,
    so concurrent launches on disjoint slices use the others), or one slice on a GPU."""
    return _even_slices(n, min(cpu_threads(), n) if device == "cpu" else 1)


def _part(arr, lo: int, hi: int):
    """Lattices (or columns) lo..hi of a Warp array: the array itself when that is all of it (slicing a Warp
    array costs ~10 us of host time, and a launch takes several; the kept launch commands see the same
    pointers and shapes either way)."""
    return arr if lo == 0 and hi == arr.shape[0] else arr[lo:hi]


def _parts(lo: int, hi: int, *arrays) -> list:
    """``_part`` of each array, in order."""
    return [_part(a, lo, hi) for a in arrays]


_LOCAL = threading.local()


@contextlib.contextmanager
def on_this_thread():
    """Inside, ``_in_parallel`` runs its tasks one after the other on the calling thread: a graph capture (``_Replay``,
    on the CPU with ``Tuning.graphs_on_cpu``) records the capturing thread's launches only."""
    before = getattr(_LOCAL, "serial", False)
    _LOCAL.serial = True
    try:
        yield
    finally:
        _LOCAL.serial = before


def _in_parallel(tasks) -> None:
    """Run callables concurrently (one thread each; in turn inside ``on_this_thread``); re-raise the first error."""
    if len(tasks) == 1 or getattr(_LOCAL, "serial", False):
        for task in tasks:
            task()
        return
    errors = []

    def wrap(task):
        try:
            task()
        except BaseException as exc:  # pragma: no cover - surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=wrap, args=(t,)) for t in tasks]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def engine_method(method):
    """``method`` (a name or a ``Method``) as a ``SplittingMethod``, or a ValueError that says where another
    family runs: the engine's kernels step the splitting methods only. RK4 left the engine: at every accuracy a
    splitting method is as cheap or cheaper (work-precision scene) and RK4 alone needed step loops of its own
    (``docs/derivations/model.md``); ``warpchain.reference`` and ``ReferenceFlow`` keep it."""
    from ..integrators import METHODS, SplittingMethod, get_method

    m = get_method(method)  # a name or a Method; anything else raises ValueError there
    if not isinstance(m, SplittingMethod):
        named = METHODS.get(m.name) is m
        where = (
            f"warpchain.reference.integrate({m.name!r}, ...), or ReferenceFlow(method={m.name!r}) for Newton and "
            "Floquet"
            if named
            else "warpchain.reference.integrate(method, ...) with the method object"
        )
        raise ValueError(
            f"{m.name!r} is not a splitting method: the Warp engine (simulate, propagate_tangent, Flow) runs "
            f"the splitting methods of warpchain.METHODS; run it on the numpy reference instead ({where})"
        )
    return m


def resolve_layout(layout: str, device: str, n_sites: int, table: bool = False) -> str:
    """Kernel layout: ``"block"`` (a thread block per lattice: the GPU path), ``"sites"`` (a thread per site, a
    launch per force evaluation: the GPU path for lattices longer than a block) or ``"thread"`` (a thread per
    lattice: the CPU path). ``"auto"`` picks block on a GPU when the lattice fits one block, else sites on a GPU,
    else thread. A lattice given as a neighbour ``table`` (``warpchain.lattice.LatticeParams``) runs in the sites
    layout, on any device."""
    from . import block_kernels

    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if table:
        if layout not in ("auto", "sites"):
            raise ValueError(
                f"a lattice given as a neighbour table (LatticeParams) runs in the 'sites' layout, got {layout!r}; "
                "use layout='auto' or 'sites'"
            )
        return "sites"
    if layout == "auto":
        if device == "cpu":
            return "thread"
        return "block" if block_kernels.supports(n_sites) else "sites"
    if layout == "block" and not block_kernels.supports(n_sites):
        raise ValueError(
            f"layout 'block' needs N <= {block_kernels.MAX_BLOCK} (one site per thread), got N = {n_sites}"
        )
    return layout


def held(owner, key, make: Callable[[], object]):
    """``make()``, kept on ``owner`` under ``key``: made on first request and never replaced, so a graph
    captured with it (``_Replay``) keeps a valid address (a runner's or a plan's buffers)."""
    kept = owner.__dict__.setdefault("_held", {})
    if key not in kept:
        kept[key] = make()
    return kept[key]


# ----------------------------------------------------------------------------- a state kept on a device
#
# A batch state that stays in device memory between ``simulate`` calls.
#
# Why: from a host array every call moves the whole state twice, and on the H200 host the moves (host copy
# into staging, PCIe both ways) cost as much as half the kernel at 805 lattices and 2000 steps
# (``benchmarks/results/h200-2026-11-22n.json``). A study that runs segment after segment (run, look at a few scalars,
# run on) needs the state on the host only when it wants to look at it. ``simulate(..., keep_on_device=True)``
# returns the final state as a :class:`DeviceState`, and a ``DeviceState`` passed as ``x0`` is copied device to
# device (microseconds) into the run's buffers. The guard's per-lattice scalars (energy, finite flag, minimum
# contact) still reach the host after every chunk, so a blow-up is found exactly as before.
#
# A ``DeviceState`` owns its device buffer: nothing else writes it, so it may be passed as ``x0`` any number
# of times. ``numpy()`` (or ``np.asarray``) copies it to the host.


class DeviceState:
    """The state of a batch of lattices in one device's memory.

    Args:
        array: a C-contiguous float64 Warp array of shape (batch, 4, N), ordered (u, v, u', v') per lattice.
            The ``DeviceState`` keeps it; nothing in warpchain writes it afterwards.

    Attributes:
        array: that Warp array.
        shape: (batch, 4, N).
        device: the Warp device it lives on (``"cuda:0"``, or ``"cpu"``).
    """

    __slots__ = ("array",)

    def __init__(self, array):
        wp = _warp()
        if not isinstance(array, wp.array):
            raise TypeError(f"DeviceState wraps a Warp array; got {type(array).__name__} (use DeviceState.of)")
        if array.dtype != wp.float64 or array.ndim != 3 or array.shape[1] != 4 or array.shape[0] < 1:
            raise ValueError(
                f"DeviceState needs a float64 Warp array of shape (batch, 4, N); got {array.dtype} {array.shape}"
            )
        if not array.is_contiguous:
            raise ValueError("DeviceState needs a contiguous Warp array")
        self.array = array

    @classmethod
    def of(cls, x, *, device: str | None = None) -> "DeviceState":
        """A batch state copied to ``device`` (None: the GPU ``simulate`` would pick).

        Args:
            x: host array of shape (batch, 4, N) or (4, N), finite float64 values (``simulate`` checks them on
                the device when it starts from the state).
        """

        arr = np.asarray(x, dtype=np.float64)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[1] != 4 or arr.shape[0] < 1:
            raise ValueError(f"a batch state has shape (batch, 4, N) or (4, N); got {np.shape(x)}")
        wp, device = _warp(), resolve_device(device)
        with device_lock(device):
            return cls(wp.array(np.ascontiguousarray(arr), dtype=wp.float64, device=device))

    @classmethod
    def empty(cls, shape: tuple, device: str) -> "DeviceState":
        """An unfilled state of ``shape`` (batch, 4, N) on ``device`` (``simulate`` fills it)."""
        wp = _warp()
        with device_lock(device):
            return cls(wp.empty(tuple(int(s) for s in shape), dtype=wp.float64, device=device))

    @property
    def shape(self) -> tuple:
        return tuple(self.array.shape)

    @property
    def size(self) -> int:
        return int(self.array.size)

    @property
    def device(self) -> str:
        return str(self.array.device)

    def device_for(self, n_sites: int, device: str | None) -> str:
        """The device a run from this state uses (its own), checked against the chain and the ``device`` asked."""
        if self.shape[2] != n_sites:
            raise ValueError(f"x0 (a DeviceState of shape {self.shape}) does not fit a chain of N = {n_sites} cells")
        if device is not None and resolve_device(device) != self.device:
            raise ValueError(
                f"x0 lives on {self.device!r} but device={device!r}: run on {self.device!r} (device=None), or pass "
                "x0.numpy() to move the state"
            )
        return self.device

    def __len__(self) -> int:
        return self.shape[0]

    def numpy(self) -> np.ndarray:
        """A host copy, shape (batch, 4, N) (waits for the device's queued work on the state)."""
        with device_lock(self.device):
            out = self.array.numpy()
        return out.copy() if self.array.device.is_cpu else out  # on the CPU .numpy() is a view of the buffer

    def __array__(self, dtype=None, copy=None):
        out = self.numpy()
        return out if dtype is None else out.astype(dtype, copy=False)

    def __repr__(self) -> str:
        return f"DeviceState(shape={self.shape}, device={self.device!r})"
