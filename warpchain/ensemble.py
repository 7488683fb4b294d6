"""Batched runs on a Warp device: ``simulate`` (direct simulation with recording and a stability
guard; the tangent runs are ``warpchain.tangent``).

A run is split into chunks of many steps; each chunk is one kernel launch that loops over time
inside the kernel. Between chunks the state is checked (finite, energy within bound), recorded
fields are copied out (and optionally handed to a callback, e.g. a zarr writer), and the
progress bar advances.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from .integrators import steps_for
from .losses import Damping, as_damping
from .model import ChainParams, _signed_energy_change, as_batch, per_lattice_parameters, real_number
from .engine.tuning import active
from .integrators import IntegrationError, StepSizeError, check_step, stability_limit  # noqa: F401  (re-exported)
from .options import Guard, Placement, Record, from_legacy

from .engine.devices import (  # noqa: F401  (re-exported: the public face of the engine)
    DeviceState,
    available_devices,
    cpu_threads,
    device_lock,
    engine_method,
    on_one_thread,
    record_on,
    resolve_device,
    resolve_layout,
    _warp,
)
from .engine.hostmem import (  # noqa: F401
    _check_frames_out,
    _FrameSink,
    _frames_per_chunk,
    _prefault,
    _SlicedTransfers,
    frame_buffers,
    slice_bounds,
)
from .engine.plans import sites_per_thread  # noqa: F401
from .engine.runner import _GuardReader, _pooled_runner, _release_runner, _Replay, _Runner, time_steps  # noqa: F401


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
        layout: the kernel layout that ran (``"block"``, ``"sites"`` or ``"thread"``).
        stats: where the wall time went, host clock (seconds): ``setup`` (checks, buffers, the start's
            upload, until the first chunk is queued; ``runner`` of it: the device buffers taken from the
            pool and loaded with the batch's parameters), ``waiting`` (the host blocked on the device's
            chunks), ``frames`` (recorded frames copied into ``u`` and ``v``), ``final`` (the final
            state copied into ``x``), and ``chunks``, ``sites_per_thread`` (block layout),
            ``x0_on_device``, ``kept_on_device``.
        observed: with ``observe``, the observables (``warpchain.observe.ObservedRun``), else None.
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
    observed: "ObservedRun | None" = None  # noqa: F821  (``warpchain.observe``)


def _as_state(x0, N: int) -> np.ndarray:
    """``model.as_batch`` without its scan for non-finite values (``simulate`` runs that check on the
    device, in its guard: on a large batch the host scan alone cost twice the kernel)."""
    arr = np.asarray(x0) if not isinstance(x0, np.ndarray) else x0
    if arr.dtype == np.float64 and arr.ndim == 3 and arr.shape[1:] == (4, N) and arr.shape[0] >= 1:
        return np.ascontiguousarray(arr)
    if arr.dtype == np.float64 and arr.ndim == 2 and arr.shape == (4, N):
        return np.ascontiguousarray(arr[None])
    return as_batch(x0, N, "x0")  # anything else: the full validation, with its messages


@on_one_thread
def simulate(
    params: ChainParams,
    x0,
    t_final: float,
    dt: float,
    *,
    method: str = "verlet",
    device: str | None = None,
    M=None,
    K=None,
    damping: Damping | tuple | None = None,
    record: Record | None = None,
    guard: Guard = Guard(),
    placement: Placement = Placement(),
    observe=None,
    progress: bool = False,
    **deprecated,
) -> SimulationResult:
    """Integrate a batch of lattices with a float64 Warp kernel.

    Args:
        params: the chain (N, boundary, and M, K unless given per lattice).
        x0: initial state, shape (4, N) (a batch of one) or (batch, 4, N), ordered (u, v, u', v'); or a
            ``DeviceState`` (e.g. an earlier result's ``x`` with ``Placement(keep_on_device=True)``), copied
            device to device.
        t_final: final time (>= 0). When it is not a whole multiple of ``dt`` the step is
            shortened slightly so that it is; the result reports the step used.
        dt: time step (> 0), below the method's linear stability limit.
        method: a splitting method's name in ``METHODS`` (``verlet``, ``yoshida4``, ``yoshida6``, ``kahan8``, ...;
            RK4 runs on ``warpchain.reference`` only).
        device: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``; None picks CUDA when Warp sees a GPU (or, for a
            ``DeviceState`` x0, the device it lives on).
        M, K: per-lattice parameters, shape (batch,), so that a sweep runs in one launch.
        damping: losses (``losses.Damping`` or a (contact, substrate) pair of rates, scalars or per
            lattice), splitting methods only. Energy then decays; the guard flags a lattice whose
            energy *grows* by more than ``guard.max_energy_error`` (relative), which no lossy run can do.
        record: what to record (``Record``: every how many steps, into which arrays, with which callback);
            None records nothing but the energy trace.
        guard: the energy guard after every chunk (``Guard``: the bound, the step-size check, the chunks).
        placement: kernel layout and whether the final state stays on the device (``Placement``).
        observe: a ``warpchain.Observation``: reduce its observables on the device every ``frame_every`` steps
            (the step is shortened so that t_final > 0 is a whole number of frames; splitting methods, not with
            ``record``; every layout, a lattice given as a table in the sites layout with the table's peak rule),
            returned as ``result.observed``.
            The guard then also bounds every frame's energy plus what the losses took.
        progress: show a tqdm progress bar.
        **deprecated: the flat keywords of earlier releases (``save_every``, ``frames_out``, ``on_chunk``,
            ``max_energy_error``, ``allow_unstable_step``, ``chunks``, ``layout``, ``keep_on_device``), folded
            into the options with a ``DeprecationWarning`` (``warpchain.options``).

    Returns:
        SimulationResult.

    Raises:
        ValueError: bad input (shape, non-finite values, dt, t_final, method, device).
        StepSizeError: dt above the linear stability limit.
        IntegrationError: the state became non-finite or the energy error exceeded its bound.
    """
    guard = Guard() if guard is None else guard  # None means the defaults, also beside a flat keyword
    placement = Placement() if placement is None else placement
    if deprecated:
        record, guard, placement = from_legacy(deprecated, record, guard, placement)
    for name, value, cls in (("record", record, Record), ("guard", guard, Guard), ("placement", placement, Placement)):
        if value is not None and not isinstance(value, cls):
            raise TypeError(f"simulate(): {name} must be a warpchain.{cls.__name__}, got {type(value).__name__}")
    run = _Run(params, x0, t_final, dt, method, device, M, K, damping, record, guard, placement, observe, progress)
    return run.execute()


def chunk_plan(nsteps: int, unit: int, n_chunks: int, frames_cap: int | None, lag_step: int | None) -> list:
    """(first step, steps, frames) of each chunk of a run of ``nsteps`` steps: chunks of a whole number of ``unit``
    steps (the save or frame interval), about ``n_chunks`` of them, at most ``frames_cap`` frames each when recording
    (what fits the host staging buffers), and a chunk end at ``lag_step`` (where observe reads the lag envelope)."""
    units_total = max(1, math.ceil(nsteps / unit))
    units_per_chunk = max(1, math.ceil(units_total / n_chunks))
    if frames_cap is not None:
        units_per_chunk = min(units_per_chunk, frames_cap)
    plan = []
    for first in range(0, nsteps, units_per_chunk * unit):
        steps = min(units_per_chunk * unit, nsteps - first)
        if lag_step is not None and first < lag_step < first + steps:
            plan.append((first, lag_step - first, 0))
            first, steps = lag_step, first + steps - lag_step
        plan.append((first, steps, steps // unit if frames_cap is not None else 0))
    return plan


class _Run:
    """One ``simulate`` call as a run loop. ``__init__`` turns the request into what runs (the method, the step,
    the device, the chunk plan) and fails on bad input before any device work; ``execute`` holds the loop: it
    queues chunk i + 1 on the device (``_enqueue``) while the host checks chunk i (``_check``: the guard's energy,
    finite flag and contact), takes its frames, and returns the result (``_result``). The state moves in lattice
    slices for a large batch (``hostmem._SlicedTransfers``), or stays on the device (``DeviceState``)."""

    def __init__(
        self, params, x0, t_final, dt, method, device, M, K, damping, record, guard, placement, observe, progress
    ):
        self.start = time.perf_counter()
        self.params, self.observe, self.progress = params, observe, progress
        self.save_every = record.every if record is not None else None
        frames_out = record.into if record is not None else None
        self.on_chunk = record.on_chunk if record is not None else None
        self.max_energy_error, chunks = guard.max_energy_error, guard.chunks
        layout, self.keep_on_device = placement.layout, placement.keep_on_device
        self.meth = meth = engine_method(method)
        self.resident = isinstance(x0, DeviceState)  # x0 in device memory: no transfer at all
        if self.resident:
            device = x0.device_for(params.N, device)
        else:
            x0 = _as_state(x0, params.N)  # the check for non-finite values runs on the device (the guard)
        self.x0 = x0
        self.batch = batch = x0.shape[0]
        self.Mb, self.Kb = per_lattice_parameters(params, batch, M, K)
        self.damping = as_damping(damping)
        if self.damping is not None:
            self.damping.per_lattice(batch)  # validated here, at the boundary
        t_final = real_number("t_final", t_final, nonnegative=True)
        checked = (M if M is None else self.Mb, K if K is None else self.Kb, guard.allow_unstable_step)
        if observe is None:
            self.limit = check_step(meth, params, dt, *checked)
        dt = real_number("dt", dt, positive=True)
        self.device = device = resolve_device(device)
        self.nsteps, self.dt_used = nsteps, dt_used = steps_for(t_final, dt)
        self.frame_every = 0
        lag_step = None
        if observe is not None:
            if record is not None:
                raise ValueError("simulate(): observe and record are exclusive (observables replace the fields)")
            if t_final <= 0:
                raise ValueError(f"simulate(): observe needs t_final > 0, got {t_final!r}")
            self.frame_every = observe.validated(batch).frame_every
            n_frames = max(1, math.ceil(nsteps / self.frame_every - 1e-9))  # whole frames, no longer a step
            self.nsteps = nsteps = n_frames * self.frame_every
            self.dt_used = dt_used = t_final / nsteps
            self.limit = check_step(meth, params, dt_used, *checked)  # the step that runs
            lag_step = (n_frames - min(observe.lag_frames, n_frames)) * self.frame_every  # the envelope is kept here
        self.layout = layout
        if frames_out is not None:
            frames_out = _check_frames_out(
                frames_out, self.save_every, nsteps, batch, params.N, None if self.resident else x0
            )
        self.frames_out = frames_out
        if self.save_every is not None and self.save_every > max(nsteps, 1):
            raise ValueError(
                f"Record.every = {self.save_every} is larger than the run ({nsteps} steps of {dt_used:.6g}): "
                f"no frame after t = 0 would be saved; use every <= {max(nsteps, 1)}"
            )
        self.lag_step = lag_step
        # chunk length: a whole number of save intervals, at least Tuning.chunk_work force evaluations of the whole
        # batch (launch, guard and transfer costs stay small against the kernel), at most 10 chunks (50 with a
        # progress bar), and, when recording, at most the frames that fit the host staging buffers
        work = batch * params.N * max(nsteps, 1) * meth.force_evaluations
        tuning = active()
        n_chunks = chunks or max(1, min(50 if progress else 10, math.ceil(work / tuning.chunk_work)))
        large = x0.size >= tuning.sliced_min_values and (device != "cpu" or tuning.slice_on_cpu)
        # a large batch from and to the host: the state moved in slices, overlapped with the first and last chunk
        self.sliced = large and not (self.resident or self.keep_on_device) and nsteps > 0
        # a short run on a large batch: two chunks, whether its state moves or stays on the device (a run
        # continued on the device has the chunks, hence the energy trace, of the same run from a plain x0)
        short = large and chunks is None and not progress
        if short and nsteps * meth.force_evaluations <= tuning.short_run_evaluations:
            n_chunks = min(n_chunks, tuning.short_run_chunks)
        cap = _frames_per_chunk(batch, params.N) if self.save_every else None
        self.plan = chunk_plan(nsteps, self.save_every or self.frame_every or 1, n_chunks, cap, lag_step)
        self.gpu = device != "cpu"

    # ------------------------------------------------------------------ the loop

    def execute(self) -> SimulationResult:
        params, x0, plan, device = self.params, self.x0, self.plan, self.device
        t_runner = time.perf_counter()
        runner = _pooled_runner(self.meth, params, x0, self.Mb, self.Kb, device, self.layout, upload=False)
        self.runner = runner  # x0 is uploaded below
        runner.set_damping(self.damping, self.dt_used)
        self.frames = None
        if self.observe is not None:  # the observation makes its device side (``observe._Frames``)
            self.frames = self.observe.frames(runner, self.nsteps // self.frame_every)
        t_runner = time.perf_counter() - t_runner
        wp = runner.wp
        self.final = DeviceState.empty(x0.shape, device) if self.keep_on_device else None  # behind the last chunk
        target = None  # else the final state's host array, touched in the background once the device is busy
        guard = self.guard = _GuardReader.of(runner, self.gpu)
        transfers = self.transfers = _SlicedTransfers(runner, x0, slice_bounds(self.batch)) if self.sliced else None
        if not plan:
            runner.upload(x0)
            self.E0, finite0, self.contact = (a.copy() for a in guard.read(runner.guard(), 0))  # of x0, on the device
            if not finite0.all():
                guard.close()
                raise ValueError(f"x0 has non-finite entries in lattice(s) {np.flatnonzero(~finite0).tolist()}")
        else:
            # the start's guard (energy, finite flag, contact of x0) is queued with chunk 0 and read after it,
            # so the host never waits for the device before the first kernel runs
            self.E0 = self.contact = None
        self.trace_t, self.trace_E = [0.0], [self.E0]
        self.max_err = np.zeros(self.batch)

        sink = self.sink = None
        save_every = self.save_every
        if save_every:
            self.n_saved = 1 + self.nsteps // save_every
            sink = self.sink = _FrameSink(
                runner, self.n_saved, max(p[2] for p in plan) if plan else 0, self.gpu, out=self.frames_out
            )
            sink.put_initial(x0.numpy() if self.resident else x0)
            if self.on_chunk is not None:
                self.on_chunk(np.array([0.0]), *sink.view(0, 1))

        bar = None
        if self.progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=self.nsteps, desc=f"{self.meth.name} dt={self.dt_used:.4g}", unit="step", leave=False)

        saved = 1
        stats = self.stats = {"chunks": len(plan), "runner": t_runner, "waiting": 0.0, "frames": 0.0, "final": 0.0}
        stats["slices"] = len(transfers.slices) if self.sliced else 1
        stats["x0_on_device"], stats["kept_on_device"] = self.resident, bool(self.keep_on_device)
        if runner.layout == "block":
            lattices = transfers.slices[0][1] if self.sliced else self.batch
            stats["sites_per_thread"] = sites_per_thread(lattices, params.N, self.meth.stages, device)
        failed = False
        try:
            if plan:
                if not self.sliced:
                    runner.upload(x0)
                self._enqueue(0)
            stats["setup"] = time.perf_counter() - self.start
            if self.gpu and self.final is None and x0.size >= active().prefault_min_values:
                target = _prefault(x0.shape)
            for i, (first, steps, n_rec) in enumerate(plan):
                if i + 1 < len(plan):
                    self._enqueue(i + 1)  # the device works on the next chunk while the host checks this one
                if self.sliced and i == len(plan) - 1:
                    if target is not None:
                        target.join()
                    out = target.result if target is not None else np.empty(x0.shape)
                    t0 = time.perf_counter()
                    for s_ in range(len(transfers.slices)):
                        transfers.take(s_, out)  # while the device finishes the later slices
                    stats["final"] += time.perf_counter() - t0
                t0 = time.perf_counter()
                E, finite, low = guard.wait(i)
                stats["waiting"] += time.perf_counter() - t0
                if i == 0:
                    self.E0, finite0, _ = guard.init()
                    if not finite0.all():
                        raise ValueError(f"x0 has non-finite entries in lattice(s) {np.flatnonzero(~finite0).tolist()}")
                    self.trace_E[0] = self.E0
                self._check(i, E, finite, low)
                if n_rec:
                    t0 = time.perf_counter()
                    sink.take(i, saved, n_rec)
                    stats["frames"] += time.perf_counter() - t0
                    if self.on_chunk is not None:
                        ts = (np.arange(1, n_rec + 1) * save_every + first) * self.dt_used
                        self.on_chunk(ts, *sink.view(saved, saved + n_rec))
                    saved += n_rec
                if bar is not None:
                    bar.update(steps)
        except BaseException:
            failed = True
            raise
        finally:
            if bar is not None:
                bar.close()
            if self.gpu:
                wp.synchronize_device(device)  # no copy into the staging buffers is left in flight
            guard.close()
            if sink is not None:
                sink.close()
            if transfers is not None:
                transfers.close()
            if target is not None:
                target.join()
            if failed:
                _release_runner(runner)  # the device is idle (synchronised above): its buffers serve the next call
        t0 = time.perf_counter()
        if self.final is not None:
            if not plan:
                runner.enqueue_download(self.final)
                wp.synchronize_device(device)
            x = self.final  # the device wrote it (and the finally waited for that)
        elif self.sliced:
            x = out  # the slices were taken into it
        else:
            x = runner.download(target.result if target is not None else None)
        stats["final"] += time.perf_counter() - t0
        return self._result(x)

    def _enqueue(self, i: int) -> None:
        """Queue chunk i on the device: kernel, guard, and the copies of its scalars and frames."""
        runner, guard, frames, transfers = self.runner, self.guard, self.frames, self.transfers
        first, steps, n_rec = self.plan[i]
        last = len(self.plan) - 1
        rec = self.sink.rec if n_rec else None
        observer = frames.at(first) if frames is not None else None
        if self.sliced and (i == 0 or i == last):
            for s, lattices in enumerate(transfers.slices):
                if i == 0:
                    transfers.upload(s)
                    runner.guard(slot=2, lattices=lattices)  # the start: energy, finite, contact
                runner.launch(steps, self.dt_used, self.save_every or 0, rec, lattices=lattices, observer=observer)
                if i == last:
                    transfers.download(s)
            if i == 0:
                guard.enqueue_init(runner.guard_out[2])
        else:
            if i == 0:
                runner.guard(slot=2)
            runner.launch(steps, self.dt_used, self.save_every or 0, rec, observer=observer)
            if i == 0:
                guard.enqueue_init(runner.guard_out[2])  # after the kernel's launch: it need not wait for this
        if frames is not None:
            if first + steps == self.lag_step:
                frames.keep_lag()
            frames.enqueue_copy(first // self.frame_every, (first + steps) // self.frame_every)
        guard.enqueue(runner.guard(rec, n_rec, i), i)
        if n_rec:
            self.sink.enqueue(n_rec, i, 1 + first // self.save_every)
        guard.record(i)
        if i == last and self.final is not None:
            runner.enqueue_download(self.final)  # device to device, right behind the last chunk

    def _check(self, i: int, E, finite, low) -> None:
        """Chunk i's guard on the host: trace the energy, raise on a blow-up."""
        first, steps, _ = self.plan[i]
        t_now = (first + steps) * self.dt_used
        change = _signed_energy_change(E, self.E0, self.params.N)  # lattices with losses: only growth is an error
        err = np.where(self.runner.lossy_host, np.maximum(change, 0.0), np.abs(change))
        if self.frames is not None:  # and the chunk's frames: energy plus what the losses took, both signs
            fe = self.frame_every
            balance, frames_finite = self.frames.balance(first // fe, (first + steps) // fe)
            err, finite = np.maximum(err, balance), finite & frames_finite
        err = np.where(finite, err, np.inf)
        self.max_err = np.maximum(self.max_err, err)
        self.trace_t.append(t_now)
        self.trace_E.append(E.copy())
        bound = self.max_energy_error
        bad = ~finite | ((err > bound) if bound is not None else False)
        if np.any(bad):
            if self.gpu:
                self.runner.wp.synchronize_device(self.device)  # the next chunk may still be running; let it finish
            failed = np.flatnonzero(bad).tolist()
            what = "non-finite state" if not finite.all() else f"energy error above {bound:g}"
            name, dt, limit = self.meth.name, self.dt_used, self.limit
            raise IntegrationError(
                f"integration blew up ({what}) at t = {t_now:.6g} with method '{name}', "
                f"dt = {dt:.6g} (linear stability limit {limit:.6g}); failing lattices: {failed[:20]}"
                + (" ..." if len(failed) > 20 else "")
                + f"; largest relative energy error {np.nanmax(err):.3g}. Reduce dt or choose another method.",
                method=name,
                dt=dt,
                stability_limit=limit,
                failed=failed,
                t=t_now,
            )
        self.contact = low.copy()

    def _result(self, x) -> SimulationResult:
        """The result, once the final state ``x`` is where it goes; the runner goes back to its pool."""
        observed = None
        nsteps, dt_used = self.nsteps, self.dt_used
        if self.frames is not None:  # read before the runner (and its host buffer) serves another call
            how = dict(method=self.meth.name, dt=dt_used, nsteps=nsteps, device=self.device)
            observed = self.frames.result(self.x0, x, wall_seconds=time.perf_counter() - self.start, **how)
        _release_runner(self.runner)
        E0, E1 = self.E0, self.trace_E[-1]
        if self.save_every:
            t_arr = (np.arange(self.n_saved) * self.save_every) * dt_used
            u_arr, v_arr = self.sink.u, self.sink.v
        else:
            t_arr, u_arr, v_arr = np.array([0.0, nsteps * dt_used]), None, None
        return SimulationResult(
            x=x,
            t=t_arr,
            u=u_arr,
            v=v_arr,
            energy_initial=E0,
            energy_final=E1,
            energy_error=np.abs(_signed_energy_change(E1, E0, self.params.N)),
            max_energy_error=self.max_err,
            min_contact=self.contact,
            energy_t=np.array(self.trace_t),
            energy_trace=np.stack(self.trace_E),
            method=self.meth.name,
            dt=dt_used,
            nsteps=nsteps,
            t_final=nsteps * dt_used,
            device=self.device,
            wall_seconds=time.perf_counter() - self.start,
            layout=self.runner.layout,
            stats=self.stats,
            observed=observed,
        )
