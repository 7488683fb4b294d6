"""The site: what every kernel layout computes at one site, written once (float64).

A batch state is a ``wp.array3d`` of shape (batch, 4, N) ordered (u, v, u', v'). This module holds the arithmetic of
one site that the layouts' step loops (``thread_kernels``: a thread per lattice; ``block_kernels``: a block per
lattice, a thread per site; ``site_group_kernels``: a block per lattice, a thread per run of sites;
``site_kernels``: a thread per site, a launch per force evaluation) share, and the structs they read:

- the contact law (``contact_force``, ``contact_potential``, ``contact_stiffness``: the Hertzian f(z), its potential
  and f'(z));
- the neighbour rules: the chain's walls (``wall_values``, ``neighbours_at``, ``laplacian_at``) and a neighbour table's
  (``table_laplacian``, ``table_bonds``: the 2-D lattices of ``warpchain.lattice``);
- the force from the gathered neighbours (``coupled_acceleration``, ``site_acceleration`` and its block form
  ``site_acceleration_times``) and its tangent (``coupled_tangent_acceleration``, ``site_tangent_acceleration``);
- the damped kick and the energy it dissipates (``site_kick``, ``kick_loss``; ``warpchain.losses``);
- the energy and the guard's tests (``site_energy``, ``held_energy``, ``finite_state``);
- the observables' per-site tests (``peak_test``, ``peak_verdict``, the chain's windows ``window_peak``) and their store
  (``store_observables``);
- the structs passed whole: ``Lattice`` (M, 1/M, K, losses, boundary, neighbour table), ``Recording`` (frames and the
  f'(z) history) and ``Observer`` (``warpchain.observe``).

Accelerations multiply by a precomputed 1/M (``inv_mass`` arrays, rounded once on the host, as the numpy reference
does): no division in any time loop. Float constants are module-level ``wp.constant`` values: a literal such as
``wp.float64(2.0/3.0)`` written inside a kernel is evaluated in float32 (errors of ~5e-9), which these avoid.
``warpchain.reference`` is the numpy oracle of every formula here, operation for operation.
"""

from __future__ import annotations

import warp as wp

from ..lattice import WALL
from ..model import BOUNDARY_CODES

#: the kernels' annotation types: float64 arrays of 1 to 3 axes, int32 indices, float64
Array1 = wp.array(dtype=wp.float64)
Array2 = wp.array2d(dtype=wp.float64)
Array3 = wp.array3d(dtype=wp.float64)
Indices = wp.array(dtype=wp.int32)
F64 = wp.float64

ZERO = wp.constant(wp.float64(0.0))
ONE = wp.constant(wp.float64(1.0))
HALF = wp.constant(wp.float64(0.5))
TWO_THIRDS = wp.constant(wp.float64(2.0 / 3.0))
TWO_FIFTHS = wp.constant(wp.float64(0.4))
FOUR_FIFTEENTHS = wp.constant(wp.float64(4.0 / 15.0))
#: the min-contact value of a site that holds nothing (idle block threads): larger than any real one
NO_CONTACT = wp.constant(wp.float64(1.0e300))

#: the boundaries' codes (``model.BOUNDARY_CODES``: their order in ``model.BOUNDARIES``)
BOUNDARY_FIXED = wp.constant(BOUNDARY_CODES["fixed"])
BOUNDARY_FREE = wp.constant(BOUNDARY_CODES["free"])
BOUNDARY_PERIODIC = wp.constant(BOUNDARY_CODES["periodic"])
#: a neighbour table's wall slot (``warpchain.lattice.WALL``: reads u = 0); any other negative slot (``MISSING``: no
#: neighbour) reads the site itself
TABLE_WALL = wp.constant(WALL)


@wp.struct
class Recording:
    """What a run writes besides its state, passed whole to the step kernels: u and v after every ``every``-th
    step into frames ``u``, ``v`` (frames, batch, N) (``every`` 0: none), and with ``stiffness`` set f'(z) at
    every force evaluation into ``hist`` (slots, batch, N), which tangent runs read."""

    every: int
    u: Array3
    v: Array3
    stiffness: int
    hist: Array3


@wp.struct
class Lattice:
    """What the kernels read of a batch of lattices besides the state, passed whole: per lattice the mass M, 1/M
    (the step kernels multiply by it), the coupling K and the losses (``lossy`` flag, the damped kicks'
    coefficients ``damp``, ``losses``), and the boundary's code; a lattice given as a neighbour table
    (``warpchain.lattice.Lattice``: the square and triangular monolayers) adds the table and its bond weights
    (``degree`` > 0; read by ``table_laplacian`` and ``table_bonds``), which the ``"sites"`` layout runs. Built by
    ``Runner.lattice``."""

    mass: Array1
    inv_mass: Array1
    coupling: Array1
    lossy: Indices
    damp: Array3
    boundary: int
    #: 0: the chain's two neighbours (``neighbours_at``, the walls of ``boundary``); D > 0: ``table``'s D slots
    degree: int
    #: (sites, D) int32: a neighbour's site index, ``lattice.WALL`` or ``lattice.MISSING`` (``warpchain.lattice``)
    table: wp.array2d(dtype=wp.int32)
    #: (sites, D) float64: the bonds' weights
    weights: Array2


# ----------------------------------------------------------------------------- the site's arithmetic


@wp.func
def contact_force(z: F64) -> F64:
    """f(z) = (2/3)([1 + z]_+^{3/2} - 1). Branch-free (a select, not a jump: cheaper on a GPU);
    ``max(0, s)`` keeps a NaN as NaN, as numpy's ``maximum`` does."""
    s = wp.max(ZERO, ONE + z)
    return TWO_THIRDS * (s * wp.sqrt(s) - ONE)


@wp.func
def contact_potential(z: F64) -> F64:
    """(2/3)((2/5)[1+z]_+^{5/2} - z) - 4/15, as ``model.contact_potential``."""
    s = wp.max(ZERO, ONE + z)
    return TWO_THIRDS * (TWO_FIFTHS * s * s * wp.sqrt(s) - z) - FOUR_FIFTEENTHS


@wp.func
def contact_stiffness(z: F64) -> F64:
    """f'(z) = [1 + z]_+^{1/2}."""
    return wp.sqrt(wp.max(ZERO, ONE + z))


@wp.func
def wall_values(first: F64, last: F64, boundary: int) -> wp.vec2d:
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
def neighbours_at(x: Array3, b: int, comp: int, j: int, n: int, boundary: int) -> wp.vec2d:
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
def table_neighbour(x: Array3, b: int, comp: int, u: F64, t: int) -> F64:
    """The u a neighbour-table slot reads (``warpchain.lattice``): site t's, 0 at a wall, the site's own ``u``
    where the slot holds no neighbour (its bond, weight 0, adds nothing)."""
    if t >= 0:
        return x[b, comp, t]
    if t == TABLE_WALL:
        return ZERO
    return u


@wp.func
def table_laplacian(x: Array3, b: int, comp: int, j: int, u: F64, lat: Lattice) -> F64:
    """(L u)_j = sum_d w_jd (u_j - u_nb(j,d)) over the table's slots in order (``Lattice.laplacian``, operation
    for operation: on the chain's table (u - left) + (u - right), the weights 1 multiplying exactly)."""
    lap = lat.weights[j, 0] * (u - table_neighbour(x, b, comp, u, lat.table[j, 0]))
    for d in range(1, lat.degree):
        lap = lap + lat.weights[j, d] * (u - table_neighbour(x, b, comp, u, lat.table[j, d]))
    return lap


@wp.func
def table_bonds(x: Array3, b: int, j: int, u: F64, lat: Lattice) -> F64:
    """sum w (u_j - u_t)^2 over the bonds site j holds in the energy: its slots along +e_k (odd: each bond
    between two sites is held once, a wrapped one too) and its walls (a wall bond belongs to its site alone)."""
    bonds = ZERO
    for d in range(lat.degree):
        t = lat.table[j, d]
        if d % 2 == 1 or t == TABLE_WALL:
            diff = u - table_neighbour(x, b, 0, u, t)
            bonds = bonds + lat.weights[j, d] * (diff * diff)
    return bonds


@wp.func
def laplacian_at(x: Array3, b: int, comp: int, j: int, n: int, boundary: int) -> F64:
    """(u_j - u_{j-1}) + (u_j - u_{j+1}) of component ``comp`` of lattice b at site j."""
    u = x[b, comp, j]
    nb = neighbours_at(x, b, comp, j, n, boundary)
    return (u - nb[0]) + (u - nb[1])


@wp.func
def coupled_acceleration(u: F64, v: F64, lap: F64, inv_mass: F64, coupling: F64) -> wp.vec2d:
    """(u_j'', v_j'') from u_j, v_j and the Laplacian (L u)_j of any lattice: the arithmetic of the numpy
    reference, operation for operation, multiplied by 1/M."""
    force = contact_force(u - v)
    au = -(coupling * lap + force) * inv_mass
    return wp.vec2d(au, force)


@wp.func
def coupled_tangent_acceleration(du: F64, dv: F64, lap: F64, inv_mass: F64, coupling: F64, stiffness: F64) -> wp.vec2d:
    """The linear accelerations of a tangent (du, dv) with Laplacian ``lap`` at a site whose base has
    f'(z) = ``stiffness``."""
    dz = du - dv
    au = -(coupling * lap + stiffness * dz) * inv_mass
    return wp.vec2d(au, stiffness * dz)


@wp.func
def site_acceleration(u: F64, v: F64, left: F64, right: F64, inv_mass: F64, coupling: F64) -> wp.vec2d:
    """``coupled_acceleration`` on the chain, from the u of both neighbours (or the wall values): the arithmetic
    of ``acceleration_at`` (and ``laplacian_at``). Shared by the thread kernels' fused sweep and the block kernels."""
    return coupled_acceleration(u, v, (u - left) + (u - right), inv_mass, coupling)


@wp.func
def site_tangent_acceleration(
    du: F64, dv: F64, left: F64, right: F64, inv_mass: F64, coupling: F64, stiffness: F64
) -> wp.vec2d:
    """``coupled_tangent_acceleration`` on the chain (``tangent_acceleration_at``'s arithmetic)."""
    return coupled_tangent_acceleration(du, dv, (du - left) + (du - right), inv_mass, coupling, stiffness)


@wp.func
def kick_loss(pu: F64, pv: F64, au: F64, av: F64, damp: Array3, b: int, i: int, mass: F64) -> F64:
    """The energy damped kick i dissipates at one site from its velocities before the kick and its
    accelerations, exactly: f . (F w + H a) - (T(w') - T(w)) (``losses.kick_dissipation``)."""
    pu1 = damp[b, i, 0] * pu + damp[b, i, 1] * pv + (damp[b, i, 4] * au + damp[b, i, 5] * av)
    pv1 = damp[b, i, 2] * pu + damp[b, i, 3] * pv + (damp[b, i, 6] * au + damp[b, i, 7] * av)
    iu = damp[b, i, 4] * pu + damp[b, i, 5] * pv + (damp[b, i, 8] * au + damp[b, i, 9] * av)
    iv = damp[b, i, 6] * pu + damp[b, i, 7] * pv + (damp[b, i, 10] * au + damp[b, i, 11] * av)
    work = mass * au * iu + av * iv
    kinetic = HALF * (mass * (pu1 - pu) * (pu1 + pu) + (pv1 - pv) * (pv1 + pv))
    return work - kinetic


@wp.func
def site_energy(
    u: F64, v: F64, pu: F64, pv: F64, left: F64, right: F64, j: int, boundary: int, mass: F64, coupling: F64
) -> F64:
    """Site j's share of the Hamiltonian (``model.site_energies``): kinetic energy, the bond to its right neighbour
    and, at j = 0, the bond to its left unless the chain is a ring (whose last site holds that bond), and the
    contact energy. ``left``, ``right``: the neighbours' u, at the chain's ends the wall values (``wall_values``:
    a fixed wall's bond is u^2, a free end's 0)."""
    bonds = (right - u) * (right - u)
    if j == 0 and boundary != BOUNDARY_PERIODIC:
        bonds = bonds + (u - left) * (u - left)
    return held_energy(u, v, pu, pv, bonds, mass, coupling)


@wp.func
def held_energy(u: F64, v: F64, pu: F64, pv: F64, bonds: F64, mass: F64, coupling: F64) -> F64:
    """A site's share of the Hamiltonian given the sum of the squared (weighted) bond stretches it holds
    (``site_energy`` on the chain, ``table_bonds`` on a table): kinetic, (K/2) bonds, contact."""
    kinetic = HALF * mass * (pu * pu) + HALF * (pv * pv)
    return kinetic + HALF * coupling * bonds + contact_potential(u - v)


@wp.func
def finite_state(u: F64, v: F64, pu: F64, pv: F64) -> F64:
    """1 when all four values are finite, else 0."""
    if wp.isfinite(u) and wp.isfinite(v) and wp.isfinite(pu) and wp.isfinite(pv):
        return ONE
    return ZERO


@wp.struct
class Observer:
    """What an ``observed`` step loop reduces, and where (``warpchain.observe``; the unobserved ones take an empty
    one). Per lattice: ``spot`` (half-width in sites; on a lattice the radius of a disc, in lattice spacings), the
    running z extremes ``z_low``/``z_high`` (batch, N), the energy dissipated so far ``lost`` (batch, 1 in the thread
    layout; per site in the block and sites layouts), the last frame's ``envelope`` (batch, N), and ``values``
    (frames, batch, 7): the observables."""

    first_step: int
    frame_every: int
    threshold: F64
    radius: int
    contrast: F64
    spot: Array1
    z_low: Array2
    z_high: Array2
    lost: Array2
    envelope: Array2
    values: Array3


@wp.func
def peak_test(env: F64, left: F64, right: F64, state: wp.vec3d) -> wp.vec3d:
    """One distance of the localized-peak test (``warpchain.observe``) of a site with envelope ``env`` > threshold
    >= 0, whose neighbours at that distance have envelopes ``left`` and ``right`` (0 past a chain end, which never
    beats env): ``state`` (1 while still the largest, the lowest value on the left, on the right) after it."""
    peak = state[0]
    if left >= env or right > env:  # the largest within the radius: strictly on the left, at least on the right
        peak = ZERO
    return wp.vec3d(peak, wp.min(state[1], left), wp.min(state[2], right))


@wp.func
def peak_verdict(env: F64, state: wp.vec3d, contrast: F64) -> F64:
    """1 for a localized peak after every distance's ``peak_test`` (started from (1, env, env)): the largest,
    and the envelope falls to ``contrast`` * env or below on both sides; else 0."""
    if state[1] > contrast * env or state[2] > contrast * env:
        return ZERO
    return state[0]


@wp.func
def window_peak(envelope: Array2, b: int, j: int, n: int, env: F64, radius: int, contrast: F64) -> F64:
    """1 when site j of lattice b (envelope ``env`` above the threshold, the caller's test) is a localized peak by the
    chain's rule (``reference.peak_mask``): its windows of ``radius`` sites in ``envelope``, 0 past the chain's ends."""
    test = wp.vec3d(ONE, env, env)
    for i in range(1, radius + 1):
        left = ZERO  # past the chain's end
        right = ZERO
        if j - i >= 0:
            left = envelope[b, j - i]
        if j + i < n:
            right = envelope[b, j + i]
        test = peak_test(env, left, right, test)
    return peak_verdict(env, test, contrast)


@wp.func
def store_observables(
    ob: Observer, r: int, b: int, peaks: F64, total: F64, squares: F64, inside: F64, top: F64, low: F64, dissipated: F64
):
    """values[r, b] = (peaks, participation, spot energy, max envelope, min contact, energy, dissipated)."""
    pr = ZERO
    if squares > ZERO:
        pr = total * total / squares
    ob.values[r, b, 0] = peaks
    ob.values[r, b, 1] = pr
    ob.values[r, b, 2] = inside
    ob.values[r, b, 3] = top
    ob.values[r, b, 4] = low
    ob.values[r, b, 5] = total
    ob.values[r, b, 6] = dissipated


@wp.func
def site_acceleration_times(u: F64, v: F64, left: F64, right: F64, minus_inv_mass: F64, coupling: F64) -> wp.vec2d:
    """``site_acceleration`` with -1/M given: (K lap + f) * (-1/M) has the same bits as -(K lap + f) * (1/M)
    (rounding is symmetric in sign), and saves the negation (a dependent DADD on the GPU) in the time loop."""
    force = contact_force(u - v)
    au = (coupling * ((u - left) + (u - right)) + force) * minus_inv_mass
    return wp.vec2d(au, force)


@wp.func
def site_kick(pu: F64, pv: F64, a: wp.vec2d, h: F64, lossy: int, damp: Array3, b: int, i: int) -> wp.vec2d:
    """Kick i of one site: w + h a without losses, else the exact damped kick E w + F a (``losses``;
    ``damp[b, i]`` = E00, E01, E10, E11, F00, F01, F10, F11, the reference's operation order)."""
    if lossy != 0:
        npu = damp[b, i, 0] * pu + damp[b, i, 1] * pv + (damp[b, i, 4] * a[0] + damp[b, i, 5] * a[1])
        npv = damp[b, i, 2] * pu + damp[b, i, 3] * pv + (damp[b, i, 6] * a[0] + damp[b, i, 7] * a[1])
        return wp.vec2d(npu, npv)
    return wp.vec2d(pu + h * a[0], pv + h * a[1])
