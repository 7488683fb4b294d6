"""Tiles with halos: a 2-D lattice given as a table, stepped several steps per launch (temporal blocking, float64).

The sites layout (``site_kernels``) launches once per force evaluation and reads every neighbour from global memory:
a tenth of the chain's block kernel (docs/performance.md). Here a thread block of ``EDGE`` x ``EDGE`` threads holds an
extended tile of the lattice's grid (site s = x + nx y) in registers, its u shared through a ping-pong tile in shared
memory as in ``block_kernels``, and runs ``steps`` whole steps of a splitting method in one launch. Each force
evaluation needs its neighbours' u of the same evaluation, so the ring of sites that is still exact shrinks by one
per evaluation: with ``1 + stages * steps`` evaluations (the first recomputes the accelerations of the state loaded,
as every launch of the block kernels does) the halo is that wide, and the block writes back only its owned tile of
``EDGE - 2 halo`` squared sites. The state moves between two buffers (``src`` -> ``dst``), since a block's owned sites
are its neighbours' halo.

The arithmetic is the sites layout's, site for site: the table's slots in order (``site.table_laplacian``: a wall
reads 0, a slot without neighbour reads the site itself), ``site.coupled_acceleration``, the kicks and drifts of the
method's coefficients times dt (``block_kernels.Scheme``), ``site.site_kick`` for lattices with losses; bit for bit
with the numpy reference on the CPU. A neighbour's u is read from the tile at the grid offset of its slot
(``grid_offsets``: only a table that is a grid with those offsets, wrapped or walled, takes this path).
"""

from __future__ import annotations

import functools

import numpy as np
import warp as wp

from .block_kernels import Scheme
from .site import BOUNDARY_PERIODIC, TABLE_WALL, Array3, Lattice, coupled_acceleration, site_kick

#: the extended tile's edge: EDGE x EDGE threads per block
EDGE = 32
#: the narrowest owned tile worth a launch (a halo wider than (EDGE - MIN_OWNED) / 2 is refused)
MIN_OWNED = 8


def halo(stages: int, steps: int) -> int:
    """The rings a launch of ``steps`` steps of a ``stages``-stage method consumes: one per force evaluation."""
    return 1 + stages * steps


def owned_edge(stages: int, steps: int) -> int:
    return EDGE - 2 * halo(stages, steps)


@functools.lru_cache(maxsize=32)
def grid_offsets(lattice) -> np.ndarray | None:
    """(D,) int32 offsets in the tile's lanes (dy EDGE + dx) of each slot of ``lattice``'s table, or None when the table
    is not the grid of its directions (a slot 2k steps by -e_k, 2k + 1 by +e_k; a wrapped or walled edge)."""
    directions = getattr(lattice, "directions", None)
    if directions is None or lattice.degree != 2 * len(directions):
        return None
    nx, ny = (tuple(lattice.shape) + (1,))[:2]
    s = np.arange(lattice.n_sites)
    x, y = s % nx, s // nx
    offsets = np.empty(lattice.degree, dtype=np.int32)
    for d in range(lattice.degree):
        dx, dy = (2 * (d % 2) - 1) * np.asarray(directions[d // 2])
        t = lattice.neighbours[:, d]
        inside = t >= 0
        expect = (x + dx) % nx + nx * ((y + dy) % ny)
        if not np.array_equal(t[inside], expect[inside]):
            return None
        offsets[d] = dy * EDGE + dx
    return offsets


@functools.lru_cache(maxsize=None)
def tile_kernel(degree: int, stages: int, steps: int, damped: bool):
    """The tile kernel for a table of ``degree`` slots and ``steps`` steps of a ``stages``-stage splitting method
    (compiled in; ``damped``: the exact damped kicks of lattices with losses). Launch with
    ``dim=(lattices * tiles, EDGE * EDGE)``, ``block_dim=EDGE * EDGE``."""
    H = halo(stages, steps)
    T = owned_edge(stages, steps)
    if T < MIN_OWNED:
        raise ValueError(
            f"{steps} steps of a {stages}-stage method need a halo of {H}: owned tiles of {T} < {MIN_OWNED}"
        )
    threads = EDGE * EDGE
    halves = 2 * threads
    slots_i = wp.types.vector(length=degree, dtype=wp.int32)
    slots_f = wp.types.vector(length=degree, dtype=wp.float64)

    @wp.kernel(enable_backward=False, module="unique", launch_bounds=threads)
    def tiles(
        src: Array3, dst: Array3, lat: Lattice, offsets: wp.array(dtype=wp.int32), grid: wp.vec4i, scheme: Scheme
    ):
        """``steps`` steps of lattice b's tile (grid: nx, ny, tiles along x, tiles along y; block g = b * tiles +
        tile, thread = lane of the extended tile), from ``src`` into ``dst`` (the owned sites only)."""
        g, lane = wp.tid()
        nx = grid[0]
        ny = grid[1]
        per = grid[2] * grid[3]
        b = g / per
        tile = g - b * per
        ty = tile / grid[2]
        tx = tile - ty * grid[2]
        ey = lane / wp.static(EDGE)
        ex = lane - ey * wp.static(EDGE)
        X = tx * wp.static(T) + ex - wp.static(H)
        Y = ty * wp.static(T) + ey - wp.static(H)
        owned = ex >= wp.static(H) and ex < wp.static(H + T) and ey >= wp.static(H) and ey < wp.static(H + T)
        owned = owned and X < nx and Y < ny
        Xs = X
        Ys = Y
        active = X >= 0 and X < nx and Y >= 0 and Y < ny
        if lat.boundary == BOUNDARY_PERIODIC:  # a halo site is the wrapped one
            Xs = ((X % nx) + nx) % nx
            Ys = ((Y % ny) + ny) % ny
            active = True
        s = Xs + nx * Ys
        u = wp.float64(0.0)
        v = wp.float64(0.0)
        pu = wp.float64(0.0)
        pv = wp.float64(0.0)
        t = slots_i()
        w = slots_f()
        off = slots_i()
        for d in range(wp.static(degree)):
            off[d] = offsets[d]
        if active:
            u = src[b, 0, s]
            v = src[b, 1, s]
            pu = src[b, 2, s]
            pv = src[b, 3, s]
            for d in range(wp.static(degree)):
                t[d] = lat.table[s, d]
                w[d] = lat.weights[s, d]
        m = lat.inv_mass[b]
        k = lat.coupling[b]
        loss = int(0)
        if wp.static(damped):
            loss = lat.lossy[b]
        drifts = scheme.drifts
        kicks = scheme.kicks
        buf = wp.tile_zeros(shape=(halves,), dtype=wp.float64, storage="shared")
        parity = int(0)
        wp.tile_assign(buf, wp.tile(u), offset=(0,))
        lap = wp.float64(0.0)
        for d in range(wp.static(degree)):
            other = u  # a slot without neighbour reads the site itself
            if t[d] == TABLE_WALL:
                other = wp.float64(0.0)
            elif t[d] >= 0:
                other = buf[wp.clamp(lane + off[d], 0, wp.static(threads - 1))]
            if d == 0:
                lap = w[d] * (u - other)
            else:
                lap = lap + w[d] * (u - other)
        a = coupled_acceleration(u, v, lap, m, k)
        for step in range(wp.static(steps)):
            h = kicks[0]
            if wp.static(damped):
                q = site_kick(pu, pv, a, h, loss, lat.damp, b, 0)
                pu = q[0]
                pv = q[1]
            else:
                pu = pu + h * a[0]
                pv = pv + h * a[1]
            for st in range(wp.static(stages)):
                h = drifts[st]
                u = u + h * pu
                v = v + h * pv
                parity = 1 - parity
                base = parity * wp.static(threads)
                wp.tile_assign(buf, wp.tile(u), offset=(base,))
                for d in range(wp.static(degree)):
                    other = u
                    if t[d] == TABLE_WALL:
                        other = wp.float64(0.0)
                    elif t[d] >= 0:
                        other = buf[base + wp.clamp(lane + off[d], 0, wp.static(threads - 1))]
                    if d == 0:
                        lap = w[d] * (u - other)
                    else:
                        lap = lap + w[d] * (u - other)
                a = coupled_acceleration(u, v, lap, m, k)
                h = kicks[st + 1]
                if wp.static(damped):
                    q = site_kick(pu, pv, a, h, loss, lat.damp, b, st + 1)
                    pu = q[0]
                    pv = q[1]
                else:
                    pu = pu + h * a[0]
                    pv = pv + h * a[1]
        if owned:
            dst[b, 0, s] = u
            dst[b, 1, s] = v
            dst[b, 2, s] = pu
            dst[b, 3, s] = pv

    return tiles
