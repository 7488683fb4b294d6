"""Observables reduced on the device: large ensembles where only per-lattice scalars reach the host.

``simulate(..., observe=Observation(...))`` (or ``observe``, which returns just the observables) integrates a
batch with the same splitting kernels, chunks and guard as any run (losses included) but, instead of fields,
returns per lattice and frame a few numbers computed on the device (hooks compiled into the engine's
splitting kernels: ``thread_kernels.observed_splitting_kernel``, ``block_kernels`` ``observed``; in the sites
layout ``site_kernels.evaluate`` tracks and ``site_kernels.observe_frame`` reduces). Every
step the kernel tracks, per site, the lowest and highest relative displacement z_j = u_j - v_j
since the last frame; at each frame (every ``frame_every`` steps) it reduces over the lattice:

* ``peaks``: how many sites are *localized peaks* of the envelope env_j = max |z_j| over the frame
  interval: env_j > ``threshold``; env_j the largest value within ``radius`` sites (strictly larger
  than those on its left, at least as large as those on its right, so a plateau counts once); and
  localized: on *each* side, within ``radius`` sites, the envelope falls to ``contrast`` * env_j or
  below (sites past a chain end count as 0; the window does not wrap around a periodic chain). A
  breather narrower than the window is such a peak; a wide hump that has not broken up (or the
  ripples on it) is none; a filamented spot is several. ``contrast = 1`` drops the localization test.
* ``participation``: (sum_j e_j)^2 / sum_j e_j^2 of the site energies e_j (``site.site_energy``):
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

On a lattice given as a table (``warpchain.lattice.LatticeParams``: the square and triangular monolayers) the same
numbers with the table's neighbourhoods (``reference.table_peak_mask``): the window is the ball of ``radius`` bonds
(lower-indexed sites strictly below, higher ones at most equal), the localization test runs along each bonded slot
direction (a step past a wall or a free edge reads 0; a periodic patch's rays wrap), the site energies hold the bonds
of ``site.table_bonds``, and the spot is the disc of radius ``spot`` (in lattice spacings) about the centre site.

The envelope profile of the last frame is kept on the device, copied there ``lag_frames`` frames before
the end (a chunk ends at that frame) and read with the one at the end; ``peak_tracks`` turns the two into
peak positions, amplitudes and drift velocities on the host (along a chain: on a 2-D lattice the envelopes are
the table's sites, and ``reference.table_peak_mask`` finds their peaks). Frame 0 (the initial state, envelope
|z|) is reduced by the kernels too, at the start of the first launch. ``reference.observe`` is the
numpy oracle of all of this (the same steps, the same tracking), against which the kernels are tested.
"""

import dataclasses

import numpy as np

from .engine.devices import on_one_thread
from .losses import Damping
from .reference import N_OBSERVABLES, OBSERVABLES, peak_mask  # noqa: F401  (the observables' names, re-exported)
from .model import (
    ChainParams,
    _signed_energy_change,
    real_number,
    whole_number,
)

_ENERGY, _DISSIPATED = OBSERVABLES.index("energy"), OBSERVABLES.index("dissipated")


@dataclasses.dataclass(frozen=True)
class Observation:
    """What ``observe`` reduces, and how often.

    Attributes:
        frame_every: steps between frames (the envelope's interval: about a period or more).
        threshold: envelope |z| above which a localized peak counts.
        radius: a peak is the largest envelope value within this many sites (bonds on a lattice), and falls to
            ``contrast`` times its value within them on both sides (along every bonded direction on a lattice).
        contrast: the localization test's fraction (1: no test).
        spot: half-width in sites of the spot whose energy is reported, about site N // 2 (on a lattice the radius
            of a disc about the centre site, in lattice spacings); scalar or per lattice.
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

    def frames(self, runner, n_frames: int) -> "_Frames":
        """The device side of one run that ``simulate`` drives (``_Frames``): asked of the observation, so that
        the engine's driver needs no import of this module (which calls ``simulate``)."""
        return _Frames(runner, self, n_frames)


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


def peak_tracks(
    env_lag, env_end, dt_lag: float, observation: Observation, max_speed: float, max_peaks: int = 32, lattice=None
):
    """Peaks at the end, their amplitudes and drift velocities from two envelope profiles along a chain (vectorised
    over the batch: no Python loop per lattice). ``lattice``: the envelopes' geometry, when known; a 2-D one is
    refused (its peaks are ``reference.table_peak_mask``'s, its positions the lattice's).

    Each peak of ``env_end`` (positions refined by a parabola through the peak and its neighbours) is
    matched with the nearest peak of ``env_lag`` when they are each other's nearest and at most
    ``max_speed * dt_lag`` sites apart; velocity = displacement / dt_lag (sites per unit time), NaN when
    there is no such match (a peak born, merged or gone within the lag).

    Args:
        env_lag, env_end: envelope profiles (batch, N), ``dt_lag`` apart in time.
        max_peaks: columns of the result; a lattice's peaks past it (in site order) are dropped. Peaks
            are ``radius`` sites apart or more, so N / radius + 1 columns always suffice.
        lattice: a ``warpchain.lattice.Lattice`` (or None): anything but a chain raises ValueError.

    Returns:
        (position, amplitude, velocity), each (batch, max_peaks), peaks in site order, NaN padded;
        positions in sites (0-based).
    """

    if lattice is not None and lattice.name != "chain":
        raise ValueError(
            f"peak_tracks follows peaks along a chain; these envelopes are a {lattice.name} lattice's sites: find "
            "their peaks with warpchain.reference.table_peak_mask(lattice, envelope, ...), their places in "
            "lattice.positions"
        )

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


class _Frames:
    """The device side of ``simulate(..., observe=...)``: one run's observables and tracking buffers on the device
    (kept across its chunks) and the ``site.Observer`` a chunk's launch hands the observed kernels."""

    def __init__(self, runner, observation: Observation, n_frames: int):
        wp, f64 = runner.wp, runner.wp.float64
        shape = (runner.batch, runner.N)
        self.wp, self.observation, self.layout = wp, observation, runner.layout
        spot = np.broadcast_to(np.asarray(observation.spot, dtype=np.float64), (runner.batch,))
        self.kept = {
            "spot": wp.array(spot, dtype=f64, device=runner.device),
            "z_low": wp.empty(shape, dtype=f64, device=runner.device),  # the tracked z extremes (set at frame 0)
            "z_high": wp.empty(shape, dtype=f64, device=runner.device),
            # the energy dissipated so far: per site (block, sites layouts) or per lattice (thread), across launches
            "lost": wp.zeros(
                (runner.batch, runner.N if runner.layout in ("block", "sites") else 1), dtype=f64, device=runner.device
            ),
            "envelope": wp.zeros(shape, dtype=f64, device=runner.device),
        }
        self.values = wp.zeros((n_frames + 1, runner.batch, N_OBSERVABLES), dtype=f64, device=runner.device)
        self.lag = None  # the envelope lag_frames before the end (``keep_lag``)
        # the frames on the host, each chunk's copied behind its kernel (on a GPU a page-locked buffer kept with the
        # runner, its size a power of two so that runs of other lengths share it; on the CPU the device array itself)
        self.host = self.values
        if runner.device != "cpu":
            self.host = runner.host_buffer("observed frames", 1 << (self.values.size - 1).bit_length())
        self.host_values = self.host.numpy()[: self.values.size].reshape(self.values.shape)
        self.n_sites = runner.N

    def at(self, first_step: int):
        """The observers of a launch that starts at ``first_step``: a function of the lattices (lo, hi)."""
        from .engine.site import Observer

        f64, observation = self.wp.float64, self.observation

        def observer(lo, hi):
            ob = Observer()
            ob.first_step, ob.frame_every, ob.radius = int(first_step), observation.frame_every, observation.radius
            ob.threshold, ob.contrast = f64(observation.threshold), f64(observation.contrast)
            for name, array in self.kept.items():
                setattr(ob, name, array[lo:hi])
            ob.values = self.values[:, lo:hi]
            return ob

        return observer

    def enqueue_copy(self, a: int, b: int) -> None:
        """Queue the copy of frames a..b to the host (read by ``balance`` once the chunk's guard has arrived)."""
        if self.host is not self.values:
            row = self.values.size // self.values.shape[0]
            self.wp.copy(self.host, self.values, dest_offset=a * row, src_offset=a * row, count=(b - a + 1) * row)

    def balance(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Per lattice over frames a..b: the largest relative change of energy plus what the losses took since
        frame 0 (both signs count), and whether every observable is finite."""
        values = self.host_values
        total = values[a : b + 1, :, _ENERGY] + values[a : b + 1, :, _DISSIPATED]
        change = np.abs(_signed_energy_change(total, values[0, :, _ENERGY], self.n_sites))
        finite = np.isfinite(values[a : b + 1]).all(axis=(0, 2))
        return np.where(finite, change.max(axis=0), np.inf), finite

    def keep_lag(self) -> None:
        """Queue a copy of the last frame's envelope (read after the run)."""
        self.lag = self.wp.clone(self.kept["envelope"])

    def result(self, x0, x, **how) -> "ObservedRun":
        """The ``ObservedRun`` once the run is done (``how``: method, dt, nsteps, device, wall_seconds)."""
        values = self.host_values.copy()
        n_frames, dt_used, fe = values.shape[0] - 1, how["dt"], self.observation.frame_every
        t = np.arange(n_frames + 1) * fe * dt_used
        if self.lag is None:  # the lag reaches back to frame 0: the envelope |z| of x0
            x0 = x0.numpy() if hasattr(x0, "numpy") else x0
            envelope_lag = np.abs(x0[:, 0] - x0[:, 1])
        else:
            envelope_lag = self.lag.numpy()
        lag = min(self.observation.lag_frames, n_frames)
        return ObservedRun(
            t=t,
            values=values,
            envelope=self.kept["envelope"].numpy(),
            envelope_lag=envelope_lag,
            t_lag=(n_frames - lag) * fe * dt_used,
            x=x.numpy() if hasattr(x, "numpy") else x,
            energy_initial=values[0, :, _ENERGY].copy(),
            layout=self.layout,
            **how,
        )


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
    """``simulate(..., observe=observation)``'s observables: integrate a batch and reduce them on the device (module
    docstring).

    Args:
        params, x0, dt, method, damping, M, K, device, progress: as ``simulate`` (splitting methods only).
        t_final: final time, kept; the step is shortened (never lengthened) so that t_final is a whole
            number of frames of ``observation.frame_every`` steps (the result reports the step used).
        observation: what to reduce and how often.
        layout, chunks, max_energy_error: ``Placement.layout``, ``Guard.chunks``, ``Guard.max_energy_error``;
            the bound also holds for every frame's energy plus what the losses took.

    Returns:
        ObservedRun.

    Raises:
        ValueError: bad input. StepSizeError: dt above the stability limit.
        IntegrationError: non-finite state or energy error above the bound (names method, dt, limit).
    """
    from .ensemble import simulate
    from .options import Guard, Placement

    same = dict(method=method, device=device, M=M, K=K, damping=damping, progress=progress)  # as simulate's
    guard = Guard(max_energy_error=max_energy_error, chunks=chunks)
    t_final = real_number("t_final", t_final, positive=True)
    run = simulate(
        params, x0, t_final, dt, observe=observation, guard=guard, placement=Placement(layout=layout), **same
    )
    return run.observed
