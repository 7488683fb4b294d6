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
    Recording,
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


@wp.kernel
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
        w = site_kick(pu, pv, a, h_kick, loss, lat.damp, b, kick)
        pu = w[0]
        pv = w[1]
    if save_row >= 0:
        out.u[save_row, b, j] = u
        out.v[save_row, b, j] = v
    if pre != 0:
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
                last=e == total,
            )
        )
    return out
