"""Block-per-lattice Warp kernels (float64): the GPU path.

Layout and arithmetic match ``thread_kernels`` (state (batch, 4, N) ordered (u, v, u', v'), the same
``@wp.func`` contact law, the same operation order as the numpy reference), but the work is laid
out the way a GPU wants it:

* one thread block owns one lattice (or one tangent column), one thread owns one site;
* a site's state lives in registers for the whole launch, the time loop runs inside the kernel;
* the only communication, the neighbours' u for the coupling term, goes through a shared-memory
  tile that each thread writes once per force evaluation (``wp.tile`` of the per-thread value,
  ``wp.tile_assign`` into shared storage) and reads two entries of. The tile has two halves used in
  turn (ping-pong), so the barrier inside ``tile_assign`` that follows the writes also guarantees
  that every thread has finished reading the other half: one barrier per force evaluation.

The block size is the lattice length rounded up to a whole number of warps (32 lanes); threads past
the end of the lattice carry zeros and only take part in the barriers. It is a compile-time
constant of the tile, so kernels are built per block size (``block_kernels(block)``, cached).

On the CPU, Warp runs a block of threads as cooperative fibers only when
``wp.config.enable_cpu_blocks`` is set; ``ensemble`` does that so the tests can check these kernels
against the numpy reference without a GPU. The thread-per-lattice kernels stay the CPU default.
"""

import functools

import warp as wp

from .site import (
    Lattice,
    Recording,
    F64,
    Array1,
    Array2,
    Array3,
    Indices,
    wall_values,
    BOUNDARY_PERIODIC,
    NO_CONTACT,
    ONE,
    ZERO,
    contact_stiffness,
    finite_state,
    kick_loss,
    neighbours_at,
    Observer,
    peak_test,
    peak_verdict,
    site_acceleration,
    site_energy,
    site_kick,
    held_energy,
    table_bonds,
    site_tangent_acceleration,
    store_observables,
)

#: Largest block Warp launches (CUDA's limit); longer lattices use the thread-per-lattice kernels.
MAX_BLOCK = 1024
WARP_LANES = 32


def block_size(n_sites: int) -> int:
    """Threads per block for a lattice of ``n_sites``: rounded up to whole warps."""
    return max(WARP_LANES, -(-int(n_sites) // WARP_LANES) * WARP_LANES)


def supports(n_sites: int) -> bool:
    """Whether a lattice of this length fits one block (one site per thread)."""
    return block_size(n_sites) <= MAX_BLOCK


# ----------------------------------------------------------------------------- per-site helpers


@wp.func
def left_index(j: int, n: int, boundary: int) -> int:
    """Index (in the shared tile) of site j's left neighbour; j itself where there is none."""
    if j > 0:
        return j - 1
    if boundary == BOUNDARY_PERIODIC:
        return n - 1
    return j


@wp.func
def right_index(j: int, n: int, boundary: int) -> int:
    if j < n - 1:
        return j + 1
    if boundary == BOUNDARY_PERIODIC:
        return 0
    return j


@wp.func
def neighbour_or_wall(value: F64, u: F64, has_neighbour: int, boundary: int, side: int) -> F64:
    """The neighbour's u, or at a chain end the wall value on that ``side`` (0 left, 1 right) of the end site u
    (``site.wall_values``: 0 at a fixed wall, u itself at a free end; a ring always has a neighbour)."""
    if has_neighbour != 0:
        return value
    return wall_values(u, u, boundary)[side]


@wp.func
def has_left(j: int, boundary: int) -> int:
    if j > 0 or boundary == BOUNDARY_PERIODIC:
        return 1
    return 0


@wp.func
def has_right(j: int, n: int, boundary: int) -> int:
    if j < n - 1 or boundary == BOUNDARY_PERIODIC:
        return 1
    return 0


@wp.func
def site_neighbours(j: int, n: int, boundary: int) -> wp.vec4i:
    """(left index, right index, has left, has right) of site j: fixed for the whole launch."""
    return wp.vec4i(
        left_index(j, n, boundary), right_index(j, n, boundary), has_left(j, boundary), has_right(j, n, boundary)
    )


@wp.func
def load_site(x: Array3, b: int, j: int, active: bool) -> wp.vec4d:
    """(u, v, u', v') of site j of lattice (or column) b; zeros for the block's idle threads."""
    if active:
        return wp.vec4d(x[b, 0, j], x[b, 1, j], x[b, 2, j], x[b, 3, j])
    return wp.vec4d()


@wp.func
def store_site(x: Array3, b: int, j: int, active: bool, state: wp.vec4d):
    if active:
        for i in range(4):
            x[b, i, j] = state[i]


# ----------------------------------------------------------------------------- kernel factory


#: Splitting methods are compiled per stage count (their stage loop unrolled, coefficients in kernel
#: arguments) up to this many stages; kick and drift coefficients travel as float64 vectors.
MAX_STAGES = 15
coefficients = wp.types.vector(length=MAX_STAGES + 1, dtype=wp.float64)


@wp.struct
class Scheme:
    """A splitting method as the block kernels read it: its drift and kick coefficients times dt, each zero padded
    to ``MAX_STAGES`` + 1 (``pack_scheme``)."""

    drifts: coefficients
    kicks: coefficients


def pack_scheme(drifts, kicks, dt: float = 1.0) -> Scheme:
    """The ``Scheme`` of a method's ``drifts`` and ``kicks`` for step ``dt``. The kernels use c * dt as given: the
    product rounds exactly as the reference's c * dt."""
    if len(kicks) > MAX_STAGES + 1:
        raise ValueError(f"at most {MAX_STAGES} stages are supported by the block kernels, got {len(kicks)}")
    scheme = Scheme()
    for name, values in (("drifts", drifts), ("kicks", kicks)):
        values = [float(c) * float(dt) for c in values]
        setattr(scheme, name, coefficients(*(values + [0.0] * (MAX_STAGES + 1 - len(values)))))
    return scheme


class BlockKernels:
    """The block kernels for one block size, built (and compiled, each in its own Warp module) on
    first use: ``splitting(stages, record, save, damped, observed, tangent)`` (one step loop) and ``guard``.
    Launch each with ``dim=(lattices, block), block_dim=block``."""

    def __init__(self, makers: dict):
        self._makers = makers
        self._built: dict = {}

    def _get(self, *key):
        if key not in self._built:
            self._built[key] = self._makers[key[0]](*key[1:])
        return self._built[key]

    def splitting(
        self,
        stages: int,
        record: bool = False,
        save: bool = False,
        damped: bool = False,
        observed: bool = False,
        tangent: bool = False,
    ):
        """The step loop for ``stages`` stages; ``record``/``save``/``damped``/``observed`` compile in the
        stiffness history, the field recording, the damped kicks and the observables of ``warpchain.observe``
        (left out, they cost nothing); ``tangent`` compiles the linearised step of tangent columns instead (a block
        per column, none of the others)."""
        if not 1 <= stages <= MAX_STAGES:
            raise ValueError(f"the block kernels support 1 to {MAX_STAGES} stages, got {stages}")
        if tangent and (record or save or damped or observed):
            raise ValueError("a tangent run records, saves, damps and observes nothing")
        flags = (bool(record), bool(save), bool(damped), bool(observed), bool(tangent))
        return self._get("splitting", int(stages), *flags)

    @property
    def guard(self):
        """Per-lattice energy, finite flag and running min contact (``kernels.guard_kernel``)."""
        return self._get("guard")

    def built(self) -> dict:
        """The kernels built so far, by key."""
        return dict(self._built)


def min_blocks_per_sm(stages: int) -> int:
    """``__launch_bounds__`` minimum blocks per SM used for a method with this many force
    evaluations per step (0: no register cap). Measured on the H200 (``benchmarks/kernel_variants.py``):
    the many-stage kernels hold ~110 registers uncapped; capped at 56 (5 blocks of 224 threads per
    SM, no spills) kahan8 runs 1.25x faster at 805 lattices and 1.3x at 32768 (a cap of 32 with
    spills is no better); Verlet and the 3-stage methods are fastest uncapped."""
    return 0 if stages <= 4 else 5


@functools.lru_cache(maxsize=None)
def block_kernels(block: int, min_blocks_per_sm: int = 0) -> BlockKernels:
    """The block kernels for ``block`` threads per lattice (a multiple of 32, at most 1024).

    Args:
        block: threads per lattice.
        min_blocks_per_sm: passed to ``__launch_bounds__`` (0: none), which caps registers so that
            this many blocks fit on one SM.
    """
    if block % WARP_LANES or not WARP_LANES <= block <= MAX_BLOCK:
        raise ValueError(f"block must be a multiple of {WARP_LANES} in [{WARP_LANES}, {MAX_BLOCK}], got {block}")
    threads = block
    halves = 2 * threads

    @wp.func
    def exchange(buf: wp.tile[wp.float64, halves], u: F64, parity: int, nbr: wp.vec4i, boundary: int) -> wp.vec2d:
        """Publish u in half ``parity`` of the shared tile; return (left, right) neighbour values."""
        offset = parity * threads
        wp.tile_assign(buf, wp.tile(u), offset=(offset,))
        left = neighbour_or_wall(buf[offset + nbr[0]], u, nbr[2], boundary, 0)
        right = neighbour_or_wall(buf[offset + nbr[1]], u, nbr[3], boundary, 1)
        return wp.vec2d(left, right)

    @wp.func
    def observe_frame(
        buf: wp.tile[wp.float64, halves],
        parity: int,
        state: wp.vec4d,
        nb: wp.vec2d,
        z_range: wp.vec2d,
        active: bool,
        b: int,
        j: int,
        n: int,
        lat: Lattice,
        ob: Observer,
        r: int,
        lost_site: F64,
    ):
        """``thread_kernels.observe_frame`` as block reductions: frame r of lattice b from each site's state, its
        neighbours' u (``nb``, walls included), z extremes (``z_range``: low, high) and dissipated energy; the
        envelope is shared through half ``parity`` of the tile (the caller flips parity before, as for an
        exchange). Idle threads add nothing."""
        env = ZERO
        e = ZERO
        inside = ZERO
        low = NO_CONTACT
        mine = ZERO  # idle threads run a fake dynamics (never stored): they dissipate nothing real
        if active:
            env = wp.max(z_range[1], -z_range[0])
            e = site_energy(
                state[0], state[1], state[2], state[3], nb[0], nb[1], j, lat.boundary, lat.mass[b], lat.coupling[b]
            )
            if wp.abs(wp.float64(j - n / 2)) <= ob.spot[b]:
                inside = e
            low = ONE + z_range[0]
            mine = lost_site
            ob.envelope[b, j] = env
        offset = parity * threads
        wp.tile_assign(buf, wp.tile(env), offset=(offset,))
        peak = ZERO
        if active and env > ob.threshold:
            test = wp.vec3d(ONE, env, env)
            for i in range(1, ob.radius + 1):
                left = ZERO  # past the chain's end
                right = ZERO
                if j - i >= 0:
                    left = buf[offset + j - i]
                if j + i < n:
                    right = buf[offset + j + i]
                test = peak_test(env, left, right, test)
            peak = peak_verdict(env, test, ob.contrast)
        lost_total = wp.tile_sum(wp.tile(mine))
        peaks = wp.tile_sum(wp.tile(peak))
        total = wp.tile_sum(wp.tile(e))
        squares = wp.tile_sum(wp.tile(e * e))
        spot_total = wp.tile_sum(wp.tile(inside))
        top = wp.tile_max(wp.tile(env))
        lowest = wp.tile_min(wp.tile(low))
        if j == 0:
            store_observables(ob, r, b, peaks[0], total[0], squares[0], spot_total[0], top[0], lowest[0], lost_total[0])

    bounds = (threads, min_blocks_per_sm) if min_blocks_per_sm else threads
    options = {"enable_backward": False, "module": "unique", "grid_stride": False, "launch_bounds": bounds}

    def make_splitting(
        stages: int, record: bool, save: bool, damped: bool = False, observed: bool = False, tangent: bool = False
    ):
        held_type = wp.types.vector(length=stages, dtype=wp.float64)

        @wp.kernel(**options)
        def splitting(
            x: Array3, column_base: Indices, lat: Lattice, scheme: Scheme, nsteps: int, out: Recording, ob: Observer
        ):
            """``nsteps`` steps of a kick-drift splitting method; lattice b, thread j = site. hist slot 0
            holds f'(z) at the start, slot step*s + k + 1 after drift k of ``step``. Compiled ``tangent``: block b
            is tangent column b along base trajectory column_base[b], the linearised step with the base's f'(z) read
            from ``out.hist`` one force evaluation ahead (the load is issued before the exchange's barrier, its latency
            hides behind it); nothing else is compiled in. Compiled ``damped``:
            lattices with ``lat.lossy[b]`` set take the damped kicks of ``lat.damp`` (batch, stages + 1, 12: E, F,
            and H for the energy dissipated). Compiled ``observed`` (and ``damped``): the observables of ``ob``
            (``warpchain.observe``), each site's z extremes and dissipated energy in registers.
            The step's stiffnesses are held in registers and stored after its last stage: a barrier waits for
            the stores issued before it, so a store at every force evaluation put that wait between every two."""
            b, j = wp.tid()
            drifts = scheme.drifts
            kicks = scheme.kicks
            boundary = lat.boundary
            damp = lat.damp
            n = x.shape[2]
            nbr = site_neighbours(j, n, boundary)
            active = j < n
            b_read = b  # the lattice whose parameters (and, for a tangent column, history) this block reads
            if wp.static(tangent):
                b_read = column_base[b]
            jj = wp.min(j, n - 1)  # idle threads read a valid (unused) history entry
            last = out.hist.shape[0] - 1
            start = load_site(x, b, j, active)
            u = start[0]
            v = start[1]
            pu = start[2]
            pv = start[3]
            m = lat.inv_mass[b_read]
            k = lat.coupling[b_read]
            loss = int(0)
            if wp.static(damped):
                loss = lat.lossy[b_read]
            buf = wp.tile_zeros(shape=(halves,), dtype=wp.float64, storage="shared")
            parity = int(0)
            nb = exchange(buf, u, parity, nbr, boundary)
            stiff = ZERO  # tangent: f'(z) of the base at the next force evaluation
            if wp.static(tangent):
                stiff = out.hist[wp.min(1, last), b_read, jj]
                a = site_tangent_acceleration(u, v, nb[0], nb[1], m, k, out.hist[0, b_read, jj])
            else:
                a = site_acceleration(u, v, nb[0], nb[1], m, k)
            if wp.static(record):
                if active:
                    out.hist[0, b, j] = contact_stiffness(u - v)
            lost_site = ZERO  # observed: the energy this site has dissipated (exact over each damped kick)
            z_range = wp.vec2d(u - v, u - v)  # observed: the site's z extremes since the last frame
            if wp.static(observed):
                if ob.first_step == 0:  # frame 0: the start (envelope |z|)
                    parity = 1 - parity
                    observe_frame(buf, parity, start, nb, z_range, active, b, j, n, lat, ob, 0, ZERO)
                    z_range = wp.vec2d(NO_CONTACT, -NO_CONTACT)
                elif active:
                    z_range = wp.vec2d(ob.z_low[b, j], ob.z_high[b, j])
                    lost_site = ob.lost[b, j]
            held = held_type()  # the step's stiffnesses, stored after its last stage
            for step in range(nsteps):
                h = kicks[0]  # the coefficients arrive multiplied by dt (on the host: the same product)
                if wp.static(damped):
                    if wp.static(observed):
                        if loss != 0:
                            lost_site = lost_site + kick_loss(pu, pv, a[0], a[1], damp, b_read, 0, lat.mass[b])
                    w = site_kick(pu, pv, a, h, loss, damp, b_read, 0)
                    pu = w[0]
                    pv = w[1]
                else:
                    pu = pu + h * a[0]
                    pv = pv + h * a[1]
                for s in range(wp.static(stages)):  # unrolled: coefficients become constants
                    h = drifts[s]
                    u = u + h * pu
                    v = v + h * pv
                    now = stiff
                    if wp.static(tangent):
                        stiff = out.hist[wp.min(step * wp.static(stages) + s + 2, last), b_read, jj]
                    parity = 1 - parity
                    nb = exchange(buf, u, parity, nbr, boundary)
                    if wp.static(tangent):
                        a = site_tangent_acceleration(u, v, nb[0], nb[1], m, k, now)
                    else:
                        a = site_acceleration(u, v, nb[0], nb[1], m, k)
                    if wp.static(record):
                        held[s] = contact_stiffness(u - v)
                    h = kicks[s + 1]
                    if wp.static(damped):
                        if wp.static(observed):
                            if loss != 0:
                                lost_site = lost_site + kick_loss(pu, pv, a[0], a[1], damp, b_read, s + 1, lat.mass[b])
                        w = site_kick(pu, pv, a, h, loss, damp, b_read, s + 1)
                        pu = w[0]
                        pv = w[1]
                    else:
                        pu = pu + h * a[0]
                        pv = pv + h * a[1]
                if wp.static(record):
                    if active:
                        for s in range(wp.static(stages)):
                            out.hist[step * wp.static(stages) + s + 1, b, j] = held[s]
                if wp.static(save):
                    if active and (step + 1) % out.every == 0:
                        r = (step + 1) / out.every - 1
                        out.u[r, b, j] = u
                        out.v[r, b, j] = v
                if wp.static(observed):
                    z_range = wp.vec2d(wp.min(z_range[0], u - v), wp.max(z_range[1], u - v))
                    done = ob.first_step + step + 1
                    if done % ob.frame_every == 0:
                        parity = 1 - parity
                        state = wp.vec4d(u, v, pu, pv)
                        r = done / ob.frame_every
                        lost = lost_site
                        observe_frame(buf, parity, state, nb, z_range, active, b, j, n, lat, ob, r, lost)
                        z_range = wp.vec2d(NO_CONTACT, -NO_CONTACT)
            store_site(x, b, j, active, wp.vec4d(u, v, pu, pv))
            if wp.static(observed):
                if active:
                    ob.z_low[b, j] = z_range[0]
                    ob.z_high[b, j] = z_range[1]
                    ob.lost[b, j] = lost_site

        return splitting

    @wp.kernel(**options)
    def guard(x: Array3, lat: Lattice, rec: Recording, n_rec: int, contact: Array1, out: Array2):
        """``kernels.guard_kernel`` with a block per lattice (coalesced reads, block reductions); a lattice
        longer than the block (the ``"sites"`` layout) has each thread take sites j, j + block, ..."""
        b, j = wp.tid()
        n = x.shape[2]
        e = ZERO  # idle threads (past the lattice's end) contribute these: 0, finite, no contact
        finite = ONE
        low = NO_CONTACT
        site = j
        while site < n:
            state = load_site(x, b, site, True)
            if lat.degree > 0:  # a neighbour table (the sites layout)
                bonds = table_bonds(x, b, site, state[0], lat)
                e = e + held_energy(state[0], state[1], state[2], state[3], bonds, lat.mass[b], lat.coupling[b])
            else:
                nb = neighbours_at(x, b, 0, site, n, lat.boundary)
                e = e + site_energy(
                    state[0],
                    state[1],
                    state[2],
                    state[3],
                    nb[0],
                    nb[1],
                    site,
                    lat.boundary,
                    lat.mass[b],
                    lat.coupling[b],
                )
            finite = wp.min(finite, finite_state(state[0], state[1], state[2], state[3]))
            low = wp.min(low, (ONE + state[0]) - state[1])
            for r in range(n_rec):
                low = wp.min(low, (ONE + rec.u[r, b, site]) - rec.v[r, b, site])
            site += wp.static(threads)
        total = wp.tile_sum(wp.tile(e))
        all_finite = wp.tile_min(wp.tile(finite))
        lowest = wp.tile_min(wp.tile(low))
        if j == 0:
            c = wp.min(contact[b], lowest[0])
            contact[b] = c
            out[b, 0] = total[0]
            out[b, 1] = all_finite[0]
            out[b, 2] = c

    return BlockKernels(
        {
            "guard": lambda: guard,
            "splitting": make_splitting,
        }
    )
