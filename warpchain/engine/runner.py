"""The runner: device buffers and launches for one batch and one method, kept in a small pool between
calls on a GPU; launches replayed as CUDA graphs (``_Replay``) or kept launch commands; the guard's
scalars on their way to the host (``_GuardReader``)."""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from ..integrators import Method, check_step
from ..lattice import geometry_key, neighbour_table
from ..losses import KICK_ENTRIES, Damping, kick_matrices, lossless
from ..model import BOUNDARY_CODES, ChainParams, as_batch, per_lattice_parameters
from .devices import DeviceState
from ..reference import inverse_mass
from .devices import (
    _in_parallel,
    _part,
    _parts,
    _slices,
    _warp,
    engine_method,
    held,
    on_one_thread,
    on_this_thread,
    record_on,
    resolve_device,
    resolve_layout,
)
from .hostmem import _STAGING_LOCK, _copy, _give_buffer, _take_buffer
from .plans import PLANS
from .tuning import active


class _Replay:
    """A fixed sequence of launches and copies on fixed buffers (``enqueue``), issued eagerly the first
    ``after`` times and then captured once into a CUDA graph that every later call launches. On the CPU
    (or with ``Tuning.graph_after`` None) every call issues the operations one by one; the tests also capture
    them on the CPU (``Tuning.graphs_on_cpu``, Warp's CPU graphs) and check the replay bit for bit. ``enqueue``
    must not synchronise or allocate (every buffer it uses is kept alive by its closure)."""

    def __init__(self, wp, device: str, enqueue: Callable[[], None], after: int | None = None):
        self.wp, self.device, self.enqueue = wp, device, enqueue
        self.after = active().graph_after if after is None else after
        self.issued = 0
        self.graph = None

    def prepare(self) -> bool:
        """Capture the graph now if calls are due to replay one (without running it); True if they are."""
        graphs_here = self.device != "cpu" or active().graphs_on_cpu
        if self.graph is None and graphs_here and active().graph_after is not None and self.issued >= self.after:
            with on_this_thread(), self.wp.ScopedCapture(device=self.device) as capture:
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
        from . import block_kernels
        from . import site
        from . import thread_kernels as kernels

        method = engine_method(method)  # the plans step splitting methods only
        self.wp, self.k, self.site, self.method, self.device = wp, kernels, site, method, device
        self.batch, _, self.N = x0.shape
        table = neighbour_table(params)  # a lattice given as a neighbour table: the sites layout
        self.table_lattice = table
        self.layout = resolve_layout(layout, device, self.N, table=table is not None)
        if self.layout in ("block", "sites"):
            # the sites layout's guard: the block guard of a full block, each thread summing several sites
            self.block = block_kernels.block_size(min(self.N, block_kernels.MAX_BLOCK))
            self.bk = block_kernels.block_kernels(self.block, block_kernels.min_blocks_per_sm(method.stages))
            if device == "cpu":
                # run the block's threads as cooperative fibers (Warp's experimental CPU blocks)
                wp.config.enable_cpu_blocks = True
        # CPU fiber blocks crash when launched from several Python threads at once: one launch
        self.serial = self.layout in ("block", "sites") and device == "cpu"
        self.boundary = BOUNDARY_CODES[params.boundary]
        f64 = wp.float64
        if table is None:
            self.degree = 0
            self.table = wp.zeros((1, 1), dtype=wp.int32, device=device)
            self.weights = wp.zeros((1, 1), dtype=f64, device=device)
        else:
            self.degree = table.degree
            self.table = wp.array(table.neighbours, dtype=wp.int32, device=device)
            self.weights = wp.array(table.weights, dtype=f64, device=device)
        # pinned host staging of the state (made on first use), and the event after the last copy from each
        self._pinned_up_done = self._pinned_down_done = None
        self.x = wp.empty(x0.shape, dtype=f64, device=device)
        if upload:
            self.upload(x0)
        self.mass = wp.array(M, dtype=f64, device=device)
        self.inv_mass = wp.array(inverse_mass(M), dtype=f64, device=device)  # the kernels multiply by 1/M
        self.coupling = wp.array(K, dtype=f64, device=device)
        self._parameters_held = (np.array(M, dtype=np.float64), np.array(K, dtype=np.float64))  # what M, K hold
        self.plan = PLANS[self.layout](self)
        self.no_record = wp.zeros((1, 1, 1), dtype=f64, device=device)
        self.no_base = wp.zeros(1, dtype=wp.int32, device=device)
        self.no_observer = site.Observer()  # the unobserved kernels' (unused) observables
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
        before = (self.damped, self.damp)
        if damping is None:
            if self.damped:
                self.lossy.zero_()
            self.damped, self.damp = False, self.no_damp
            self.lossy_host = np.zeros(self.batch, dtype=bool)
        else:
            coefficients = kick_matrices(self.method.kicks, dt, self.mass.numpy(), damping, self.batch)
            self.lossy_host = ~lossless(coefficients)
            self.lossy.assign(self.lossy_host.astype(np.int32))
            if self.damp.shape != coefficients.shape:
                self.damp = wp.empty(coefficients.shape, dtype=wp.float64, device=self.device)
            self.damp.assign(coefficients)
            self.damped = True
        if before[0] != self.damped or before[1] is not self.damp:  # the kept Lattice structs name the old arrays
            self._lattices = {}

    def lattice(self, lo: int = 0, hi: int | None = None):
        """The kernels' ``site.Lattice`` of lattices lo..hi (default all: what tangent columns index
        through their base): views of this runner's parameters and losses, kept per slice (their values change in
        place; ``set_damping`` starts afresh when it swaps the losses' arrays), so that a repeated launch passes the
        same argument."""
        hi = self.batch if hi is None else hi
        kept = self.__dict__.setdefault("_lattices", {})
        if (lo, hi) not in kept:
            lat = self.site.Lattice()
            lat.mass, lat.inv_mass, lat.coupling, lat.lossy = _parts(
                lo, hi, self.mass, self.inv_mass, self.coupling, self.lossy
            )
            lat.damp = _part(self.damp, lo, hi) if self.damped else self.no_damp
            lat.boundary = self.boundary
            lat.degree, lat.table, lat.weights = self.degree, self.table, self.weights
            kept[lo, hi] = lat
        return kept[lo, hi]

    def _pinned(self, name: str):
        """This runner's own pinned host buffer ``name`` of the state's size (``host_buffer``: made once, the
        runner is pooled, so later calls on the same batch shape reuse it), after any copy from it has finished."""
        buf = self.host_buffer(name, self.x.size)
        done = getattr(self, name + "_done")
        if done is not None:
            self.wp.synchronize_event(done)
        return buf

    def upload(self, x0) -> None:
        """Copy a batch state to the device: a ``DeviceState`` device to device; on a GPU a host array through
        this runner's pinned buffer (~55 GB/s instead of the ~15 GB/s of pageable memory). Kernels queued
        after it see the new state."""
        wp = self.wp
        if isinstance(x0, DeviceState):  # device to device, on the compute stream: no wait needed
            wp.copy(self.x, x0.array, count=x0.size)
            return
        if self.device == "cpu" or x0.size < (1 << 16):
            self.x.assign(np.ascontiguousarray(x0, dtype=np.float64))
            return
        buf = self._pinned("_pinned_up")
        _copy(buf.numpy(), np.ascontiguousarray(x0, dtype=np.float64))
        wp.copy(self.x, buf, count=x0.size)
        self._pinned_up_done = record_on(wp, self.device)

    def download(self, out: np.ndarray | None = None) -> np.ndarray:
        """The batch state as a new host array (on a GPU through a pinned buffer, then a few threads
        write the result: fresh host memory is filled ~5x faster that way than by one thread);
        ``out``: a host array of the state's shape to fill instead (e.g. one touched in advance)."""
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

    def enqueue_download(self, out: DeviceState) -> None:
        """Queue the state's copy into the ``DeviceState`` ``out`` behind the work queued so far."""
        self.wp.copy(out.array, self.x, count=self.x.size)

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

    def record(self, every: int = 0, frames=None, stiffness: bool = False):
        """A launch's ``site.Recording``: u and v into ``frames`` (u, v) every ``every`` steps (None: no
        frames), f'(z) into this runner's history when ``stiffness`` (tangent runs read the history from it). One
        without frames is kept per (every, stiffness): building a struct costs ~20 us of host time per launch."""
        if frames is None:
            kept = self.__dict__.setdefault("_recordings", {})
            key = (int(every), bool(stiffness))
            if key not in kept:
                kept[key] = self._recording(every, None, stiffness)
            return kept[key]
        return self._recording(every, frames, stiffness)

    def _recording(self, every: int, frames, stiffness: bool):
        out = self.site.Recording()
        out.every, out.stiffness, out.hist = int(every), int(stiffness), self.hist
        out.u, out.v = frames if frames is not None else (self.no_record, self.no_record)
        return out

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
        observer=None,
    ):
        """Advance every lattice by nsteps; with ``rec`` (device (u, v) frame buffers from ``frames``)
        also record u and v every ``save_every`` steps into them; with ``observer`` (a function of (lo, hi)
        giving the ``site.Observer`` of lattices lo..hi) reduce the observables of
        ``warpchain.observe`` instead. Asynchronous on a GPU.

        On the CPU the batch is split into one slice per thread (launched concurrently); a run that
        records the contact stiffness (tangent base) runs as one slice, since its history is shared."""
        slices = [(0, self.batch)] if record_stiffness or self.serial else _slices(self.batch, self.device)
        if lattices is not None:  # only these lattices (lo, hi), in one launch (a slice of a sliced run)
            slices = [lattices]
        save = int(save_every) if rec is not None else 0

        def task(lo, hi):
            if observer is not None:
                self.plan.observe(lo, hi, dt, nsteps, observer(lo, hi))
                return
            frames = None  # no frames: the plan's record() passes the runner's placeholders
            if rec is not None:
                frames = [rec[0][:, lo:hi], rec[1][:, lo:hi]] if (lo, hi) != (0, self.batch) else list(rec)
            self.plan.step(lo, hi, dt, nsteps, save, frames, bool(record_stiffness))

        _in_parallel([lambda lo=lo, hi=hi: task(lo, hi) for lo, hi in slices])

    def guard(self, rec=None, n_rec: int = 0, slot: int = 0, lattices: tuple | None = None):
        """Launch the guard on the device: per lattice (energy, 1 if finite else 0, running min contact
        over the chunk ends and the first ``n_rec`` frames of ``rec``). Returns the device array
        (batch, 3) of slot ``slot`` (0 and 1 alternate between chunks, 2 holds the start); only it, not
        the state, needs to reach the host. ``lattices``: (lo, hi) to guard only those."""
        lo, hi = lattices if lattices is not None else (0, self.batch)
        frames = (rec[0][:, lo:hi], rec[1][:, lo:hi]) if rec is not None and n_rec else None
        out = self.guard_out[slot if slot == 2 else slot % 2]
        inputs = [_part(self.x, lo, hi), self.lattice(lo, hi), self.record(0, frames), int(n_rec)]
        inputs += _parts(lo, hi, self.contact, out)
        if self.layout in ("block", "sites"):
            self.launch_kernel(self.bk.guard, (hi - lo, self.block), inputs, self.block)
        else:
            self.launch_kernel(self.k.guard_kernel, hi - lo, inputs)
        return out

    def launch_kernel(self, kernel, dim, inputs: list, block_dim: int | None = None) -> None:
        """``wp.launch`` of ``kernel`` on this runner's device, on a GPU through a launch command kept under
        (kernel, dim, block_dim, the arguments' values: each array's pointer, shape and strides): a launch
        repeated with the same arguments (every call of an ensemble study on a pooled runner) skips Warp's
        argument packing (``Tuning.commands_per_runner`` says what it saved); the oldest are dropped. On
        the CPU (``Tuning.commands_on_cpu`` unset) a plain launch."""
        wp = self.wp
        key = (
            _launch_key(wp, kernel, dim, block_dim, inputs)
            if self.device != "cpu" or active().commands_on_cpu
            else None
        )
        if key is None:
            wp.launch(kernel, dim=dim, block_dim=block_dim, device=self.device, inputs=inputs)
            return
        commands = self.__dict__.setdefault("_commands", {})
        command = commands.pop(key, None)  # re-inserted below: the dict keeps the most recent last
        if command is None:
            command = wp.launch(
                kernel, dim=dim, block_dim=block_dim, device=self.device, inputs=inputs, record_cmd=True
            )
            while len(commands) >= active().commands_per_runner:
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
        request, kept for later ones (at most ``Tuning.graphs_per_runner``, the oldest dropped)."""
        replays = self.__dict__.setdefault("_replays", {})
        if key not in replays:
            while len(replays) >= active().graphs_per_runner:
                del replays[next(iter(replays))]
            replays[key] = _Replay(self.wp, self.device, enqueue)
        return replays[key]

    def host_buffer(self, name: str, size: int):
        """A host array of ``size`` float64 values kept with the runner under (``name``, ``size``) (page-locked
        on a GPU, so that copies into and out of it can be captured in a graph and run at the bus's rate)."""
        pinned = self.device != "cpu"
        make = lambda: self.wp.empty(size, dtype=self.wp.float64, device="cpu", pinned=pinned)  # noqa: E731
        return held(self, ("host", name, int(size)), make)


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
        elif hasattr(arg, "_ctype"):  # a Warp struct (``Recording``, ``Observer``): its arrays' pointers, values
            key.append((type(arg), bytes(arg._ctype)))
        elif hasattr(arg, "value"):  # a Warp scalar (wp.float64(dt))
            key.append((type(arg), arg.value))
        elif hasattr(arg, "_length_"):  # a Warp vector (coefficients, tableau)
            key.append((type(arg), bytes(arg)))  # its values' bytes
        else:
            return None
    return tuple(key)


_RUNNER_POOL: dict = {}


def _pooled_runner(
    method: Method, params: ChainParams, x0, M, K, device: str, layout: str, upload: bool = True
) -> "_Runner":
    """A runner for this (method, chain, batch, device, layout): on a GPU one kept from an earlier call
    (its device buffers reused, the new batch and parameters uploaded), else a new one. A runner in use
    is out of the pool, so concurrent calls never share one."""
    if device == "cpu":
        return _Runner(method, params, x0, M, K, device, layout=layout, upload=upload)
    table = neighbour_table(params) is not None
    layout = resolve_layout(layout, device, params.N, table=table)
    key = (method, params.N, params.boundary, geometry_key(params), x0.shape[0], device, layout)
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
        while sum(len(v) for v in _RUNNER_POOL.values()) > active().runner_pool_size:
            oldest = next(k for k, v in _RUNNER_POOL.items() if v)
            _RUNNER_POOL[oldest].pop(0)
            if not _RUNNER_POOL[oldest]:
                del _RUNNER_POOL[oldest]


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
            record_on(self.wp, self.runner.device, self.events[i % 2])  # not the current device's stream

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


@on_one_thread
def time_steps(
    params, x0, nsteps: int, dt: float, *, method="verlet", device=None, layout="auto", repeats=3, M=None, K=None
):
    """Best of ``repeats`` timings (seconds) of one launch of ``nsteps`` steps on a batch already on
    the device: kernel time alone (the device is synchronised before and after; compilation, set-up
    and transfers are excluded). This is what the throughput benchmark divides by.

    Args:
        x0: state, shape (4, N) or (batch, 4, N); it keeps evolving from one repeat to the next.
        method, device, layout, M, K: as ``simulate`` (``layout``: ``Placement.layout``).
    """
    meth = engine_method(method)
    x0 = as_batch(x0, params.N, "x0")
    Mb, Kb = per_lattice_parameters(params, x0.shape[0], M, K)
    check_step(meth, params, dt, Mb, Kb, False)
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
