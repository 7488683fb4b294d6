"""Observables reduced on the device: large ensembles where only per-lattice scalars reach the host.

``observe`` integrates a batch like ``simulate`` (the same splitting schemes, losses included) but,
instead of fields, returns per lattice and frame a few numbers computed inside the kernel. Every
step the kernel tracks, per site, the lowest and highest relative displacement z_j = u_j - v_j
since the last frame; at each frame (every ``frame_every`` steps) it reduces over the lattice:

* ``peaks``: how many sites are *localized peaks* of the envelope env_j = max |z_j| over the frame
  interval: env_j > ``threshold``; env_j the largest value within ``radius`` sites (strictly larger
  than those on its left, at least as large as those on its right, so a plateau counts once); and
  localized: on *each* side, within ``radius`` sites, the envelope falls to ``contrast`` * env_j or
  below (sites past a chain end count as 0; the window does not wrap around a periodic chain). A
  breather narrower than the window is such a peak; a wide hump that has not broken up (or the
  ripples on it) is none; a filamented spot is several. ``contrast = 1`` drops the localization test.
* ``participation``: (sum_j e_j)^2 / sum_j e_j^2 of the site energies e_j (``kernels.site_energy``):
  about the number of sites that carry the energy.
* ``spot_energy``: sum of e_j over |j - c| <= ``spot`` (c = N // 2, the spot's centre; ``spot`` per
  lattice, in sites).
* ``max_envelope``: max_j env_j.
* ``min_contact``: min over the interval's steps and the sites of 1 + z_j (<= 0: contact lost).
* ``energy``: sum_j e_j at the frame.
* ``dissipated``: energy lost to damping since t = 0 (exact over every damped kick, per site:
  ``losses.kick_dissipation``; ``reference.step(dissipated=...)``), so that ``energy + dissipated`` stays
  the initial energy to the scheme's accuracy, at its order: that is what the guard checks for lattices
  with losses.

The envelope profile of the last frame is kept on the device; ``observe`` reads it once
``lag_frames`` frames before the end and once at the end, and ``peak_tracks`` turns the two into
peak positions, amplitudes and drift velocities on the host. Frame 0 (the initial state, envelope
|z|) is reduced by the kernels too, at the start of the first launch. ``reference_observe`` is the
numpy oracle of all of this (the same steps, the same tracking), against which the kernels are tested.
"""

import dataclasses
import math
import time

import numpy as np

from .engine.devices import on_one_thread, resolve_device, resolve_layout
from .ensemble import IntegrationError, _signed_energy_change
from .integrators import check_step
from .integrators import SplittingMethod, get_method, steps_for
from .losses import Damping, as_damping
from .model import (
    ChainParams,
    as_batch,
    site_energies,
    per_lattice_parameters,
    real_number,
    whole_number,
)

OBSERVABLES = ("peaks", "participation", "spot_energy", "max_envelope", "min_contact", "energy", "dissipated")
N_OBSERVABLES = len(OBSERVABLES)
_ENERGY, _DISSIPATED = OBSERVABLES.index("energy"), OBSERVABLES.index("dissipated")
#: the tracked extremes of z start from these (any real displacement replaces them)
_FAR = 1.0e300


@dataclasses.dataclass(frozen=True)
class Observation:
    """What ``observe`` reduces, and how often.

    Attributes:
        frame_every: steps between frames (the envelope's interval: about a period or more).
        threshold: envelope |z| above which a localized peak counts.
        radius: a peak is the largest envelope value within this many sites, and falls to ``contrast``
            times its value within them on both sides.
        contrast: the localization test's fraction (1: no test).
        spot: half-width in sites of the spot whose energy is reported (scalar or per lattice).
        lag_frames: the envelope profile is also read this many frames before the end (drift velocities).
    """

    frame_every: int
    threshold: float = 0.05
    radius: int = 10
    contrast: float = 0.5
    spot: float | np.ndarray = 0.0
    lag_frames: int = 8

    def validated(self, batch: int) -> "Observation":
        whole_number("frame_every", self.frame_every, minimum=1)
        real_number("threshold", self.threshold, nonnegative=True)
        whole_number("radius", self.radius, minimum=1)
        if not 0.0 < real_number("contrast", self.contrast) <= 1.0:
            raise ValueError(f"contrast must be in (0, 1], got {self.contrast!r}")
        whole_number("lag_frames", self.lag_frames, minimum=1)
        spot = np.broadcast_to(np.asarray(self.spot, dtype=np.float64), (batch,))
        if not np.all(np.isfinite(spot)) or np.any(spot < 0):
            raise ValueError(f"spot must be finite and >= 0, got {self.spot!r}")
        return self


@dataclasses.dataclass(frozen=True)
class ObservedRun:
    """Outcome of ``observe``.

    Attributes:
        t: frame times, shape (n_frames,) (t = 0 first).
        values: observables, shape (n_frames, batch, len(OBSERVABLES)); ``run["peaks"]`` etc. give one.
        envelope: envelope profile of the last frame, shape (batch, N).
        envelope_lag: the same ``t_lag`` earlier (``lag_frames`` frames), shape (batch, N).
        t_lag: the time of ``envelope_lag``'s frame.
        x: final state, shape (batch, 4, N).
        energy_initial: shape (batch,).
        method, dt, nsteps, device, layout, wall_seconds: how it ran.
    """

    t: np.ndarray
    values: np.ndarray
    envelope: np.ndarray
    envelope_lag: np.ndarray
    t_lag: float
    x: np.ndarray
    energy_initial: np.ndarray
    method: str
    dt: float
    nsteps: int
    device: str
    layout: str
    wall_seconds: float

    def __getitem__(self, name: str) -> np.ndarray:
        """One observable, shape (n_frames, batch)."""
        if name not in OBSERVABLES:
            raise KeyError(f"unknown observable {name!r}; choose one of {OBSERVABLES}")
        return self.values[..., OBSERVABLES.index(name)]

    def first_contact_loss(self) -> np.ndarray:
        """Per lattice, the first frame time whose interval lost contact (min contact <= 0); NaN if none."""
        lost = self["min_contact"] <= 0.0
        first = np.argmax(lost, axis=0)
        return np.where(lost.any(axis=0), self.t[first], np.nan)


# ----------------------------------------------------------------------------- numpy reference


def peak_mask(env: np.ndarray, threshold: float, radius: int, contrast: float = 1.0) -> np.ndarray:
    """Localized peaks of envelope profiles env (..., N): the rule of the kernels (module docstring).
    Running extremes over ``radius`` sites on each side, in place (past the chain's ends: -inf for the
    largest-value test, 0 for the localization test)."""
    env = np.asarray(env, dtype=np.float64)
    n = env.shape[-1]
    r = min(int(radius), n)
    j = np.arange(n)
    left_max = np.full_like(env, -np.inf)
    right_max = np.full_like(env, -np.inf)
    left_min = np.broadcast_to(np.where(j < r, 0.0, np.inf), env.shape).copy()  # a window past an end holds 0
    right_min = np.broadcast_to(np.where(j >= n - r, 0.0, np.inf), env.shape).copy()
    for i in range(1, r + 1):
        if i >= n:
            break
        np.maximum(left_max[..., i:], env[..., :-i], out=left_max[..., i:])
        np.maximum(right_max[..., :-i], env[..., i:], out=right_max[..., :-i])
        np.minimum(left_min[..., i:], env[..., :-i], out=left_min[..., i:])
        np.minimum(right_min[..., :-i], env[..., i:], out=right_min[..., :-i])
    mask = (env > threshold) & (env > left_max) & (env >= right_max)
    return mask & (left_min <= contrast * env) & (right_min <= contrast * env)


def frame_observables(
    params, x, z_low, z_high, M, K, observation: Observation, dissipated=0.0
) -> tuple[np.ndarray, np.ndarray]:
    """The observables of one frame from the state x (batch, 4, N), the interval's z extremes
    (batch, N) and the energy dissipated so far (batch,). Returns (values (batch, len(OBSERVABLES)),
    envelope (batch, N))."""
    env = np.maximum(z_high, -z_low)
    e = site_energies(params, x, M, K)
    n = x.shape[-1]
    spot = np.broadcast_to(np.asarray(observation.spot, dtype=np.float64), (x.shape[0],))
    inside = np.abs(np.arange(n)[None, :] - n // 2) <= spot[:, None]
    total = e.sum(axis=-1)
    squares = (e * e).sum(axis=-1)
    out = np.empty((x.shape[0], N_OBSERVABLES))
    out[:, 0] = peak_mask(env, observation.threshold, observation.radius, observation.contrast).sum(axis=-1)
    out[:, 1] = np.where(squares > 0, total * total / np.where(squares > 0, squares, 1.0), 0.0)
    out[:, 2] = np.where(inside, e, 0.0).sum(axis=-1)
    out[:, 3] = env.max(axis=-1)
    out[:, 4] = (1.0 + z_low).min(axis=-1)
    out[:, 5] = total
    out[:, 6] = dissipated
    return out, env


def reference_observe(
    method, params: ChainParams, x0, dt: float, nsteps: int, observation: Observation, M=None, K=None, damping=None
):
    """``observe``'s numpy oracle: the same scheme (``reference.step``) and the same tracking.

    Returns:
        (values (n_frames, batch, len(OBSERVABLES)), envelope of the last frame (batch, N), final state).
    """
    from . import reference

    x = np.array(x0, dtype=np.float64)
    batch = x.shape[0]
    Mb, Kb = per_lattice_parameters(params, batch, M, K)
    lost = np.zeros(batch)
    z = x[:, 0] - x[:, 1]
    first, env = frame_observables(params, x, z, z, Mb, Kb, observation)
    frames = [first]
    low = np.full_like(z, _FAR)
    high = np.full_like(z, -_FAR)
    for n in range(nsteps):
        x = reference.step(method, params, x, dt, Mb, Kb, damping=damping, dissipated=lost)
        z = x[:, 0] - x[:, 1]
        low, high = np.minimum(low, z), np.maximum(high, z)
        if (n + 1) % observation.frame_every == 0:
            values, env = frame_observables(params, x, low, high, Mb, Kb, observation, lost.copy())
            frames.append(values)
            low = np.full_like(z, _FAR)
            high = np.full_like(z, -_FAR)
    return np.stack(frames), env, x


def peak_tracks(env_lag, env_end, dt_lag: float, observation: Observation, max_speed: float, max_peaks: int = 32):
    """Peaks at the end, their amplitudes and drift velocities from two envelope profiles (vectorised
    over the batch: no Python loop per lattice).

    Each peak of ``env_end`` (positions refined by a parabola through the peak and its neighbours) is
    matched with the nearest peak of ``env_lag`` when they are each other's nearest and at most
    ``max_speed * dt_lag`` sites apart; velocity = displacement / dt_lag (sites per unit time), NaN when
    there is no such match (a peak born, merged or gone within the lag).

    Args:
        env_lag, env_end: envelope profiles (batch, N), ``dt_lag`` apart in time.
        max_peaks: columns of the result; a lattice's peaks past it (in site order) are dropped. Peaks
            are ``radius`` sites apart or more, so N / radius + 1 columns always suffice.

    Returns:
        (position, amplitude, velocity), each (batch, max_peaks), peaks in site order, NaN padded;
        positions in sites (0-based).
    """

    def located(env):
        env = np.asarray(env, dtype=np.float64)
        batch, n = env.shape
        mask = peak_mask(env, observation.threshold, observation.radius, observation.contrast)
        b, j = np.nonzero(mask)  # row-major: lattice by lattice, in site order
        slot = np.arange(b.size) - np.searchsorted(b, b)  # the peak's rank within its lattice
        keep = slot < max_peaks
        b, j, slot = b[keep], j[keep], slot[keep]
        pos = j.astype(float)
        inner = (j > 0) & (j < n - 1)
        left = env[b, np.maximum(j - 1, 0)]
        mid = env[b, j]
        right = env[b, np.minimum(j + 1, n - 1)]
        curv = left - 2 * mid + right
        ok = inner & (curv < 0)
        shift = np.zeros_like(pos)
        shift[ok] = 0.5 * (left[ok] - right[ok]) / curv[ok]
        pos = pos + np.clip(shift, -0.5, 0.5)
        positions = np.full((batch, max_peaks), np.nan)
        amplitudes = np.full((batch, max_peaks), np.nan)
        positions[b, slot] = pos
        amplitudes[b, slot] = mid
        return positions, amplitudes

    p0, _ = located(env_lag)
    p1, amp = located(env_end)
    gap = np.abs(p1[:, :, None] - p0[:, None, :])  # (batch, end peaks, lag peaks)
    gap = np.where(np.isnan(gap), np.inf, gap)
    nearest_lag = np.argmin(gap, axis=2)  # (batch, end peaks)
    nearest_end = np.argmin(gap, axis=1)  # (batch, lag peaks)
    back = np.take_along_axis(nearest_end, nearest_lag, axis=1)  # the lag peak's nearest end peak
    d = np.take_along_axis(gap, nearest_lag[:, :, None], axis=2)[..., 0]
    matched = (back == np.arange(p1.shape[1])[None, :]) & (d <= max_speed * dt_lag) & np.isfinite(d)
    start = np.take_along_axis(p0, nearest_lag, axis=1)
    velocity = np.where(matched, (p1 - start) / dt_lag, np.nan)
    return p1, amp, velocity


# ----------------------------------------------------------------------------- driver


@on_one_thread
def observe(
    params: ChainParams,
    x0,
    t_final: float,
    dt: float,
    *,
    observation: Observation,
    method: str = "verlet",
    damping: Damping | tuple | None = None,
    M=None,
    K=None,
    device: str | None = None,
    layout: str = "auto",
    chunks: int | None = None,
    progress: bool = False,
    max_energy_error: float | None = 0.05,
) -> ObservedRun:
    """Integrate a batch and reduce the observables on the device (module docstring).

    Args:
        params, x0, dt, method, M, K, device, layout: as ``simulate`` (splitting methods only).
        t_final: final time, kept; the step is shortened (never lengthened) so that t_final is a whole
            number of frames of ``observation.frame_every`` steps (the result reports the step used).
        observation: what to reduce and how often.
        damping: losses (``losses.Damping`` or a (contact, substrate) pair; per lattice allowed).
        chunks: launches the run is split into (progress and guard points; default 20).
        max_energy_error: relative change of energy + dissipated energy that counts as a blow-up.

    Returns:
        ObservedRun.

    Raises:
        ValueError: bad input. StepSizeError: dt above the stability limit.
        IntegrationError: non-finite state or energy error above the bound (names method, dt, limit).
    """
    from .engine.devices import _warp
    from .engine.runner import _pooled_runner, _release_runner
    from .engine.thread_kernels import Observer

    wp = _warp()
    start = time.perf_counter()
    meth = get_method(method)
    if not isinstance(meth, SplittingMethod):
        raise ValueError(f"observe runs the splitting methods; {meth.name!r} is not one (choose verlet, yoshida4, ...)")
    x0 = as_batch(x0, params.N, "x0")
    batch = x0.shape[0]
    Mb, Kb = per_lattice_parameters(params, batch, M, K)
    observation = observation.validated(batch)
    damping = as_damping(damping)
    t_final = real_number("t_final", t_final, positive=True)
    if chunks is not None:
        chunks = whole_number("chunks", chunks, minimum=1)
    if max_energy_error is not None:
        max_energy_error = real_number("max_energy_error", max_energy_error, positive=True)
    device = resolve_device(device)
    layout = "block" if resolve_layout(layout, device, params.N) == "block" else "thread"
    fe = observation.frame_every
    nsteps, dt_used = steps_for(t_final, real_number("dt", dt, positive=True))
    n_frames = max(1, math.ceil(nsteps / fe - 1e-9))  # whole frames, the step no longer than asked
    nsteps = n_frames * fe
    dt_used = t_final / nsteps
    limit = check_step(meth, params, dt_used, Mb, Kb, False)
    lag = min(observation.lag_frames, n_frames)

    # the engine's runner (state, parameters, losses, launches; on a GPU one kept from an earlier call of this
    # shape, its buffers reused); the observables in an ``Observer``
    runner = _pooled_runner(meth, params, x0, Mb, Kb, device, layout)
    runner.set_damping(damping, dt_used)
    f64 = wp.float64
    shape = (batch, params.N)
    spot = np.broadcast_to(np.asarray(observation.spot, dtype=np.float64), (batch,))
    kept = {
        "spot": wp.array(spot, dtype=f64, device=device),
        "z_low": wp.empty(shape, dtype=f64, device=device),  # the tracked z extremes (set at frame 0)
        "z_high": wp.empty(shape, dtype=f64, device=device),
        # the energy dissipated so far: per site (block layout) or per lattice (thread layout), across launches
        "lost": wp.zeros((batch, params.N if layout == "block" else 1), dtype=f64, device=device),
        "envelope": wp.zeros(shape, dtype=f64, device=device),
    }
    obs = wp.zeros((n_frames + 1, batch, N_OBSERVABLES), dtype=f64, device=device)

    def launch(first, steps):
        def observer(lo, hi):
            ob = Observer()
            ob.first_step, ob.frame_every, ob.radius = int(first), fe, int(observation.radius)
            ob.threshold, ob.contrast = f64(observation.threshold), f64(observation.contrast)
            for name, array in kept.items():
                setattr(ob, name, array[lo:hi])
            ob.values = obs[:, lo:hi]
            return ob

        runner.launch(int(steps), dt_used, observer=observer)

    # chunks: whole frames; the last `lag` frames form their own chunk so that the envelope is read there
    n_chunks = chunks or 20
    main_frames = n_frames - lag
    bounds = [0]
    if main_frames > 0:
        per = max(1, math.ceil(main_frames / max(1, n_chunks - 1)))
        bounds += list(range(per, main_frames, per)) + [main_frames]
    bounds.append(n_frames)
    bounds = sorted(set(bounds))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n_frames, desc=f"observe {meth.name} x{batch}", unit="frame", leave=False)
    env_lag = np.abs(x0[:, 0] - x0[:, 1]) if main_frames == 0 else None  # frame 0's envelope
    values = np.empty((n_frames + 1, batch, N_OBSERVABLES))
    E0 = None
    try:
        for a, b in zip(bounds[:-1], bounds[1:]):
            launch(a * fe, (b - a) * fe)  # frames a + 1 .. b (and frame 0 with the first)
            values[a : b + 1] = obs[a : b + 1].numpy()
            if E0 is None:
                E0 = values[0, :, _ENERGY].copy()
            if b == main_frames:
                env_lag = kept["envelope"].numpy().copy()
            E = (
                values[b, :, _ENERGY] + values[b, :, _DISSIPATED]
            )  # plus what the losses took: E(0), to the scheme's accuracy
            finite = np.isfinite(values[a : b + 1]).all(axis=(0, 2))
            err = np.where(finite, np.abs(_signed_energy_change(E, E0, params.N)), np.inf)
            bad = ~finite | ((err > max_energy_error) if max_energy_error is not None else False)
            if np.any(bad):
                failed = np.flatnonzero(bad).tolist()
                t_now = b * fe * dt_used
                what = "non-finite state" if not finite.all() else f"energy error above {max_energy_error:g}"
                raise IntegrationError(
                    f"integration blew up ({what}) at t = {t_now:.6g} with method '{meth.name}', dt = {dt_used:.6g} "
                    f"(linear stability limit {limit:.6g}); failing lattices: {failed[:20]}. Reduce dt.",
                    method=meth.name,
                    dt=dt_used,
                    stability_limit=limit,
                    failed=failed,
                    t=t_now,
                )
            if bar is not None:
                bar.update(b - a)
        envelope, x = kept["envelope"].numpy().copy(), runner.x.numpy().copy()
    finally:
        if bar is not None:
            bar.close()
        _release_runner(runner)  # back to the pool (a GPU's), its buffers for the next call of this shape
    return ObservedRun(
        t=np.arange(n_frames + 1) * fe * dt_used,
        values=values,
        envelope=envelope,
        envelope_lag=env_lag,
        t_lag=(n_frames - lag) * fe * dt_used,
        x=x,
        energy_initial=E0,
        method=meth.name,
        dt=dt_used,
        nsteps=nsteps,
        device=device,
        layout=layout,
        wall_seconds=time.perf_counter() - start,
    )
