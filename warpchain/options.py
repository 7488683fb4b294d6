"""Option objects of ``simulate``: what a run records (``Record``), when it counts as blown up (``Guard``),
and where its state lives (``Placement``). Frozen, validated where they are made, passed whole.

    run = wc.simulate(params, x0, t_final, dt, method="yoshida4", record=wc.Record(every=10),
                      guard=wc.Guard(max_energy_error=1e-3), placement=wc.Placement(keep_on_device=True))

The flat keywords these replace (``save_every``, ``frames_out``, ``on_chunk``, ``max_energy_error``,
``allow_unstable_step``, ``chunks``, ``layout``, ``keep_on_device``) are still accepted by ``simulate``
with a ``DeprecationWarning`` naming the option to use; they go away in 0.3.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Callable

import numpy as np

from .model import real_number, whole_number

LAYOUTS = ("auto", "block", "sites", "thread")


@dataclasses.dataclass(frozen=True)
class Record:
    """Record u and v every ``every`` steps (and at t = 0).

    Attributes:
        every: steps between recorded frames (>= 1).
        into: two host arrays (u, v) of shape (n_saved, batch, N), float64, C-contiguous, that receive the
            frames (and become the result's ``u`` and ``v``) instead of new arrays. A study that records run
            after run allocates them once (``frame_buffers``, page-locked on a GPU: the device copies straight
            into them): writing into memory already touched is several times faster than into fresh pages.
        on_chunk: called after every chunk with (t, u, v) of the frames recorded in it, shapes (n,),
            (n, batch, N), (n, batch, N), read-only views (the t = 0 frame comes with the first call); e.g. a
            zarr writer's ``append``.
    """

    every: int
    into: tuple[np.ndarray, np.ndarray] | None = None
    on_chunk: Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None = None

    def __post_init__(self):
        object.__setattr__(self, "every", whole_number("Record.every", self.every, minimum=1))
        if self.on_chunk is not None and not callable(self.on_chunk):
            raise ValueError(f"Record.on_chunk must be callable, got {type(self.on_chunk).__name__}")


@dataclasses.dataclass(frozen=True)
class Guard:
    """The energy guard that runs on the device after every chunk.

    Attributes:
        max_energy_error: relative energy error that counts as a blow-up (None: only a non-finite state).
            With losses only energy *growth* counts, which no lossy run can show.
        allow_unstable_step: run (with a warning) even when dt is above the method's linear stability limit
            (else ``StepSizeError``).
        chunks: launches the run is split into, each followed by the guard (None: from the work, at most 10,
            or 50 with a progress bar).
    """

    max_energy_error: float | None = 0.05
    allow_unstable_step: bool = False
    chunks: int | None = None

    def __post_init__(self):
        if self.max_energy_error is not None:
            value = real_number("Guard.max_energy_error", self.max_energy_error, positive=True)
            object.__setattr__(self, "max_energy_error", value)
        if self.chunks is not None:
            object.__setattr__(self, "chunks", whole_number("Guard.chunks", self.chunks, minimum=1))


@dataclasses.dataclass(frozen=True)
class Placement:
    """How the run is laid out on its device.

    Attributes:
        layout: ``"block"`` (a thread block per lattice: the GPU path), ``"sites"`` (a thread per site and a
            launch per force evaluation: the GPU path for lattices longer than a block),
            ``"thread"`` (a thread per lattice: the CPU path) or ``"auto"`` (on a GPU block when the lattice fits
            one block, else sites; thread on the CPU).
        keep_on_device: leave the final state on the device: the result's ``x`` is a ``DeviceState``, which
            the next call takes as its ``x0`` with no transfer either way. Only the guard's scalars (and
            recorded frames) reach the host.
    """

    layout: str = "auto"
    keep_on_device: bool = False

    def __post_init__(self):
        if self.layout not in LAYOUTS:
            raise ValueError(f"Placement.layout must be one of {LAYOUTS}, got {self.layout!r}")


#: the flat keywords ``simulate`` still accepts: (option class, its field)
LEGACY = {
    "save_every": (Record, "every"),
    "frames_out": (Record, "into"),
    "on_chunk": (Record, "on_chunk"),
    "max_energy_error": (Guard, "max_energy_error"),
    "allow_unstable_step": (Guard, "allow_unstable_step"),
    "chunks": (Guard, "chunks"),
    "layout": (Placement, "layout"),
    "keep_on_device": (Placement, "keep_on_device"),
}


def from_legacy(legacy: dict, record: Record | None, guard: Guard, placement: Placement, caller: str = "simulate"):
    """(record, guard, placement) with the flat keywords of ``legacy`` folded in, after one
    ``DeprecationWarning`` naming the options to use. Unknown keywords raise ``TypeError``, and a keyword
    given beside its option object raises ``ValueError`` (two sources for one setting)."""
    unknown = sorted(set(legacy) - set(LEGACY))
    if unknown:
        raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}")
    fields = {Record: {}, Guard: {}, Placement: {}}
    for name, value in legacy.items():
        cls, field = LEGACY[name]
        fields[cls][field] = value
    hints = []
    given = {Record: record, Guard: guard, Placement: placement}
    for cls, values in fields.items():
        if not values:
            continue
        current = given[cls]
        if current is not None and current != (None if cls is Record else cls()):  # not simulate's default
            raise ValueError(f"{', '.join(values)} given beside {cls.__name__.lower()}=: give one of them")
        if cls is Record and values.get("every") is None:
            if values.get("into") is not None:
                raise ValueError("frames_out receives recorded frames: give save_every too")
            continue  # no save_every: nothing is recorded and an on_chunk is never called, as before
        base = Record(every=values["every"]) if cls is Record else current
        given[cls] = dataclasses.replace(base, **values)
        hints.append(f"{cls.__name__.lower()}={cls.__name__}({', '.join(f'{k}=...' for k in values)})")
    warnings.warn(
        f"{caller}(): {', '.join(sorted(legacy))} are deprecated; use {'; '.join(hints) or 'nothing (defaults)'}",
        DeprecationWarning,
        stacklevel=4,  # the caller of simulate (through on_one_thread)
    )
    return given[Record], given[Guard], given[Placement]
