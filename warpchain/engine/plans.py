"""Launch plans: what one kernel layout launches, with its arguments, and the rules that
pick a kernel variant (sites per thread, site groups) from the batch and the device."""

from __future__ import annotations

import weakref

import numpy as np

from .devices import _part, _parts, held
from .tuning import active


def sites_per_thread(batch: int, n_sites: int, stages: int, device: str) -> int:
    """Sites each thread of a block splitting launch owns: ceil(N / 32) (at most ``MAX_SITES_PER_THREAD``, so
    that a lattice of up to 256 sites is one warp) on a GPU from ``Tuning.sites_min_batch`` lattices for methods
    of at most ``Tuning.sites_max_stages`` stages, else 1."""
    from .block_kernels import WARP_LANES
    from .site_group_kernels import MAX_SITES_PER_THREAD

    if active().sites_per_thread is not None:
        return active().sites_per_thread
    if device == "cpu" or batch < active().sites_min_batch or stages > active().sites_max_stages:
        return 1
    return max(1, min(MAX_SITES_PER_THREAD, -(-int(n_sites) // WARP_LANES)))


def site_group_launch(sites: int, stages: int, device: str) -> bool:
    """Whether a block splitting launch with this many sites per thread runs ``site_group_kernels``: always
    for several sites, and on a GPU for one site per thread and few stages too (its walls compiled in, one
    float64 per thread in the tile: one lattice 118.6 ns per Verlet step, 3.08e11 site-steps/s at 805 lattices,
    H200, ``benchmarks/results/h200-2026-11-22k.json``; in ``h200-2026-11-22e.json`` it was 170 ns against
    ``block_kernels``'
    202 ns); the many-stage methods keep ``block_kernels``' register-capped kernel. ``Tuning.group_one_site``
    (tests, benchmarks) forces it."""
    if sites > 1:
        return True
    if active().group_one_site is not None:
        return active().group_one_site
    return device != "cpu" and stages <= active().sites_max_stages


class _Plan:
    """What one kernel layout launches: the kernels and, built beside each launch, their arguments. ``PLANS``
    maps the layout to the plan; the runner holds the buffers."""

    def __init__(self, runner):
        self.r = weakref.proxy(runner)  # the runner holds its plan: no cycle (the runner is freed by refcount)

    def step(self, lo: int, hi: int, dt: float, nsteps: int, save_every: int, frames, record: bool) -> None:
        raise NotImplementedError

    def observe(self, lo: int, hi: int, dt: float, nsteps: int, observer) -> None:
        """``step`` compiled with the observables of ``warpchain.observe`` (``observer``: a
        ``site.Observer`` for lattices lo..hi)."""
        raise NotImplementedError

    def tangent(self, dx, column_base, lo: int, hi: int, dt: float, nsteps: int) -> None:
        raise NotImplementedError

    def kept(self, name: str, shape: tuple):
        """A device array of ``shape`` kept under (``name``, ``shape``): launches allocate nothing, so that
        they can be captured in a graph (``_Replay``) and replayed."""
        wp, device = self.r.wp, self.r.device
        return held(self, (name, tuple(shape)), lambda: wp.zeros(shape, dtype=wp.float64, device=device))


class _BlockSplitting(_Plan):
    """A thread block per lattice, a splitting method compiled for its stage count."""

    def __init__(self, runner):
        super().__init__(runner)
        from . import block_kernels

        self.pack = block_kernels.pack_scheme
        self.scaled = {}

    def scheme(self, dt: float):
        """The method's ``block_kernels.Scheme`` for step dt (coefficients times dt, which the kernels use as is)."""
        if dt not in self.scaled:
            self.scaled = {dt: self.pack(self.r.method.drifts, self.r.method.kicks, dt)}
        return self.scaled[dt]

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        inputs = [_part(r.x, lo, hi), r.lattice(lo, hi), self.scheme(dt), int(nsteps)]
        inputs.append(r.record(save_every, frames, record))
        from . import block_kernels, site_group_kernels

        stages = r.method.stages
        damped = r.damped
        sites = sites_per_thread(hi - lo, r.N, stages, r.device)
        if site_group_launch(sites, stages, r.device):
            threads = site_group_kernels.group_threads(r.N, sites)
            group = site_group_kernels.site_group_kernels(threads, sites, r.boundary)
            kernel = group.splitting(stages, record=record, save=save_every > 0, damped=damped)
            r.launch_kernel(kernel, (hi - lo, threads), inputs, threads)
            return
        kernels = r.bk
        if record and hi - lo <= active().record_uncapped_max_batch:
            kernels = block_kernels.block_kernels(r.block, 0)  # the step's history in registers: no cap
        kernel = kernels.splitting(stages, record=record, save=save_every > 0, damped=damped)
        r.launch_kernel(kernel, (hi - lo, r.block), [inputs[0], r.no_base, *inputs[1:], r.no_observer], r.block)

    def observe(self, lo, hi, dt, nsteps, observer):
        r = self.r
        from . import block_kernels

        inputs = [_part(r.x, lo, hi), r.no_base, r.lattice(lo, hi), self.scheme(dt), int(nsteps), r.record(), observer]
        kernel = block_kernels.block_kernels(r.block, 0).splitting(r.method.stages, damped=True, observed=True)
        r.launch_kernel(kernel, (hi - lo, r.block), inputs, r.block)

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        r = self.r
        inputs = [*_parts(lo, hi, dx, column_base), r.lattice(), self.scheme(dt), int(nsteps), r.record()]
        inputs.append(r.no_observer)
        kernel = r.bk.splitting(r.method.stages, tangent=True)
        r.wp.launch(kernel, dim=(hi - lo, r.block), block_dim=r.block, device=r.device, inputs=inputs)


class _ThreadSplitting(_Plan):
    """A thread per lattice (the CPU path), a splitting method; accelerations in a scratch array."""

    def __init__(self, runner):
        super().__init__(runner)
        wp, m, f64 = runner.wp, runner.method, runner.wp.float64
        self.acc = wp.zeros((runner.batch, 2, runner.N), dtype=f64, device=runner.device)
        self.drifts = wp.array(np.array(m.drifts), dtype=f64, device=runner.device)
        self.kicks = wp.array(np.array(m.kicks), dtype=f64, device=runner.device)

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        inputs = [*self.inputs(lo, hi, dt, nsteps), r.record(save_every, frames, record), r.no_observer]
        r.launch_kernel(r.k.splitting_kernel, hi - lo, inputs)

    def inputs(self, lo, hi, dt, nsteps) -> list:
        """The splitting kernel's arguments for lattices lo..hi up to its ``Recording``."""
        r = self.r
        return [
            *_parts(lo, hi, r.x, self.acc),
            0,
            r.no_base,
            r.lattice(lo, hi),
            self.drifts,
            self.kicks,
            r.wp.float64(dt),
            int(nsteps),
        ]

    def observe(self, lo, hi, dt, nsteps, observer):
        r = self.r
        inputs = [*self.inputs(lo, hi, dt, nsteps), r.record(), observer]
        r.launch_kernel(r.k.observed_splitting_kernel, hi - lo, inputs)

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        r, wp = self.r, self.r.wp
        dacc = self.kept("dacc", (dx.shape[0], 2, r.N))  # written before it is read
        inputs = [*_parts(lo, hi, dx, dacc), 1, _part(column_base, lo, hi), r.lattice(), self.drifts, self.kicks]
        inputs += [wp.float64(dt), int(nsteps), r.record(), r.no_observer]
        wp.launch(r.k.splitting_kernel, dim=hi - lo, device=r.device, inputs=inputs)


class _SitesSplitting(_Plan):
    """A thread per site and one launch per force evaluation (``site_kernels``): lattices longer than a block,
    a splitting method. The u of the next evaluation goes to a scratch row and back (ping-pong)."""

    def __init__(self, runner):
        super().__init__(runner)
        from . import site_kernels

        self.kernels = site_kernels
        self.sequences = {}

    def evaluations(self, dt: float, nsteps: int, save_every: int) -> list:
        key = (dt, nsteps, save_every)
        if key not in self.sequences:
            m = self.r.method
            self.sequences = {key: self.kernels.evaluations(m.drifts, m.kicks, dt, nsteps, save_every)}
        return self.sequences[key]

    def run(self, x, lo, hi, dt, nsteps, save_every, frames, tangent, column_base, record, lattice, observer=None):
        r, sk = self.r, self.kernels
        ob = r.no_observer if observer is None else observer
        out = r.record(0, frames, record)  # the frames' rows are given per evaluation (``save_row``)
        scratch = _parts(lo, hi, self.kept("u", (x.shape[0], 1, r.N)))[0]
        x = _parts(lo, hi, x)[0]
        src, src_row = x, 0
        for e in self.evaluations(dt, nsteps, save_every):
            dst, dst_row = (scratch, 0) if src is x else (x, 0)
            drift = (sk.KEEP if src is x else sk.COPY) if e["last"] else sk.DRIFT
            slot = e["slot"] if record or tangent else 0  # unused otherwise: repeated launches share a kept command
            inputs = [x, src, src_row, dst, dst_row, column_base, lattice, int(tangent), slot, out]
            inputs += [e["kick"], e["h_kick"], e["pre"], e["h_pre"], drift, e["c"], e["save_row"]]
            inputs += [e["ends"] if observer is not None else 0, ob]
            r.launch_kernel(sk.evaluate if observer is None else sk.observed_evaluate, (hi - lo, r.N), inputs)
            src, src_row = dst, dst_row

    def step(self, lo, hi, dt, nsteps, save_every, frames, record):
        r = self.r
        self.run(r.x, lo, hi, dt, nsteps, save_every, frames, 0, r.no_base, record, r.lattice(lo, hi))

    def tangent(self, dx, column_base, lo, hi, dt, nsteps):
        self.run(dx, lo, hi, dt, nsteps, 0, None, 1, _part(column_base, lo, hi), False, self.r.lattice())

    def observe(self, lo, hi, dt, nsteps, observer):
        """``nsteps`` steps of lattices lo..hi with the observables of ``observer`` (``site.Observer``; frame 0 too
        when it starts the run): each frame's steps track z and the losses in ``evaluate``, then ``observe_frame``
        reduces the frame (``reference.frame_observables``, the table's peak rule on a lattice)."""
        r, sk = self.r, self.kernels
        x, lattice, fe = _parts(lo, hi, r.x)[0], r.lattice(lo, hi), observer.frame_every
        nh = self.neighbourhoods(observer.radius)

        def frame(index: int) -> None:
            r.launch_kernel(sk.observe_envelope, (hi - lo, r.N), [x, observer, int(index == 0)])
            inputs = [x, lattice, observer, nh, index]
            r.launch_kernel(sk.observe_frame, (hi - lo, sk.FRAME_BLOCK), inputs, sk.FRAME_BLOCK)

        done = observer.first_step
        if done == 0:
            frame(0)
        # a run per frame: each starts with a force evaluation at the frame's state (the accelerations the last one
        # gave, recomputed: one evaluation per frame more than a run of the whole chunk, the same bits)
        while nsteps > 0:
            steps = min(nsteps, fe - done % fe)
            self.run(r.x, lo, hi, dt, steps, 0, None, 0, r.no_base, False, lattice, observer=observer)
            done, nsteps = done + steps, nsteps - steps
            if done % fe == 0:
                frame(done // fe)

    def neighbourhoods(self, radius: int):
        """The peak rule's ``site_kernels.Neighbourhoods`` for ``radius`` (kept with the plan): the lattice's balls,
        table and distances from its centre; the chain's rule (degree 0) on a chain."""
        r = self.r

        def make():
            wp, f64 = r.wp, r.wp.float64
            nh = self.kernels.Neighbourhoods()
            lattice = r.table_lattice
            if lattice is None:
                nh.degree = 0
                nh.ball_ptr = nh.ball_idx = r.no_base
                nh.table, nh.weights, nh.dist = r.table, r.weights, wp.zeros(1, dtype=f64, device=r.device)
                return nh
            from ..colouring import balls_of

            ball, _ = balls_of(lattice, int(radius))
            nh.degree = lattice.degree
            nh.ball_ptr = wp.array(ball.indptr.astype(np.int32), dtype=wp.int32, device=r.device)
            nh.ball_idx = wp.array(ball.indices.astype(np.int32), dtype=wp.int32, device=r.device)
            nh.table, nh.weights = r.table, r.weights
            nh.dist = wp.array(lattice.distances(lattice.centre), dtype=f64, device=r.device)
            return nh

        return held(self, ("neighbourhoods", int(radius)), make)


#: The plan of each kernel layout (every layout steps the splitting methods: ``devices.engine_method``).
PLANS = {"block": _BlockSplitting, "thread": _ThreadSplitting, "sites": _SitesSplitting}
