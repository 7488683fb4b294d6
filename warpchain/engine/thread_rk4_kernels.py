"""The classical fourth-order Runge-Kutta method in the thread-per-lattice layout (the CPU path): base runs
and tangent columns in one kernel (``rk4_kernel``: for base runs a fused pass over contiguous rows per stage,
the stage states in scratch arrays), the arithmetic of ``warpchain.reference`` operation for operation."""

from __future__ import annotations

import warp as wp

from .thread_kernels import (
    Lattice,
    Tableau,
    base_of,
    Recording,
    F64,
    Array1,
    Array3,
    Indices,
    compute_accelerations,
    contact_stiffness,
    row,
    save_positions,
    site_acceleration,
    unit_stride,
    wall_values,
)


@wp.func
def velocities(y: Array3, out: Array3, b: int, n: int):
    """Rows 0, 1 of out[b] = y[b]'s velocities (u', v'): the first half of a stage's derivative F(y) = (y', a(y))."""
    for j in range(n):
        out[b, 0, j] = y[b, 2, j]
        out[b, 1, j] = y[b, 3, j]


@wp.func
def rk4_advance(
    x: Array3,
    y: Array3,
    k: Array3,
    total: Array3,
    b: int,
    n: int,
    stage: int,
    dt: F64,
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
def rk4_finish(x: Array3, total: Array3, b: int, n: int, dt: F64, divisor: F64):
    for i in range(4):
        for j in range(n):
            x[b, i, j] = x[b, i, j] + (dt / divisor) * total[b, i, j]


@wp.struct
class Rows:
    """The rows (u, v, u', v') of one lattice of a state array as unit-stride views (``row``)."""

    u: Array1
    v: Array1
    pu: Array1
    pv: Array1


@wp.func
def rows_of(x: Array3, b: int) -> Rows:
    r = Rows()
    r.u = row(x, b, 0)
    r.v = row(x, b, 1)
    r.pu = row(x, b, 2)
    r.pv = row(x, b, 3)
    return r


@wp.struct
class Stage:
    """What one fused Runge-Kutta stage applies at every site: the lattice's 1/M and K, ``first`` (set for the
    stage that starts the weighted total), the stage's weight, ah = a dt, and f'(z) into ``stiffness`` when
    ``record``."""

    inv_mass: F64
    coupling: F64
    first: int
    weight: F64
    ah: F64
    record: int
    stiffness: Array1


@wp.func
def stage_of(inv_mass: F64, coupling: F64, first: int, weight: F64, ah: F64, record: int, stiffness: Array1) -> Stage:
    c = Stage()
    c.inv_mass = inv_mass
    c.coupling = coupling
    c.first = first
    c.weight = weight
    c.ah = ah
    c.record = record
    c.stiffness = stiffness
    return c


@wp.func
def rk4_site(x: Rows, s: Rows, y: Rows, t: Rows, j: int, left: F64, u: F64, right: F64, c: Stage):
    """Site j of a Runge-Kutta stage ``c`` at the state s (u: s.u[j], read before y may overwrite it) between
    neighbours at u = left and right: the derivative k = (u', v', a) (as the per-pass path forms it), its
    weighted sum into t and the next stage state y = x + ah k (``rk4_advance``; ah = a dt)."""
    v = s.v[j]
    pu = s.pu[j]
    pv = s.pv[j]
    a = site_acceleration(u, v, left, right, c.inv_mass, c.coupling)
    weight = c.weight
    first = c.first
    t.u[j] = wp.where(first != 0, weight * pu, t.u[j] + weight * pu)
    t.v[j] = wp.where(first != 0, weight * pv, t.v[j] + weight * pv)
    t.pu[j] = wp.where(first != 0, weight * a[0], t.pu[j] + weight * a[0])
    t.pv[j] = wp.where(first != 0, weight * a[1], t.pv[j] + weight * a[1])
    y.u[j] = x.u[j] + c.ah * pu
    y.v[j] = x.v[j] + c.ah * pv
    y.pu[j] = x.pu[j] + c.ah * a[0]
    y.pv[j] = x.pv[j] + c.ah * a[1]
    if c.record != 0:
        c.stiffness[j] = contact_stiffness(u - v)


@wp.func
def rk4_fused_stage(x: Rows, s: Rows, y: Rows, t: Rows, n: int, boundary: int, c: Stage):
    """One Runge-Kutta stage ``c`` on one lattice's rows in a single pass over the sites: the derivative at the
    stage state s (x itself for the first stage), its weighted sum into the total t (set by the ``first``
    stage) and the next stage state y = x + ah k. Site j's u is carried to site j + 1 in a register and
    the wall values are read first, so that y may be s itself (``rk4_kernel`` keeps them apart, which lets
    the compiler vectorise the pass)."""
    wall = wall_values(s.u[0], s.u[n - 1], boundary)
    left = wall[0]
    right = wall[1]
    here = s.u[0]
    j = wp.int32(0)
    while j < n - 1:
        nxt = s.u[j + 1]
        rk4_site(x, s, y, t, j, left, here, nxt, c)
        left = here
        here = nxt
        j += 1
    rk4_site(x, s, y, t, n - 1, left, here, right, c)


@wp.func
def rk4_fused_finish(x: Rows, t: Rows, n: int, dt: F64, divisor: F64):
    """``rk4_finish`` on rows."""
    j = wp.int32(0)
    while j < n:
        x.u[j] = x.u[j] + (dt / divisor) * t.u[j]
        x.v[j] = x.v[j] + (dt / divisor) * t.v[j]
        x.pu[j] = x.pu[j] + (dt / divisor) * t.pu[j]
        x.pv[j] = x.pv[j] + (dt / divisor) * t.pv[j]
        j += 1


@wp.kernel
def rk4_kernel(
    x: Array3,
    y: Array3,
    k: Array3,
    total: Array3,
    tangent: int,
    column_base: Indices,
    lat: Lattice,
    rk: Tableau,
    dt: F64,
    nsteps: int,
    out: Recording,
):
    """``nsteps`` steps of the Runge-Kutta method ``rk`` for lattice b = tid; hist slot
    4 step + stage. With ``tangent`` set, b is a tangent column along base lattice column_base[b] (the
    linearised step, f'(z) read from hist; the per-pass path)."""
    b = wp.tid()
    n = x.shape[2]
    boundary = lat.boundary
    tableau = rk.nodes
    weights = rk.weights
    base = base_of(b, tangent, column_base)
    m = lat.inv_mass[base]
    cpl = lat.coupling[base]
    hist = out.hist
    record = wp.where(out.stiffness != 0 and tangent == 0, 1, 0)
    rows = unit_stride(x) * unit_stride(y) * unit_stride(k) * unit_stride(total)
    rows = rows * wp.where(record != 0, unit_stride(hist), 1)
    if rows != 0 and tangent == 0:
        # the fast path: a stage in one pass over contiguous rows (``rk4_fused_stage``). The stage states
        # alternate between the scratch arrays y and k (k itself is not stored), so that no stage writes
        # the rows it reads (the last stage's next state, which nothing reads, goes to k)
        xr = rows_of(x, b)
        yr = rows_of(y, b)
        kr = rows_of(k, b)
        tr = rows_of(total, b)
        for step in range(nsteps):
            slot = 4 * step
            s0 = row(hist, slot * record, b * record)
            s1 = row(hist, (slot + 1) * record, b * record)
            s2 = row(hist, (slot + 2) * record, b * record)
            s3 = row(hist, (slot + 3) * record, b * record)
            rk4_fused_stage(xr, xr, yr, tr, n, boundary, stage_of(m, cpl, 1, weights[0], tableau[0] * dt, record, s0))
            rk4_fused_stage(xr, yr, kr, tr, n, boundary, stage_of(m, cpl, 0, weights[1], tableau[1] * dt, record, s1))
            rk4_fused_stage(xr, kr, yr, tr, n, boundary, stage_of(m, cpl, 0, weights[2], tableau[2] * dt, record, s2))
            rk4_fused_stage(xr, yr, kr, tr, n, boundary, stage_of(m, cpl, 0, weights[3], tableau[2] * dt, record, s3))
            rk4_fused_finish(xr, tr, n, dt, tableau[3])
            save_positions(x, out, b, n, step)
    else:
        for step in range(nsteps):
            # each stage's derivative F(y) = (y', a(y)) into k: a base run's (f'(z) recorded when asked), or with
            # ``tangent`` its linearisation along base lattice ``base``'s recorded f'(z)
            velocities(x, k, b, n)
            compute_accelerations(x, k, b, base, n, boundary, m, cpl, tangent, hist, record, 4 * step, 2)
            rk4_advance(x, y, k, total, b, n, 0, dt, tableau, weights)
            for stage in range(1, 4):
                velocities(y, k, b, n)
                compute_accelerations(y, k, b, base, n, boundary, m, cpl, tangent, hist, record, 4 * step + stage, 2)
                rk4_advance(x, y, k, total, b, n, stage, dt, tableau, weights)
            rk4_finish(x, total, b, n, dt, tableau[3])
            save_positions(x, out, b, n, step)
