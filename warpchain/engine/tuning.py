"""Every policy number of the engine in one frozen object, with an explicit override.

The engine reads the active ``Tuning`` (``active()``) where it decides something: how long a chunk is,
how many sites a thread owns, when a launch is replayed as a CUDA graph. None of these change results:
the arithmetic is the same bits on every setting (the tests run the GPU-only paths on the CPU with
``override`` and compare them with the numpy reference). Tests and benchmarks change settings only through

    with tuning.override(sites_per_thread=7, group_one_site=True):
        ...

which restores the previous settings on exit, also after an error. No module global is patched.

The defaults are measurements; each field says where it was measured.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading


@dataclasses.dataclass(frozen=True)
class Tuning:
    """The engine's policy numbers (see the module docstring for how to change them)."""

    #: a ``simulate`` chunk holds at least this many site force evaluations of the whole batch (the chunk
    #: count comes from the work: launch, guard and transfer overheads stay small against the kernel)
    chunk_work: int = 1 << 28
    #: bytes of recorded u (and as many of v) per chunk: the size of each host staging buffer
    staging_bytes: int = 128 << 20
    #: ``simulate`` touches the final state's host array on background threads while the device runs from
    #: this many values up (fresh memory fills at ~3 GB/s per thread: 0.9 ms for the 805-lattice state)
    prefault_min_values: int = 1 << 16
    #: on a GPU, a state of at least this many values (5.2k lattices of 201 sites) moves to and from the device
    #: in lattice slices overlapped with the first and the last chunk's kernels (``hostmem._SlicedTransfers``):
    #: H100, 2000 Verlet steps at 32768 lattices from a plain x0, ``simulate()`` ran at 0.56x the kernel
    #: without slices (``benchmarks/results/h100-2026-11-25/engine-split.json``) and at 0.79x with them
    #: (``.../9fb3bfb.json``)
    sliced_min_values: int = 1 << 22
    #: lattices per slice and the most slices (H200: 8 slices of 4096 lattices, 2 of 4096 and the whole batch
    #: at 805 were each the best or within 2 % of it, ``benchmarks/results/h200-2026-11-22h.json``); ``slices``
    #: forces a count
    slice_lattices: int = 4096
    max_slices: int = 8
    slices: int | None = None
    #: a run of at most this many force evaluations per site on such a batch runs in at most
    #: ``short_run_chunks`` chunks (by default): the first and the last chunk, whose kernels hide the
    #: slices' transfers, then hold the whole run; a run continued on the device gets the same chunks
    short_run_evaluations: int = 1 << 15
    short_run_chunks: int = 2
    #: the sliced path on the CPU too (the tests), else GPU-only
    slice_on_cpu: bool = False
    #: from this many lattices a GPU launch of a splitting method with at most ``sites_max_stages`` stages
    #: gives each thread a run of sites (one warp per lattice up to 256 sites). H200, N = 201
    #: (``benchmarks/sites_per_thread.py``, ``benchmarks/results/h200-2026-11-22e.json``): Verlet 3.28e11
    #: site-steps/s at 2400
    #: lattices with 7 sites per thread against 3.19e11 with one, 4.40e11 against 3.75e11 at 32768; yoshida4
    #: 1.50e11 against 1.20e11 at 32768; kahan8 (15 stages) is slower that way at every batch (1.98e10
    #: against 2.46e10 at 32768), so it keeps one site per thread
    sites_min_batch: int = 2048
    sites_max_stages: int = 4
    #: sites per thread forced for every block splitting launch (None: the rule above); the tests set it to
    #: run the site-group kernels on the CPU
    sites_per_thread: int | None = None
    #: None: a one-site-per-thread launch runs the site-group kernel on a GPU for few stages (one float64 per
    #: thread in the tile, walls compiled in: 118.6 ns per Verlet step of one lattice against 202 ns, H200,
    #: ``benchmarks/results/h200-2026-11-22k.json``); True/False force the choice (the tests run it on the CPU)
    group_one_site: bool | None = None
    #: a recording launch of at most this many lattices (a tangent base run) drops the many-stage kernels'
    #: register cap (under it the held stiffnesses would spill): one block per SM of an H200
    record_uncapped_max_batch: int = 132
    #: operations issued again and again with the same arguments (a Flow's base run, a Newton iteration's
    #: columns) are captured into a CUDA graph at their ``graph_after``-th issue and replayed from then on:
    #: one launch from Python instead of several (~0.1 ms of host time each). None: never captured
    graph_after: int | None = 1
    #: graphs kept per runner (a frequency continuation changes dt, hence the graphs, at every point)
    graphs_per_runner: int = 8
    #: launch commands kept per runner (a launch repeated with the same arguments skips Warp's argument
    #: packing: 0.1-0.35 ms per launch on the H200 host before, 0.05-0.11 ms after,
    #: ``benchmarks/results/h200-2026-11-22l.json``)
    commands_per_runner: int = 256
    #: the GPU-only host paths run on the CPU too (CUDA graphs as Warp's CPU graphs, kept launch commands),
    #: so that CI checks what they hold; off by default
    graphs_on_cpu: bool = False
    commands_on_cpu: bool = False
    #: runners (device buffers of one method, chain and batch) kept between ``simulate`` calls on a GPU
    runner_pool_size: int = 4
    #: float64 values per host copy thread (2 MB: with 8 MB, a 13 MB copy went on one thread at ~5 GB/s,
    #: H200 host, ``benchmarks/results/h200-2026-11-22h.json``) and the most copy threads
    copy_slice: int = 1 << 18
    max_copy_threads: int = 16

    def replace(self, **changes) -> "Tuning":
        """A copy with ``changes`` (unknown names raise ``TypeError``)."""
        return dataclasses.replace(self, **changes)


_LOCK = threading.Lock()
_DEFAULT = Tuning()
_STACK: list = []  # the overrides in force, innermost last
_ACTIVE = _DEFAULT


def active() -> Tuning:
    """The settings the engine uses now."""
    return _ACTIVE


@contextlib.contextmanager
def override(tuning: Tuning | None = None, **changes):
    """Use ``tuning`` (default: the active settings) with ``changes`` inside the ``with`` block.

    Process-wide (the engine's worker threads see it too): meant for tests and benchmarks. Overrides nest;
    on exit an override leaves the stack, and the innermost one still in force (or the defaults) applies, so
    overlapping overrides from several threads never leave a stale value behind once all have exited (while
    they overlap, each sees the settings of the innermost). A replayed CUDA graph keeps the launches it
    captured: an override changes what later captures and launches do, not earlier graphs (same bits
    either way, only the speed differs)."""
    global _ACTIVE
    with _LOCK:
        mine = (tuning or _ACTIVE).replace(**changes)
        _STACK.append(mine)
        _ACTIVE = mine
    try:
        yield mine
    finally:
        with _LOCK:
            # the last entry that is this very object (an equal Tuning of another override is not ours)
            for i in range(len(_STACK) - 1, -1, -1):
                if _STACK[i] is mine:
                    del _STACK[i]
                    break
            _ACTIVE = _STACK[-1] if _STACK else _DEFAULT
