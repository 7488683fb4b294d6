"""Colourings and balls of bonds of a lattice (``warpchain.lattice``), for probing Jacobian columns by colour groups
(``flow.Linearization.probed_columns``): sites of one colour are more than a given number of bonds apart, so one
tangent run from all of them gives each one's column over its ball.

``colouring`` picks the modular colouring on patches without wrapped axes (as few colours as the ball of half the
distance has sites, where such balls tile the plane) and the greedy one otherwise; ``kept_colouring`` and
``balls_and_rims`` (``balls_of``) keep theirs per lattice (Newton asks at every iterate).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp


def colouring(lattice, distance: int) -> np.ndarray:
    """``modular_colouring`` where it finds one, else ``greedy_colouring``."""
    modular = modular_colouring(lattice, distance)
    return modular if modular is not None else greedy_colouring(lattice, distance)


def greedy_colouring(lattice, distance: int) -> np.ndarray:
    """In site order, each site the smallest colour none of the sites within ``distance`` bonds has (any lattice,
    wrapped axes too)."""
    n, nb = lattice.n_sites, lattice.neighbours
    s, d = np.nonzero((nb >= 0) & (lattice.weights != 0))
    keep = nb[s, d] != s
    adjacency = sp.csr_matrix((np.ones(keep.sum()), (s[keep], nb[s, d][keep])), shape=(n, n))
    reach = sp.identity(n, format="csr")
    for _ in range(distance):
        reach = (reach + reach @ adjacency).astype(bool).astype(np.int64)
    colours = np.full(n, -1, dtype=np.int64)
    for site in range(n):
        taken = set(colours[reach.indices[reach.indptr[site] : reach.indptr[site + 1]]].tolist())
        colour = 0
        while colour in taken:
            colour += 1
        colours[site] = colour
    return colours


def modular_colouring(lattice, distance: int) -> "np.ndarray | None":
    """Colours c = (i + k j) mod m on the lattice's axial coordinates (i, j), with the smallest m from a start and a
    k for which no step between two sites within ``distance`` bonds is a multiple of the colour period. Those steps
    are the offsets a walk of at most ``distance`` bonds reaches without leaving the patch's extent (|di| < nx,
    |dj| < ny): on a patch without wrapped axes a path between two sites stays inside it. The start is the number of
    such offsets within distance // 2 bonds (on a wide patch the ball of distance / 2 bonds, whose sites are
    pairwise within distance, so no colouring has fewer). The balls tile the square (2 b^2 + 2 b + 1 sites) and
    triangular (3 b^2 + 3 b + 1) lattices, where the greedy colouring takes about 15 % and 30 % more colours (on a
    strip narrower than the distance it can take fewer: 61 x 4 at distance 16, 95 against 68). Every site its own
    colour when the start reaches the sites; None on wrapped axes, where bonds of weight 0 would be read as steps,
    or when no m up to twice the start works."""
    if any(lattice._wraps):
        return None
    steps = [tuple(e) for e, w in zip(lattice.directions.tolist(), lattice.direction_weights) if w != 0]
    bonded = (lattice.neighbours >= 0) & (lattice.weights != 0)
    if not steps or np.any(lattice.weights[bonded] != np.repeat(lattice.direction_weights, 2)[np.nonzero(bonded)[1]]):
        return None  # weights other than the directions' (a bond of weight 0 would not be a step)
    steps += [(-a, -b) for a, b in steps]
    nx, ny = lattice._grid
    balls, frontier, seen = [1], {(0, 0)}, {(0, 0)}
    for _ in range(distance):
        frontier = {(a + da, b + db) for a, b in frontier for da, db in steps}
        frontier = {o for o in frontier if abs(o[0]) < nx and abs(o[1]) < ny} - seen
        seen |= frontier
        balls.append(len(seen))
    lowest = balls[distance // 2]
    if lowest >= lattice.n_sites:
        return np.arange(lattice.n_sites, dtype=np.int64)
    # o and -o forbid the same k: half the offsets
    offsets = np.array([o for o in sorted(seen) if o[1] > 0 or (o[1] == 0 and o[0] > 0)], dtype=np.int64)
    di, dj = offsets[None, :, 0], offsets[None, :, 1]
    rows = max(1, (1 << 22) // max(1, len(offsets)))  # k values tested at once (memory ~ rows x offsets)
    coords = lattice._coords
    for m in range(lowest, 2 * lowest + 1):
        for first in range(0, m, rows):
            k = np.arange(first, min(m, first + rows), dtype=np.int64)[:, None]
            ok = ~np.any((di + k * dj) % m == 0, axis=1)
            if ok.any():
                colours = (coords[:, 0] + int(k[np.argmax(ok), 0]) * coords[:, 1]) % m
                return np.unique(colours, return_inverse=True)[1].astype(np.int64)
    return None


@functools.lru_cache(maxsize=8)
def kept_colouring(lattice, distance: int) -> np.ndarray:
    """``lattice.colouring(distance)``, kept (with ``balls_and_rims``): Newton asks for a patch's probed columns at
    every iterate (``flow.Linearization``), and a periodic patch's greedy colouring takes seconds at 101 x 101."""
    colours = lattice.colouring(distance)
    colours.setflags(write=False)
    return colours


def balls_of(lattice, b: int) -> tuple:
    """CSR (sites x sites) of the sites within b bonds (weight != 0) of each site, and of those exactly b away (kept:
    ``balls_and_rims``)."""
    return balls_and_rims(lattice, b)[:2]


@functools.lru_cache(maxsize=8)
def balls_and_rims(lattice, b: int) -> tuple:
    """``balls_of``'s ball and rim at b, and the rim one bond nearer (the sites exactly b - 1 away, for b >= 2), from
    the same growth of the ball, kept per lattice and b: the probe's decay check reads both rims
    (``Linearization._probed_lattice``), where it grew the ball to b - 1 a second time."""
    n, nb = lattice.n_sites, lattice.neighbours
    s, d = np.nonzero((nb >= 0) & (lattice.weights != 0))
    eye = sp.identity(n, dtype=bool, format="csr")
    step = sp.csr_matrix((np.ones(len(s), bool), (s, nb[s, d])), shape=(n, n)) + eye
    nearer, inner = eye, eye
    for _ in range(b - 1):
        nearer, inner = inner, (inner @ step).astype(bool)
    ball = (inner @ step).astype(bool).tocsr()
    rims = []
    for outer, within in ((ball, inner), (inner, nearer)):
        rim = (outer.astype(np.int8) - within.astype(np.int8)).astype(bool).tocsr()
        rim.eliminate_zeros()
        rim.sort_indices()
        rims.append(rim)
    ball.sort_indices()
    return ball, rims[0], rims[1]
