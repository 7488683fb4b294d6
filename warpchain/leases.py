"""Page-locked host memory lent to ``simulate``'s results, and taken back when the caller drops them.

Why: on a GPU the final state (and any recorded frames) must reach a host numpy array. Into fresh pageable
memory that costs two host passes per value: touching the new pages (~3 GB/s per thread) and copying out of
a pinned staging buffer. On the H200 host the two cost 8.6 + 12 ms at 32768 lattices against 29 ms of
kernel, and 0.45 ms at 805 against 1.1 ms (``benchmarks/h200-2026-11-22l/timeline-*.txt``). A page-locked
result takes the device's copy directly, at the bus's rate, with no host pass at all.

Page-locking itself is slow (~0.4 s per GiB), so a result's pinned buffer is not freed with the result: the
array's ``base`` is a :class:`HostLease` whose finaliser puts the buffer back in a pool, and the next call of
the same shape takes it again. A loop ``r = simulate(p, x0, ...)`` therefore page-locks twice in all (the
result alive during the next call, and that call's own) and then only reuses. Three rules keep it safe:

1. A shape is lent only from its second request on: a one-off call pays no page-locking and gets a plain array.
2. All pinned bytes of the pool for a device (lent and free) stay under ``limit_bytes`` (1/16 of the host's
   memory, at most 8 GiB); past it, free buffers are released (largest first) and, if even releasing all of
   them would not make room, none is and the result is a plain array. A study that keeps many results alive
   falls back to plain arrays, it never pins the host.
3. Buffers are released only in ``lend`` (on the caller's thread; ``simulate`` calls it before it queues any
   work of its own), never in a finaliser: freeing pinned memory may synchronise the device, which a
   finaliser run by the garbage collector in the middle of a chunk must not do. Finalisers take no lock
   either: they put the buffer on a queue that ``lend`` empties.

A lent array is an ordinary, writeable, C-contiguous float64 numpy array; ``pinned_buffer`` finds its Warp
array again, so that a lent result passed back as ``x0`` (or as ``frames_out``) is copied to the device
straight from it, without a staging pass.
"""

from __future__ import annotations

import os
import queue
import threading

import numpy as np

#: all pinned bytes of the pool for one device, lent and free (None: from the host's memory, ``limit_bytes``)
LIMIT_BYTES: int | None = None
#: requests of a shape before it is lent pinned memory (1: from the second request on)
LEND_AFTER = 1
_LOCK = threading.Lock()
#: buffers given back by finalisers, taken into ``_FREE`` under the lock by ``lend``, ``held_bytes``, ``clear``.
#: A finaliser never takes the lock: the garbage collector can run one on a thread that holds it (a
#: ``HostLease`` in a reference cycle, e.g. a caught exception's traceback holding simulate's frame, collected
#: while ``lend`` allocates), and ``threading.Lock`` is not reentrant. ``SimpleQueue.put`` is safe there.
_RETURNED: queue.SimpleQueue = queue.SimpleQueue()
_FREE: dict = {}  # device -> [pinned Warp arrays], free to be lent again
_HELD: dict = {}  # device -> pinned bytes made by the pool and not yet released
_SEEN: dict = {}  # (device, shape) -> requests so far (at most _SEEN_KEPT shapes remembered)
_SEEN_KEPT = 1024


def limit_bytes() -> int:
    """Pinned bytes the pool may hold per device (``LIMIT_BYTES``, or 1/16 of physical memory, at most 8 GiB)."""
    if LIMIT_BYTES is not None:
        return int(LIMIT_BYTES)
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        physical = 8 << 30
    return int(min(physical // 16, 8 << 30))


class HostLease:
    """The owner of a lent pinned buffer: a numpy array made from it (its ``base``) keeps it alive, and
    when the last such array is gone the buffer goes back to the pool."""

    __slots__ = ("buffer", "device", "__array_interface__", "__weakref__")

    def __init__(self, buffer, device: str, shape: tuple):
        self.buffer, self.device = buffer, device
        self.__array_interface__ = {
            "shape": tuple(int(s) for s in shape),
            "typestr": "<f8",
            "data": (int(buffer.ptr), False),
            "version": 3,
        }

    def __del__(self):
        try:
            _RETURNED.put((self.device, self.buffer))  # no lock here: see _RETURNED
        except Exception:  # noqa: BLE001 - interpreter shutdown: the module's globals may be gone
            pass


def _take_returned() -> None:
    """Move the buffers finalisers gave back into the free lists (call with ``_LOCK`` held)."""
    while True:
        try:
            device, buf = _RETURNED.get_nowait()
        except queue.Empty:
            return
        _FREE.setdefault(device, []).append(buf)


def lend(wp, device: str, shape, count: int = 1, first: bool = False) -> list[np.ndarray] | None:
    """``count`` float64 host arrays of ``shape`` in page-locked memory lent by the pool (one request), or
    None where the rules above say plain arrays are better (first request of this shape, pool full).
    ``first``: lend on a first request too (the caller asked for page-locked memory).
    ``device`` names the GPU they serve; on ``"cpu"`` (tests only) the buffers are plain Warp host arrays."""
    shape = tuple(int(s) for s in shape)
    values = int(np.prod(shape))
    if values == 0 or count < 1:
        return None
    nbytes = 8 * values
    taken, release = [], []
    with _LOCK:
        _take_returned()
        free = _FREE.setdefault(device, [])
        if len(_SEEN) >= _SEEN_KEPT and (device, shape) not in _SEEN:
            _SEEN.clear()  # a study of ever-new shapes: forget, and start counting again
        seen = _SEEN.get((device, shape), 0)
        _SEEN[(device, shape)] = seen + 1
        while len(taken) < count:
            fits = [i for i, buf in enumerate(free) if values <= buf.size <= 2 * values]
            if not fits:
                break
            taken.append(free.pop(min(fits, key=lambda i: free[i].size)))
        missing = count - len(taken)
        held, limit = _HELD.get(device, 0), limit_bytes()
        if missing and (seen < LEND_AFTER and not first or held - _bytes(free) + missing * nbytes > limit):
            free.extend(taken)  # all or none; and nothing released when even that would not make room
            return None
        free.sort(key=lambda b: b.size)
        while missing and held + missing * nbytes > limit:
            dropped = free.pop()  # the largest free buffer first
            held -= 8 * dropped.size
            release.append(dropped)
        _HELD[device] = held + missing * nbytes
    del release  # freed here, outside the lock, on the caller's thread
    pinned = device != "cpu"
    made = []
    try:
        for _ in range(missing):
            made.append(wp.empty(values, dtype=wp.float64, device="cpu", pinned=pinned))
    except BaseException:  # page-locking failed, or an interrupt: give back what this call holds
        with _LOCK:
            _HELD[device] -= (missing - len(made)) * nbytes
            _FREE.setdefault(device, []).extend(taken + made)
        raise
    return [np.asarray(HostLease(buf, device, shape)) for buf in taken + made]


def _bytes(buffers) -> int:
    return sum(8 * b.size for b in buffers)


def pinned_buffer(arr: np.ndarray):
    """(pinned Warp array, offset in values) when ``arr`` is a contiguous float64 view of a lent buffer,
    else None."""
    base = arr
    while base is not None and not isinstance(base, HostLease):
        base = getattr(base, "base", None)
    if base is None or arr.dtype != np.float64 or not arr.flags.c_contiguous:
        return None
    buf = base.buffer
    offset = arr.ctypes.data - buf.ptr
    if offset < 0 or offset % 8 or offset // 8 + arr.size > buf.size:
        return None
    return buf, offset // 8


def held_bytes(device: str) -> int:
    """Pinned bytes the pool holds for ``device`` (lent and free)."""
    with _LOCK:
        _take_returned()
        return _HELD.get(device, 0)


def clear() -> None:
    """Forget every free buffer and every request count (tests; lent arrays stay valid: they hold their own).
    The free buffers are released after the lock is let go."""
    with _LOCK:
        _take_returned()
        dropped = dict(_FREE)
        for device, free in dropped.items():
            _HELD[device] = _HELD.get(device, 0) - _bytes(free)
        _FREE.clear()
        _SEEN.clear()
    del dropped
