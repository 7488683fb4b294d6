"""NVIDIA Warp kernels (float64) for batches of mass-in-mass chains.

Layout: a batch state is a ``wp.array3d`` of shape (batch, 4, N) ordered (u, v, u', v'). Each
kernel thread owns one lattice (``b = wp.tid()``) and loops over time *inside* the kernel, so a
long run costs one launch per chunk of many steps, never one per step. All per-site arithmetic
lives in ``@wp.func`` helpers that take (lattice, site) indices, so that a later kernel where a
thread block owns a lattice (one thread per site) can reuse them unchanged.

The splitting and Runge-Kutta kernels (and the splitting tangent kernel) take a fast path where a
lattice's rows are contiguous (always, as ``ensemble`` allocates them): each stage is one pass over the
sites (``fused_stage``, ``rk4_fused_stage``) through 1-D row views (``row``), whose compile-time unit
stride lets the CPU compiler vectorise the pass. Every value is computed by the same operations in the
same order as the per-pass helpers below, which remain the path for strided arrays and, in the splitting
kernels, for lattices with losses and N = 1.

Accelerations multiply by a precomputed 1/M (``inv_mass`` arrays, rounded once on the host, as the numpy
reference does): no division in any time loop.

Float constants are module-level ``wp.constant`` values: a literal such as ``wp.float64(2.0/3.0)``
written inside a kernel is evaluated in float32 (errors of ~5e-9), which these avoid.

Tangent runs (exact derivative of the discrete map): the base kernel records the contact stiffness
f'(z_j) at every force evaluation of the base trajectory into a history array (n_evals, n_base, N);
the tangent kernels then propagate Jacobian columns, one column per thread, reading that history.
A column costs a linear step, not a nonlinear one, and all columns of a base trajectory share it.
"""

from __future__ import annotations

import warp as wp

ZERO = wp.constant(wp.float64(0.0))
ONE = wp.constant(wp.float64(1.0))
TWO = wp.constant(wp.float64(2.0))
HALF = wp.constant(wp.float64(0.5))
SIX = wp.constant(wp.float64(6.0))
TWO_THIRDS = wp.constant(wp.float64(2.0 / 3.0))
TWO_FIFTHS = wp.constant(wp.float64(0.4))
FOUR_FIFTEENTHS = wp.constant(wp.float64(4.0 / 15.0))
#: the min-contact value of a site that holds nothing (idle block threads): larger than any real one
NO_CONTACT = wp.constant(wp.float64(1.0e300))

BOUNDARY_FIXED = wp.constant(0)
BOUNDARY_FREE = wp.constant(1)
BOUNDARY_PERIODIC = wp.constant(2)


# ----------------------------------------------------------------------------- per-site helpers


@wp.func
def contact_force(z: wp.float64) -> wp.float64:
    """f(z) = (2/3)([1 + z]_+^{3/2} - 1). Branch-free (a select, not a jump: cheaper on a GPU);
    ``max(0, s)`` keeps a NaN as NaN, as numpy's ``maximum`` does."""
    s = wp.max(ZERO, ONE + z)
    return TWO_THIRDS * (s * wp.sqrt(s) - ONE)


@wp.func
def contact_potential(z: wp.float64) -> wp.float64:
    """(2/3)((2/5)[1+z]_+^{5/2} - z) - 4/15, as ``model.contact_potential``."""
    s = wp.max(ZERO, ONE + z)
    return TWO_THIRDS * (TWO_FIFTHS * s * s * wp.sqrt(s) - z) - FOUR_FIFTEENTHS


@wp.func
def contact_stiffness(z: wp.float64) -> wp.float64:
    """f'(z) = [1 + z]_+^{1/2}."""
    return wp.sqrt(wp.max(ZERO, ONE + z))


@wp.func
def wall_values(first: wp.float64, last: wp.float64, boundary: int) -> wp.vec2d:
    """(the u left of site 0, the u right of site n - 1) given the u of site 0 (``first``) and of site n - 1
    (``last``): 0 at a fixed wall, the site itself at a free end, the other end on a ring. The one place the
    kernels define a boundary's values (the block kernels through ``block_kernels.neighbour_or_wall``; the
    site-group kernels compile the same three cases in); the energy's wall bonds are in ``site_energy``."""
    if boundary == BOUNDARY_FREE:
        return wp.vec2d(first, last)
    if boundary == BOUNDARY_PERIODIC:
        return wp.vec2d(last, first)
    return wp.vec2d(ZERO, ZERO)


@wp.func
def neighbours_at(x: wp.array3d(dtype=wp.float64), b: int, comp: int, j: int, n: int, boundary: int) -> wp.vec2d:
    """(u_{j-1}, u_{j+1}) of component ``comp`` of lattice b, the wall values (``wall_values``) at the ends."""
    wall = wall_values(x[b, comp, 0], x[b, comp, n - 1], boundary)
    left = wall[0]
    right = wall[1]
    if j > 0:
        left = x[b, comp, j - 1]
    if j < n - 1:
        right = x[b, comp, j + 1]
    return wp.vec2d(left, right)


@wp.func
def laplacian_at(x: wp.array3d(dtype=wp.float64), b: int, comp: int, j: int, n: int, boundary: int) -> wp.float64:
    """(u_j - u_{j-1}) + (u_j - u_{j+1}) of component ``comp`` of lattice b at site j."""
    u = x[b, comp, j]
    nb = neighbours_at(x, b, comp, j, n, boundary)
    return (u - nb[0]) + (u - nb[1])


@wp.func
def acceleration_at(
    x: wp.array3d(dtype=wp.float64), b: int, j: int, n: int, boundary: int, inv_mass: wp.float64, coupling: wp.float64
) -> wp.vec2d:
    """(u_j'', v_j'') of lattice b from the positions in rows 0 and 1 of x."""
    force = contact_force(x[b, 0, j] - x[b, 1, j])
    au = -(coupling * laplacian_at(x, b, 0, j, n, boundary) + force) * inv_mass
    return wp.vec2d(au, force)


@wp.func
def tangent_acceleration_at(
    dx: wp.array3d(dtype=wp.float64),
    c: int,
    j: int,
    n: int,
    boundary: int,
    inv_mass: wp.float64,
    coupling: wp.float64,
    stiffness: wp.float64,
) -> wp.vec2d:
    """Derivative of (u_j'', v_j'') along the tangent column c (positions in rows 0, 1 of dx)."""
    dz = dx[c, 0, j] - dx[c, 1, j]
    au = -(coupling * laplacian_at(dx, c, 0, j, n, boundary) + stiffness * dz) * inv_mass
    return wp.vec2d(au, stiffness * dz)


@wp.func
def compute_accelerations(
    x: wp.array3d(dtype=wp.float64),
    acc: wp.array3d(dtype=wp.float64),
    b: int,
    base: int,
    n: int,
    boundary: int,
    inv_mass: wp.float64,
    coupling: wp.float64,
    tangent: int,
    hist: wp.array3d(dtype=wp.float64),
    record: int,
    slot: int,
    row: int,
):
    """acc[b, row], acc[b, row + 1] = a(x[b]) (u'', v''), recording hist[slot, b, :] = f'(z) when ``record`` is set;
    with ``tangent`` the linear accelerations of column b along the f'(z) of base lattice ``base`` in hist[slot]."""
    for j in range(n):
        if tangent != 0:
            a = tangent_acceleration_at(x, b, j, n, boundary, inv_mass, coupling, hist[slot, base, j])
        else:
            a = acceleration_at(x, b, j, n, boundary, inv_mass, coupling)
            if record != 0:
                hist[slot, b, j] = contact_stiffness(x[b, 0, j] - x[b, 1, j])
        acc[b, row, j] = a[0]
        acc[b, row + 1, j] = a[1]


@wp.func
def kick(x: wp.array3d(dtype=wp.float64), acc: wp.array3d(dtype=wp.float64), b: int, n: int, h: wp.float64):
    for j in range(n):
        x[b, 2, j] = x[b, 2, j] + h * acc[b, 0, j]
        x[b, 3, j] = x[b, 3, j] + h * acc[b, 1, j]


@wp.func
def drift(x: wp.array3d(dtype=wp.float64), b: int, n: int, h: wp.float64):
    for j in range(n):
        x[b, 0, j] = x[b, 0, j] + h * x[b, 2, j]
        x[b, 1, j] = x[b, 1, j] + h * x[b, 3, j]


@wp.func
def save_positions(
    x: wp.array3d(dtype=wp.float64),
    rec_u: wp.array3d(dtype=wp.float64),
    rec_v: wp.array3d(dtype=wp.float64),
    b: int,
    n: int,
    step: int,
    save_every: int,
):
    if save_every > 0:
        if (step + 1) % save_every == 0:
            r = (step + 1) / save_every - 1
            for j in range(n):
                rec_u[r, b, j] = x[b, 0, j]
                rec_v[r, b, j] = x[b, 1, j]


# ----------------------------------------------------------------------------- row views (fused sweeps)


@wp.func_native("return (wp::uint64)(&wp::index(x, i, r, 0));")
def _row_address(x: wp.array3d(dtype=wp.float64), i: int, r: int) -> wp.uint64: ...


@wp.func_native("return x.strides[2] == (int)sizeof(wp::float64) ? 1 : 0;")
def unit_stride(x: wp.array3d(dtype=wp.float64)) -> int:
    """1 when the last axis of x is contiguous (what ``row`` needs), else 0."""


@wp.func
def row(x: wp.array3d(dtype=wp.float64), i: int, r: int) -> wp.array(dtype=wp.float64):
    """x[i, r, :] as a 1-D array of unit stride (only where ``unit_stride(x)``). Its stride is a compile-time
    constant, so that the compiler can vectorise a loop over sites; through the 3-D array's runtime
    strides it cannot (on the project's AVX-512 CPU the fused sweep runs 8 sites per instruction)."""
    return wp.array(ptr=_row_address(x, i, r), shape=(x.shape[2],), dtype=wp.float64)


@wp.func
def site_acceleration(
    u: wp.float64, v: wp.float64, left: wp.float64, right: wp.float64, inv_mass: wp.float64, coupling: wp.float64
) -> wp.vec2d:
    """(u_j'', v_j'') from u_j, v_j and the u of both neighbours (or the wall values): the arithmetic of
    ``acceleration_at`` (and ``laplacian_at``) and of the numpy reference, operation for operation,
    multiplied by 1/M. Shared by the thread kernels' fused sweep and the block kernels."""
    force = contact_force(u - v)
    au = -(coupling * ((u - left) + (u - right)) + force) * inv_mass
    return wp.vec2d(au, force)


@wp.func
def site_tangent_acceleration(
    du: wp.float64,
    dv: wp.float64,
    left: wp.float64,
    right: wp.float64,
    inv_mass: wp.float64,
    coupling: wp.float64,
    stiffness: wp.float64,
) -> wp.vec2d:
    """The linear accelerations of a tangent (du, dv) at a site whose base has f'(z) = ``stiffness``
    (``tangent_acceleration_at``'s arithmetic)."""
    dz = du - dv
    au = -(coupling * ((du - left) + (du - right)) + stiffness * dz) * inv_mass
    return wp.vec2d(au, stiffness * dz)


@wp.func
def advance_site(
    u: wp.array(dtype=wp.float64),
    v: wp.array(dtype=wp.float64),
    pu: wp.array(dtype=wp.float64),
    pv: wp.array(dtype=wp.float64),
    au: wp.array(dtype=wp.float64),
    av: wp.array(dtype=wp.float64),
    j: int,
    pre: int,
    h_pre: wp.float64,
    c: wp.float64,
) -> wp.vec4d:
    """Site j's kick with the stored accelerations (when ``pre``; as ``kick``) and its drift (as ``drift``):
    returns (u, v, u', v') after them, not yet stored. A select, not a branch: a branch here keeps the
    compiler from vectorising the sweep (2.8 against 0.7 ns per site-step)."""
    qu = wp.where(pre != 0, pu[j] + h_pre * au[j], pu[j])
    qv = wp.where(pre != 0, pv[j] + h_pre * av[j], pv[j])
    return wp.vec4d(u[j] + c * qu, v[j] + c * qv, qu, qv)


def _fused_stage(tangent: bool):
    """``fused_stage`` compiled for base runs (``tangent`` False: the contact law, f'(z) recorded when asked)
    or for tangent columns (``fused_tangent_stage``: the linear accelerations with the base's f'(z) of this
    stage in ``stiffness``)."""

    @wp.func
    def finish_site(
        u: wp.array(dtype=wp.float64),
        v: wp.array(dtype=wp.float64),
        pu: wp.array(dtype=wp.float64),
        pv: wp.array(dtype=wp.float64),
        au: wp.array(dtype=wp.float64),
        av: wp.array(dtype=wp.float64),
        j: int,
        left: wp.float64,
        site: wp.vec4d,
        right: wp.float64,
        inv_mass: wp.float64,
        coupling: wp.float64,
        h: wp.float64,
        record: int,
        stiffness: wp.array(dtype=wp.float64),
    ):
        """Site j (``site``: from ``advance_site``) between neighbours at u = left and right: its acceleration
        (and f'(z) when ``record``), the kick with it, and the stores."""
        if wp.static(tangent):
            a = site_tangent_acceleration(site[0], site[1], left, right, inv_mass, coupling, stiffness[j])
        else:
            a = site_acceleration(site[0], site[1], left, right, inv_mass, coupling)
        u[j] = site[0]
        v[j] = site[1]
        au[j] = a[0]
        av[j] = a[1]
        pu[j] = site[2] + h * a[0]
        pv[j] = site[3] + h * a[1]
        if wp.static(not tangent):
            if record != 0:
                stiffness[j] = contact_stiffness(site[0] - site[1])

    @wp.func
    def fused_stage(
        u: wp.array(dtype=wp.float64),
        v: wp.array(dtype=wp.float64),
        pu: wp.array(dtype=wp.float64),
        pv: wp.array(dtype=wp.float64),
        au: wp.array(dtype=wp.float64),
        av: wp.array(dtype=wp.float64),
        n: int,
        boundary: int,
        inv_mass: wp.float64,
        coupling: wp.float64,
        pre: int,
        h_pre: wp.float64,
        c: wp.float64,
        h: wp.float64,
        record: int,
        stiffness: wp.array(dtype=wp.float64),
    ):
        """One stage of a splitting step on one lattice's rows (n >= 2) in a single pass over the sites: the
        kick h_pre (when ``pre``: the step's first), the drift c, the accelerations (f'(z) into ``stiffness``
        when ``record``) and the kick h. Each value is computed as by ``kick``, ``drift`` and
        ``compute_accelerations`` one after the other (same operations, same order): site j + 1 is drifted
        just before site j's acceleration needs it, the sites at both ends first (a periodic wall needs
        them), so that the loop over the interior has no branch."""
        first = advance_site(u, v, pu, pv, au, av, 0, pre, h_pre, c)
        last = advance_site(u, v, pu, pv, au, av, n - 1, pre, h_pre, c)
        wall = wall_values(first[0], last[0], boundary)
        left = wall[0]
        right = wall[1]
        here = first
        j = wp.int32(0)
        while j < n - 2:
            nxt = advance_site(u, v, pu, pv, au, av, j + 1, pre, h_pre, c)
            finish_site(u, v, pu, pv, au, av, j, left, here, nxt[0], inv_mass, coupling, h, record, stiffness)
            left = here[0]
            here = nxt
            j += 1
        finish_site(u, v, pu, pv, au, av, n - 2, left, here, last[0], inv_mass, coupling, h, record, stiffness)
        finish_site(u, v, pu, pv, au, av, n - 1, here[0], last, right, inv_mass, coupling, h, record, stiffness)

    return fused_stage


fused_stage = _fused_stage(False)
fused_tangent_stage = _fused_stage(True)


# ----------------------------------------------------------------------------- splitting methods


@wp.func
def damped_kick(
    x: wp.array3d(dtype=wp.float64),
    acc: wp.array3d(dtype=wp.float64),
    b: int,
    n: int,
    damp: wp.array3d(dtype=wp.float64),
    i: int,
):
    """The exact damped kick w <- E w + F a of lattice b, kick i (``losses``; the reference's order)."""
    e0 = damp[b, i, 0]
    e1 = damp[b, i, 1]
    e2 = damp[b, i, 2]
    e3 = damp[b, i, 3]
    f0 = damp[b, i, 4]
    f1 = damp[b, i, 5]
    f2 = damp[b, i, 6]
    f3 = damp[b, i, 7]
    for j in range(n):
        pu = x[b, 2, j]
        pv = x[b, 3, j]
        au = acc[b, 0, j]
        av = acc[b, 1, j]
        x[b, 2, j] = e0 * pu + e1 * pv + (f0 * au + f1 * av)
        x[b, 3, j] = e2 * pu + e3 * pv + (f2 * au + f3 * av)


@wp.func
def any_kick(
    x: wp.array3d(dtype=wp.float64),
    acc: wp.array3d(dtype=wp.float64),
    b: int,
    n: int,
    h: wp.float64,
    lossy: int,
    damp: wp.array3d(dtype=wp.float64),
    i: int,
):
    """Kick i: the plain one (w += h a) for a lattice without losses, else the exact damped one."""
    if lossy != 0:
        damped_kick(x, acc, b, n, damp, i)
    else:
        kick(x, acc, b, n, h)


@wp.func
def kick_loss(
    pu: wp.float64,
    pv: wp.float64,
    au: wp.float64,
    av: wp.float64,
    damp: wp.array3d(dtype=wp.float64),
    b: int,
    i: int,
    mass: wp.float64,
) -> wp.float64:
    """The energy damped kick i dissipates at one site from its velocities before the kick and its
    accelerations, exactly: f . (F w + H a) - (T(w') - T(w)) (``losses.kick_dissipation``)."""
    pu1 = damp[b, i, 0] * pu + damp[b, i, 1] * pv + (damp[b, i, 4] * au + damp[b, i, 5] * av)
    pv1 = damp[b, i, 2] * pu + damp[b, i, 3] * pv + (damp[b, i, 6] * au + damp[b, i, 7] * av)
    iu = damp[b, i, 4] * pu + damp[b, i, 5] * pv + (damp[b, i, 8] * au + damp[b, i, 9] * av)
    iv = damp[b, i, 6] * pu + damp[b, i, 7] * pv + (damp[b, i, 10] * au + damp[b, i, 11] * av)
    work = mass * au * iu + av * iv
    kinetic = HALF * (mass * (pu1 - pu) * (pu1 + pu) + (pv1 - pv) * (pv1 + pv))
    return work - kinetic


@wp.kernel
def splitting_kernel(
    x: wp.array3d(dtype=wp.float64),
    acc: wp.array3d(dtype=wp.float64),
    tangent: int,
    column_base: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    coupling: wp.array(dtype=wp.float64),
    drifts: wp.array(dtype=wp.float64),
    kicks: wp.array(dtype=wp.float64),
    boundary: int,
    dt: wp.float64,
    nsteps: int,
    save_every: int,
    rec_u: wp.array3d(dtype=wp.float64),
    rec_v: wp.array3d(dtype=wp.float64),
    record_stiffness: int,
    hist: wp.array3d(dtype=wp.float64),
    lossy: wp.array(dtype=wp.int32),
    damp: wp.array3d(dtype=wp.float64),
):
    """``nsteps`` steps of a kick-drift splitting method for lattice b = tid, or with ``tangent`` set for
    tangent column b along base trajectory column_base[b] (the linearised step, f'(z) read from hist).

    hist slot 0 holds f'(z) at the start, slot step*s + k + 1 after drift k of ``step``. Lattices with
    ``lossy[b]`` set take the damped kicks of ``damp`` (batch, stages + 1, 12: E, F, then H for the energy
    dissipated) (``losses``; base runs only).
    """
    b = wp.tid()
    n = x.shape[2]
    stages = drifts.shape[0]
    base = b
    loss = int(0)
    if tangent != 0:
        base = column_base[b]
    else:
        loss = lossy[b]
    m = inv_mass[base]
    k = coupling[base]
    record = wp.where(record_stiffness != 0 and tangent == 0, 1, 0)
    compute_accelerations(x, acc, b, base, n, boundary, m, k, tangent, hist, record, 0, 0)
    rows = unit_stride(x) * unit_stride(acc) * wp.where(record != 0 or tangent != 0, unit_stride(hist), 1)
    if loss == 0 and n >= 2 and rows != 0:
        # the fast path: a stage in one pass over contiguous rows (``fused_stage``)
        u = row(x, b, 0)
        v = row(x, b, 1)
        pu = row(x, b, 2)
        pv = row(x, b, 3)
        au = row(acc, b, 0)
        av = row(acc, b, 1)
        for step in range(nsteps):
            for s in range(stages):
                pre = wp.where(s == 0, 1, 0)
                h0 = kicks[0] * dt
                c = drifts[s] * dt
                h = kicks[s + 1] * dt
                e = step * stages + s + 1
                if tangent != 0:
                    stiffness = row(hist, e, base)
                    fused_tangent_stage(u, v, pu, pv, au, av, n, boundary, m, k, pre, h0, c, h, 0, stiffness)
                else:
                    stiffness = row(hist, e * record, b * record)
                    fused_stage(u, v, pu, pv, au, av, n, boundary, m, k, pre, h0, c, h, record, stiffness)
            save_positions(x, rec_u, rec_v, b, n, step, save_every)
    else:
        for step in range(nsteps):
            any_kick(x, acc, b, n, kicks[0] * dt, loss, damp, 0)
            for s in range(stages):
                drift(x, b, n, drifts[s] * dt)
                e = step * stages + s + 1
                compute_accelerations(x, acc, b, base, n, boundary, m, k, tangent, hist, record, e, 0)
                any_kick(x, acc, b, n, kicks[s + 1] * dt, loss, damp, s + 1)
            save_positions(x, rec_u, rec_v, b, n, step, save_every)


# ----------------------------------------------------------------------------- run guard


@wp.func
def site_energy(
    u: wp.float64,
    v: wp.float64,
    pu: wp.float64,
    pv: wp.float64,
    right: wp.float64,
    j: int,
    n: int,
    boundary: int,
    mass: wp.float64,
    coupling: wp.float64,
) -> wp.float64:
    """Site j's share of the Hamiltonian (``model.energy``): kinetic energy, the bond to its right
    neighbour (``right`` is that neighbour's u; at the right end the wall bond (fixed), the bond to
    site 0 (periodic) or none (free)), the left wall bond at j = 0 (fixed), and the contact energy."""
    bonds = ZERO
    if j < n - 1:
        bonds = (right - u) * (right - u)
    elif boundary == BOUNDARY_PERIODIC:
        if n > 1:
            bonds = (right - u) * (right - u)
    elif boundary != BOUNDARY_FREE:
        bonds = u * u
    if j == 0 and boundary != BOUNDARY_FREE and boundary != BOUNDARY_PERIODIC:
        bonds = bonds + u * u
    kinetic = HALF * mass * (pu * pu) + HALF * (pv * pv)
    return kinetic + HALF * coupling * bonds + contact_potential(u - v)


@wp.func
def finite_state(u: wp.float64, v: wp.float64, pu: wp.float64, pv: wp.float64) -> wp.float64:
    """1 when all four values are finite, else 0."""
    if wp.isfinite(u) and wp.isfinite(v) and wp.isfinite(pu) and wp.isfinite(pv):
        return ONE
    return ZERO


@wp.kernel
def guard_kernel(
    x: wp.array3d(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    coupling: wp.array(dtype=wp.float64),
    boundary: int,
    rec_u: wp.array3d(dtype=wp.float64),
    rec_v: wp.array3d(dtype=wp.float64),
    n_rec: int,
    contact: wp.array(dtype=wp.float64),
    out: wp.array2d(dtype=wp.float64),
):
    """Per lattice b = tid, on the device: out[b] = (energy, 1 if finite else 0, min contact), where the
    min contact runs over the state, the first ``n_rec`` recorded frames and ``contact[b]`` (the running
    min of earlier chunks), which it also updates. Only these scalars need to reach the host."""
    b = wp.tid()
    n = x.shape[2]
    m = mass[b]
    k = coupling[b]
    total = ZERO
    finite = ONE
    low = contact[b]
    for j in range(n):
        u = x[b, 0, j]
        v = x[b, 1, j]
        right = x[b, 0, (j + 1) % n]
        total = total + site_energy(u, v, x[b, 2, j], x[b, 3, j], right, j, n, boundary, m, k)
        finite = wp.min(finite, finite_state(u, v, x[b, 2, j], x[b, 3, j]))
        low = wp.min(low, (ONE + u) - v)
    for r in range(n_rec):
        for j in range(n):
            low = wp.min(low, (ONE + rec_u[r, b, j]) - rec_v[r, b, j])
    contact[b] = low
    out[b, 0] = total
    out[b, 1] = finite
    out[b, 2] = low
