"""Host memory on the way to and from the device: pinned staging buffers kept in a pool, multi-threaded
host copies (numpy releases the GIL), fresh arrays touched in the background, and recorded frames on
their way into the result arrays (``FrameSink``), straight into page-locked ``frame_buffers`` when given."""

from __future__ import annotations

import os
import threading

import numpy as np

from ..integrators import steps_for
from ..model import ChainParams, real_number, whole_number
from .devices import _even_slices, _warp, held, resolve_device, usable_cores
from .tuning import active


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


_STAGING_POOL: dict = {}


_STAGING_LOCK = threading.Lock()


_COPY_POOL = None


def _frames_per_chunk(batch: int, n_sites: int) -> int:
    return max(1, active().staging_bytes // (8 * batch * n_sites))


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
    """Threads for a host copy of this many float64 values: one per ``Tuning.copy_slice`` values (handing a piece to
    a pool thread costs tens of us), at most ``Tuning.max_copy_threads`` and the usable cores."""
    return max(1, min(active().max_copy_threads, usable_cores(), int(values) // active().copy_slice))


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


def _after_fork_in_child() -> None:
    """A forked child has none of its parent's threads: the copy pool's are gone (a copy would wait for them for
    ever) and a lock one of them held stays held. Start both afresh there."""
    global _COPY_POOL, _STAGING_LOCK
    _COPY_POOL, _STAGING_LOCK = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def _copy_pool(workers: int):
    """The host copy threads: made once with as many threads as any copy may use (not as the first copy asks:
    a pool sized by a small first copy would serialise every later large one)."""
    global _COPY_POOL
    with _STAGING_LOCK:
        if _COPY_POOL is None:
            from concurrent.futures import ThreadPoolExecutor

            size = max(workers, min(active().max_copy_threads, usable_cores()))
            _COPY_POOL = ThreadPoolExecutor(max_workers=size, thread_name_prefix="warpchain-copy")
    return _COPY_POOL


def slice_bounds(batch: int) -> list[tuple[int, int]]:
    """Lattice slices (lo, hi) of a sliced ``simulate`` run: ``Tuning.slices`` (else one per
    ``Tuning.slice_lattices`` lattices, 2 to ``Tuning.max_slices``) equal slices. Slices that grow from a small
    first one, so that the first kernel starts sooner, were slower on the H200 (13.7 against 12.0 ms at 8192
    lattices): the uploads' host copies, not the kernels, bound the first chunk there
    (``benchmarks/results/h200-2026-11-22n.json``)."""
    t = active()
    return _even_slices(
        batch, t.slices if t.slices is not None else max(2, min(t.max_slices, batch // t.slice_lattices))
    )


class _SlicedTransfers:
    """The state's trip to the device and back in lattice slices, overlapped with kernels: slice s is
    copied (host -> pinned -> device, on an upload stream) while the kernels run on slice s - 1, and its
    final state goes back (on a download stream) while they run on slice s + 1, so only one slice's
    transfer each way is exposed (on a GPU; on the CPU the same steps run in order). ``simulate`` runs the
    first and the last chunk slice by slice for it; a short run on a large batch has only those two."""

    def __init__(self, runner, x0: np.ndarray, slices: list):
        """``slices``: (lo, hi) lattice ranges covering the batch (``slice_bounds``)."""
        wp = runner.wp
        self.wp, self.r, self.x0 = wp, runner, x0
        self.gpu = runner.device != "cpu"
        self.slices = list(slices)
        self.site_values = 4 * runner.N
        self.up = _take_buffer(wp, runner.device, x0.size, self.gpu)
        self.down = _take_buffer(wp, runner.device, x0.size, self.gpu)
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
        _copy(self.up.numpy()[a:b], np.ascontiguousarray(self.x0[lo:hi]))
        if self.gpu:
            self.wp.copy(self.r.x, self.up, dest_offset=a, src_offset=a, count=b - a, stream=self.up_stream)
            self.main.wait_event(self.up_stream.record_event())
        else:
            self.wp.copy(self.r.x, self.up, dest_offset=a, src_offset=a, count=b - a)

    def download(self, s: int) -> None:
        """Slice s's state back to pinned memory once the kernels queued so far have run."""
        a, b = self._range(s)
        if self.gpu:
            self.down_stream.wait_event(self.main.record_event())
            self.wp.copy(self.down, self.r.x, dest_offset=a, src_offset=a, count=b - a, stream=self.down_stream)
            self.events[s] = self.down_stream.record_event()
        else:
            self.wp.copy(self.down, self.r.x, dest_offset=a, src_offset=a, count=b - a)

    def take(self, s: int, out: np.ndarray) -> None:
        """Write slice s's final state into ``out`` (the whole batch's host array) once its copy has landed."""
        a, b = self._range(s)
        if self.gpu:
            self.wp.synchronize_event(self.events[s])
        _copy(out.reshape(-1)[a:b], self.down.numpy()[a:b])

    def close(self) -> None:
        if self.closed:
            return
        if self.gpu:
            self.wp.synchronize_stream(self.up_stream)
            self.wp.synchronize_stream(self.down_stream)
        for buf in (self.up, self.down):
            _give_buffer(self.r.device, self.gpu, buf)
        self.up = self.down = None
        self.closed = True


def frame_buffers(
    params: ChainParams, batch: int, t_final: float, dt: float, save_every: int, *, device: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Host arrays (u, v) for ``simulate(..., record=Record(every=save_every, into=...))``, each
    (n_saved, batch, N) float64 with n_saved = 1 + nsteps // save_every, as ``simulate`` records with the same
    ``t_final``, ``dt`` and ``save_every``.

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


def _pinned_view(arr: np.ndarray):
    """(pinned Warp array, offset in values) when ``arr`` views page-locked Warp host memory (as the arrays
    of ``frame_buffers`` do), else None. Only a C-contiguous float64 view
    qualifies: the copies read and write it as one run of values from the offset."""
    if arr.dtype != np.float64 or not arr.flags.c_contiguous:
        return None
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


def _check_frames_out(frames_out, save_every, nsteps: int, batch: int, n_sites: int, x0: np.ndarray | None):
    """``simulate``'s ``frames_out``, checked once at the boundary: (u, v) host arrays of the frames' shape
    (``x0``: the host x0 they must not overlap; None for a ``DeviceState``)."""
    if not isinstance(frames_out, (tuple, list)) or len(frames_out) != 2:
        raise ValueError("Record.into must be a pair (u, v) of arrays")
    shape = (1 + nsteps // save_every, batch, n_sites)
    for name, arr in zip("uv", frames_out):
        if not isinstance(arr, np.ndarray) or arr.dtype != np.float64 or arr.shape != shape:
            got = f"{type(arr).__name__} {getattr(arr, 'dtype', '')} {getattr(arr, 'shape', '')}"
            raise ValueError(f"Record.into {name} must be a float64 numpy array of shape {shape}, got {got}")
        if not (arr.flags.c_contiguous and arr.flags.writeable):
            raise ValueError(f"Record.into {name} must be C-contiguous and writeable")
    if np.shares_memory(frames_out[0], frames_out[1]):
        raise ValueError("Record.into u and v must not share memory")
    if x0 is not None and any(np.may_share_memory(arr, x0) for arr in frames_out):
        raise ValueError("Record.into must not share memory with x0 (the device may still be reading x0)")
    return tuple(frames_out)
