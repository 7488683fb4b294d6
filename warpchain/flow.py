"""The Flow: the discrete map of one integrator, the only thing continuation knows of it.

A ``Flow`` carries the method, the steps per period, the device and the kernel layout, and offers
two operations on one lattice:

* ``run(params, x0, nsteps, dt)``: the end state and the minimum contact ``1 + u - v`` over the
  step boundaries (batched over lattices);
* ``linearize(params, x0, nsteps, dt)``: the same base trajectory, run once with its contact
  stiffness recorded at every force evaluation, returned as a ``Linearization`` whose
  ``columns(directions)`` replays that history for any set of tangent directions. Newton reads the
  residual from it, asks for the Jacobian's columns only when it needs them, and Floquet asks the
  same object for the remaining columns: no base trajectory is integrated twice.

``Flow`` runs the float64 Warp kernels and keeps its device buffers between calls (allocated once
per lattice size and step count, as the Warp examples do; a small pool so that Newton's trial point
does not overwrite the history of the point it came from). ``ReferenceFlow`` is the same contract
on the numpy reference (``warpchain.reference``): slow, Warp-free, and the arithmetic oracle, so
continuation can be tested without Warp.

Adding a flow: subclass ``Flow`` and implement ``run`` and ``linearize`` (returning a
``Linearization`` whose ``_columns`` callable maps directions (ncols, 4, N) to the end-state
derivatives (ncols, 4, N); optionally a ``unit`` callable for the unit directions, which ``Flow``
makes once on the device so that Newton's 2N columns cost no host-to-device copy of an identity).
"""

from __future__ import annotations

import dataclasses
import math
import weakref
from typing import Callable

import numpy as np

from .integrators import get_method
from .colouring import balls_and_rims, kept_colouring
from .lattice import geometry_key, neighbour_table
from .model import ChainParams, as_batch, min_contact


#: ``unit_columns`` probes colour groups (``Linearization.probed_columns``) from this many sites on; below, one run
#: per unit direction (the paper's chains, bit for bit as before)
PROBE_MIN_SITES = 1025

#: the first half-bandwidth a probe tries (sites)
PROBE_HALFWIDTH = 32

#: the first ball radius (bonds) a lattice's probe tries (``Linearization._probed_lattice``)
LATTICE_HALFWIDTH = 4

#: a probed column's entries at its band's edge must be below this fraction of its run's largest entry
PROBE_TOLERANCE = 1e-16


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """End of a batched run.

    Attributes:
        x_end: end states, shape (batch, 4, N).
        min_contact: min over sites and step boundaries (start and end included) of 1 + u - v,
            shape (batch,).
    """

    x_end: np.ndarray
    min_contact: np.ndarray


class Linearization:
    """One base trajectory with its recorded history: end state, min contact, and tangent columns
    on demand.

    Attributes:
        x0, x_end: start and end state, shape (4, N).
        min_contact: min over sites and step boundaries of 1 + u - v.
        nsteps, dt: the time grid.
        stats: counters (``tangent_columns`` propagated so far).
        device: the device of the flow that made it (``"cpu"``, ``"cuda:0"``, ..., ``"numpy"`` for the reference).
    """

    def __init__(
        self,
        x0,
        x_end,
        min_contact_value,
        nsteps,
        dt,
        columns: Callable[[np.ndarray], np.ndarray],
        unit: Callable[[int, int], np.ndarray] | None = None,
        banded: bool = True,
        lattice=None,
        device: str = "numpy",
    ):
        self.x0, self.x_end, self.min_contact = x0, x_end, float(min_contact_value)
        self.device = device  # where the columns are computed (a Warp device, or "numpy"): the host's eig or a GPU's
        self.nsteps, self.dt = int(nsteps), float(dt)
        self._columns = columns
        # optional: (first, count) -> the end-state derivatives along unit directions first .. first + count - 1
        # of the 4N, shape (count, 4, N), without the directions crossing from the host
        self._unit = unit
        # whether a perturbation stays near its site (fixed and free ends; a periodic ring carries it round to the
        # other end, where a colour group's decoding would give it to the wrong site): ``probed_columns`` needs it
        self.banded = bool(banded)
        # a lattice given as a neighbour table (``warpchain.lattice``, not periodic): probed by its own colouring
        # (``probed_columns``), the bands being balls of bonds around each site instead of index intervals
        self.lattice = lattice
        self._cache: dict[str, np.ndarray] = {}
        self.stats = {"tangent_columns": 0}

    def columns(self, directions, key: str | None = None) -> np.ndarray:
        """Derivative of the end state along each direction, shape (4N, ncols).

        Args:
            directions: shape (ncols, 4, N).
            key: cache the result under this name (e.g. ``"positions"``) so that a second request
                costs nothing.
        """
        if key is not None and key in self._cache:
            return self._cache[key]
        d = np.asarray(directions, dtype=np.float64)
        cols = self._columns(d).reshape(len(d), -1).T
        self.stats["tangent_columns"] += len(d)
        if key is not None:
            self._cache[key] = cols
        return cols

    def unit_columns(self, which: str, probe: bool = True) -> np.ndarray:
        """Columns along the unit directions of the positions (``"positions"``: u then v, 2N) or the
        velocities (``"velocities"``: u' then v', 2N) or of the whole state (``"all"``, 4N).

        From ``PROBE_MIN_SITES`` sites on they come from colour groups (``probed_columns``: 2 (2 b + 1) tangent
        runs per half of the state instead of 2N, the same columns to ~1e-33, entries below 1e-16 of their run's
        largest dropped); ``probe=False`` takes one tangent run per unit direction (a dense matrix, every entry).
        Columns already cached under ``which`` are returned as they are."""
        if which in self._cache:
            return self._cache[which]
        if which == "all" and "positions" in self._cache and "velocities" in self._cache:
            return np.hstack([self._cache["positions"], self._cache["velocities"]])
        if probe and self.x0.shape[1] >= PROBE_MIN_SITES and (self.banded or self.lattice is not None):
            cols = self.probed_columns(which)[0].toarray()
            self._cache[which] = cols
            return cols
        return self._plain_columns(which)

    def _plain_columns(self, which: str) -> np.ndarray:
        """``unit_columns`` from one tangent run per unit direction (cached under ``which``)."""
        N = self.x0.shape[1]
        first, count = {"positions": (0, 2 * N), "velocities": (2 * N, 2 * N), "all": (0, 4 * N)}[which]
        if which in self._cache:
            return self._cache[which]
        if self._unit is not None:
            cols = self._unit(first, count).reshape(count, -1).T
            self.stats["tangent_columns"] += count
            self._cache[which] = cols
            return cols
        eye = np.eye(4 * N)[first : first + count].reshape(count, 4, N)
        return self.columns(eye, key=which)

    def probed_columns(self, which: str = "all", halfwidth: int = PROBE_HALFWIDTH) -> tuple:
        """The unit columns of ``which`` as a sparse (CSC) matrix, from colour groups, and the half-bandwidth b used.

        A tangent perturbation travels a few sites per unit time (the lattice's largest group velocity is
        ~ sqrt(K / M)) and beyond that light cone its amplitude falls faster than exponentially: on the paper chain
        (M = 30, K = 160, w_b = 1.01, kahan8) an entry of the half-period map is below 1e-28 of the largest 32 sites
        off the diagonal. So the columns of sites further apart than 2 b do not overlap, and one tangent run from all
        sites {r, r + s, r + 2 s, ...} of a component (s = 2 b + 1) gives all their columns at once: the entries
        within b of each site are that site's. The check is measured, not assumed: each decoded column's entries at
        distance b must be below ``PROBE_TOLERANCE`` of its run's largest, else b is doubled (plain unit columns once
        2 b + 1 >= N, and on a periodic ring, where a perturbation wraps round to the other end). A lattice given as a
        table (``lattice``) is probed by its own colouring and balls of bonds instead (``_probed_lattice``, from
        ``LATTICE_HALFWIDTH``; ``halfwidth`` is the chain's).
        """
        import scipy.sparse as sp

        N = self.x0.shape[1]
        comps = {"positions": (0, 1), "velocities": (2, 3), "all": (0, 1, 2, 3)}[which]
        if self.lattice is not None:
            return self._probed_lattice(which, comps)
        b = int(halfwidth)
        while self.banded and 2 * b + 1 < N:
            A, edge = self._probe(comps, b)
            if edge <= PROBE_TOLERANCE:
                return A, b
            b *= 2
        return sp.csc_matrix(self._plain_columns(which)), N

    def _probed_lattice(self, which: str, comps: tuple) -> tuple:
        """``probed_columns`` on a lattice given as a table: sites are coloured so that no two within 2 b bonds share
        a colour (``Lattice.colouring``), one tangent run per colour and component gives the columns of all its
        sites, and site j's column is its entries within b bonds of j (its ball). Checked as on the chain: the
        entries on each ball's rim (exactly b bonds away) must be below ``PROBE_TOLERANCE`` of their run's largest.
        From ``LATTICE_HALFWIDTH`` on, a b that fails is followed by the b the measured decay asks for
        (``_next_halfwidth``), until the balls span the patch or the colours are no fewer than the sites (plain
        columns)."""
        import scipy.sparse as sp

        lat, N = self.lattice, self.x0.shape[1]
        span = sum(n - 1 for n in lat.shape)  # every two sites are within this many bonds (axial steps)
        b = LATTICE_HALFWIDTH
        while True:
            colours = None if 2 * b >= span else kept_colouring(lat, 2 * b)
            if colours is None or colours.max() + 1 >= N:
                return sp.csc_matrix(self._plain_columns(which)), N
            ball, rim, inner_rim = balls_and_rims(lat, b)
            A, edge, inner = self._probe_groups(comps, colours, (ball, rim), inner_rim)
            if edge <= PROBE_TOLERANCE:
                return A, b
            b = _next_halfwidth(b, edge, inner)

    def _probe_groups(self, comps: tuple, colours: np.ndarray, balls: tuple, inner_rim) -> tuple:
        """The columns of ``comps`` from one run per (component, colour), site j's entries those of its ball (CSR
        rows ``balls[0]``; ``balls[1]`` its rim), and the largest entry on the rim and on ``inner_rim`` (CSR: the
        sites one bond nearer), each relative to its run's largest."""
        import scipy.sparse as sp

        N, n_colours = self.x0.shape[1], int(colours.max()) + 1
        j = np.arange(N)
        dirs = np.zeros((len(comps), n_colours, 4, N))
        for c, comp in enumerate(comps):
            dirs[c, colours, comp, j] = 1.0
        C = self.columns(dirs.reshape(-1, 4, N)).reshape(4, N, len(comps), n_colours)  # [out, i, comp, colour]
        top = np.max(np.abs(C), axis=(0, 1))  # (comps, colours)
        top[top == 0] = 1.0

        def largest(rim) -> float:
            rim_site = np.repeat(j, np.diff(rim.indptr))
            if not rim.nnz:
                return 0.0
            values = np.abs(C[:, rim.indices, :, colours[rim_site]])  # (rim entries, out, comp)
            return float(np.max(values / top.T[colours[rim_site]][:, None, :]))

        ball, rim = balls
        owner = np.repeat(j, np.diff(ball.indptr))  # the column (site) of each ball entry
        blocks = []
        for c in range(len(comps)):
            data = C[:, ball.indices, c, colours[owner]]  # (out, entries)
            rows = np.arange(4)[:, None] * N + ball.indices[None, :]
            cols = np.broadcast_to(c * N + owner, rows.shape)
            blocks.append((data.ravel(), rows.ravel(), cols.ravel()))
        data, rows, cols = (np.concatenate(x) for x in zip(*blocks))
        return sp.csc_matrix((data, (rows, cols)), shape=(4 * N, len(comps) * N)), largest(rim), largest(inner_rim)

    def _probe(self, comps: tuple, b: int) -> tuple:
        """The columns of components ``comps`` from the len(comps) (2 b + 1) colour-group runs at half-bandwidth b,
        and the largest band-edge entry relative to its run's largest."""
        import scipy.sparse as sp

        N = self.x0.shape[1]
        s = 2 * b + 1
        j = np.arange(N)
        dirs = np.zeros((len(comps), s, 4, N))
        for c, comp in enumerate(comps):
            dirs[c, j % s, comp, j] = 1.0
        C = self.columns(dirs.reshape(-1, 4, N)).reshape(4, N, len(comps), s)  # [out, i, comp, r]
        top = np.max(np.abs(C), axis=(0, 1))  # (comps, s)
        top[top == 0] = 1.0
        rows = j[:, None] + np.arange(-b, b + 1)[None, :]  # (N, 2b+1): the rows of site j's band
        ok = (rows >= 0) & (rows < N)
        r = (j % s)[:, None]
        band = np.moveaxis(C, (0, 2), (2, 3))[np.clip(rows, 0, N - 1), r]  # (N, 2b+1, out, comp)
        edges = np.abs(band[:, [0, -1]]) / np.moveaxis(top, 0, 1)[j % s][:, None, None, :]
        edge = float(np.max(np.where(ok[:, [0, -1], None, None], edges, 0.0)))
        # CSC directly, column (comp, j) after column, its rows (out, band row) ascending: no sort of 4 N (2 b + 1)
        # entries per component
        n_comps = len(comps)
        data = np.moveaxis(band, (3, 0, 2, 1), (0, 1, 2, 3))[:, ok[:, None, :].repeat(4, axis=1)]  # (comp, nnz)
        index = (np.arange(4)[None, :, None] * N + rows[:, None, :])[ok[:, None, :].repeat(4, axis=1)]
        per_column = 4 * ok.sum(axis=1)
        indptr = np.concatenate([[0], np.cumsum(np.tile(per_column, n_comps))])
        shape = (4 * N, n_comps * N)
        return sp.csc_matrix((data.ravel(), np.tile(index, n_comps), indptr), shape=shape), edge


def _next_halfwidth(b: int, edge: float, inner: float) -> int:
    """The ball radius to probe after b failed: where the largest entries, falling by edge / inner per bond between
    b - 1 and b bonds, would reach a tenth of ``PROBE_TOLERANCE`` at that rate. Beyond its light cone a tangent
    perturbation falls faster than any fixed rate, so the guess errs on the wide side (a 41 x 41 square patch's
    breather, M = 30, K = 1: 1e-4, 2e-6, 2e-8, 9e-11, ..., 2e-18 at 0 .. 9 bonds: from b = 4 the guess is 11, where
    the doubling it replaces took 8, failed there, then 16). Doubling where the entries did not fall; at most 4 b (a
    slow decay would ask for radii whose colouring alone does not fit in memory)."""
    if not 0.0 < edge < inner:
        return 2 * b
    return min(4 * b, b + max(1, math.ceil(math.log(0.1 * PROBE_TOLERANCE / edge) / math.log(edge / inner))))


#: (N, boundary, table, batch, steps) keys whose runners a Flow keeps (two each, handed out in turn); a Flow that walks
#: through more shapes (a scan over N) frees the oldest
POOL_KEYS = 4


@dataclasses.dataclass(frozen=True)
class Flow:
    """The discrete map of one integrator on the float64 Warp kernels.

    Attributes:
        method: a splitting method's name in ``warpchain.METHODS`` (``ReferenceFlow`` also runs ``rk4``).
        steps_per_period: steps in one period of the orbit (even: the half period is a whole
            number of steps).
        device: ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or None (CUDA when Warp sees a GPU).
        layout: kernel layout (``"auto"``, ``"block"``, ``"sites"``, ``"thread"``; ``warpchain.Placement``).
    """

    method: str = "kahan8"
    steps_per_period: int = 32
    device: str | None = None
    layout: str = "auto"
    _pool: dict = dataclasses.field(default_factory=dict, init=False, repr=False, compare=False, hash=False)

    def __post_init__(self):
        self._check_method()
        spp = self.steps_per_period
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 2 or spp % 2:
            raise ValueError(f"steps_per_period must be an even integer >= 2, got {spp!r}")
        object.__setattr__(self, "steps_per_period", int(spp))

    def _check_method(self) -> None:
        from .engine.devices import engine_method

        engine_method(self.method)  # an unknown name, or a method the Warp kernels do not step, raises

    # ------------------------------------------------------------------ the time grid

    def half_steps(self) -> int:
        return self.steps_per_period // 2

    def grid(self, omega: float) -> tuple[int, float]:
        """Steps per half period and the step for frequency omega."""
        omega = float(omega)
        if not (math.isfinite(omega) and omega > 0):
            raise ValueError(f"omega must be a finite number > 0, got {omega!r}")
        n = self.half_steps()
        return n, math.pi / omega / n

    def replace(self, **changes) -> "Flow":
        return dataclasses.replace(self, **changes)

    def describe(self) -> dict:
        return {
            "flow": type(self).__name__,
            "method": self.method,
            "steps_per_period": self.steps_per_period,
            "device": self.device,
            "layout": self.layout,
        }

    # ------------------------------------------------------------------ Warp backend

    def _runner(self, params: ChainParams, x0: np.ndarray, nsteps: int, record: bool):
        """A runner with buffers for this (N, boundary, batch, nsteps), reused between calls; two per
        key, handed out in turn, each tagged with a generation so a stale history is detected. The
        parameters are loaded, the state is not (``_base_run`` uploads it)."""
        from .engine.devices import resolve_device
        from .engine.runner import _Runner
        from .model import per_lattice_parameters

        device = resolve_device(self.device)
        batch = x0.shape[0]
        Mb, Kb = per_lattice_parameters(params, batch, None, None)
        key = (params.N, params.boundary, geometry_key(params), batch, int(nsteps) if record else 0, device)
        slot = self._pool.pop(key, None) or {"runners": [], "turn": 0}
        self._pool[key] = slot  # the most recent key last
        while len(self._pool) > POOL_KEYS:  # the oldest key's runners go (freed once no Linearization holds them)
            del self._pool[next(iter(self._pool))]
        if len(slot["runners"]) < 2:
            runner = _Runner(
                get_method(self.method),
                params,
                x0,
                Mb,
                Kb,
                device,
                record_stiffness_steps=max(int(nsteps), 1) if record else 0,
                layout=self.layout,
                upload=False,
            )
            runner.generation = 0
            slot["runners"].append(runner)
        else:
            runner = slot["runners"][slot["turn"] % 2]
            runner.load(x0, Mb, Kb, upload=False)
        slot["turn"] += 1
        runner.generation += 1
        return runner

    def _lock(self):
        """The device's lock (``ensemble.device_lock``): each operation holds it from its first launch to its
        last wait, so Flows on several threads never enter each other's graph captures."""
        from .engine.devices import device_lock, resolve_device

        return device_lock(resolve_device(self.device))

    def run(self, params: ChainParams, x0, nsteps: int, dt: float) -> Trajectory:
        """Advance a batch by ``nsteps`` steps of ``dt``; end states and min contact."""
        x0 = as_batch(x0, params.N, "x0")
        with self._lock():
            runner = self._runner(params, x0, nsteps, record=False)
            x_end, contact = _base_run(runner, x0, int(nsteps), float(dt), record_stiffness=False)
        return Trajectory(x_end=x_end, min_contact=contact)

    def linearize(self, params: ChainParams, x0, nsteps: int, dt: float) -> Linearization:
        """Run one lattice once, recording its contact stiffness, and return its Linearization."""
        x0 = as_batch(x0, params.N, "x0")
        if x0.shape[0] != 1:
            raise ValueError(f"linearize takes one lattice, got a batch of {x0.shape[0]}")
        from .engine.hostmem import _copy

        lock = self._lock()
        with lock:
            runner = self._runner(params, x0, nsteps, record=True)
            x_end, contact = _base_run(runner, x0, int(nsteps), float(dt), record_stiffness=True)
            generation = runner.generation
        wp = runner.wp

        def propagate(fill, count, key=None):
            """Tangent columns from ``fill(dx)`` (dx: a device (count, 4, N) buffer) back on the host; with a
            ``key`` naming ``fill``'s arguments the operations are replayed (``_Replay``: a CUDA graph from
            the second call with that key)."""
            nonlocal generation
            with lock:
                if runner.generation != generation:  # the buffers were handed to another run since
                    runner.load(x0, *_parameters(params))
                    runner.launch(int(nsteps), float(dt), record_stiffness=True)
                    runner.generation += 1  # its own history again: later calls need not re-run it
                    generation = runner.generation
                dx, base = _column_buffers(runner, count)
                out_host = runner.host_buffer("columns", dx.size)
                kept = weakref.proxy(runner)  # the replay is kept on the runner: no cycle through it

                def enqueue():
                    fill(dx)
                    kept.launch_tangent(dx, base, int(nsteps), float(dt))
                    wp.copy(out_host, dx, count=dx.size)

                if key is None:
                    enqueue()
                else:
                    runner.replay(("columns", *key, int(nsteps), float(dt)), enqueue)()
                wp.synchronize_device(runner.device)
                out = np.empty(dx.shape)
                _copy(out, out_host.numpy().reshape(dx.shape))
            if not np.isfinite(out).all():
                from .ensemble import IntegrationError
                from .integrators import stability_limit

                limit = stability_limit(self.method, params)
                raise IntegrationError(
                    f"tangent propagation produced non-finite values with method '{self.method}', dt = {dt:g} "
                    f"(linear stability limit {limit:.6g})",
                    method=self.method,
                    dt=dt,
                    stability_limit=limit,
                    failed=[0],
                    t=nsteps * dt,
                )
            return out

        def columns(directions):
            """Through a host buffer of the directions' size kept with the runner (page-locked on a GPU), so that
            the copy in is part of the replay: a Krylov solver's products, one column at a time, are one graph
            launch each from the second on (on the sites layout a half period is ~240 launches)."""
            count = len(directions)
            staged = runner.host_buffer("directions", directions.size)
            with lock:  # reentrant; the last replay that read the buffer has finished (``propagate`` synchronises)
                staged.numpy()[:] = np.asarray(directions, dtype=np.float64).ravel()
                return propagate(lambda dx: wp.copy(dx, staged, count=dx.size), count, key=("directions", count))

        def unit(first, count):
            with lock:  # made once on the device: an allocation, never inside another thread's capture
                eye = _unit_directions(runner)
            n = 4 * params.N
            return propagate(
                lambda dx: wp.copy(dx, eye, src_offset=first * n, count=count * n), count, key=("unit", first, count)
            )

        banded = _banded(params)
        return Linearization(
            x0[0], x_end[0], contact[0], nsteps, dt, columns, unit=unit, banded=banded, lattice=_probed(params),
            device=runner.device,
        )  # fmt: skip


def _column_buffers(runner, count: int):
    """The runner's device buffers for ``count`` tangent columns (directions, base indices), kept between
    calls (Newton asks for the same columns at every iterate), one pair per count."""
    from .engine.devices import held

    wp, shape = runner.wp, (count, 4, runner.N)
    return held(
        runner,
        ("columns", count),
        lambda: (
            wp.empty(shape, dtype=wp.float64, device=runner.device),
            wp.zeros(count, dtype=wp.int32, device=runner.device),
        ),
    )


def _unit_directions(runner):
    """A device array (4N, 4, N) of the unit directions, kept with the runner."""
    from .engine.devices import held

    def make():
        n = 4 * runner.N
        return runner.wp.array(np.eye(n).reshape(n, 4, runner.N), dtype=runner.wp.float64, device=runner.device)

    return held(runner, "unit directions", make)


def _base_run(runner, x0: np.ndarray, nsteps: int, dt: float, record_stiffness: bool):
    """Load ``x0`` (batch, 4, N), run ``nsteps`` steps recording u and v at every step into device buffers
    (kept by the runner), reduce 1 + u - v to its min per lattice on the device, and return the end
    state and min contact (start included), shapes (batch, 4, N) and (batch,). The state goes in and out
    through host buffers kept with the runner (page-locked on a GPU), so the whole sequence is one
    ``_Replay``: a single CUDA graph launch from the second call with the same (nsteps, dt) on."""
    wp = runner.wp
    contact = min_contact(x0)
    if not nsteps:
        runner.upload(x0)
        return np.array(x0, dtype=np.float64), contact
    frames = runner.__dict__.setdefault("_contact_frames", {})
    if nsteps not in frames:
        frames.clear()  # one step count at a time (a replay keeps the frames it was captured with alive)
        frames[nsteps] = runner.frames(nsteps)
    rec = frames[nsteps]
    x_in, x_out = runner.host_buffer("x_in", x0.size), runner.host_buffer("x_out", x0.size)
    low = runner.host_buffer("guard", 3 * runner.batch)
    x_in.numpy()[:] = x0.ravel()  # the last replay that read it has finished (synchronised below)
    # the replay is kept on the runner, so it holds the runner weakly: a runner in a reference cycle with its
    # own replays (and its buffers: 2 x 82 MB of unit directions and columns at N = 801) waited for the cyclic
    # garbage collector, and a scan solving a breather per point grew by GBs in a minute
    kept = weakref.proxy(runner)

    def enqueue():
        wp.copy(kept.x, x_in, count=x0.size)
        kept.reset_contact()
        kept.launch(nsteps, dt, save_every=1, rec=rec, record_stiffness=record_stiffness)
        guard = kept.guard(rec, nsteps)
        wp.copy(low, guard, count=guard.size)
        wp.copy(x_out, kept.x, count=x0.size)

    runner.replay(("base", nsteps, dt, record_stiffness), enqueue)()
    wp.synchronize_device(runner.device)
    x_end = x_out.numpy().reshape(x0.shape).copy()
    return x_end, np.minimum(contact, low.numpy().reshape(runner.batch, 3)[:, 2])


def _banded(params) -> bool:
    """Whether a perturbation stays near its site index (``Linearization.banded``): on the chain with ends, not on
    a ring, and not on a 2-D lattice given as a table (whose neighbours lie a row apart in the site order)."""
    return neighbour_table(params) is None and params.boundary != "periodic"


def _probed(params):
    """The lattice whose colouring probes the columns (``Linearization._probed_lattice``): a table's, unless periodic
    (a perturbation wraps round: plain columns)."""
    table = neighbour_table(params)
    return table if table is not None and params.boundary != "periodic" else None


def _parameters(params: ChainParams):
    from .model import per_lattice_parameters

    return per_lattice_parameters(params, 1, None, None)


@dataclasses.dataclass(frozen=True)
class ReferenceFlow(Flow):
    """The same contract on the numpy reference (``warpchain.reference``): no Warp, same arithmetic."""

    device: str | None = "numpy"
    layout: str = "reference"

    def _check_method(self) -> None:
        get_method(self.method)  # every method of warpchain.METHODS, RK4 included

    def run(self, params: ChainParams, x0, nsteps: int, dt: float) -> Trajectory:
        from . import reference

        x0 = as_batch(x0, params.N, "x0")
        out = reference.integrate(self.method, params, x0, float(dt), int(nsteps), save_every=1)
        contact = np.min(1.0 + out["u"] - out["v"], axis=(0, 2))
        return Trajectory(x_end=out["x"], min_contact=contact)

    def linearize(self, params: ChainParams, x0, nsteps: int, dt: float) -> Linearization:
        from . import reference

        x0 = as_batch(x0, params.N, "x0")
        traj = self.run(params, x0, nsteps, dt)

        def columns(directions):
            out = reference.integrate(self.method, params, x0, float(dt), int(nsteps), dx0=directions[None])
            return out["dx"][0]

        banded = _banded(params)
        return Linearization(
            x0[0], traj.x_end[0], traj.min_contact[0], nsteps, dt, columns, banded=banded, lattice=_probed(params)
        )
