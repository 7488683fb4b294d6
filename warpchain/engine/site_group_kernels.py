"""Block kernels in which each thread owns a run of consecutive sites (``site_group_kernels``): the GPU's
path for large batches of splitting runs (one warp per lattice up to 256 sites), and for one site per thread
with few stages. Same arithmetic as ``block_kernels`` and the numpy reference, bit for bit on the CPU."""

import functools

import warp as wp

from ..model import BOUNDARY_CODES
from .block_kernels import (
    MAX_BLOCK,
    WARP_LANES,
    BlockKernels,
    block_size,
    Scheme,
)
from .site import (
    site_acceleration_times,
    site_kick,
    Lattice,
    Recording,
    F64,
    Array3,
    BOUNDARY_FIXED,
    BOUNDARY_PERIODIC,
    contact_stiffness,
    wall_values,
)


def group_threads(n_sites: int, sites: int) -> int:
    """Threads per lattice when each thread owns ``sites`` consecutive sites: ceil(n / sites), rounded
    up to whole warps (N = 201: 7 sites per thread fit one warp, 224 slots; 2 per thread, four warps)."""
    return block_size(-(-int(n_sites) // int(sites)))


#: most sites one thread may own (its state lives in 4 x sites float64 registers)
MAX_SITES_PER_THREAD = 8


#: the site-group kernels built so far, by (threads, sites, boundary, min blocks per SM)
SITE_GROUPS: dict = {}


@functools.lru_cache(maxsize=None)
def site_group_kernels(threads: int, sites: int, boundary: int, min_blocks_per_sm: int = 0) -> BlockKernels:
    """Block kernels in which each of ``threads`` threads owns ``sites`` consecutive sites of one lattice.

    Why: with one site per thread every force evaluation pays a shared-memory round trip and a block
    barrier per site, and at 805 lattices the 224-thread blocks need two waves of the GPU
    (``benchmarks/results/h200-2026-11-22b.json``, ``ncu.txt``: 36 % of the stall cycles at the barrier). A thread
    that owns
    a run of sites takes its interior neighbours from its own registers; only the two ends of its run
    cross threads, through one shared tile entry (first u, last u) per thread and per force evaluation,
    ping-ponged as in ``block_kernels`` (one barrier). With 7 sites per thread a lattice of 201 sites is
    one warp, so the barrier spans one warp only.

    Layout: thread t owns sites j = t * sites + s, s < sites; the slots past the lattice's end hold
    zeros and stay there, because their 1/M is 0 (so u'' = 0) and f(0 - 0) = 0 (so v'' = 0): no branch
    and no select is spent on them. The shared tile has a zero entry before thread 0's and after the last
    thread's, so fixed walls cost nothing; other ends (``boundary``, compiled in) replace the wall values of
    site 0 and site n - 1 with a select of ``site.wall_values``.

    The arithmetic is that of ``block_kernels`` and the numpy reference (same operations, same order), so
    the results are the same bit for bit on the CPU. The kick that ends one step and the kick that starts
    the next use the same accelerations, which are carried into the next iteration, whose first kick comes
    at the top of the loop, as in the hand-written kernel. (Both kicks inside the step, the second behind a
    ``step + 1 < nsteps`` test, hold fewer live registers but ran slower: one lattice 129.5 against 118.6 ns
    per Verlet step, 2.80e11 against 3.08e11 site-steps/s at 805 lattices on the H200,
    ``benchmarks/results/h200-2026-11-22k.json``.)

    ``min_blocks_per_sm`` goes to ``__launch_bounds__`` (0: none), capping registers so that this many
    blocks fit on one SM.

    With one site per thread the first and last u of a run are the same value, so the shared tile holds one
    float64 per thread (8-byte stores and loads) instead of a pair: one lattice 129.5 ns per Verlet step
    against 160 ns (H200, ``benchmarks/results/h200-2026-11-22k.json``).

    Launch with ``dim=(lattices, threads), block_dim=threads``.
    """
    if threads % WARP_LANES or not WARP_LANES <= threads <= MAX_BLOCK:
        raise ValueError(f"threads must be a multiple of {WARP_LANES} in [{WARP_LANES}, {MAX_BLOCK}], got {threads}")
    if not 1 <= sites <= MAX_SITES_PER_THREAD:
        raise ValueError(f"sites per thread must be in [1, {MAX_SITES_PER_THREAD}], got {sites}")
    if boundary not in BOUNDARY_CODES.values():
        raise ValueError(f"unknown boundary code {boundary}")
    run = wp.types.vector(length=sites, dtype=wp.float64)
    entries = threads + 2  # one (first u, last u) per thread and a zero wall entry at each end
    halves = 2 * entries
    last_slot = sites - 1
    fixed = boundary == int(BOUNDARY_FIXED)
    periodic = boundary == int(BOUNDARY_PERIODIC)
    scalar_ends = sites == 1
    entry = wp.float64 if scalar_ends else wp.vec2d

    if scalar_ends:

        @wp.func
        def ends(buf: wp.tile[wp.float64, halves], u: run, t: int, n: int, parity: int) -> wp.vec4d:
            """``ends`` with one site per thread: its u is both ends of its run, one float64 per thread."""
            offset = parity * entries
            wp.tile_assign(buf, wp.tile(u[0]), offset=(offset + 1,))
            left = buf[offset + t]
            right = buf[offset + t + 2]
            end = wp.float64(0.0)
            start = wp.float64(0.0)
            if wp.static(periodic):
                end = buf[offset + n]
                start = buf[offset + 1]
            return wp.vec4d(left, right, end, start)

    else:

        @wp.func
        def ends(buf: wp.tile[wp.vec2d, halves], u: run, t: int, n: int, parity: int) -> wp.vec4d:
            """Publish this thread's end values in half ``parity``; return (u left of its first site, u right
            of its last site, u of site n - 1, u of site 0): the last two only matter for periodic ends."""
            offset = parity * entries
            last = u[last_slot]
            if wp.static(periodic):  # the thread holding site n - 1 publishes it as its last value
                for s in range(wp.static(sites)):
                    last = wp.where(t * wp.static(sites) + s == n - 1, u[s], last)
            wp.tile_assign(buf, wp.tile(wp.vec2d(u[0], last), preserve_type=True), offset=(offset + 1,))
            left = buf[offset + t][1]
            right = buf[offset + t + 2][0]
            end = wp.float64(0.0)
            start = wp.float64(0.0)
            if wp.static(periodic):
                end = buf[offset + 1 + (n - 1) / wp.static(sites)][1]
                start = buf[offset + 1][0]
            return wp.vec4d(left, right, end, start)

    @wp.func
    def neighbour_values(u: run, e: wp.vec4d, t: int, n: int, s: int) -> wp.vec2d:
        """(left, right) neighbour u of slot s (s is a constant of the unrolled slot loop)."""
        left = wp.where(s == 0, e[0], u[wp.max(s - 1, 0)])
        right = wp.where(s == wp.static(last_slot), e[1], u[wp.min(s + 1, wp.static(last_slot))])
        if wp.static(not fixed):  # a fixed wall is the tile's zero entry; other walls: ``wall_values``
            j = t * wp.static(sites) + s
            left = wp.where(j == 0, wall_values(u[s], e[2], wp.static(boundary))[0], left)
            right = wp.where(j == n - 1, wall_values(e[3], u[s], wp.static(boundary))[1], right)
        return wp.vec2d(left, right)

    bounds = (threads, min_blocks_per_sm) if min_blocks_per_sm else threads
    options = {"enable_backward": False, "module": "unique", "grid_stride": False, "launch_bounds": bounds}

    def make_splitting(
        stages: int, record: bool, save: bool, damped: bool = False, observed: bool = False, tangent: bool = False
    ):
        if observed or tangent:
            raise ValueError("the site-group kernels step base runs: observables and tangents run in block_kernels")

        @wp.func
        def kick(pu: F64, pv: F64, au: F64, av: F64, h: F64, loss: int, damp: Array3, b: int, i: int) -> wp.vec2d:
            """Kick i of one slot: the plain kick, or compiled ``damped``, ``site_kick``'s damped one."""
            if wp.static(damped):
                return site_kick(pu, pv, wp.vec2d(au, av), h, loss, damp, b, i)
            else:
                return wp.vec2d(pu + h * au, pv + h * av)

        @wp.func
        def accelerations(u: run, v: run, m: run, e: wp.vec4d, t: int, n: int, k: F64, hist: Array3, slot: int, b: int):
            """The slots' accelerations (u'', v'') between the run's end values ``e``; compiled ``record``, f'(z) of
            the lattice's sites into hist[slot, b]."""
            au = run()
            av = run()
            for s in range(wp.static(sites)):
                nb = neighbour_values(u, e, t, n, s)
                a = site_acceleration_times(u[s], v[s], nb[0], nb[1], m[s], k)
                au[s] = a[0]
                av[s] = a[1]
                if wp.static(record):
                    if t * wp.static(sites) + s < n:
                        hist[slot, b, t * wp.static(sites) + s] = contact_stiffness(u[s] - v[s])
            return au, av

        @wp.kernel(**options)
        def splitting(x: Array3, lat: Lattice, scheme: Scheme, nsteps: int, out: Recording):
            """``block_kernels``' splitting kernel (same arguments but no ``Observer``; the boundary is compiled in,
            ``lat.boundary`` unused) with ``sites`` sites per thread: lattice b, thread t."""
            b, t = wp.tid()
            n = x.shape[2]
            first = t * wp.static(sites)
            drifts = scheme.drifts
            kicks = scheme.kicks
            mb = -lat.inv_mass[b]
            k = lat.coupling[b]
            damp = lat.damp
            loss = int(0)
            if wp.static(damped):
                loss = lat.lossy[b]
            u = run()
            v = run()
            pu = run()
            pv = run()
            m = run()  # -1/M on the lattice's slots, 0 past its end (those slots never move)
            for s in range(wp.static(sites)):
                j = first + s
                if j < n:
                    u[s] = x[b, 0, j]
                    v[s] = x[b, 1, j]
                    pu[s] = x[b, 2, j]
                    pv[s] = x[b, 3, j]
                    m[s] = mb
            buf = wp.tile_zeros(shape=(halves,), dtype=entry, storage="shared")
            parity = int(0)
            e = ends(buf, u, t, n, parity)
            au, av = accelerations(u, v, m, e, t, n, k, out.hist, 0, b)
            # every step's first kick uses the accelerations of the previous step's last kick (carried over)
            for step in range(nsteps):
                for s in range(wp.static(sites)):
                    w = kick(pu[s], pv[s], au[s], av[s], kicks[0], loss, damp, b, 0)
                    pu[s] = w[0]
                    pv[s] = w[1]
                for stage in range(wp.static(stages)):  # unrolled: coefficients become constants
                    h = drifts[stage]
                    for s in range(wp.static(sites)):
                        u[s] = u[s] + h * pu[s]
                        v[s] = v[s] + h * pv[s]
                    parity = 1 - parity
                    e = ends(buf, u, t, n, parity)
                    au, av = accelerations(u, v, m, e, t, n, k, out.hist, step * wp.static(stages) + stage + 1, b)
                    h = kicks[stage + 1]
                    for s in range(wp.static(sites)):
                        w = kick(pu[s], pv[s], au[s], av[s], h, loss, damp, b, stage + 1)
                        pu[s] = w[0]
                        pv[s] = w[1]
                if wp.static(save):
                    if (step + 1) % out.every == 0:
                        r = (step + 1) / out.every - 1
                        for s in range(wp.static(sites)):
                            if first + s < n:
                                out.u[r, b, first + s] = u[s]
                                out.v[r, b, first + s] = v[s]
            for s in range(wp.static(sites)):
                j = first + s
                if j < n:
                    x[b, 0, j] = u[s]
                    x[b, 1, j] = v[s]
                    x[b, 2, j] = pu[s]
                    x[b, 3, j] = pv[s]

        return splitting

    group = BlockKernels({"splitting": make_splitting})
    SITE_GROUPS[threads, sites, boundary, min_blocks_per_sm] = group
    return group
