"""A batch state that stays in device memory between ``simulate`` calls.

Why: from a host array every call moves the whole state twice, and on the H200 host the moves (host copy
into staging, PCIe both ways) cost as much as half the kernel at 805 lattices and 2000 steps
(``benchmarks/results/h200-2026-11-22n.json``). A study that runs segment after segment (run, look at a few scalars,
run on) needs the state on the host only when it wants to look at it. ``simulate(..., keep_on_device=True)``
returns the final state as a :class:`DeviceState`, and a ``DeviceState`` passed as ``x0`` is copied device to
device (microseconds) into the run's buffers. The guard's per-lattice scalars (energy, finite flag, minimum
contact) still reach the host after every chunk, so a blow-up is found exactly as before.

A ``DeviceState`` owns its device buffer: nothing else writes it, so it may be passed as ``x0`` any number
of times. ``numpy()`` (or ``np.asarray``) copies it to the host.
"""

from __future__ import annotations

import numpy as np


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
        from .engine.devices import _warp

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
        from .engine.devices import _warp, device_lock, resolve_device

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
        from .engine.devices import _warp, device_lock

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
        from .engine.devices import resolve_device

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
        from .engine.devices import device_lock

        with device_lock(self.device):
            out = self.array.numpy()
        return out.copy() if self.array.device.is_cpu else out  # on the CPU .numpy() is a view of the buffer

    def __array__(self, dtype=None, copy=None):
        out = self.numpy()
        return out if dtype is None else out.astype(dtype, copy=False)

    def __repr__(self) -> str:
        return f"DeviceState(shape={self.shape}, device={self.device!r})"
