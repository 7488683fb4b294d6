"""The thread layout's Warp kernels (float64): a thread per lattice, the CPU path.

Layout: a batch state is a ``wp.array3d`` of shape (batch, 4, N) ordered (u, v, u', v'). Each
kernel thread owns one lattice (``b = wp.tid()``) and loops over time *inside* the kernel, so a
long run costs one launch per chunk of many steps, never one per step. The arithmetic of one site (contact
law, neighbour rules, force, energy) and the structs are ``engine.site``'s, shared with the other layouts;
this module holds the per-pass helpers over a lattice's rows, the step loop and the guard.

The splitting kernel (base runs and tangent columns) takes a fast path where a lattice's rows are
contiguous (always, as ``ensemble`` allocates them): each stage is one pass over the sites
(``fused_stage``) through 1-D row views (``row``), whose compile-time unit
stride lets the CPU compiler vectorise the pass. Every value is computed by the same operations in the
same order as the per-pass helpers below, which remain the path for strided arrays and, in the splitting
kernels, for lattices with losses, N = 1 and the observed kernel (``observed_splitting_kernel``: the hooks of
``warpchain.observe`` after each kick and step).

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

from .site import (
    Array1,
    Array2,
    Array3,
    Indices,
    F64,
    ZERO,
    ONE,
    NO_CONTACT,
    Recording,
    Lattice,
    contact_force,
    contact_stiffness,
    wall_values,
    neighbours_at,
    laplacian_at,
    site_acceleration,
    site_tangent_acceleration,
    kick_loss,
    site_energy,
    finite_state,
    Observer,
    window_peak,
    store_observables,
)


# ----------------------------------------------------------------------------- per-site helpers


@wp.func
def base_of(b: int, tangent: int, column_base: Indices) -> int:
    """The lattice whose parameters (and recorded f'(z)) launch index b reads: b itself, or, for a tangent column
    (``tangent`` set), the base trajectory it follows, column_base[b]."""
    if tangent != 0:
        return column_base[b]
    return b


@wp.func
def acceleration_at(x: Array3, b: int, j: int, n: int, boundary: int, inv_mass: F64, coupling: F64) -> wp.vec2d:
    """(u_j'', v_j'') of lattice b from the positions in rows 0 and 1 of x."""
    force = contact_force(x[b, 0, j] - x[b, 1, j])
    au = -(coupling * laplacian_at(x, b, 0, j, n, boundary) + force) * inv_mass
    return wp.vec2d(au, force)


@wp.func
def tangent_acceleration_at(
    dx: Array3, c: int, j: int, n: int, boundary: int, inv_mass: F64, coupling: F64, stiffness: F64
) -> wp.vec2d:
    """Derivative of (u_j'', v_j'') along the tangent column c (positions in rows 0, 1 of dx)."""
    dz = dx[c, 0, j] - dx[c, 1, j]
    au = -(coupling * laplacian_at(dx, c, 0, j, n, boundary) + stiffness * dz) * inv_mass
    return wp.vec2d(au, stiffness * dz)


@wp.func
def compute_accelerations(
    x: Array3,
    acc: Array3,
    b: int,
    base: int,
    n: int,
    boundary: int,
    inv_mass: F64,
    coupling: F64,
    tangent: int,
    hist: Array3,
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
def kick(x: Array3, acc: Array3, b: int, n: int, h: F64):
    for j in range(n):
        x[b, 2, j] = x[b, 2, j] + h * acc[b, 0, j]
        x[b, 3, j] = x[b, 3, j] + h * acc[b, 1, j]


@wp.func
def drift(x: Array3, b: int, n: int, h: F64):
    for j in range(n):
        x[b, 0, j] = x[b, 0, j] + h * x[b, 2, j]
        x[b, 1, j] = x[b, 1, j] + h * x[b, 3, j]


@wp.func
def save_positions(x: Array3, out: Recording, b: int, n: int, step: int):
    """Lattice b's u and v into ``out``'s frames after ``step`` when a frame is due."""
    if out.every > 0:
        if (step + 1) % out.every == 0:
            r = (step + 1) / out.every - 1
            for j in range(n):
                out.u[r, b, j] = x[b, 0, j]
                out.v[r, b, j] = x[b, 1, j]


# ----------------------------------------------------------------------------- row views (fused sweeps)


@wp.func_native("return (wp::uint64)(&wp::index(x, i, r, 0));")
def _row_address(x: Array3, i: int, r: int) -> wp.uint64: ...


@wp.func_native("return x.strides[2] == (int)sizeof(wp::float64) ? 1 : 0;")
def unit_stride(x: Array3) -> int:
    """1 when the last axis of x is contiguous (what ``row`` needs), else 0."""


@wp.func
def row(x: Array3, i: int, r: int) -> wp.array(dtype=wp.float64):
    """x[i, r, :] as a 1-D array of unit stride (only where ``unit_stride(x)``). Its stride is a compile-time
    constant, so that the compiler can vectorise a loop over sites; through the 3-D array's runtime
    strides it cannot (on the project's AVX-512 CPU the fused sweep runs 8 sites per instruction)."""
    return wp.array(ptr=_row_address(x, i, r), shape=(x.shape[2],), dtype=wp.float64)


@wp.struct
class Sweep:
    """One fused splitting stage (``fused_stage``) of one lattice: its rows (unit-stride views, ``row``) of the
    state (u, v, u', v') and of the accelerations (au, av), its 1/M and K, the step's first kick ``h_pre`` (given
    when ``pre`` is set), the drift ``c``, the kick ``h``, and f'(z) into ``stiffness`` when ``record`` (a tangent
    column reads its base's f'(z) from it)."""

    u: Array1
    v: Array1
    pu: Array1
    pv: Array1
    au: Array1
    av: Array1
    inv_mass: F64
    coupling: F64
    pre: int
    h_pre: F64
    c: F64
    h: F64
    record: int
    stiffness: Array1


@wp.func
def advance_site(w: Sweep, j: int) -> wp.vec4d:
    """Site j's kick with the stored accelerations (when ``pre``; as ``kick``) and its drift (as ``drift``):
    returns (u, v, u', v') after them, not yet stored. A select, not a branch: a branch here keeps the
    compiler from vectorising the sweep (2.8 against 0.7 ns per site-step)."""
    qu = wp.where(w.pre != 0, w.pu[j] + w.h_pre * w.au[j], w.pu[j])
    qv = wp.where(w.pre != 0, w.pv[j] + w.h_pre * w.av[j], w.pv[j])
    return wp.vec4d(w.u[j] + w.c * qu, w.v[j] + w.c * qv, qu, qv)


def _fused_stage(tangent: bool):
    """``fused_stage`` compiled for base runs (``tangent`` False: the contact law, f'(z) recorded when asked)
    or for tangent columns (``fused_tangent_stage``: the linear accelerations with the base's f'(z) of this
    stage in ``stiffness``)."""

    @wp.func
    def finish_site(w: Sweep, j: int, left: F64, site: wp.vec4d, right: F64):
        """Site j (``site``: from ``advance_site``) between neighbours at u = left and right: its acceleration
        (and f'(z) when ``record``), the kick with it, and the stores."""
        if wp.static(tangent):
            a = site_tangent_acceleration(site[0], site[1], left, right, w.inv_mass, w.coupling, w.stiffness[j])
        else:
            a = site_acceleration(site[0], site[1], left, right, w.inv_mass, w.coupling)
        w.u[j] = site[0]
        w.v[j] = site[1]
        w.au[j] = a[0]
        w.av[j] = a[1]
        w.pu[j] = site[2] + w.h * a[0]
        w.pv[j] = site[3] + w.h * a[1]
        if wp.static(not tangent):
            if w.record != 0:
                w.stiffness[j] = contact_stiffness(site[0] - site[1])

    @wp.func
    def fused_stage(w: Sweep, n: int, boundary: int):
        """One stage ``w`` of a splitting step on one lattice's rows (n >= 2) in a single pass over the sites: the
        kick h_pre (when ``pre``: the step's first), the drift c, the accelerations (f'(z) into ``stiffness``
        when ``record``) and the kick h. Each value is computed as by ``kick``, ``drift`` and
        ``compute_accelerations`` one after the other (same operations, same order): site j + 1 is drifted
        just before site j's acceleration needs it, the sites at both ends first (a periodic wall needs
        them), so that the loop over the interior has no branch."""
        first = advance_site(w, 0)
        last = advance_site(w, n - 1)
        wall = wall_values(first[0], last[0], boundary)
        left = wall[0]
        right = wall[1]
        here = first
        j = wp.int32(0)
        while j < n - 2:
            nxt = advance_site(w, j + 1)
            finish_site(w, j, left, here, nxt[0])
            left = here[0]
            here = nxt
            j += 1
        finish_site(w, n - 2, left, here, last[0])
        finish_site(w, n - 1, here[0], last, right)

    return fused_stage


fused_stage = _fused_stage(False)
fused_tangent_stage = _fused_stage(True)


# ----------------------------------------------------------------------------- splitting methods


@wp.func
def damped_kick(x: Array3, acc: Array3, b: int, n: int, damp: Array3, i: int):
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
def any_kick(x: Array3, acc: Array3, b: int, n: int, h: F64, lossy: int, damp: Array3, i: int):
    """Kick i: the plain one (w += h a) for a lattice without losses, else the exact damped one."""
    if lossy != 0:
        damped_kick(x, acc, b, n, damp, i)
    else:
        kick(x, acc, b, n, h)


def _splitting_kernel(observed: bool):
    """``splitting_kernel``, or compiled ``observed`` (``observed_splitting_kernel``): with the hooks of
    ``warpchain.observe`` (``observe_start``, ``kick_losses``, ``observe_step``) in the per-pass loop."""

    @wp.kernel(enable_backward=False)
    def splitting(
        x: Array3,
        acc: Array3,
        tangent: int,
        column_base: Indices,
        lat: Lattice,
        drifts: Array1,
        kicks: Array1,
        dt: F64,
        nsteps: int,
        out: Recording,
        ob: Observer,
    ):
        """``nsteps`` steps of a kick-drift splitting method for lattice b = tid, or with ``tangent`` set for
        tangent column b along base trajectory column_base[b] (the linearised step, f'(z) read from hist).

        hist slot 0 holds f'(z) at the start, slot step*s + k + 1 after drift k of ``step``. Lattices with
        ``lat.lossy[b]`` set take the damped kicks of ``lat.damp`` (batch, stages + 1, 12: E, F, then H for the
        energy dissipated) (``losses``; base runs only). Compiled ``observed``: the observables of ``ob`` every step
        and frame (``warpchain.observe``), on the per-pass path.
        """
        b = wp.tid()
        n = x.shape[2]
        stages = drifts.shape[0]
        hist = out.hist
        boundary = lat.boundary
        damp = lat.damp
        base = base_of(b, tangent, column_base)
        loss = int(0)
        if tangent == 0:  # a tangent column's index b may lie past the lattices
            loss = lat.lossy[b]
        m = lat.inv_mass[base]
        k = lat.coupling[base]
        record = wp.where(out.stiffness != 0 and tangent == 0, 1, 0)
        compute_accelerations(x, acc, b, base, n, boundary, m, k, tangent, hist, record, 0, 0)
        rows = unit_stride(x) * unit_stride(acc) * wp.where(record != 0 or tangent != 0, unit_stride(hist), 1)
        fast = loss == 0 and n >= 2 and rows != 0
        dissipated = ZERO
        if wp.static(observed):
            fast = False
            dissipated = observe_start(x, b, n, lat, ob)
        if fast:
            # the fast path: a stage in one pass over contiguous rows (``fused_stage``)
            w = Sweep()
            w.u = row(x, b, 0)
            w.v = row(x, b, 1)
            w.pu = row(x, b, 2)
            w.pv = row(x, b, 3)
            w.au = row(acc, b, 0)
            w.av = row(acc, b, 1)
            w.inv_mass = m
            w.coupling = k
            w.h_pre = kicks[0] * dt
            w.record = record
            for step in range(nsteps):
                for s in range(stages):
                    w.pre = wp.where(s == 0, 1, 0)
                    w.c = drifts[s] * dt
                    w.h = kicks[s + 1] * dt
                    e = step * stages + s + 1
                    if tangent != 0:
                        w.stiffness = row(hist, e, base)
                        fused_tangent_stage(w, n, boundary)
                    else:
                        w.stiffness = row(hist, e * record, b * record)
                        fused_stage(w, n, boundary)
                save_positions(x, out, b, n, step)
        else:
            for step in range(nsteps):
                if wp.static(observed):
                    dissipated = dissipated + kick_losses(x, acc, b, n, loss, damp, 0, lat.mass[b])
                any_kick(x, acc, b, n, kicks[0] * dt, loss, damp, 0)
                for s in range(stages):
                    drift(x, b, n, drifts[s] * dt)
                    e = step * stages + s + 1
                    compute_accelerations(x, acc, b, base, n, boundary, m, k, tangent, hist, record, e, 0)
                    if wp.static(observed):
                        dissipated = dissipated + kick_losses(x, acc, b, n, loss, damp, s + 1, lat.mass[b])
                    any_kick(x, acc, b, n, kicks[s + 1] * dt, loss, damp, s + 1)
                save_positions(x, out, b, n, step)
                if wp.static(observed):
                    observe_step(x, b, n, lat, ob, step, dissipated)
        if wp.static(observed):
            ob.lost[b, 0] = dissipated

    return splitting


# ----------------------------------------------------------------------------- run guard


@wp.kernel
def guard_kernel(x: Array3, lat: Lattice, rec: Recording, n_rec: int, contact: Array1, out: Array2):
    """Per lattice b = tid, on the device: out[b] = (energy, 1 if finite else 0, min contact), where the
    min contact runs over the state, the first ``n_rec`` frames of ``rec`` and ``contact[b]`` (the running
    min of earlier chunks), which it also updates. Only these scalars need to reach the host."""
    b = wp.tid()
    n = x.shape[2]
    boundary = lat.boundary
    m = lat.mass[b]
    k = lat.coupling[b]
    total = ZERO
    finite = ONE
    low = contact[b]
    for j in range(n):
        u = x[b, 0, j]
        v = x[b, 1, j]
        nb = neighbours_at(x, b, 0, j, n, boundary)
        total = total + site_energy(u, v, x[b, 2, j], x[b, 3, j], nb[0], nb[1], j, boundary, m, k)
        finite = wp.min(finite, finite_state(u, v, x[b, 2, j], x[b, 3, j]))
        low = wp.min(low, (ONE + u) - v)
    for r in range(n_rec):
        for j in range(n):
            low = wp.min(low, (ONE + rec.u[r, b, j]) - rec.v[r, b, j])
    contact[b] = low
    out[b, 0] = total
    out[b, 1] = finite
    out[b, 2] = low


# ----------------------------------------------------------------------------- observables (``warpchain.observe``)


@wp.func
def observe_frame(x: Array3, b: int, n: int, lat: Lattice, ob: Observer, r: int, dissipated: F64):
    """Frame r of lattice b: values[r, b] from the state and the interval's z extremes, which it resets."""
    centre = n / 2
    boundary = lat.boundary
    mass = lat.mass[b]
    coupling = lat.coupling[b]
    for j in range(n):
        ob.envelope[b, j] = wp.max(ob.z_high[b, j], -ob.z_low[b, j])
    total = ZERO
    squares = ZERO
    inside = ZERO
    top = ZERO
    low = NO_CONTACT
    peaks = ZERO
    for j in range(n):
        nb = neighbours_at(x, b, 0, j, n, boundary)
        e = site_energy(x[b, 0, j], x[b, 1, j], x[b, 2, j], x[b, 3, j], nb[0], nb[1], j, boundary, mass, coupling)
        total = total + e
        squares = squares + e * e
        if wp.abs(wp.float64(j - centre)) <= ob.spot[b]:
            inside = inside + e
        env = ob.envelope[b, j]
        top = wp.max(top, env)
        low = wp.min(low, ONE + ob.z_low[b, j])
        if env > ob.threshold:
            peaks = peaks + window_peak(ob.envelope, b, j, n, env, ob.radius, ob.contrast)
    for j in range(n):
        ob.z_low[b, j] = NO_CONTACT
        ob.z_high[b, j] = -NO_CONTACT
    store_observables(ob, r, b, peaks, total, squares, inside, top, low, dissipated)


@wp.func
def observe_start(x: Array3, b: int, n: int, lat: Lattice, ob: Observer) -> F64:
    """At the run's start (``first_step`` 0) frame 0 (envelope |z|); returns the energy dissipated so far."""
    if ob.first_step != 0:
        return ob.lost[b, 0]
    for j in range(n):
        z = x[b, 0, j] - x[b, 1, j]
        ob.z_low[b, j] = z
        ob.z_high[b, j] = z
    observe_frame(x, b, n, lat, ob, 0, ZERO)
    return ZERO


@wp.func
def kick_losses(x: Array3, acc: Array3, b: int, n: int, loss: int, damp: Array3, i: int, mass: F64) -> F64:
    """The energy damped kick i is about to dissipate on lattice b (``kick_loss`` summed over the sites)."""
    spent = ZERO
    if loss != 0:
        for j in range(n):
            spent = spent + kick_loss(x[b, 2, j], x[b, 3, j], acc[b, 0, j], acc[b, 1, j], damp, b, i, mass)
    return spent


@wp.func
def observe_step(x: Array3, b: int, n: int, lat: Lattice, ob: Observer, step: int, dissipated: F64):
    """After ``step``: the z extremes, and the frame when one is due."""
    for j in range(n):
        z = x[b, 0, j] - x[b, 1, j]
        ob.z_low[b, j] = wp.min(ob.z_low[b, j], z)
        ob.z_high[b, j] = wp.max(ob.z_high[b, j], z)
    done = ob.first_step + step + 1
    if done % ob.frame_every == 0:
        observe_frame(x, b, n, lat, ob, done / ob.frame_every, dissipated)


splitting_kernel = _splitting_kernel(False)
observed_splitting_kernel = _splitting_kernel(True)
