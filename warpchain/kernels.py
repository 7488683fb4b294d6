"""NVIDIA Warp kernels (float64) for batches of mass-in-mass chains.

Layout: a batch state is a ``wp.array3d`` of shape (batch, 4, N) ordered (u, v, u', v'). Each
kernel thread owns one lattice (``b = wp.tid()``) and loops over time *inside* the kernel, so a
long run costs one launch per chunk of many steps, never one per step. All per-site arithmetic
lives in ``@wp.func`` helpers that take (lattice, site) indices, so that a later kernel where a
thread block owns a lattice (one thread per site) can reuse them unchanged.

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
def laplacian_at(x: wp.array3d(dtype=wp.float64), b: int, comp: int, j: int, n: int, boundary: int) -> wp.float64:
    """(u_j - u_{j-1}) + (u_j - u_{j+1}) of component ``comp`` of lattice b at site j."""
    u = x[b, comp, j]
    left = ZERO
    right = ZERO
    if j > 0:
        left = x[b, comp, j - 1]
    elif boundary == BOUNDARY_FREE:
        left = u
    elif boundary == BOUNDARY_PERIODIC:
        left = x[b, comp, n - 1]
    if j < n - 1:
        right = x[b, comp, j + 1]
    elif boundary == BOUNDARY_FREE:
        right = u
    elif boundary == BOUNDARY_PERIODIC:
        right = x[b, comp, 0]
    return (u - left) + (u - right)


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
    n: int,
    boundary: int,
    inv_mass: wp.float64,
    coupling: wp.float64,
    hist: wp.array3d(dtype=wp.float64),
    record: int,
    slot: int,
):
    """acc[b] = a(x[b]); when ``record`` is set, also hist[slot, b, :] = f'(z)."""
    for j in range(n):
        a = acceleration_at(x, b, j, n, boundary, inv_mass, coupling)
        acc[b, 0, j] = a[0]
        acc[b, 1, j] = a[1]
        if record != 0:
            hist[slot, b, j] = contact_stiffness(x[b, 0, j] - x[b, 1, j])


@wp.func
def compute_tangent_accelerations(
    dx: wp.array3d(dtype=wp.float64),
    dacc: wp.array3d(dtype=wp.float64),
    c: int,
    base: int,
    n: int,
    boundary: int,
    inv_mass: wp.float64,
    coupling: wp.float64,
    hist: wp.array3d(dtype=wp.float64),
    slot: int,
):
    for j in range(n):
        a = tangent_acceleration_at(dx, c, j, n, boundary, inv_mass, coupling, hist[slot, base, j])
        dacc[c, 0, j] = a[0]
        dacc[c, 1, j] = a[1]


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


@wp.kernel
def splitting_kernel(
    x: wp.array3d(dtype=wp.float64),
    acc: wp.array3d(dtype=wp.float64),
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
    """``nsteps`` steps of a kick-drift splitting method for lattice b = tid.

    hist slot 0 holds f'(z) at the start, slot step*s + k + 1 after drift k of ``step``. Lattices with
    ``lossy[b]`` set take the damped kicks of ``damp`` (batch, stages + 1, 8) (``losses``).
    """
    b = wp.tid()
    n = x.shape[2]
    stages = drifts.shape[0]
    m = inv_mass[b]
    k = coupling[b]
    loss = lossy[b]
    compute_accelerations(x, acc, b, n, boundary, m, k, hist, record_stiffness, 0)
    for step in range(nsteps):
        any_kick(x, acc, b, n, kicks[0] * dt, loss, damp, 0)
        for s in range(stages):
            drift(x, b, n, drifts[s] * dt)
            compute_accelerations(x, acc, b, n, boundary, m, k, hist, record_stiffness, step * stages + s + 1)
            any_kick(x, acc, b, n, kicks[s + 1] * dt, loss, damp, s + 1)
        save_positions(x, rec_u, rec_v, b, n, step, save_every)


@wp.kernel
def splitting_tangent_kernel(
    dx: wp.array3d(dtype=wp.float64),
    dacc: wp.array3d(dtype=wp.float64),
    column_base: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    coupling: wp.array(dtype=wp.float64),
    drifts: wp.array(dtype=wp.float64),
    kicks: wp.array(dtype=wp.float64),
    boundary: int,
    dt: wp.float64,
    nsteps: int,
    hist: wp.array3d(dtype=wp.float64),
):
    """Tangent column c = tid of the splitting step, along base trajectory column_base[c]."""
    c = wp.tid()
    base = column_base[c]
    n = dx.shape[2]
    stages = drifts.shape[0]
    m = inv_mass[base]
    k = coupling[base]
    compute_tangent_accelerations(dx, dacc, c, base, n, boundary, m, k, hist, 0)
    for step in range(nsteps):
        kick(dx, dacc, c, n, kicks[0] * dt)
        for s in range(stages):
            drift(dx, c, n, drifts[s] * dt)
            compute_tangent_accelerations(dx, dacc, c, base, n, boundary, m, k, hist, step * stages + s + 1)
            kick(dx, dacc, c, n, kicks[s + 1] * dt)


# ----------------------------------------------------------------------------- classical RK4


@wp.func
def rk4_stage_derivative(
    y: wp.array3d(dtype=wp.float64),
    out: wp.array3d(dtype=wp.float64),
    b: int,
    n: int,
    boundary: int,
    inv_mass: wp.float64,
    coupling: wp.float64,
    record: int,
    hist: wp.array3d(dtype=wp.float64),
    slot: int,
):
    """out[b] = F(y[b]) = (y', a(y)); records f'(z) of the stage when asked."""
    for j in range(n):
        a = acceleration_at(y, b, j, n, boundary, inv_mass, coupling)
        out[b, 0, j] = y[b, 2, j]
        out[b, 1, j] = y[b, 3, j]
        out[b, 2, j] = a[0]
        out[b, 3, j] = a[1]
        if record != 0:
            hist[slot, b, j] = contact_stiffness(y[b, 0, j] - y[b, 1, j])


@wp.func
def rk4_tangent_stage_derivative(
    dy: wp.array3d(dtype=wp.float64),
    out: wp.array3d(dtype=wp.float64),
    c: int,
    base: int,
    n: int,
    boundary: int,
    inv_mass: wp.float64,
    coupling: wp.float64,
    hist: wp.array3d(dtype=wp.float64),
    slot: int,
):
    for j in range(n):
        a = tangent_acceleration_at(dy, c, j, n, boundary, inv_mass, coupling, hist[slot, base, j])
        out[c, 0, j] = dy[c, 2, j]
        out[c, 1, j] = dy[c, 3, j]
        out[c, 2, j] = a[0]
        out[c, 3, j] = a[1]


@wp.func
def rk4_advance(
    x: wp.array3d(dtype=wp.float64),
    y: wp.array3d(dtype=wp.float64),
    k: wp.array3d(dtype=wp.float64),
    total: wp.array3d(dtype=wp.float64),
    b: int,
    n: int,
    stage: int,
    dt: wp.float64,
    tableau: wp.vec4d,
    weights: wp.vec4d,
):
    """After stage ``stage`` (0..3) has put its derivative in k: accumulate weights[stage] k into
    total and, for stages 0..2, form the next stage state y = x + tableau[stage] dt k (the method's
    own coefficients: ``RungeKuttaMethod.nodes``, ``weights``)."""
    weight = weights[stage]
    a = tableau[wp.min(stage, 2)]
    for i in range(4):
        for j in range(n):
            if stage == 0:
                total[b, i, j] = weight * k[b, i, j]
            else:
                total[b, i, j] = total[b, i, j] + weight * k[b, i, j]
            if stage < 3:
                y[b, i, j] = x[b, i, j] + (a * dt) * k[b, i, j]


@wp.func
def rk4_finish(
    x: wp.array3d(dtype=wp.float64),
    total: wp.array3d(dtype=wp.float64),
    b: int,
    n: int,
    dt: wp.float64,
    divisor: wp.float64,
):
    for i in range(4):
        for j in range(n):
            x[b, i, j] = x[b, i, j] + (dt / divisor) * total[b, i, j]


@wp.kernel
def rk4_kernel(
    x: wp.array3d(dtype=wp.float64),
    y: wp.array3d(dtype=wp.float64),
    k: wp.array3d(dtype=wp.float64),
    total: wp.array3d(dtype=wp.float64),
    inv_mass: wp.array(dtype=wp.float64),
    coupling: wp.array(dtype=wp.float64),
    tableau: wp.vec4d,
    weights: wp.vec4d,
    boundary: int,
    dt: wp.float64,
    nsteps: int,
    save_every: int,
    rec_u: wp.array3d(dtype=wp.float64),
    rec_v: wp.array3d(dtype=wp.float64),
    record_stiffness: int,
    hist: wp.array3d(dtype=wp.float64),
):
    """``nsteps`` Runge-Kutta steps (tableau: nodes and divisor, weights) for lattice b = tid;
    hist slot 4 step + stage."""
    b = wp.tid()
    n = x.shape[2]
    m = inv_mass[b]
    cpl = coupling[b]
    for step in range(nsteps):
        rk4_stage_derivative(x, k, b, n, boundary, m, cpl, record_stiffness, hist, 4 * step)
        rk4_advance(x, y, k, total, b, n, 0, dt, tableau, weights)
        for stage in range(1, 4):
            rk4_stage_derivative(y, k, b, n, boundary, m, cpl, record_stiffness, hist, 4 * step + stage)
            rk4_advance(x, y, k, total, b, n, stage, dt, tableau, weights)
        rk4_finish(x, total, b, n, dt, tableau[3])
        save_positions(x, rec_u, rec_v, b, n, step, save_every)


@wp.kernel
def rk4_tangent_kernel(
    dx: wp.array3d(dtype=wp.float64),
    dy: wp.array3d(dtype=wp.float64),
    dk: wp.array3d(dtype=wp.float64),
    dtotal: wp.array3d(dtype=wp.float64),
    column_base: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    coupling: wp.array(dtype=wp.float64),
    tableau: wp.vec4d,
    weights: wp.vec4d,
    boundary: int,
    dt: wp.float64,
    nsteps: int,
    hist: wp.array3d(dtype=wp.float64),
):
    """Tangent column c = tid of the RK4 step along base trajectory column_base[c]."""
    c = wp.tid()
    base = column_base[c]
    n = dx.shape[2]
    m = inv_mass[base]
    cpl = coupling[base]
    for step in range(nsteps):
        rk4_tangent_stage_derivative(dx, dk, c, base, n, boundary, m, cpl, hist, 4 * step)
        rk4_advance(dx, dy, dk, dtotal, c, n, 0, dt, tableau, weights)
        for stage in range(1, 4):
            rk4_tangent_stage_derivative(dy, dk, c, base, n, boundary, m, cpl, hist, 4 * step + stage)
            rk4_advance(dx, dy, dk, dtotal, c, n, stage, dt, tableau, weights)
        rk4_finish(dx, dtotal, c, n, dt, tableau[3])


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
