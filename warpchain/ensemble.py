"""Batched runs on a Warp device: ``simulate`` (direct simulation with recording and a stability
guard) and ``propagate_tangent`` (end state plus Jacobian columns of the discrete map).

A run is split into chunks of many steps; each chunk is one kernel launch that loops over time
inside the kernel. Between chunks the state is checked (finite, energy within bound), recorded
fields are copied out (and optionally handed to a callback, e.g. a zarr writer), and the
progress bar advances.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import threading
import time
import warnings
from typing import Callable

import numpy as np

from . import leases
from .integrators import Method, RungeKuttaMethod, SplittingMethod, get_method, steps_for
from .losses import KICK_ENTRIES, Damping, as_damping, kick_matrices, lossless, require_splitting
from .model import (
    BOUNDARY_CODES,
    ChainParams,
    as_batch,
    band_edges,
    per_lattice_parameters,
    real_number,
    whole_number,
)
from .device_state import DeviceState
from .reference import inverse_mass


class IntegrationError(RuntimeError):
    """A run blew up (non-finite state or energy error past its bound).

    Attributes:
        method, dt, stability_limit: the scheme, its step, and its linear stability limit.
        failed: indices of the failing lattices.
        t: time reached when the failure was detected.
    """

    def __init__(self, message, *, method, dt, stability_limit, failed, t):
        super().__init__(message)
        self.method = method
        self.dt = dt
        self.stability_limit = stability_limit
        self.failed = failed
        self.t = t


class StepSizeError(ValueError):
    """A step above the method's linear stability limit was refused before the run started."""


@dataclasses.dataclass(frozen=True)
class SimulationResult:
    """Outcome of ``simulate``.

    Attributes:
        x: final state, shape (batch, 4, N): a numpy array, or with ``keep_on_device`` a ``DeviceState``.
        t: times of the recorded fields, shape (n_saved,); ``[0, t_final]`` when nothing was saved.
        u, v: recorded fields, shape (n_saved, batch, N) each, or None without ``save_every``.
        energy_initial, energy_final: Hamiltonian of each lattice, shape (batch,).
        energy_error: relative energy error |E(t_final) - E(0)| / |E(0)| per lattice, shape (batch,).
        max_energy_error: largest relative energy error seen at chunk boundaries, per lattice.
        min_contact: min over sites and checked times of 1 + u_j - v_j, per lattice (<= 0:
            contact was lost at some point).
        energy_t, energy_trace: times of the chunk ends and the energy of each lattice there,
            shapes (n_chunks + 1,) and (n_chunks + 1, batch) (the t = 0 value first).
        method, dt, nsteps, t_final, device, wall_seconds: how it ran (dt is the step used).
        layout: the kernel layout that ran (``"block"`` or ``"thread"``).
        stats: where the wall time went, host clock (seconds): ``setup`` (checks, buffers, the start's
            upload, until the first chunk is queued; ``runner`` of it: the device buffers taken from the
            pool and loaded with the batch's parameters), ``waiting`` (the host blocked on the device's
            chunks), ``frames`` (recorded frames copied into ``u`` and ``v``), ``final`` (the final
            state copied into ``x``), and ``chunks``, ``slices`` (lattice slices the state moved in),
            ``sites_per_thread`` (block layout), ``lent`` (``x`` is page-locked memory lent by ``leases``).

    On a GPU, ``x`` (and ``u``, ``v`` without ``frames_out``) are, from the second call of a size on, ordinary
    numpy arrays in page-locked host memory that the device copied into directly (``warpchain.leases``): they
    go back to a pool when dropped, and a run continued from ``x`` is uploaded straight from it.
    """

    x: np.ndarray | DeviceState
    t: np.ndarray
    u: np.ndarray | None
    v: np.ndarray | None
    energy_initial: np.ndarray
    energy_final: np.ndarray
    energy_error: np.ndarray
    max_energy_error: np.ndarray
    min_contact: np.ndarray
    energy_t: np.ndarray
    energy_trace: np.ndarray
    method: str
    dt: float
    nsteps: int
    t_final: float
    device: str
    wall_seconds: float
    layout: str = "thread"
    stats: dict = dataclasses.field(default_factory=dict)


# ----------------------------------------------------------------------------- devices


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


# ----------------------------------------------------------------------------- helpers


def stability_limit(method: Method | str, params: ChainParams, M=None, K=None) -> float:
    """Linear stability limit on dt of ``method`` for these parameters (smallest over a batch),
    from the top of the optical band, w_max: dt < bound / w_max (bound = 2 for Verlet)."""
    method = get_method(method)
    if M is None and K is None:  # one chain for the whole batch (simulate's set-up: kept per chain)
        return method.linear_stability_limit(_optical_top(params.M, params.K))
    Ms = np.atleast_1d(params.M if M is None else M).astype(float)
    Ks = np.atleast_1d(params.K if K is None else K).astype(float)
    Ms, Ks = np.broadcast_arrays(Ms, Ks)
    if Ms.min() == Ms.max() and Ks.min() == Ks.max():
        pairs = [(Ms.flat[0], Ks.flat[0])]  # one chain for the whole batch
    else:
        pairs = np.unique(np.stack([Ms.ravel(), Ks.ravel()], axis=1), axis=0)
    w_max = max(band_edges(float(m), float(k))["optical_top"] for m, k in pairs)
    return method.linear_stability_limit(w_max)


@functools.lru_cache(maxsize=256)
def _optical_top(M: float, K: float) -> float:
    return band_edges(M, K)["optical_top"]


def _as_state(x0, N: int) -> np.ndarray:
    """``model.as_batch`` without its scan for non-finite values (``simulate`` runs that check on the
    device, in its guard: on a large batch the host scan alone cost twice the kernel)."""
    arr = np.asarray(x0) if not isinstance(x0, np.ndarray) else x0
    if arr.dtype == np.float64 and arr.ndim == 3 and arr.shape[1:] == (4, N) and arr.shape[0] >= 1:
        return np.ascontiguousarray(arr)
    if arr.dtype == np.float64 and arr.ndim == 2 and arr.shape == (4, N):
        return np.ascontiguousarray(arr[None])
    return as_batch(x0, N, "x0")  # anything else: the full validation, with its messages


def _state_device(x0: DeviceState, n_sites: int, device: str | None) -> str:
    """The device a ``DeviceState`` x0 runs on (its own), checked against the chain and ``device``."""
    if x0.shape[2] != n_sites:
        raise ValueError(f"x0 (a DeviceState of shape {x0.shape}) does not fit a chain of N = {n_sites} cells")
    own = x0.device
    if device is not None and resolve_device(device) != own:
        raise ValueError(
            f"x0 lives on {own!r} but device={device!r}: run on {own!r} (device=None), or pass x0.numpy() "
            "to move the state"
        )
    return own


def _check_step(method: Method, params, dt, M, K, allow_unstable_step: bool) -> float:
    dt = real_number("dt", dt, positive=True)
    limit = stability_limit(method, params, M, K)
    if dt >= limit:
        message = (
            f"dt = {dt:g} is above the linear stability limit {limit:.6g} of method '{method.name}' "
            f"for these parameters (bound {method.stability_bound:.4f} / optical band top); "
            f"use dt < {limit:.6g}"
        )
        if not allow_unstable_step:
            raise StepSizeError(message + " or pass allow_unstable_step=True to run anyway")
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    return limit


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


def _in_parallel(tasks) -> None:
    """Run callables concurrently (one thread each); re-raise the first error."""
    if len(tasks) == 1:
        tasks[0]()
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


LAYOUTS = ("auto", "block", "thread")


def resolve_layout(layout: str, device: str, n_sites: int) -> str:
    """Kernel layout: ``"block"`` (a thread block per lattice, a thread per site: the GPU path) or
    ``"thread"`` (a thread per lattice: the CPU path). ``"auto"`` picks block on a GPU when the
    lattice fits one block, thread otherwise."""
    from . import block_kernels

    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if layout == "auto":
        return "block" if device != "cpu" and block_kernels.supports(n_sites) else "thread"
    if layout == "block" and not block_kernels.supports(n_sites):
        raise ValueError(
            f"layout 'block' needs N <= {block_kernels.MAX_BLOCK} (one site per thread), got N = {n_sites}"
        )
    return layout


#: ``simulate`` touches the final state's host array on background threads while the device runs from this
#: many values up (fresh memory fills at ~3 GB/s per thread: 0.9 ms for the 805-lattice state)
_PREFAULT_MIN_VALUES = 1 << 16
#: ``simulate`` moves the state in lattice slices (overlapped with the kernels) from this many values up
#: (5.2k lattices of 201 sites), in the slices of ``_slice_bounds``
_SLICED_MIN_VALUES = 1 << 22
_SLICES = None
#: lattices per slice and the most slices: on the H200, 8 slices of 4096 lattices, 2 of 4096 and the whole
#: batch at 805 were each the best or within 2 % of it (benchmarks/h200-2026-11-22h/slices.txt)
_SLICE_LATTICES = 4096
_MAX_SLICES = 8
#: a sliced run of at most this many force evaluations per site runs in at most ``_SHORT_RUN_CHUNKS`` chunks
#: by default: the first and the last chunk, whose kernels hide the slices' transfers, then hold the whole run
_SHORT_RUN_EVALUATIONS = 1 << 15
_SHORT_RUN_CHUNKS = 2
_SLICE_ON_CPU = False  # tests set it to run the sliced path on the CPU
#: a short sliced run without recording from a page-locked x0 (a lent result, ``page_locked``) runs its first and
#: last (sliced) chunk for this fraction of its steps each, and the rest on the whole batch in one chunk, which
#: runs ~8 % faster than slice after slice. From a plain x0 the uploads' host copies (~1.7 ms per 26 MB slice on
#: the H200 host) need the longer sliced half-run chunks to hide behind. On the H200 at 32768 lattices: 32.8
#: against 34.2 ms from a page-locked x0, but 43.8 against 35.8 ms from a plain one
#: (benchmarks/h200-2026-11-22m/slices-ends.txt)
_LOCKED_ENDS: float | None = 0.125
_SLICED_ENDS: float | None = None  # benchmarks: this fraction for every short sliced run (None: as above)
#: on a GPU ``simulate`` returns its final state (and, without ``frames_out``, its recorded frames) in
#: page-locked host memory lent by ``leases``, which the device copies into directly: no page touching and no
#: host copy per call (False: plain arrays, as before; benchmarks compare the two)
_LEASE_RESULTS = True
_UPLOAD_PAGEABLE = False  # benchmarks: a whole-batch upload from plain memory by the driver, not our staging
#: tests set it to lend (plain Warp host) buffers on the CPU, so CI runs the direct copies into and out of them
#: (those work on any device: only the lending is GPU-only by default)
_LEASE_ON_CPU = False
#: from this many lattices a launch of a method with few stages would take two lattices per thread block
#: (None: never). Off: on the H200 it made the Verlet kernel slower, 3.27e11 against 3.56e11 site-steps/s
#: at 4096 lattices and 3.41e11 against 3.76e11 at 32768 (benchmarks/h200-2026-11-22b/two-per-block/),
#: although two per block is what makes the hand-written CUDA kernel faster there.
_PAIR_MIN_BATCH = None
_PAIR_ON_CPU = False  # tests set it to run the two-per-block kernels on the CPU
#: sites per thread of the block splitting kernels (``block_kernels.site_group_kernels``), forced for every
#: batch (None: ``sites_per_thread`` chooses); tests set it to run the site-group kernels on the CPU
_SITES_FORCED: int | None = None


#: from this many lattices a GPU launch of a splitting method with at most _SITES_MAX_STAGES stages gives each
#: thread a run of sites (one warp per lattice up to 256 sites). H200, N = 201 (``benchmarks/sites_per_thread.py``,
#: ``benchmarks/h200-2026-11-22e``): Verlet 3.28e11 site-steps/s at 2400 lattices with 7 sites per thread against
#: 3.19e11 with one, 4.40e11 against 3.75e11 at 32768; yoshida4 1.50e11 against 1.20e11 at 32768; kahan8 (15
#: stages) is slower that way at every batch (1.98e10 against 2.46e10 at 32768), so it keeps one site per thread.
_SITES_MIN_BATCH = 2048
_SITES_MAX_STAGES = 4


def sites_per_thread(batch: int, n_sites: int, stages: int, device: str) -> int:
    """Sites each thread of a block splitting launch owns: ceil(N / 32) (at most ``MAX_SITES_PER_THREAD``, so
    that a lattice of up to 256 sites is one warp) on a GPU from ``_SITES_MIN_BATCH`` lattices for methods
    of at most ``_SITES_MAX_STAGES`` stages, else 1."""
    from .block_kernels import MAX_SITES_PER_THREAD, WARP_LANES

    if _SITES_FORCED is not None:
        return _SITES_FORCED
    if device == "cpu" or batch < _SITES_MIN_BATCH or stages > _SITES_MAX_STAGES:
        return 1
    return max(1, min(MAX_SITES_PER_THREAD, -(-int(n_sites) // WARP_LANES)))


def site_group_launch(sites: int, stages: int, device: str) -> bool:
    """Whether a block splitting launch with this many sites per thread runs ``site_group_kernels``: always
    for several sites, and on a GPU for one site per thread and few stages too (its walls compiled in, one
    float64 per thread in the tile: one lattice 118.6 ns per Verlet step, 3.08e11 site-steps/s at 805 lattices,
    H200, ``benchmarks/h200-2026-11-22k``; in ``h200-2026-11-22e`` it was 170 ns against ``block_kernels``'
    202 ns); the many-stage methods keep ``block_kernels``' register-capped kernel. ``_GROUP_ONE_SITE``
    (tests, benchmarks) forces it."""
    if sites > 1:
        return True
    if _GROUP_ONE_SITE is not None:
        return _GROUP_ONE_SITE
    return device != "cpu" and stages <= _SITES_MAX_STAGES


#: the block splitting kernel holds a step's contact stiffnesses in registers and stores them after the step
#: (True) instead of at every force evaluation: each block barrier waits for the stores issued before it.
#: H200, the paper breather's base run (one lattice, kahan8, 480 force evaluations; ncu, clocks locked): 108 us
#: storing at every evaluation, 90.6 us per step, 75 us without a history (``benchmarks/h200-2026-11-22j``)
_RECORD_PER_STEP = True
#: a recording launch of at most this many lattices (a tangent base run) drops the many-stage kernels'
#: register cap (under it the held stiffnesses would spill): one block per SM of an H200 needs no occupancy
_RECORD_UNCAPPED_MAX_BATCH = 132
#: None: ``site_group_launch`` decides; True/False force the one-site launch's kernel (tests, benchmarks)
_GROUP_ONE_SITE: bool | None = None
#: ``__launch_bounds__`` minimum blocks per SM of the site-group kernels, by sites per thread (absent: none)
_GROUP_MIN_BLOCKS: dict = {}
#: keyword options of ``block_kernels.site_group_kernels`` (``scalar_ends``, ``carry``): its defaults unless
#: tests or benchmarks set them
_GROUP_OPTIONS: dict = {}


#: tangent columns per block of the block splitting tangent kernel: None lets ``tangent_columns_per_block``
#: choose; 1 or 2 forces it (tests, benchmarks)
_TANGENT_COLUMNS: int | None = None
#: from this many columns a GPU tangent launch carries two columns per block. H200, the paper breather's
#: 804-column monodromy (kahan8, 32 steps; ``benchmarks/tangent_variants.py``, ``benchmarks/h200-2026-11-22i``):
#: 0.348 ms with one column per block as before, 0.305 ms with its history loaded one evaluation ahead, 0.303 ms
#: with two columns per block (0.322 ms with both); 402 columns: 0.23-0.24 ms every way
_TANGENT_PAIR_MIN_COLUMNS = 256
#: ``__launch_bounds__`` minimum blocks per SM of the two-column tangent kernel, by "many stages" (more than
#: ``_SITES_MAX_STAGES``): the 804 columns of a monodromy are 402 blocks, one wave of the H200's 132 SMs at 4
_TANGENT_PAIR_MIN_BLOCKS = {True: 4, False: 0}
#: the tangent kernel loads each history entry one force evaluation ahead: None does so with one column per
#: block (where it paid) and not with two (the extra registers cost more than it saved); True/False force it
_TANGENT_PREFETCH: bool | None = None


def tangent_columns_per_block(ncols: int, stages: int, device: str) -> int:
    """Tangent columns each block of a block splitting tangent launch carries: 2 on a GPU from
    ``_TANGENT_PAIR_MIN_COLUMNS`` columns (each thread then runs two independent chains: more work in flight
    per barrier and per history load, and half the blocks), else 1."""
    if _TANGENT_COLUMNS is not None:
        return _TANGENT_COLUMNS
    return 2 if device != "cpu" and ncols >= _TANGENT_PAIR_MIN_COLUMNS else 1


_RUNNER_POOL: dict = {}
_RUNNER_POOL_SIZE = 4


def _slice_bounds(batch: int) -> list[tuple[int, int]]:
    """Lattice slices (lo, hi) of a sliced ``simulate`` run: ``_SLICES`` (else one per ``_SLICE_LATTICES``
    lattices, 2 to ``_MAX_SLICES``) equal slices. Slices that grow from a small first one, so that the first
    kernel starts sooner, were slower on the H200 (13.7 against 12.0 ms at 8192 lattices): the uploads' host
    copies, not the kernels, bound the first chunk there (``benchmarks/h200-2026-11-22n``)."""
    return _even_slices(batch, _SLICES if _SLICES is not None else max(2, min(_MAX_SLICES, batch // _SLICE_LATTICES)))


def _pooled_runner(
    method: Method, params: ChainParams, x0, M, K, device: str, layout: str, upload: bool = True
) -> "_Runner":
    """A runner for this (method, chain, batch, device, layout): on a GPU one kept from an earlier call
    (its device buffers reused, the new batch and parameters uploaded), else a new one. A runner in use
    is out of the pool, so concurrent calls never share one."""
    if device == "cpu":
        return _Runner(method, params, x0, M, K, device, layout=layout, upload=upload)
    key = (method, params.N, params.boundary, x0.shape[0], device, resolve_layout(layout, device, params.N))
    with _STAGING_LOCK:
        free = _RUNNER_POOL.get(key)
        runner = free.pop() if free else None
    if runner is None:
        runner = _Runner(method, params, x0, M, K, device, layout=layout, upload=upload)
    else:
        runner.load(x0, M, K, upload=upload)
    runner._pool_key = key
    return runner


def _release_runner(runner: "_Runner") -> None:
    key = getattr(runner, "_pool_key", None)
    if key is None:
        return
    with _STAGING_LOCK:
        _RUNNER_POOL.setdefault(key, []).append(runner)
        while sum(len(v) for v in _RUNNER_POOL.values()) > _RUNNER_POOL_SIZE:
            oldest = next(k for k, v in _RUNNER_POOL.items() if v)
            _RUNNER_POOL[oldest].pop(0)
            if not _RUNNER_POOL[oldest]:
                del _RUNNER_POOL[oldest]


def _prefault(shape) -> "threading.Thread":
    """Start filling a new host array of this shape on background threads (the page faults of fresh
    memory, ~3 GB/s on one thread, happen while the GPU computes); ``.result`` holds it after join()."""

    def work():
        out = np.empty(shape)
        _fill_zero(out)
        holder.result = out

    holder = threading.Thread(target=work, daemon=True)
    holder.result = None
    holder.start()
    return holder


def _check_frames_out(frames_out, save_every, nsteps: int, batch: int, n_sites: int, x0: np.ndarray | None):
    """``simulate``'s ``frames_out``, checked once at the boundary: (u, v) host arrays of the frames' shape
    (``x0``: the host x0 they must not overlap; None for a ``DeviceState``)."""
    if save_every is None:
        raise ValueError("frames_out receives recorded frames: give save_every too")
    if not isinstance(frames_out, (tuple, list)) or len(frames_out) != 2:
        raise ValueError("frames_out must be a pair (u, v) of arrays")
    shape = (1 + nsteps // save_every, batch, n_sites)
    for name, arr in zip("uv", frames_out):
        if not isinstance(arr, np.ndarray) or arr.dtype != np.float64 or arr.shape != shape:
            got = f"{type(arr).__name__} {getattr(arr, 'dtype', '')} {getattr(arr, 'shape', '')}"
            raise ValueError(f"frames_out {name} must be a float64 numpy array of shape {shape}, got {got}")
        if not (arr.flags.c_contiguous and arr.flags.writeable):
            raise ValueError(f"frames_out {name} must be C-contiguous and writeable")
    if np.shares_memory(frames_out[0], frames_out[1]):
        raise ValueError("frames_out u and v must not share memory")
    if x0 is not None and any(np.may_share_memory(arr, x0) for arr in frames_out):
        raise ValueError("frames_out must not share memory with x0 (the device may still be reading x0)")
    return tuple(frames_out)


def _relative_energy_error(E, E0, N):
    return np.abs(_signed_energy_change(E, E0, N))


def _signed_energy_change(E, E0, N):
    scale = np.maximum(np.abs(E0), 1e-14 * N)
    return (E - E0) / scale


#: a chunk holds at least this many site force evaluations of the whole batch (``simulate``'s chunk count
#: comes from the work: launch, guard and transfer overheads stay small against the kernel)
_CHUNK_WORK = 1 << 28
#: bytes of recorded u (and as many of v) per chunk: the size of each host staging buffer
_STAGING_BYTES = 128 << 20
_STAGING_POOL: dict = {}
_STAGING_LOCK = threading.Lock()
_COPY_POOL = None


def _frames_per_chunk(batch: int, n_sites: int) -> int:
    return max(1, _STAGING_BYTES // (8 * batch * n_sites))


def _take_buffer(wp, device: str, elements: int, pinned: bool):
    """A flat float64 host buffer of at least ``elements``, pinned for a GPU (page-locking costs ~0.4 s
    per GiB, so buffers are kept in a small pool and reused across calls)."""
    with _STAGING_LOCK:
        free = _STAGING_POOL.setdefault((device, pinned), [])
        fits = [i for i, buf in enumerate(free) if buf.shape[0] >= elements]
        if fits:
            return free.pop(min(fits, key=lambda i: free[i].shape[0]))
    return wp.empty(max(int(elements), 1), dtype=wp.float64, device="cpu", pinned=pinned)


def _give_buffer(device: str, pinned: bool, buf) -> None:
    with _STAGING_LOCK:
        free = _STAGING_POOL.setdefault((device, pinned), [])
        free.append(buf)
        if len(free) > 12:  # keep the largest few
            free.sort(key=lambda b: b.shape[0])
            del free[0]


def _copy(dst: np.ndarray, src: np.ndarray) -> None:
    """dst[...] = src for large contiguous arrays, in pieces on a few threads (numpy releases the GIL;
    one thread moves ~10 GB/s, and into memory it touches first ~3 GB/s (page faults); eight threads
    17-35 GB/s on the H200 host)."""
    global _COPY_POOL
    d, s_ = dst.reshape(-1), src.reshape(-1)
    workers = _workers(d.size)
    if workers == 1:
        np.copyto(d, s_)
        return
    _copy_pool(workers)
    jobs = [_COPY_POOL.submit(np.copyto, d[a:b], s_[a:b]) for a, b in _even_slices(d.size, workers)]
    for job in jobs:
        job.result()


def _workers(values: int) -> int:
    """Threads for a host copy of this many float64 values: one per _COPY_SLICE values (handing a piece to
    a pool thread costs tens of us), at most _MAX_COPY_THREADS and the usable cores."""
    return max(1, min(_MAX_COPY_THREADS, usable_cores(), int(values) // _COPY_SLICE))


#: values per host copy thread (``_workers``): 2 MB. With 8 MB, a 13 MB slice of the state went on one thread
#: at ~5 GB/s (H200 host, benchmarks/h200-2026-11-22h/slices-before-copy-fix.txt)
_COPY_SLICE = 1 << 18
_MAX_COPY_THREADS = 16


def _fill_zero(arr: np.ndarray) -> None:
    """arr[...] = 0 in pieces on the copy threads (touches fresh memory in parallel)."""
    flat = arr.reshape(-1)
    workers = _workers(flat.size)
    if workers == 1:
        flat.fill(0.0)
        return
    _copy_pool(workers)
    jobs = [_COPY_POOL.submit(flat[a:b].fill, 0.0) for a, b in _even_slices(flat.size, workers)]
    for job in jobs:
        job.result()


def _copy_pool(workers: int):
    """The host copy threads: made once with as many threads as any copy may use (not as the first copy asks:
    a pool sized by a small first copy would serialise every later large one)."""
    global _COPY_POOL
    with _STAGING_LOCK:
        if _COPY_POOL is None:
            from concurrent.futures import ThreadPoolExecutor

            size = max(workers, min(_MAX_COPY_THREADS, usable_cores()))
            _COPY_POOL = ThreadPoolExecutor(max_workers=size, thread_name_prefix="warpchain-copy")
    return _COPY_POOL


class _GuardReader:
    """The guard's per-lattice scalars on their way to the host: two slots (chunk i uses slot i % 2),
    pinned host buffers and an event per slot on a GPU, so the host can read chunk i while the device
    runs chunk i + 1. ``simulate`` keeps one per runner (``of``): its buffers and events are made once (on
    the H200 host making them cost ~0.08 ms per call), and a runner serves one call at a time."""

    @classmethod
    def of(cls, runner, gpu: bool) -> "_GuardReader":
        """The reader kept with ``runner`` (made on first use; its ``close`` keeps the buffers)."""
        return held(runner, ("guard reader", gpu), lambda: cls(runner, gpu, kept=True))

    def __init__(self, runner, gpu: bool, kept: bool = False):
        wp = runner.wp
        self.wp, self.gpu, self.runner, self.kept = wp, gpu, runner, kept
        if gpu:
            self.flat = [_take_buffer(wp, runner.device, 3 * runner.batch, True) for _ in range(2)]
            self.host = [buf[: 3 * runner.batch].reshape((runner.batch, 3)) for buf in self.flat]
            self.events = [wp.Event(runner.device) for _ in range(2)]
        else:
            self.host = [None, None]

    def enqueue_init(self, out) -> None:
        """Copy slot 2 (the start's scalars) to the host; read it with ``init`` once a later event
        recorded after it has completed."""
        if self.gpu:
            if not hasattr(self, "init_flat"):
                self.init_flat = _take_buffer(self.wp, self.runner.device, 3 * self.runner.batch, True)
                self.flat.append(self.init_flat)
            self.init_host = self.init_flat[: 3 * self.runner.batch].reshape((self.runner.batch, 3))
            self.wp.copy(self.init_host, out)
        else:
            self.init_host = out

    def init(self):
        g = self.init_host.numpy()
        return g[:, 0].copy(), g[:, 1] > 0.5, g[:, 2].copy()

    def close(self) -> None:
        if self.kept:
            return  # the buffers stay with the runner, for its next call
        if self.gpu and self.flat:
            for buf in self.flat:
                _give_buffer(self.runner.device, True, buf)
            self.flat = []

    def enqueue(self, out, i: int) -> None:
        if self.gpu:
            self.wp.copy(self.host[i % 2], out)
        else:
            self.host[i % 2] = out

    def record(self, i: int) -> None:
        if self.gpu:
            self.wp.record_event(self.events[i % 2])

    def wait(self, i: int):
        """(energy, finite, min contact) of chunk i, each (batch,), once the device has finished it."""
        if self.gpu:
            self.wp.synchronize_event(self.events[i % 2])
        g = self.host[i % 2].numpy()
        return g[:, 0], g[:, 1] > 0.5, g[:, 2]

    def read(self, out, i: int):
        self.enqueue(out, i)
        self.record(i)
        return self.wait(i)


class _SlicedTransfers:
    """The state's trip to the device and back in lattice slices, overlapped with kernels: slice s is
    copied (host -> pinned -> device, on an upload stream) while the kernels run on slice s - 1, and its
    final state goes back (on a download stream) while they run on slice s + 1, so only one slice's
    transfer each way is exposed (on a GPU; on the CPU the same steps run in order). ``simulate`` runs the
    first and the last chunk slice by slice for it; a short run on a large batch has only those two."""

    def __init__(self, runner, x0: np.ndarray, slices: list, out: np.ndarray | None = None):
        """``slices``: (lo, hi) lattice ranges covering the batch (``_slice_bounds``). ``out``: the final
        state's host array when it is page-locked (a lent result): the slices are copied into it by the device,
        and ``take`` only waits for them. A page-locked ``x0`` is likewise copied to the device straight from
        where it is."""
        wp = runner.wp
        self.wp, self.r, self.x0 = wp, runner, x0
        self.gpu = runner.device != "cpu"
        self.slices = list(slices)
        self.site_values = 4 * runner.N
        self.direct_up = _pinned_view(x0)
        self.direct_down = _pinned_view(out) if out is not None else None
        self.out = out if self.direct_down is not None else None
        self.up = None if self.direct_up else _take_buffer(wp, runner.device, x0.size, self.gpu)
        self.down = None if self.direct_down else _take_buffer(wp, runner.device, x0.size, self.gpu)
        self.closed = False
        self.events = {}
        if self.gpu:
            # uploads and downloads on streams of their own: slice s + 1's upload never waits behind slice s's
            # download, which waits for slice s's kernels
            make = lambda: (wp.Stream(runner.device), wp.Stream(runner.device))  # noqa: E731
            self.up_stream, self.down_stream = held(runner, "transfer streams", make)  # kept with the runner
            self.main = wp.get_stream(runner.device)

    def _range(self, s: int):
        lo, hi = self.slices[s]
        return lo * self.site_values, hi * self.site_values

    def upload(self, s: int) -> None:
        """Slice s to the device; the compute stream waits for it."""
        a, b = self._range(s)
        lo, hi = self.slices[s]
        if self.direct_up is not None:
            src, base = self.direct_up
        else:
            src, base = self.up, 0
            _copy(self.up.numpy()[a:b], np.ascontiguousarray(self.x0[lo:hi]))
        if self.gpu:
            self.wp.copy(self.r.x, src, dest_offset=a, src_offset=base + a, count=b - a, stream=self.up_stream)
            self.main.wait_event(self.up_stream.record_event())
        else:
            self.wp.copy(self.r.x, src, dest_offset=a, src_offset=base + a, count=b - a)

    def download(self, s: int) -> None:
        """Slice s's state back to pinned memory once the kernels queued so far have run."""
        a, b = self._range(s)
        dst, base = self.direct_down if self.direct_down is not None else (self.down, 0)
        if self.gpu:
            self.down_stream.wait_event(self.main.record_event())
            self.wp.copy(dst, self.r.x, dest_offset=base + a, src_offset=a, count=b - a, stream=self.down_stream)
            self.events[s] = self.down_stream.record_event()
        else:
            self.wp.copy(dst, self.r.x, dest_offset=base + a, src_offset=a, count=b - a)

    def take(self, s: int, out: np.ndarray) -> None:
        """Write slice s's final state into ``out`` (the whole batch's host array; when it is the page-locked
        ``out`` given at construction, the device has written it already: only wait for that copy)."""
        a, b = self._range(s)
        if self.gpu:
            self.wp.synchronize_event(self.events[s])
        if out is self.out:
            return
        _copy(out.reshape(-1)[a:b], self.down.numpy()[a:b])

    def close(self) -> None:
        if self.closed:
            return
        if self.gpu:
            self.wp.synchronize_stream(self.up_stream)
            self.wp.synchronize_stream(self.down_stream)
        for buf in (self.up, self.down):
            if buf is not None:
                _give_buffer(self.r.device, self.gpu, buf)
        self.up = self.down = None
        self.closed = True


def frame_buffers(
    params: ChainParams, batch: int, t_final: float, dt: float, save_every: int, *, device: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Host arrays (u, v) for ``simulate(..., frames_out=...)``, each (n_saved, batch, N) float64 with
    n_saved = 1 + nsteps // save_every, as ``simulate`` records with the same ``t_final``, ``dt`` and
    ``save_every``.

    On a GPU they are page-locked (pinned): ``simulate`` then copies each chunk's frames from the device
    straight into them, at the bus's rate, instead of through staging buffers and host copies (which
    bound recording at ~10 GB/s on the H200 host). Page-locking costs ~0.4 s per GiB, so allocate them
    once per study and pass them to every run; on the CPU they are plain numpy arrays.

    Raises:
        ValueError: bad sizes, or ``save_every`` longer than the run.
    """
    batch = whole_number("batch", batch, minimum=1)
    save_every = whole_number("save_every", save_every, minimum=1)
    nsteps, _ = steps_for(real_number("t_final", t_final, nonnegative=True), real_number("dt", dt, positive=True))
    shape = (1 + nsteps // save_every, batch, params.N)
    device = resolve_device(device)
    if device == "cpu":
        return np.zeros(shape), np.zeros(shape)
    wp = _warp()
    size = int(np.prod(shape))
    # each a view of its own pinned Warp array (the view's base), which _pinned_view finds again
    return tuple(wp.zeros(size, dtype=wp.float64, device="cpu", pinned=True).numpy().reshape(shape) for _ in range(2))


def page_locked(x, *, device: str | None = None) -> np.ndarray:
    """A copy of the float64 array ``x`` in page-locked host memory, for ``simulate(x0=...)`` on a GPU: the
    device copies it straight from there, with no staging pass on the host (a result's ``x`` is lent such
    memory already, so a run continued from it needs no call here). On the CPU a plain copy.

    The memory comes from ``leases``' pool and goes back to it when the array is dropped; when the pool is full
    (``leases.limit_bytes``) the copy is a plain array.

    Raises:
        ValueError: not a real array.
    """
    arr = np.asarray(x)
    if not np.issubdtype(arr.dtype, np.floating) and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"page_locked needs a real array, got dtype {arr.dtype}")
    device = resolve_device(device)
    lent = leases.lend(_warp(), device, arr.shape, first=True) if device != "cpu" else None
    out = lent[0] if lent else np.empty(arr.shape)
    np.copyto(out, arr, casting="unsafe")
    return out


def _pinned_view(arr: np.ndarray):
    """(pinned Warp array, offset in values) when ``arr`` views page-locked Warp host memory (as the arrays
    of ``frame_buffers`` and the results ``simulate`` lends do), else None. Only a C-contiguous float64 view
    qualifies: the copies read and write it as one run of values from the offset."""
    if arr.dtype != np.float64 or not arr.flags.c_contiguous:
        return None
    lent = leases.pinned_buffer(arr)
    if lent is not None:
        return lent
    wp = _warp()
    base = arr
    while base is not None and not isinstance(base, wp.array):
        base = getattr(base, "base", None)
    if base is None or not getattr(base, "pinned", False) or base.dtype != wp.float64 or not base.is_contiguous:
        return None
    offset = arr.ctypes.data - base.ptr
    if offset < 0 or offset % 8 or offset // 8 + arr.size > base.size:
        return None
    flat = base if base.ndim == 1 else base.flatten()
    return flat, offset // 8


class _FrameSink:
    """Recorded frames on their way to the result arrays ``u`` and ``v`` (n_saved, batch, N): the kernel
    writes a chunk's frames into device buffers, which are copied (asynchronously, on a GPU into pinned
    host staging buffers, two slots) and then, by a few host threads, into the preallocated results.
    When the results are page-locked (``frame_buffers``) the device copies straight into them."""

    def __init__(self, runner, n_saved: int, max_frames: int, gpu: bool, out=None):
        wp = runner.wp
        self.wp, self.runner, self.gpu = wp, runner, gpu
        self.batch, self.N = runner.batch, runner.N
        if out is None:
            self.u = np.empty((n_saved, self.batch, self.N))
            self.v = np.empty((n_saved, self.batch, self.N))
        else:  # the caller's arrays (``simulate(frames_out=...)``), checked at the boundary
            self.u, self.v = out
        self.frame = self.batch * self.N
        cached = getattr(runner, "_sink_frames", None)
        if cached is None or cached[0] < max(max_frames, 1):
            cached = (max(max_frames, 1), runner.frames(max(max_frames, 1)))
            runner._sink_frames = cached  # kept with the runner (reused by the next call)
        self.rec = cached[1]
        self.device = runner.device
        direct = [_pinned_view(a) for a in (self.u, self.v)] if out is not None else [None]
        self.direct = direct if all(d is not None for d in direct) else None
        self.staging = []
        if self.direct is None:
            self.staging = [_take_buffer(wp, self.device, max(max_frames, 1) * self.frame, gpu) for _ in range(4)]

    def put_initial(self, x0: np.ndarray) -> None:
        self.u[0] = x0[:, 0]
        self.v[0] = x0[:, 1]

    def enqueue(self, n_rec: int, i: int, first: int) -> None:
        """Copy chunk i's ``n_rec`` frames (frames ``first`` on of the result) off the device."""
        count = n_rec * self.frame
        if self.direct is not None:
            for (dst, offset), rec in zip(self.direct, self.rec):
                self.wp.copy(dst, rec, dest_offset=offset + first * self.frame, count=count)
            return
        for buf, rec in zip(self.staging[2 * (i % 2) : 2 * (i % 2) + 2], self.rec):
            self.wp.copy(buf, rec, count=count)

    def take(self, i: int, first: int, n_rec: int) -> None:
        """Write chunk i's frames into the results (once its copies have completed)."""
        if self.direct is not None:
            return  # already there
        count = n_rec * self.frame
        shape = (n_rec, self.batch, self.N)
        for dst, buf in zip((self.u, self.v), self.staging[2 * (i % 2) : 2 * (i % 2) + 2]):
            _copy(dst[first : first + n_rec], buf.numpy()[:count].reshape(shape))

    def view(self, a: int, b: int):
        """Read-only views of frames a..b-1 of u and v (what ``on_chunk`` receives: no copy)."""
        out = []
        for arr in (self.u, self.v):
            view = arr[a:b]
            view.flags.writeable = False
            out.append(view)
        return out

    def close(self) -> None:
        for buf in self.staging:
            _give_buffer(self.device, self.gpu, buf)
        self.staging = []


class _Plan:
    """What one (kernel layout, method type) launches: the kernels and, built beside each launch, their
    arguments. ``_PLANS`` maps (layout, method type) to the plan; the runner holds the buffers."""

    def __init__(self, runner: "_Runner"):
        self.r = runner

    def step(self, lo: int, hi: int, dt: float, nsteps: int, save_every: int, frames, record: bool) -> None:
        raise NotImplementedError

    def tangent(self, dx, column_base, lo: int, hi: int, dt: float, nsteps: int) -> None:
        raise NotImplementedError

    def kept(self, name: str, shape: tuple):
        """A device array of ``shape`` kept under (``name``, ``shape``): launches allocate nothing, so that
        they can be captured in a graph (``_Replay``) and replayed."""
        wp, device = self.r.wp, self.r.device
        return held(self, (name, tuple(shape)), lambda: wp.zeros(shape, dtype=wp.float64, device=device))


class _BlockSplitting(_Plan):
    """A thread block per lattice, a splitting method compiled for its stage count."""

    def __init__(self, runner):
        super().__init__(runner)
        from . import block_kernels

        self.pack = block_kernels.pack_coefficients
        self.scaled = {}

    def coefficients(self, dt: float) -> list:
        """Drift and kick coefficients times dt (the kernels multiply by them as they are)."""
        if dt not in self.scaled:
            m = self.r.method
            self.scaled = {dt: [self.pack(m.drifts, dt), self.pack(m.kicks, dt)]}
        return self.scaled[dt]

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        inputs = [*_parts(lo, hi, r.x, r.inv_mass, r.coupling), *self.coefficients(dt), r.boundary]
        inputs += [r.wp.float64(dt)]
        inputs += [int(nsteps), int(save_every), *frames, int(record), r.hist, *r.losses(lo, hi)]
        from . import block_kernels

        stages = r.method.stages
        damped = r.damped
        pairs = _PAIR_MIN_BATCH is not None and hi - lo >= _PAIR_MIN_BATCH
        pairs = pairs and block_kernels.min_blocks_per_sm(stages) == 0
        if pairs and (r.device != "cpu" or _PAIR_ON_CPU) and 2 * r.block <= block_kernels.MAX_BLOCK:
            # two lattices per block on a large batch (as the best hand-written kernel: hand-cuda-variants.txt)
            kernel = block_kernels.block_kernels(r.block, 0, 2).splitting(
                stages, record=record, save=save_every > 0, damped=damped
            )
            dim = (-(-(hi - lo) // 2), 2 * r.block)
            r.launch_kernel(kernel, dim, inputs, 2 * r.block)
            return
        sites = sites_per_thread(hi - lo, r.N, stages, r.device)
        if site_group_launch(sites, stages, r.device):
            threads = block_kernels.group_threads(r.N, sites)
            minb = _GROUP_MIN_BLOCKS.get(sites, 0)
            group = block_kernels.site_group_kernels(threads, sites, r.boundary, minb, **_GROUP_OPTIONS)
            kernel = group.splitting(stages, record=record, save=save_every > 0, damped=damped)
            r.launch_kernel(kernel, (hi - lo, threads), inputs, threads)
            return
        kernels = r.bk
        if record and hi - lo <= _RECORD_UNCAPPED_MAX_BATCH and _RECORD_PER_STEP:
            kernels = block_kernels.block_kernels(r.block, 0)  # the step's history in registers: no cap
        kernel = kernels.splitting(stages, record=record, save=save_every > 0, damped=damped, per_step=_RECORD_PER_STEP)
        r.launch_kernel(kernel, (hi - lo, r.block), inputs, r.block)

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        r = self.r
        from . import block_kernels

        inputs = [*_parts(lo, hi, dx, column_base), r.inv_mass, r.coupling, *self.coefficients(dt), r.boundary]
        inputs += [r.wp.float64(dt), int(nsteps), r.hist]
        stages = r.method.stages
        columns = tangent_columns_per_block(hi - lo, stages, r.device)
        kernels = r.bk
        if columns > 1:
            cap = _TANGENT_PAIR_MIN_BLOCKS[stages > _SITES_MAX_STAGES]
            kernels = block_kernels.block_kernels(r.block, cap)
        prefetch = columns == 1 if _TANGENT_PREFETCH is None else _TANGENT_PREFETCH
        kernel = kernels.splitting_tangent(stages, columns, prefetch)
        dim = (-(-(hi - lo) // columns), r.block)
        r.wp.launch(kernel, dim=dim, block_dim=r.block, device=r.device, inputs=inputs)


class _BlockRungeKutta(_Plan):
    """A thread block per lattice, a four-stage Runge-Kutta method (its tableau as arguments)."""

    def __init__(self, runner):
        super().__init__(runner)
        m, wp = runner.method, runner.wp
        self.tableau = [wp.vec4d(*m.nodes, m.divisor), wp.vec4d(*m.weights)]

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        inputs = [*_parts(lo, hi, r.x, r.inv_mass, r.coupling), *self.tableau, r.boundary, r.wp.float64(dt)]
        inputs += [int(nsteps), int(save_every), *frames, int(record), r.hist]
        r.launch_kernel(r.bk.rk4, (hi - lo, r.block), inputs, r.block)

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        r = self.r
        inputs = [*_parts(lo, hi, dx, column_base), r.inv_mass, r.coupling, *self.tableau, r.boundary]
        inputs += [r.wp.float64(dt), int(nsteps), r.hist]
        r.wp.launch(r.bk.rk4_tangent, dim=(hi - lo, r.block), block_dim=r.block, device=r.device, inputs=inputs)


class _ThreadSplitting(_Plan):
    """A thread per lattice (the CPU path), a splitting method; accelerations in a scratch array."""

    def __init__(self, runner):
        super().__init__(runner)
        wp, m, f64 = runner.wp, runner.method, runner.wp.float64
        self.acc = wp.zeros((runner.batch, 2, runner.N), dtype=f64, device=runner.device)
        self.drifts = wp.array(np.array(m.drifts), dtype=f64, device=runner.device)
        self.kicks = wp.array(np.array(m.kicks), dtype=f64, device=runner.device)

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        inputs = [*_parts(lo, hi, r.x, self.acc, r.inv_mass, r.coupling), self.drifts, self.kicks]
        inputs += [r.boundary, r.wp.float64(dt), int(nsteps), int(save_every), *frames, int(record), r.hist]
        inputs += r.losses(lo, hi)
        r.launch_kernel(r.k.splitting_kernel, hi - lo, inputs)

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        r, wp = self.r, self.r.wp
        dacc = self.kept("dacc", (dx.shape[0], 2, r.N))  # written before it is read
        inputs = [*_parts(lo, hi, dx, dacc, column_base), r.inv_mass, r.coupling, self.drifts, self.kicks]
        inputs += [r.boundary, wp.float64(dt), int(nsteps), r.hist]
        wp.launch(r.k.splitting_tangent_kernel, dim=hi - lo, device=r.device, inputs=inputs)


class _ThreadRungeKutta(_Plan):
    """A thread per lattice (the CPU path), a four-stage Runge-Kutta method; stage states in scratch arrays."""

    def __init__(self, runner):
        super().__init__(runner)
        wp, m = runner.wp, runner.method
        shape = (runner.batch, 4, runner.N)
        self.scratch = [wp.zeros(shape, dtype=wp.float64, device=runner.device) for _ in range(3)]
        self.tableau = [wp.vec4d(*m.nodes, m.divisor), wp.vec4d(*m.weights)]

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        inputs = _parts(lo, hi, r.x, *self.scratch, r.inv_mass, r.coupling)
        inputs += [*self.tableau, r.boundary, r.wp.float64(dt), int(nsteps), int(save_every), *frames]
        inputs += [int(record), r.hist]
        r.launch_kernel(r.k.rk4_kernel, hi - lo, inputs)

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        r, wp = self.r, self.r.wp
        scratch = [self.kept(f"stage{i}", (dx.shape[0], 4, r.N)) for i in range(3)]
        inputs = [*_parts(lo, hi, dx, *scratch, column_base), r.inv_mass, r.coupling, *self.tableau, r.boundary]
        inputs += [wp.float64(dt), int(nsteps), r.hist]
        wp.launch(r.k.rk4_tangent_kernel, dim=hi - lo, device=r.device, inputs=inputs)


_PLANS = {
    ("block", SplittingMethod): _BlockSplitting,
    ("block", RungeKuttaMethod): _BlockRungeKutta,
    ("thread", SplittingMethod): _ThreadSplitting,
    ("thread", RungeKuttaMethod): _ThreadRungeKutta,
}


def _plan_for(layout: str, method: Method):
    for (plan_layout, kind), plan in _PLANS.items():
        if plan_layout == layout and isinstance(method, kind):
            return plan
    raise ValueError(f"no launch plan for layout {layout!r} and method type {type(method).__name__}")


#: operations issued again and again with the same arguments (a Flow's base run, a Newton iteration's
#: columns) are captured into a CUDA graph at their ``_GRAPH_AFTER``-th issue and replayed from then on: one
#: launch from Python instead of several (~0.1 ms of host time each), and the device never waits for the host
#: between them. None: always issued one by one (tests and benchmarks compare both).
_GRAPH_AFTER: int | None = 1
#: graphs kept per runner (a frequency continuation changes dt, hence the graphs, at every point)
_GRAPHS_PER_RUNNER = 8
#: tests set it to capture and replay on the CPU too (Warp's CPU graphs), so that CI checks what a graph holds
_GRAPH_ON_CPU = False


def held(owner, key, make: Callable[[], object]):
    """``make()``, kept on ``owner`` under ``key``: made on first request and never replaced, so a graph
    captured with it (``_Replay``) keeps a valid address (a runner's or a plan's buffers)."""
    kept = owner.__dict__.setdefault("_held", {})
    if key not in kept:
        kept[key] = make()
    return kept[key]


class _Replay:
    """A fixed sequence of launches and copies on fixed buffers (``enqueue``), issued eagerly the first
    ``after`` times and then captured once into a CUDA graph that every later call launches. On the CPU
    (or with ``_GRAPH_AFTER`` None) every call issues the operations one by one; the tests also capture
    them on the CPU (``_GRAPH_ON_CPU``, Warp's CPU graphs) and check the replay bit for bit. ``enqueue``
    must not synchronise or allocate (every buffer it uses is kept alive by its closure)."""

    def __init__(self, wp, device: str, enqueue: Callable[[], None], after: int | None = None):
        self.wp, self.device, self.enqueue = wp, device, enqueue
        self.after = _GRAPH_AFTER if after is None else after
        self.issued = 0
        self.graph = None

    def prepare(self) -> bool:
        """Capture the graph now if calls are due to replay one (without running it); True if they are."""
        graphs_here = self.device != "cpu" or _GRAPH_ON_CPU
        if self.graph is None and graphs_here and _GRAPH_AFTER is not None and self.issued >= self.after:
            with self.wp.ScopedCapture(device=self.device) as capture:
                self.enqueue()
            self.graph = capture.graph
        return self.graph is not None

    def __call__(self) -> None:
        """Issue the operations (asynchronous on a GPU)."""
        if self.prepare():
            self.wp.capture_launch(self.graph)
        else:
            self.enqueue()
        self.issued += 1


class _Runner:
    """Device buffers and launches for one batch and one method."""

    def __init__(
        self,
        method: Method,
        params: ChainParams,
        x0: np.ndarray,
        M,
        K,
        device: str,
        record_stiffness_steps: int = 0,
        layout: str = "auto",
        upload: bool = True,
    ):
        wp = _warp()
        from . import block_kernels, kernels

        self.wp, self.k, self.method, self.device = wp, kernels, method, device
        self.batch, _, self.N = x0.shape
        self.layout = resolve_layout(layout, device, self.N)
        if self.layout == "block":
            self.block = block_kernels.block_size(self.N)
            self.bk = block_kernels.block_kernels(self.block, block_kernels.min_blocks_per_sm(method.stages))
            if device == "cpu":
                # run the block's threads as cooperative fibers (Warp's experimental CPU blocks)
                wp.config.enable_cpu_blocks = True
        # CPU fiber blocks crash when launched from several Python threads at once: one launch
        self.serial = self.layout == "block" and device == "cpu"
        self.boundary = BOUNDARY_CODES[params.boundary]
        f64 = wp.float64
        # pinned host staging of the state (made on first use), and the event after the last copy from each
        self._pinned_up_done = self._pinned_down_done = None
        self.x = wp.empty(x0.shape, dtype=f64, device=device)
        if upload:
            self.upload(x0)
        self.mass = wp.array(M, dtype=f64, device=device)
        self.inv_mass = wp.array(inverse_mass(M), dtype=f64, device=device)  # the kernels multiply by 1/M
        self.coupling = wp.array(K, dtype=f64, device=device)
        self._parameters_held = (np.array(M, dtype=np.float64), np.array(K, dtype=np.float64))  # what M, K hold
        self.plan = _plan_for(self.layout, method)(self)
        self.no_record = wp.zeros((1, 1, 1), dtype=f64, device=device)
        if record_stiffness_steps:
            self.hist = wp.zeros(
                (self.history_length(record_stiffness_steps), self.batch, self.N), dtype=f64, device=device
            )
        else:
            self.hist = wp.zeros((1, 1, 1), dtype=f64, device=device)
        # the guard's outputs: running min contact, and (energy, finite, min contact) per lattice
        self.contact = wp.empty(self.batch, dtype=f64, device=device)
        self.guard_out = [wp.empty((self.batch, 3), dtype=f64, device=device) for _ in range(3)]
        self.reset_contact()
        # losses (``losses``): per lattice a flag and the damped kicks' coefficients; none by default
        self.lossy = wp.zeros(self.batch, dtype=wp.int32, device=device)
        self.no_damp = wp.zeros((1, 1, KICK_ENTRIES), dtype=f64, device=device)
        self.damp = self.no_damp
        self.damped = False
        self.lossy_host = np.zeros(self.batch, dtype=bool)

    def set_damping(self, damping: Damping | None, dt: float) -> None:
        """Upload the damped kicks' coefficients of ``damping`` for step ``dt`` (None: no losses)."""
        wp = self.wp
        if damping is None:
            if self.damped:
                self.lossy.zero_()
            self.damped, self.damp = False, self.no_damp
            self.lossy_host = np.zeros(self.batch, dtype=bool)
            return
        coefficients = kick_matrices(self.method.kicks, dt, self.mass.numpy(), damping, self.batch)
        self.lossy_host = ~lossless(coefficients)
        self.lossy.assign(self.lossy_host.astype(np.int32))
        if self.damp.shape != coefficients.shape:
            self.damp = wp.empty(coefficients.shape, dtype=wp.float64, device=self.device)
        self.damp.assign(coefficients)
        self.damped = True

    def losses(self, lo: int, hi: int) -> list:
        """The kernels' loss arguments (flags, coefficients) for lattices lo..hi."""
        return [_part(self.lossy, lo, hi), _part(self.damp, lo, hi) if self.damped else self.no_damp]

    def _pinned(self, name: str):
        """This runner's own pinned host buffer ``name`` of the state's size (``host_buffer``: made once, the
        runner is pooled, so later calls on the same batch shape reuse it), after any copy from it has finished."""
        buf = self.host_buffer(name, self.x.size)
        done = getattr(self, name + "_done")
        if done is not None:
            self.wp.synchronize_event(done)
        return buf

    def upload(self, x0: np.ndarray, wait: bool = True) -> None:
        """Copy a batch state to the device (on a GPU through this runner's pinned buffer: ~55 GB/s instead
        of the ~15 GB/s of pageable memory; straight from ``x0`` when it is page-locked itself, e.g. a
        result ``simulate`` lent). Kernels queued after it see the new state. ``wait=False``: return before
        the device has read a page-locked ``x0``; the caller must not change it until the device is synchronised."""
        wp = self.wp
        if isinstance(x0, DeviceState):  # device to device, on the compute stream: no wait needed
            wp.copy(self.x, x0.array, count=x0.size)
            return
        direct = _pinned_view(x0)
        if direct is not None:
            src, offset = direct
            wp.copy(self.x, src, src_offset=offset, count=x0.size)
            if wait and self.device != "cpu":
                wp.synchronize_stream(wp.get_stream(self.device))
            return
        if self.device == "cpu" or x0.size < (1 << 16):
            self.x.assign(np.ascontiguousarray(x0, dtype=np.float64))
            return
        if _UPLOAD_PAGEABLE:  # the driver's own staged copy from pageable memory (benchmarks compare)
            flat = np.ascontiguousarray(x0, dtype=np.float64).reshape(-1)
            wp.copy(self.x, wp.array(flat, dtype=wp.float64, device="cpu", copy=False), count=x0.size)
            return
        buf = self._pinned("_pinned_up")
        _copy(buf.numpy(), np.ascontiguousarray(x0, dtype=np.float64))
        wp.copy(self.x, buf, count=x0.size)
        self._pinned_up_done = wp.get_stream(self.device).record_event()

    def download(self, out: np.ndarray | None = None) -> np.ndarray:
        """The batch state as a new host array (on a GPU through a pinned buffer, then a few threads
        write the result: fresh host memory is filled ~5x faster that way than by one thread);
        ``out``: a host array of the state's shape to fill instead (e.g. one touched in advance, or a
        page-locked one, which the device copies into directly)."""
        if self.enqueue_download(out):
            self.wp.synchronize_device(self.device)
            return out
        if self.device == "cpu":
            return self.x.numpy()  # on the CPU a view of the device buffer
        if self.x.size < (1 << 16):
            return self.x.numpy()
        buf = self._pinned("_pinned_down")
        self.wp.copy(buf, self.x, count=self.x.size)
        self.wp.synchronize_device(self.device)
        out = np.empty(self.x.shape) if out is None else out
        _copy(out, buf.numpy().reshape(self.x.shape))
        return out

    def enqueue_download(self, out) -> bool:
        """Queue the state's copy into ``out`` behind the work queued so far, without waiting, when the device
        can write ``out`` itself: a ``DeviceState`` or page-locked host memory (True); else False (``download``
        then stages it)."""
        if isinstance(out, DeviceState):
            self.wp.copy(out.array, self.x, count=self.x.size)
            return True
        direct = _pinned_view(out) if out is not None else None
        if direct is None:
            return False
        dst, offset = direct
        self.wp.copy(dst, self.x, dest_offset=offset, count=self.x.size)
        return True

    def load(self, x0: np.ndarray, M, K, upload: bool = True) -> None:
        """Copy a new batch (same shape) and its parameters into the existing device buffers."""
        if upload:
            self.upload(x0)
        M = np.ascontiguousarray(M, dtype=np.float64)
        K = np.ascontiguousarray(K, dtype=np.float64)
        held = self._parameters_held
        if not (np.array_equal(held[0], M) and np.array_equal(held[1], K)):
            self.mass.assign(M)  # three synchronous copies: skipped when a pooled runner has them already
            self.inv_mass.assign(np.ascontiguousarray(inverse_mass(M), dtype=np.float64))
            self.coupling.assign(K)
            self._parameters_held = (M.copy(), K.copy())
        self.reset_contact()

    def reset_contact(self) -> None:
        self.contact.fill_(1.0e300)

    def history_length(self, nsteps: int) -> int:
        return self.method.history_length(nsteps)

    def frames(self, n_rec: int):
        """Device buffers for ``n_rec`` recorded frames: (u, v), each (n_rec, batch, N)."""
        wp = self.wp
        return tuple(wp.empty((n_rec, self.batch, self.N), dtype=wp.float64, device=self.device) for _ in range(2))

    def launch(
        self,
        nsteps: int,
        dt: float,
        save_every: int = 0,
        rec=None,
        record_stiffness: bool = False,
        lattices: tuple | None = None,
    ):
        """Advance every lattice by nsteps; with ``rec`` (device (u, v) frame buffers from ``frames``)
        also record u and v every ``save_every`` steps into them. Asynchronous on a GPU.

        On the CPU the batch is split into one slice per thread (launched concurrently); a run that
        records the contact stiffness (tangent base) runs as one slice, since its history is shared."""
        slices = [(0, self.batch)] if record_stiffness or self.serial else _slices(self.batch, self.device)
        if lattices is not None:  # only these lattices (lo, hi), in one launch
            slices = [lattices]
        save = int(save_every) if rec is not None else 0

        def task(lo, hi):
            if rec is None:
                frames = [self.no_record, self.no_record]
            else:
                frames = [rec[0][:, lo:hi], rec[1][:, lo:hi]] if (lo, hi) != (0, self.batch) else list(rec)
            self.plan.step(lo, hi, dt, nsteps, save, frames, bool(record_stiffness))

        _in_parallel([lambda lo=lo, hi=hi: task(lo, hi) for lo, hi in slices])

    def guard(self, rec=None, n_rec: int = 0, slot: int = 0, lattices: tuple | None = None):
        """Launch the guard on the device: per lattice (energy, 1 if finite else 0, running min contact
        over the chunk ends and the first ``n_rec`` frames of ``rec``). Returns the device array
        (batch, 3) of slot ``slot`` (0 and 1 alternate between chunks, 2 holds the start); only it, not
        the state, needs to reach the host. ``lattices``: (lo, hi) to guard only those."""
        lo, hi = lattices if lattices is not None else (0, self.batch)
        ru, rv = (rec[0][:, lo:hi], rec[1][:, lo:hi]) if rec is not None and n_rec else (self.no_record,) * 2
        out = self.guard_out[slot if slot == 2 else slot % 2]
        inputs = [*_parts(lo, hi, self.x, self.mass, self.coupling), self.boundary, ru, rv, int(n_rec)]
        inputs += _parts(lo, hi, self.contact, out)
        if self.layout == "block":
            dim = (hi - lo, self.block)
            self.launch_kernel(self.bk.guard, dim, inputs, self.block)
        else:
            self.launch_kernel(self.k.guard_kernel, hi - lo, inputs)
        return out

    def launch_kernel(self, kernel, dim, inputs: list, block_dim: int | None = None) -> None:
        """``wp.launch`` of ``kernel`` on this runner's device, on a GPU through a launch command kept under
        (kernel, dim, block_dim, the arguments' values: each array's pointer, shape and strides): a launch
        repeated with the same arguments (every call of an ensemble study on a pooled runner, every slice of a
        sliced call) skips Warp's argument packing: 0.1-0.35 ms per launch on the H200 host before, 0.05-0.11 ms
        after (``benchmarks/h200-2026-11-22l/timeline-*.txt``). At most ``_COMMANDS_PER_RUNNER`` are kept,
        the oldest dropped. On the CPU (``_COMMANDS_ON_CPU`` unset) a plain launch."""
        wp = self.wp
        key = _launch_key(wp, kernel, dim, block_dim, inputs) if self.device != "cpu" or _COMMANDS_ON_CPU else None
        if key is None:
            wp.launch(kernel, dim=dim, block_dim=block_dim, device=self.device, inputs=inputs)
            return
        commands = self.__dict__.setdefault("_commands", {})
        command = commands.pop(key, None)  # re-inserted below: the dict keeps the most recent last
        if command is None:
            command = wp.launch(
                kernel, dim=dim, block_dim=block_dim, device=self.device, inputs=inputs, record_cmd=True
            )
            while len(commands) >= _COMMANDS_PER_RUNNER:
                del commands[next(iter(commands))]
        commands[key] = command
        command.launch()

    def launch_tangent(self, dx, column_base, nsteps: int, dt: float):
        """Propagate tangent columns (device array (ncols, 4, N)) along the recorded history; on the
        CPU the columns are split into one slice per thread."""
        ncols = dx.shape[0]
        slices = [(0, ncols)] if self.serial else _slices(ncols, self.device)
        _in_parallel([lambda lo=lo, hi=hi: self.plan.tangent(dx, column_base, lo, hi, dt, nsteps) for lo, hi in slices])

    def replay(self, key, enqueue: Callable[[], None]) -> _Replay:
        """This runner's ``_Replay`` of ``enqueue`` under ``key`` (which must name every argument the
        operations take that is not one of this runner's buffers, e.g. the step count and dt): made on first
        request, kept for later ones (at most ``_GRAPHS_PER_RUNNER``, the oldest dropped)."""
        replays = self.__dict__.setdefault("_replays", {})
        if key not in replays:
            while len(replays) >= _GRAPHS_PER_RUNNER:
                del replays[next(iter(replays))]
            replays[key] = _Replay(self.wp, self.device, enqueue)
        return replays[key]

    def host_buffer(self, name: str, size: int):
        """A host array of ``size`` float64 values kept with the runner under (``name``, ``size``) (page-locked
        on a GPU, so that copies into and out of it can be captured in a graph and run at the bus's rate)."""
        pinned = self.device != "cpu"
        make = lambda: self.wp.empty(size, dtype=self.wp.float64, device="cpu", pinned=pinned)  # noqa: E731
        return held(self, ("host", name, int(size)), make)


#: launch commands a runner keeps (``_Runner.launch_kernel``): a sliced call uses about five per slice
_COMMANDS_PER_RUNNER = 256
_COMMANDS_ON_CPU = False  # tests set it to run the kept commands on the CPU


def _launch_key(wp, kernel, dim, block_dim, inputs) -> tuple | None:
    """What a launch command's parameters are made of: the kernel, the launch shape and each argument's value
    (an array's pointer, shape and strides: two arrays alike in these pass the same parameters); None when an
    argument has no such value (the launch is then not kept)."""
    key = [kernel, dim if isinstance(dim, int) else tuple(dim), block_dim]
    for arg in inputs:
        if isinstance(arg, wp.array):
            key.append((arg.ptr, arg.shape, arg.strides, arg.dtype))
        elif isinstance(arg, (bool, int, float)):
            key.append((type(arg), arg))
        elif hasattr(arg, "value"):  # a Warp scalar (wp.float64(dt))
            key.append((type(arg), arg.value))
        elif hasattr(arg, "_length_"):  # a Warp vector (coefficients, tableau)
            key.append((type(arg), bytes(arg)))  # its values' bytes
        else:
            return None
    return tuple(key)


# ----------------------------------------------------------------------------- public API


@on_one_thread
def simulate(
    params: ChainParams,
    x0,
    t_final: float,
    dt: float,
    *,
    method: str = "verlet",
    device: str | None = None,
    save_every: int | None = None,
    progress: bool = False,
    M=None,
    K=None,
    max_energy_error: float | None = 0.05,
    allow_unstable_step: bool = False,
    chunks: int | None = None,
    layout: str = "auto",
    on_chunk: Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None = None,
    damping: Damping | tuple | None = None,
    frames_out: tuple[np.ndarray, np.ndarray] | None = None,
    keep_on_device: bool = False,
) -> SimulationResult:
    """Integrate a batch of lattices with a float64 Warp kernel.

    Args:
        params: the chain (N, boundary, and M, K unless given per lattice).
        x0: initial state, shape (4, N) (a batch of one) or (batch, 4, N), ordered (u, v, u', v'); or a
            ``DeviceState`` (e.g. an earlier result's ``x`` with ``keep_on_device``), copied device to device.
        t_final: final time (>= 0). When it is not a whole multiple of ``dt`` the step is
            shortened slightly so that it is; the result reports the step used.
        dt: time step (> 0), below the method's linear stability limit.
        method: a name in ``METHODS`` (``verlet``, ``yoshida4``, ``yoshida6``, ``rk4``).
        device: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``; None picks CUDA when Warp sees a GPU (or, for a
            ``DeviceState`` x0, the device it lives on).
        save_every: record u and v every this many steps (and at t = 0).
        progress: show a tqdm progress bar.
        M, K: per-lattice parameters, shape (batch,), so that a sweep runs in one launch.
        max_energy_error: relative energy error that counts as a blow-up (None: only non-finite).
        allow_unstable_step: run (with a warning) even when dt is above the linear stability limit.
        chunks: number of launches the run is split into, each followed by the energy guard (default: from
            the work, at most 10, or 50 with progress; at most 2 for a short run on a large batch on a GPU,
            whose first and last chunk hide the state's transfers, or 3 when x0 is page-locked: a first and
            last chunk of 1/8 of the run each, whose transfers need no host copy, and the rest at once).
        layout: ``"block"`` (a thread block per lattice: the GPU path), ``"thread"`` (a thread per
            lattice: the CPU path) or ``"auto"`` (block on a GPU, thread on the CPU).
        on_chunk: called after every chunk with (t, u, v) of the frames recorded in that chunk,
            shapes (n,), (n, batch, N), (n, batch, N) (the t = 0 frame comes with the first call).
        frames_out: with ``save_every``, two host arrays (u, v) of shape (n_saved, batch, N), float64,
            C-contiguous, that receive the recorded frames (and become the result's ``u`` and ``v``)
            instead of new arrays. An ensemble study that records run after run can allocate them once:
            writing into memory already touched is several times faster than into fresh pages, which is
            what bounds recording (``benchmarks/h200-2026-11-22e``). Arrays from ``frame_buffers`` are
            page-locked on a GPU: the frames are copied from the device straight into them, at 27-37 GB/s
            on the H200 against 12-23 GB/s into plain reused arrays (``benchmarks/h200-2026-11-22h``).
        damping: losses (``losses.Damping`` or a (contact, substrate) pair of rates, scalars or per
            lattice), splitting methods only. Energy then decays; the guard flags a lattice whose
            energy *grows* by more than ``max_energy_error`` (relative), which no lossy run can do.
        keep_on_device: leave the final state on the device: the result's ``x`` is a ``DeviceState``, which
            the next call takes as its ``x0`` with no transfer either way (``warpchain.device_state``). Only
            the guard's scalars (and recorded frames) reach the host.

    Returns:
        SimulationResult.

    Raises:
        ValueError: bad input (shape, non-finite values, dt, t_final, method, device).
        StepSizeError: dt above the linear stability limit.
        IntegrationError: the state became non-finite or the energy error exceeded its bound.
    """
    start = time.perf_counter()
    meth = get_method(method)
    resident = isinstance(x0, DeviceState)  # x0 in device memory: no transfer at all
    if resident:
        device = _state_device(x0, params.N, device)
    else:
        x0 = _as_state(x0, params.N)  # the check for non-finite values runs on the device (the guard)
    batch = x0.shape[0]
    Mb, Kb = per_lattice_parameters(params, batch, M, K)
    damping = as_damping(damping)
    if damping is not None:
        damping.per_lattice(batch)  # validated here, at the boundary
        require_splitting(meth)
    t_final = real_number("t_final", t_final, nonnegative=True)
    limit = _check_step(meth, params, dt, M if M is None else Mb, K if K is None else Kb, allow_unstable_step)
    dt = real_number("dt", dt, positive=True)
    if save_every is not None:
        save_every = whole_number("save_every", save_every, minimum=1)
    if max_energy_error is not None:
        max_energy_error = real_number("max_energy_error", max_energy_error, positive=True)
    if chunks is not None:
        chunks = whole_number("chunks", chunks, minimum=1)
    device = resolve_device(device)
    nsteps, dt_used = steps_for(t_final, dt)
    if frames_out is not None:
        frames_out = _check_frames_out(frames_out, save_every, nsteps, batch, params.N, None if resident else x0)
    if save_every is not None and save_every > max(nsteps, 1):
        raise ValueError(
            f"save_every = {save_every} is larger than the run ({nsteps} steps of {dt_used:.6g}): "
            f"no frame after t = 0 would be saved; use save_every <= {max(nsteps, 1)}"
        )

    # chunk length: a whole number of save intervals, at least _CHUNK_WORK force evaluations of the whole
    # batch (launch, guard and transfer costs stay small against the kernel), at most 10 chunks (50 with a
    # progress bar), and, when recording, at most the frames that fit the host staging buffers
    unit = save_every or 1
    units_total = max(1, math.ceil(nsteps / unit))
    work = batch * params.N * max(nsteps, 1) * meth.force_evaluations
    n_chunks = chunks or max(1, min(50 if progress else 10, math.ceil(work / _CHUNK_WORK)))
    large = x0.size >= _SLICED_MIN_VALUES and (device != "cpu" or _SLICE_ON_CPU)
    # a large batch from and to the host: the state moved in slices, overlapped with the first and last chunk
    sliced = large and not (resident or keep_on_device)
    # a short run on a large batch: two chunks, whether its state moves or stays on the device (a run continued
    # on the device has the chunks, hence the energy trace, of the same run from a plain x0)
    short = large and chunks is None and not progress and nsteps * meth.force_evaluations <= _SHORT_RUN_EVALUATIONS
    if short:
        n_chunks = min(n_chunks, _SHORT_RUN_CHUNKS)
    units_per_chunk = max(1, math.ceil(units_total / n_chunks))
    if save_every:
        units_per_chunk = min(units_per_chunk, _frames_per_chunk(batch, params.N))
    sizes = [units_per_chunk] * (units_total // units_per_chunk) + [units_total % units_per_chunk]
    fraction = _SLICED_ENDS
    if fraction is None and short and sliced and _pinned_view(x0) is not None:
        fraction = _LOCKED_ENDS
    ends = math.ceil(units_total * fraction) if short and sliced and not save_every and fraction else 0
    if 0 < ends and 2 * ends < units_total:
        # the sliced first and last chunk only as long as hiding the transfers needs; the rest on the whole
        # batch at once, which runs faster than slice after slice (fuller waves)
        sizes = [ends, units_total - 2 * ends, ends]
    plan = []  # (first step, steps, frames) of each chunk
    for size in sizes:
        first = sum(p[1] for p in plan)
        steps = min(size * unit, nsteps - first)
        if steps > 0:
            plan.append((first, steps, steps // save_every if save_every else 0))

    gpu = device != "cpu"
    sliced = sliced and bool(plan)  # a large batch: state moved in slices, overlapped with the first and last chunk
    t_runner = time.perf_counter()
    runner = _pooled_runner(meth, params, x0, Mb, Kb, device, layout, upload=False)  # x0: uploaded below
    runner.set_damping(damping, dt_used)
    t_runner = time.perf_counter() - t_runner
    wp = runner.wp
    lend = _LEASE_RESULTS and (gpu or _LEASE_ON_CPU)
    lent = leases.lend(wp, device, x0.shape) if lend and plan and not keep_on_device else None
    final = lent[0] if lent else None  # the final state's page-locked host array, which the device fills
    if keep_on_device:
        final = DeviceState.empty(x0.shape, device)  # filled device to device behind the last chunk
    target = None  # else the final state's host array, touched in the background once the device is busy
    guard = _GuardReader.of(runner, gpu)
    transfers = _SlicedTransfers(runner, x0, _slice_bounds(batch), out=final) if sliced else None
    if not plan:
        runner.upload(x0)
        E0, finite0, contact = (a.copy() for a in guard.read(runner.guard(), 0))  # of x0, on the device
        if not finite0.all():
            guard.close()
            raise ValueError(f"x0 has non-finite entries in lattice(s) {np.flatnonzero(~finite0).tolist()}")
    else:
        # the start's guard (energy, finite flag, contact of x0) is queued with chunk 0 and read after it,
        # so the host never waits for the device before the first kernel runs
        E0 = contact = None
    trace_t, trace_E = [0.0], [E0]
    max_err = np.zeros(batch)

    sink = None
    if save_every:
        n_saved = 1 + nsteps // save_every
        if frames_out is None and lend:
            lent_frames = leases.lend(wp, device, (n_saved, batch, params.N), count=2)
            frames_out = tuple(lent_frames) if lent_frames else None
        sink = _FrameSink(runner, n_saved, max(p[2] for p in plan) if plan else 0, gpu, out=frames_out)
        sink.put_initial(x0.numpy() if resident else x0)
        if on_chunk is not None:
            on_chunk(np.array([0.0]), *sink.view(0, 1))

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=nsteps, desc=f"{meth.name} dt={dt_used:.4g}", unit="step", leave=False)

    def enqueue(i):
        """Queue chunk i on the device: kernel, guard, and the copies of its scalars and frames."""
        _, steps, n_rec = plan[i]
        rec = sink.rec if n_rec else None
        if sliced and (i == 0 or i == len(plan) - 1):
            for s, lattices in enumerate(transfers.slices):
                if i == 0:
                    transfers.upload(s)
                    runner.guard(slot=2, lattices=lattices)  # the start: energy, finite, contact
                runner.launch(steps, dt_used, save_every or 0, rec, lattices=lattices)
                if i == len(plan) - 1:
                    transfers.download(s)
            if i == 0:
                guard.enqueue_init(runner.guard_out[2])
        else:
            if i == 0:
                runner.guard(slot=2)
            runner.launch(steps, dt_used, save_every or 0, rec)
            if i == 0:
                guard.enqueue_init(runner.guard_out[2])  # after the kernel's launch: it need not wait for this
        guard.enqueue(runner.guard(rec, n_rec, i), i)
        if n_rec:
            sink.enqueue(n_rec, i, 1 + plan[i][0] // save_every)
        guard.record(i)
        if i == len(plan) - 1 and not sliced:
            # the final state's copy right behind the last chunk, while the host still checks the chunks
            queued_final[0] = runner.enqueue_download(final)

    def check(i, E, finite, low):
        """Chunk i's guard on the host: trace the energy, raise on a blow-up."""
        nonlocal max_err, contact
        first, steps, _ = plan[i]
        t_now = (first + steps) * dt_used
        change = _signed_energy_change(E, E0, params.N)  # lattices with losses: only growth is an error
        err = np.where(runner.lossy_host, np.maximum(change, 0.0), np.abs(change))
        err = np.where(finite, err, np.inf)
        max_err = np.maximum(max_err, err)
        trace_t.append(t_now)
        trace_E.append(E.copy())
        bad = ~finite | ((err > max_energy_error) if max_energy_error is not None else False)
        if np.any(bad):
            if gpu:
                wp.synchronize_device(device)  # the next chunk may still be running; let it finish
            failed = np.flatnonzero(bad).tolist()
            what = "non-finite state" if not finite.all() else f"energy error above {max_energy_error:g}"
            raise IntegrationError(
                f"integration blew up ({what}) at t = {t_now:.6g} with method '{meth.name}', "
                f"dt = {dt_used:.6g} (linear stability limit {limit:.6g}); failing lattices: {failed[:20]}"
                + (" ..." if len(failed) > 20 else "")
                + f"; largest relative energy error {np.nanmax(err):.3g}. Reduce dt or choose another method.",
                method=meth.name,
                dt=dt_used,
                stability_limit=limit,
                failed=failed,
                t=t_now,
            )
        contact = low.copy()

    queued_final = [False]
    saved = 1
    stats = {"chunks": len(plan), "runner": t_runner, "waiting": 0.0, "frames": 0.0, "final": 0.0}
    stats["slices"] = len(transfers.slices) if sliced else 1
    stats["lent"] = lent is not None  # the final state in page-locked memory lent by ``leases``
    stats["x0_on_device"], stats["kept_on_device"] = resident, bool(keep_on_device)
    if runner.layout == "block" and isinstance(meth, SplittingMethod):
        lattices = transfers.slices[0][1] if sliced else batch
        stats["sites_per_thread"] = sites_per_thread(lattices, params.N, meth.stages, device)
    try:
        if plan:
            if not sliced:  # a page-locked x0 is read by the device after this returns: the finally waits for it
                runner.upload(x0, wait=False)
            enqueue(0)
        stats["setup"] = time.perf_counter() - start
        if gpu and final is None and x0.size >= _PREFAULT_MIN_VALUES:
            target = _prefault(x0.shape)
        for i, (first, steps, n_rec) in enumerate(plan):
            if i + 1 < len(plan):
                enqueue(i + 1)  # the device works on the next chunk while the host checks this one
            if sliced and i == len(plan) - 1:
                if final is None:
                    if target is not None:
                        target.join()
                    final = target.result if target is not None else np.empty(x0.shape)
                t0 = time.perf_counter()
                for s_ in range(len(transfers.slices)):
                    transfers.take(s_, final)  # while the device finishes the later slices
                stats["final"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            E, finite, low = guard.wait(i)
            stats["waiting"] += time.perf_counter() - t0
            if i == 0:
                E0, finite0, _ = guard.init()
                if not finite0.all():
                    raise ValueError(f"x0 has non-finite entries in lattice(s) {np.flatnonzero(~finite0).tolist()}")
                trace_E[0] = E0
            check(i, E, finite, low)
            if n_rec:
                t0 = time.perf_counter()
                sink.take(i, saved, n_rec)
                stats["frames"] += time.perf_counter() - t0
                if on_chunk is not None:
                    ts = (np.arange(1, n_rec + 1) * save_every + first) * dt_used
                    on_chunk(ts, *sink.view(saved, saved + n_rec))
                saved += n_rec
            if bar is not None:
                bar.update(steps)
    finally:
        if bar is not None:
            bar.close()
        if gpu:
            wp.synchronize_device(device)  # no copy into the staging buffers is left in flight
        guard.close()
        if sink is not None:
            sink.close()
        if transfers is not None:
            transfers.close()
        if target is not None:
            target.join()
    t0 = time.perf_counter()
    if sliced or queued_final[0]:
        x = final  # the device wrote it (and the finally waited for that)
    else:
        x = runner.download(final if final is not None else target.result if target is not None else None)
    stats["final"] += time.perf_counter() - t0
    _release_runner(runner)
    E1 = trace_E[-1]
    if save_every:
        t_arr = (np.arange(n_saved) * save_every) * dt_used
        u_arr, v_arr = sink.u, sink.v
    else:
        t_arr, u_arr, v_arr = np.array([0.0, nsteps * dt_used]), None, None
    return SimulationResult(
        x=x,
        t=t_arr,
        u=u_arr,
        v=v_arr,
        energy_initial=E0,
        energy_final=E1,
        energy_error=_relative_energy_error(E1, E0, params.N),
        max_energy_error=max_err,
        min_contact=contact,
        energy_t=np.array(trace_t),
        energy_trace=np.stack(trace_E),
        method=meth.name,
        dt=dt_used,
        nsteps=nsteps,
        t_final=nsteps * dt_used,
        device=device,
        wall_seconds=time.perf_counter() - start,
        layout=runner.layout,
        stats=stats,
    )


@dataclasses.dataclass(frozen=True)
class TangentResult:
    """Outcome of ``propagate_tangent``.

    Attributes:
        x: end states of the base trajectories, shape (n_base, 4, N).
        columns: propagated tangent columns, shape (ncols, 4, N): column c is the derivative of
            the end state of base ``column_base[c]`` along the initial direction ``dx0[c]``.
        column_base: base trajectory of each column, shape (ncols,).
        method, dt, nsteps, device, wall_seconds, layout.
        kernel_seconds: device time of the two kernels (base run and tangent columns): on a GPU between
            CUDA events captured with the two launches into one CUDA graph (so no host gap counts, before
            or between them); on the CPU as ``launch_seconds``.
        launch_seconds: host time of issuing the two launches (on a GPU the graph's launch, its
            instantiation included), the device synchronised before and after (no transfers, no set-up).
    """

    x: np.ndarray
    columns: np.ndarray
    column_base: np.ndarray
    method: str
    dt: float
    nsteps: int
    device: str
    wall_seconds: float
    layout: str = "thread"
    kernel_seconds: float = float("nan")
    launch_seconds: float = float("nan")


@on_one_thread
def propagate_tangent(
    params: ChainParams,
    x0,
    dx0,
    nsteps: int,
    dt: float,
    *,
    method: str = "verlet",
    column_base=None,
    device: str | None = None,
    M=None,
    K=None,
    allow_unstable_step: bool = False,
    layout: str = "auto",
) -> TangentResult:
    """End states and Jacobian columns of ``nsteps`` steps of the discrete map.

    The base trajectories run once, recording the contact stiffness at every force evaluation;
    the tangent columns (one per thread, batched like lattices) then replay it, so each column is
    the exact derivative of the discrete map along its initial direction.

    Args:
        x0: base states, shape (4, N) or (n_base, 4, N).
        dx0: initial tangent directions, shape (ncols, 4, N) (e.g. unit vectors: Jacobian columns).
        nsteps: number of steps; dt: step size.
        column_base: base index of each column, shape (ncols,); default all 0.
        layout: kernel layout, as in ``simulate``.
    """
    start = time.perf_counter()
    meth = get_method(method)
    x0 = as_batch(x0, params.N, "x0")
    dx0 = as_batch(dx0, params.N, "dx0")
    n_base, ncols = x0.shape[0], dx0.shape[0]
    Mb, Kb = per_lattice_parameters(params, n_base, M, K)
    _check_step(meth, params, dt, Mb, Kb, allow_unstable_step)
    if not isinstance(nsteps, (int, np.integer)) or nsteps < 0:
        raise ValueError(f"nsteps must be a non-negative integer, got {nsteps!r}")
    base = np.zeros(ncols, dtype=np.int32) if column_base is None else np.asarray(column_base, dtype=np.int32)
    if base.shape != (ncols,) or (base < 0).any() or (base >= n_base).any():
        raise ValueError(f"column_base must have shape ({ncols},) with entries in [0, {n_base})")
    device = resolve_device(device)
    runner = _Runner(meth, params, x0, Mb, Kb, device, record_stiffness_steps=max(int(nsteps), 1), layout=layout)
    wp = runner.wp
    dx = wp.array(dx0, dtype=wp.float64, device=device)
    base_dev = wp.array(base, dtype=wp.int32, device=device)
    # device time from the base run's start to the columns' end, between events captured with the two
    # launches into one graph (so the device does not wait for the host between or before them)
    events = [wp.Event(device, enable_timing=True) for _ in range(2)] if nsteps and device != "cpu" else None

    def launches():
        if events is not None:
            wp.record_event(events[0])
        runner.launch(int(nsteps), float(dt), record_stiffness=True)
        runner.launch_tangent(dx, base_dev, int(nsteps), float(dt))
        if events is not None:
            wp.record_event(events[1])

    replay = _Replay(wp, device, launches, after=0)
    if nsteps:
        replay.prepare()  # capture before the clock starts
    wp.synchronize_device(device)
    kernel_start = time.perf_counter()
    if nsteps:
        replay()
    wp.synchronize_device(device)
    launch_seconds = time.perf_counter() - kernel_start
    kernel_seconds = launch_seconds if events is None else 1e-3 * wp.get_event_elapsed_time(*events)
    x = runner.x.numpy()
    columns = dx.numpy()
    if not (np.isfinite(x).all() and np.isfinite(columns).all()):
        raise IntegrationError(
            f"tangent propagation produced non-finite values with method '{meth.name}', dt = {dt:g} "
            f"(linear stability limit {stability_limit(meth, params, Mb, Kb):.6g})",
            method=meth.name,
            dt=dt,
            stability_limit=stability_limit(meth, params, Mb, Kb),
            failed=np.flatnonzero(~np.isfinite(x).all(axis=(1, 2))).tolist(),
            t=nsteps * dt,
        )
    return TangentResult(
        x=x,
        columns=columns,
        column_base=base,
        method=meth.name,
        dt=float(dt),
        nsteps=int(nsteps),
        device=device,
        wall_seconds=time.perf_counter() - start,
        layout=runner.layout,
        kernel_seconds=kernel_seconds,
        launch_seconds=launch_seconds,
    )


@on_one_thread
def time_steps(
    params: ChainParams,
    x0,
    nsteps: int,
    dt: float,
    *,
    method: str = "verlet",
    device: str | None = None,
    layout: str = "auto",
    repeats: int = 3,
    M=None,
    K=None,
) -> float:
    """Best of ``repeats`` timings (seconds) of one launch of ``nsteps`` steps on a batch already on
    the device: kernel time alone (the device is synchronised before and after; compilation, set-up
    and transfers are excluded). This is what the throughput benchmark divides by.

    Args:
        x0: state, shape (4, N) or (batch, 4, N); it keeps evolving from one repeat to the next.
    """
    meth = get_method(method)
    x0 = as_batch(x0, params.N, "x0")
    Mb, Kb = per_lattice_parameters(params, x0.shape[0], M, K)
    _check_step(meth, params, dt, Mb, Kb, False)
    if not isinstance(nsteps, (int, np.integer)) or nsteps < 1:
        raise ValueError(f"nsteps must be a positive integer, got {nsteps!r}")
    if not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    device = resolve_device(device)
    runner = _Runner(meth, params, x0, Mb, Kb, device, layout=layout)
    wp = runner.wp
    runner.launch(1, float(dt))  # compile and load the kernel
    best = math.inf
    for _ in range(repeats):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        runner.launch(int(nsteps), float(dt))
        wp.synchronize_device(device)
        best = min(best, time.perf_counter() - t0)
    return best
