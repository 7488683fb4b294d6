"""The ``"sites"`` layout: lattices longer than a thread block, a thread per site, one launch per force
evaluation (float64). The GPU path for N > 1024 with a splitting method; on the CPU it runs too (the tests
check it against the numpy reference bit for bit).

Why: the block layouts hold a lattice in one thread block (at most 1024 threads, and a block's registers:
a lattice of 12801 sites holds 51 204 float64 of state, more than one SM's register file), so a longer
lattice ran on one thread per lattice, and one tangent column of N = 3201 over half a period took 120 ms
on an H100. Here every site has its own thread, across as many blocks as the lattice needs, and the only
synchronisation, the neighbours' u before a force evaluation, is the end of a launch. A half period of
``kahan8`` at 16 steps is 241 launches, replayed as one CUDA graph by the ``Flow``.

One launch is one force evaluation ``e`` (``evaluate``): site j reads its u from ``src`` (drifted for this
evaluation) and its neighbours' u from the same array (the chain's ``site.neighbours_at``, or a
lattice's neighbour table: ``table_laplacian``), computes the accelerations (``coupled_acceleration``: the base's
contact law; ``coupled_tangent_acceleration`` for a tangent lane, with the base's recorded f'(z) of evaluation
e), gives the kick
that follows the evaluation, records the frame when a step ends, gives the next step's first kick with the
same accelerations (as the reference, which does not recompute them) and writes the u of the next
evaluation, drifted, into ``dst``. ``src`` and ``dst`` alternate between the state's row 0 and a scratch
row (ping-pong), so no thread overwrites a u another thread still reads. Same operations in the same order
as ``reference.integrate`` and the other layouts.

A 2-D lattice (the square and triangular monolayers: ``warpchain.lattice.LatticeParams``) runs here: its
neighbour table, carried in the ``Lattice`` struct, replaces ``neighbours_at``; the launch sequence
(``evaluations``), the kick/drift arithmetic, the tangent lanes and the guard (``table_bonds``) stay. It is the
one layout that takes a table (a thread per site needs no neighbour within a block or a thread's run).
"""

import warp as wp


from .thread_kernels import (
    base_of,
)
from .site import (
    Lattice,
    Observer,
    Recording,
    Array1,
    Array2,
    NO_CONTACT,
    ONE,
    held_energy,
    kick_loss,
    window_peak,
    site_energy,
    store_observables,
    table_bonds,
    F64,
    Array3,
    Indices,
    ZERO,
    contact_stiffness,
    coupled_acceleration,
    coupled_tangent_acceleration,
    neighbours_at,
    site_kick,
    table_laplacian,
)

#: ``drift`` values of ``evaluate``: drift u by c into dst; copy u into dst unchanged; leave dst alone
DRIFT, COPY, KEEP = 1, 0, -1


def _evaluate(observed: bool):
    """``evaluate``, or compiled ``observed`` (``observed_evaluate``): the observables' tracking in the same pass
    (left out, it costs nothing: a run-time flag cost the CPU's sites layout 14 % per site)."""

    @wp.kernel(enable_backward=False)
    def evaluate(
        x: Array3,
        src: Array3,
        src_row: int,
        dst: Array3,
        dst_row: int,
        column_base: Indices,
        lat: Lattice,
        tangent: int,
        slot: int,
        out: Recording,
        kick: int,
        h_kick: F64,
        pre: int,
        h_pre: F64,
        drift: int,
        c: F64,
        save_row: int,
        ends: int,
        ob: Observer,
    ):
        """Force evaluation ``slot`` of lattice (or tangent column) b at site j, and the kicks and drift around it.

        Args (beyond the state ``x``, (lattices, 4, N): v, u', v' updated in place; u in ``src``/``dst``):
            tangent: 1 for tangent columns (accelerations linear in the column, f'(z) read from
                hist[slot, column_base[b]]; the parameters those of lattice column_base[b]), 0 for base runs
                (f'(z) stored into ``out.hist[slot, b]`` when ``out.stiffness`` is set).
            kick, h_kick: index of the kick after this evaluation (-1: none, the run's first evaluation).
            pre, h_pre: 1 when a step begins after it: its kick 0 with the same accelerations.
            drift, c: ``DRIFT`` (u + c u' into dst, v + c v'), ``COPY`` (u into dst: the run's end, u on the
                scratch row) or ``KEEP`` (the run's end, u already in the state's row 0).
            save_row: frame row of ``out.u``, ``out.v`` for (u, v) after this evaluation's kicks, -1 for none.
            ends, ob: compiled ``observed``, the energy each damped kick dissipates is added to ``ob.lost[b, j]``
                and, where a step ends (``ends``), z = u - v to the extremes ``ob.z_low``, ``ob.z_high``
                (``observe_frame`` reduces them per frame).
        """
        b, j = wp.tid()
        n = x.shape[2]
        hist = out.hist
        base = base_of(b, tangent, column_base)
        m = lat.inv_mass[base]
        k = lat.coupling[base]
        u = src[b, src_row, j]
        v = x[b, 1, j]
        lap = ZERO
        if lat.degree > 0:
            lap = table_laplacian(src, b, src_row, j, u, lat)
        else:
            nb = neighbours_at(src, b, src_row, j, n, lat.boundary)
            lap = (u - nb[0]) + (u - nb[1])
        loss = int(0)
        if tangent != 0:
            a = coupled_tangent_acceleration(u, v, lap, m, k, hist[slot, base, j])
        else:
            a = coupled_acceleration(u, v, lap, m, k)
            loss = lat.lossy[b]
            if out.stiffness != 0:
                hist[slot, b, j] = contact_stiffness(u - v)
        pu = x[b, 2, j]
        pv = x[b, 3, j]
        if kick >= 0:
            if wp.static(observed):
                if loss != 0:
                    ob.lost[b, j] = ob.lost[b, j] + kick_loss(pu, pv, a[0], a[1], lat.damp, b, kick, lat.mass[b])
            w = site_kick(pu, pv, a, h_kick, loss, lat.damp, b, kick)
            pu = w[0]
            pv = w[1]
        if save_row >= 0:
            out.u[save_row, b, j] = u
            out.v[save_row, b, j] = v
        if wp.static(observed):
            if ends != 0:
                ob.z_low[b, j] = wp.min(ob.z_low[b, j], u - v)
                ob.z_high[b, j] = wp.max(ob.z_high[b, j], u - v)
        if pre != 0:
            if wp.static(observed):
                if loss != 0:
                    ob.lost[b, j] = ob.lost[b, j] + kick_loss(pu, pv, a[0], a[1], lat.damp, b, 0, lat.mass[b])
            w = site_kick(pu, pv, a, h_pre, loss, lat.damp, b, 0)
            pu = w[0]
            pv = w[1]
        if drift == DRIFT:
            dst[b, dst_row, j] = u + c * pu
            x[b, 1, j] = v + c * pv
        elif drift == COPY:
            dst[b, dst_row, j] = u
        x[b, 2, j] = pu
        x[b, 3, j] = pv

    return evaluate


evaluate = _evaluate(False)
observed_evaluate = _evaluate(True)


def evaluations(drifts, kicks, dt: float, nsteps: int, save_every: int = 0):
    """The launches of ``nsteps`` steps of a splitting method, in order: per force evaluation a dict of
    ``evaluate``'s scalar arguments (slot, kick, h_kick, pre, h_pre, c, save_row, and ``last``: the run's
    final evaluation). Evaluation 0 is the start (no kick before it), evaluation step * stages + s + 1 follows
    drift s of ``step`` (the history slots of the other layouts). The coefficients times dt are the products
    the other kernels form."""
    stages = len(drifts)
    total = nsteps * stages
    out = []
    for e in range(total + 1):
        step, s = divmod(e - 1, stages)
        kick, h_kick = (-1, 0.0) if e == 0 else (s + 1, float(kicks[s + 1]) * float(dt))
        ends_step = e > 0 and s == stages - 1
        begins = (e == 0 and nsteps > 0) or (ends_step and step + 1 < nsteps)
        save_row = -1
        if ends_step and save_every and (step + 1) % save_every == 0:
            save_row = (step + 1) // save_every - 1
        c = float(drifts[e % stages]) * float(dt) if e < total else 0.0
        out.append(
            dict(
                slot=e,
                kick=kick,
                h_kick=h_kick,
                pre=int(begins),
                h_pre=float(kicks[0]) * float(dt),
                c=c,
                save_row=save_row,
                ends=int(ends_step),
                last=e == total,
            )
        )
    return out


# ----------------------------------------------------------------------------- observables (``warpchain.observe``)


@wp.struct
class Neighbourhoods:
    """The peak rule's geometry on a lattice given as a table (``reference.table_peak_mask``): each site's ball of
    ``radius`` bonds (CSR ``ball_ptr``, ``ball_idx``, the site itself included), the table and its weights (the rays
    of the localization test) and each site's distance from the centre site (``dist``: the spot). ``degree`` 0: the
    chain's rule (windows of sites, ``reference.peak_mask``), none of these read."""

    degree: int
    ball_ptr: Indices
    ball_idx: Indices
    table: wp.array2d(dtype=wp.int32)
    weights: Array2
    dist: Array1


@wp.kernel
def observe_envelope(x: Array3, ob: Observer, start: int):
    """Site j's envelope of the frame that ends here: max |z| over the steps since the last frame (``start``: frame
    0, the z of ``x`` itself, which also starts the extremes)."""
    b, j = wp.tid()
    if start != 0:
        z = x[b, 0, j] - x[b, 1, j]
        ob.z_low[b, j] = z
        ob.z_high[b, j] = z
    ob.envelope[b, j] = wp.max(ob.z_high[b, j], -ob.z_low[b, j])


def _observe_frame(block: int):
    @wp.kernel(enable_backward=False, module="unique")
    def observe_frame(x: Array3, lat: Lattice, ob: Observer, nh: Neighbourhoods, r: int):
        """Frame r of lattice b (``reference.frame_observables``), a block per lattice, thread j taking sites j,
        j + block, ...: the envelopes (``observe_envelope``) tested for peaks, the site energies, the spot's, the
        extremes and the dissipated energy reduced over the block; then the z extremes start again."""
        b, j = wp.tid()
        n = x.shape[2]
        total = ZERO
        squares = ZERO
        inside = ZERO
        top = ZERO
        low = NO_CONTACT
        peaks = ZERO
        lost = ZERO
        site = j
        while site < n:
            u = x[b, 0, site]
            v = x[b, 1, site]
            pu = x[b, 2, site]
            pv = x[b, 3, site]
            if lat.degree > 0:
                e = held_energy(u, v, pu, pv, table_bonds(x, b, site, u, lat), lat.mass[b], lat.coupling[b])
            else:
                nb = neighbours_at(x, b, 0, site, n, lat.boundary)
                e = site_energy(u, v, pu, pv, nb[0], nb[1], site, lat.boundary, lat.mass[b], lat.coupling[b])
            env = ob.envelope[b, site]
            total = total + e
            squares = squares + e * e
            here = wp.abs(wp.float64(site - n / 2))
            if nh.degree > 0:
                here = nh.dist[site]
            if here <= ob.spot[b]:
                inside = inside + e
            top = wp.max(top, env)
            low = wp.min(low, ONE + ob.z_low[b, site])
            lost = lost + ob.lost[b, site]
            if env > ob.threshold:
                if nh.degree > 0:
                    ok = ONE
                    for k in range(nh.ball_ptr[site], nh.ball_ptr[site + 1]):
                        t = nh.ball_idx[k]
                        other = ob.envelope[b, t]
                        if (t < site and not env > other) or (t > site and not env >= other):
                            ok = ZERO
                    for d in range(nh.degree):
                        if nh.weights[site, d] != ZERO:
                            ray = NO_CONTACT
                            t = site
                            for i in range(ob.radius):
                                if t >= 0:
                                    t = nh.table[t, d]
                                if t >= 0:
                                    ray = wp.min(ray, ob.envelope[b, t])
                                else:
                                    ray = ZERO
                            if not ray <= ob.contrast * env:
                                ok = ZERO
                    peaks = peaks + ok
                else:  # the chain's windows
                    peaks = peaks + window_peak(ob.envelope, b, site, n, env, ob.radius, ob.contrast)
            ob.z_low[b, site] = NO_CONTACT  # the next frame's extremes
            ob.z_high[b, site] = -NO_CONTACT
            site += wp.static(block)
        sums = wp.tile_sum(wp.tile(total))
        sq = wp.tile_sum(wp.tile(squares))
        spot = wp.tile_sum(wp.tile(inside))
        most = wp.tile_max(wp.tile(top))
        least = wp.tile_min(wp.tile(low))
        count = wp.tile_sum(wp.tile(peaks))
        gone = wp.tile_sum(wp.tile(lost))
        if j == 0:
            store_observables(ob, r, b, count[0], sums[0], sq[0], spot[0], most[0], least[0], gone[0])

    return observe_frame


#: threads per lattice of ``observe_frame``
FRAME_BLOCK = 256
observe_frame = _observe_frame(FRAME_BLOCK)
