"""``propagate_tangent``: the end state of a batch of base runs and the Jacobian columns of the discrete map along
them (the exact derivative of the scheme), on the Warp engine: one base run records the contact stiffness f'(z) at
every force evaluation, and the tangent columns replay that history in the layout's step loop (``compiled tangent``).
Newton and Floquet reach the same machinery through the ``Flow``; this is the direct entry point."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .engine.devices import engine_method, on_one_thread, record_on, resolve_device
from .engine.runner import _Replay, _Runner
from .integrators import IntegrationError, check_step, stability_limit
from .model import ChainParams, as_batch, per_lattice_parameters


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
    meth = engine_method(method)
    x0 = as_batch(x0, params.N, "x0")
    dx0 = as_batch(dx0, params.N, "dx0")
    n_base, ncols = x0.shape[0], dx0.shape[0]
    Mb, Kb = per_lattice_parameters(params, n_base, M, K)
    check_step(meth, params, dt, Mb, Kb, allow_unstable_step)
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
            record_on(wp, device, events[0])
        runner.launch(int(nsteps), float(dt), record_stiffness=True)
        runner.launch_tangent(dx, base_dev, int(nsteps), float(dt))
        if events is not None:
            record_on(wp, device, events[1])

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
