"""Lattices as data: the chain, the square and the triangular monolayer as neighbour tables.

A lattice is plain numpy (float64 weights, int32 indices) and no Warp: sites s = 0..n-1, each with D
neighbour *slots* (D = 2 chain, 4 square, 6 triangular). On a grid of shape (nx, ny) the site of axial
coordinates (i, j) is s = i + nx * j (i fastest; the chain is (N,), s = i). Slots come in opposite pairs:
slot 2k steps by -e_k, slot 2k + 1 by +e_k, for the bond directions e_k (axial): chain (1, 0); square
(1, 0), (0, 1); triangular (1, 0), (0, 1), (1, -1). So the chain's slot 0 is its left neighbour s - 1 and
slot 1 its right one s + 1. ``neighbours[s, d]`` is a site index (a wrapped one on a ring), ``WALL`` (a fixed
wall: reads u = 0, the bond counts) or ``MISSING`` (a free end: no bond); ``weights[s, d]`` is the bond's
weight (the direction's, 0 at MISSING). Positions are i a1 + j a2 for the rows a1, a2 of ``basis``: (i, j)
on the square, (i + j/2, j sqrt(3)/2) on the triangular patch, (s, 0) for the chain. The table is
symmetric: if slot d of s reaches t, slot d ^ 1 of t reaches s with the same weight (checked).

**Laplacian.** (L u)_s = sum_d w_sd (u_s - u_nb(s,d)), with u_WALL = 0. A MISSING slot reads the site
itself, w (u_s - u_s) = 0, as ``model.walls`` reads a free end: the slots are accumulated in order, so
the chain's (u - left) + (u - right) is ``model.laplacian`` bit for bit (weights 1 multiply exactly). A
bond of weight 0 adds a signed zero, which changes nothing but the sign of an exact -0.0 sum.

**Energy.** (1/2) sum over bonds of w (u_s - u_t)^2, wall bonds w u_s^2 included. Pairing the two ends
of each bond, u_s w (u_s - u_t) + u_t w (u_t - u_s) = w (u_s - u_t)^2, so it equals (1/2) u^T L u.

**Symbol and bands.** A Bloch wave u_s = exp(i q.x_s) (q = (q1, q2) on the axial coordinates) on the
infinite lattice has L u = lam(q) u, lam(q) = sum_k w_k (2 - e^{i q.e_k} - e^{-i q.e_k})
= sum_k 2 w_k (1 - cos q.e_k): 2(1 - cos q) chain, 2[2 - cos q1 - cos q2] square,
2[3 - cos q1 - cos q2 - cos(q1 - q2)] triangular. With u, v ~ e^{i w t} the model gives
M w^4 - [K lam + M + 1] w^2 + K lam = 0 (``_two_branches`` with s = K lam). The acoustic top comes
from lam_max: 4 w (chain) and 4 (w1 + w2) (square: directions independent, q = (pi, pi)). Triangular:
lam = 2 (sum w - F), F = sum_k w_k cos phi_k with phi = (q1, -q2, q2 - q1), sum phi = 0. Minimum of F: at a
critical point w_k sin phi_k = lam' for all k; lam' = 0 gives phi_k in {0, pi} (an even number of pi),
F = +-w1 +- w2 +- w3; lam' != 0 gives a triangle of angles pi - phi_k whose sides (law of sines) are
proportional to 1/w_k, F = -(w1 w2/w3 + w2 w3/w1 + w3 w1/w2) / 2 when 1/w_k obey the triangle
inequality. Unit weights: F = -3/2, lam_max = 9 (8 square, 4 chain).

**Periodic and small.** The table holds period-n images, so a wrapped axis of size 2 holds a double bond
(as ``model``'s ring of N = 2) and one of size 1 a bond to the site itself (u_s - u_s = 0): exactly the
infinite lattice on period-n states, with spectrum lam(2 pi k / n). Small sizes are handled, not refused.

**Extending.** A geometry is a builder calling ``_build`` with its basis, bond directions, weights and
lam_max; its point symmetries are derived (``symmetries``: the rotations and mirrors, multiples of 15
degrees, that map the basis lattice onto itself, kept when they map the patch onto itself as an
automorphism of the table). A boundary kind is one row of ``_EDGES``: what a bond across each axis's edges
reaches (WALL, MISSING or a wrap).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from .checks import real_number, whole_number
from .colouring import colouring

#: slot code: a fixed wall, read as u = 0; the bond counts (Laplacian and energy).
WALL = -1
#: slot code: no neighbour (a free end); no bond.
MISSING = -2
_WRAP = "wrap"
#: per boundary, what a bond leaving the grid across the edges of axis x, axis y reaches.
_EDGES = {"fixed": (WALL, WALL), "free": (MISSING, MISSING), "periodic": (_WRAP, _WRAP)}
BOUNDARIES = tuple(_EDGES)  # the same names, in the same order, as model.BOUNDARIES

_SQUARE = np.eye(2)
_TRIANGULAR = np.array([[1.0, 0.0], [0.5, math.sqrt(3.0) / 2.0]])


def _two_branches(s, M):
    """(acoustic, optical) frequencies of the two-mass cell at the stiffness s = K lam(q)."""
    a = s + M + 1.0
    disc = np.sqrt(np.maximum(a * a - 4.0 * M * s, 0.0))
    # the lower root in the cancellation-free form 2c / (b + sqrt(b^2 - 4ac))
    lower = np.sqrt(2.0 * s / (a + disc))
    upper = np.sqrt((a + disc) / (2.0 * M))
    return lower, upper


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Lattice:
    """One lattice as data (see the module docstring); build it with ``chain``, ``square`` or ``triangular``.

    Args:
        name: ``"chain"``, ``"square"``, ``"triangular"``.
        shape: (N,) or (nx, ny).
        boundary: one of ``BOUNDARIES``.
        neighbours: int32 (n_sites, D): site indices, ``WALL`` or ``MISSING``.
        weights: float64 (n_sites, D), >= 0, 0 at MISSING.
        positions: float64 (n_sites, 2), cartesian, for figures and distances.
        basis: float64 (2, 2), rows a1, a2: position = i a1 + j a2.
        directions: int (D/2, 2), the axial step e_k of slot 2k + 1 (slot 2k steps by -e_k).
        direction_weights: the weight of each direction (the lattice symbol's).
        lam_max: the maximum of the symbol lam(q).
    """

    name: str
    shape: tuple
    boundary: str
    neighbours: np.ndarray
    weights: np.ndarray
    positions: np.ndarray
    basis: np.ndarray
    directions: np.ndarray
    direction_weights: tuple
    lam_max: float

    def __post_init__(self):
        arrays = {"neighbours": np.int32, "weights": float, "positions": float, "basis": float, "directions": np.int64}
        for name, dtype in arrays.items():
            arr = np.array(getattr(self, name), dtype=dtype)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "shape", tuple(int(x) for x in self.shape))
        object.__setattr__(self, "direction_weights", tuple(float(w) for w in self.direction_weights))
        object.__setattr__(self, "lam_max", float(self.lam_max))
        n, nb, w = int(np.prod(self.shape)), self.neighbours, self.weights
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"Lattice.boundary must be one of {BOUNDARIES}, got {self.boundary!r}")
        if nb.shape != (n, 2 * len(self.directions)) or w.shape != nb.shape or self.positions.shape != (n, 2):
            raise ValueError(f"Lattice tables disagree with shape {self.shape} and {len(self.directions)} directions")
        if nb.min(initial=0) < MISSING or nb.max(initial=0) >= n:
            raise ValueError("Lattice.neighbours holds entries that are neither sites nor WALL/MISSING")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or np.any(w[nb == MISSING] != 0):
            raise ValueError("Lattice.weights must be finite, >= 0, and 0 at MISSING slots")
        s, d = np.nonzero(nb >= 0)
        t = nb[s, d]
        if np.any(nb[t, d ^ 1] != s) or np.any(w[t, d ^ 1] != w[s, d]):
            raise ValueError(
                "Lattice table not symmetric: s reaches t by slot d, t not s by d^1 (or by another weight)"
            )

    # ------------------------------------------------------------------ shape and numbering

    @property
    def n_sites(self) -> int:
        return self.neighbours.shape[0]

    @property
    def degree(self) -> int:
        """Slots per site, D."""
        return self.neighbours.shape[1]

    @property
    def centre(self) -> int:
        """The site nearest the geometric centre: N // 2 on the chain (as ``model``), nx//2 + nx*(ny//2) in 2D."""
        nx, ny = self._grid
        return nx // 2 + nx * (ny // 2)

    @property
    def _grid(self) -> tuple[int, int]:
        return (self.shape + (1,))[:2]

    @functools.cached_property
    def _coords(self) -> np.ndarray:
        """Axial (i, j) of each site, int64 (n_sites, 2)."""
        s = np.arange(self.n_sites)
        return np.stack([s % self._grid[0], s // self._grid[0]], axis=1)

    @property
    def _wraps(self) -> tuple[bool, bool]:
        return tuple(e == _WRAP and axis < len(self.shape) for axis, e in enumerate(_EDGES[self.boundary]))

    @functools.cached_property
    def _gather(self) -> np.ndarray:
        """Indices into u padded with one zero: a site, n_sites (the zero) at a WALL, the site itself at MISSING."""
        nb = self.neighbours.astype(np.intp)
        own = np.broadcast_to(np.arange(self.n_sites)[:, None], nb.shape)
        return np.where(nb == WALL, self.n_sites, np.where(nb == MISSING, own, nb))

    def _field(self, u) -> tuple[np.ndarray, np.ndarray]:
        """u as float64 (..., n_sites), and u padded with a zero site."""
        if np.iscomplexobj(u):
            raise ValueError("u must be real; got a complex array")
        u = np.asarray(u, dtype=np.float64)
        if u.ndim == 0 or u.shape[-1] != self.n_sites:
            raise ValueError(f"u must have the lattice's {self.n_sites} sites along its last axis, got {u.shape}")
        return u, np.concatenate([u, np.zeros(u.shape[:-1] + (1,))], axis=-1)

    # ------------------------------------------------------------------ the Laplacian and the bond energy

    def laplacian(self, u) -> np.ndarray:
        """(L u)_s = sum_d w_sd (u_s - u_nb(s,d)) along the last axis (WALL reads 0, MISSING adds nothing)."""
        u, padded = self._field(u)
        out = self.weights[:, 0] * (u - padded[..., self._gather[:, 0]])
        for d in range(1, self.degree):
            out = out + self.weights[:, d] * (u - padded[..., self._gather[:, d]])
        return out

    def laplacian_matrix(self):
        """L as a scipy.sparse CSR matrix (n_sites x n_sites), symmetric, positive semidefinite."""
        import scipy.sparse as sp

        n, nb = self.n_sites, self.neighbours
        s, d = np.nonzero(nb >= 0)
        rows = np.concatenate([np.arange(n), s])
        cols = np.concatenate([np.arange(n), nb[s, d]])
        values = np.concatenate([self.weights.sum(axis=1), -self.weights[s, d]])
        L = sp.csr_matrix((values, (rows, cols)), shape=(n, n))  # duplicates summed
        L.eliminate_zeros()
        return L

    @functools.cached_property
    def _bond_weights(self) -> np.ndarray:
        """The weights counted by ``bond_energy``: the +e_k slots (each bond once) and every WALL slot."""
        forward = np.arange(self.degree) % 2 == 1  # MISSING slots weigh 0 already
        return np.where(forward | (self.neighbours == WALL), self.weights, 0.0)

    def bond_energy(self, u) -> np.ndarray:
        """(1/2) sum over bonds of w (u_s - u_t)^2, wall bonds included, along the last axis (shape u.shape[:-1]).

        ``model.energy`` without K: (1/2)(sum of squared differences + ``model.wall_bonds``), to rounding."""
        u, padded = self._field(u)
        total = np.zeros(u.shape[:-1])
        for d in range(self.degree):
            if np.any(self._bond_weights[:, d]):
                diff = u - padded[..., self._gather[:, d]]
                total = total + np.sum(self._bond_weights[:, d] * diff * diff, axis=-1)
        return 0.5 * total

    @property
    def long_wave_curvature(self) -> float:
        """kappa in lam(q) = kappa |q|^2 + O(q^4), q cartesian (lattice spacing 1), averaged over the directions:
        sum_k w_k |e_k|^2 / dimension (unit weights: 1 on the chain and the square lattice, 3/2 on the triangular).
        The acoustic branch's long-wave speed is w0 sqrt(kappa K / (M + 1)) spacings per unit time, so a lattice
        with K / kappa has the chain's long-wave speed at K (``physical.monolayer_coupling``)."""
        steps = self.directions @ self.basis  # the bonds' cartesian vectors
        return float(np.dot(self.direction_weights, np.sum(steps * steps, axis=1)) / len(self.shape))

    @functools.cached_property
    def table_digest(self) -> tuple:
        """(n_sites, degree, a SHA-1 of the neighbour slots and the weights): equal exactly for equal tables."""
        import hashlib

        digest = hashlib.sha1(self.neighbours.tobytes() + self.weights.tobytes()).hexdigest()
        return (self.n_sites, self.degree, digest)

    def site_bond_energy(self, u, sites=None) -> np.ndarray:
        """``bond_energy`` shared out to the sites, shape u.shape: half of each bond between two sites to each, a
        wall bond to its site. Summed over the sites it is ``bond_energy`` (to rounding): an energy density.
        ``sites`` (indices): the density at those sites only, shape u.shape[:-1] + (len(sites),)."""
        u, padded = self._field(u)
        at = np.arange(self.n_sites) if sites is None else np.asarray(sites)
        if at.dtype.kind not in "iu":
            raise ValueError(f"sites must be site indices (integers), got an array of {at.dtype}")
        here = u[..., at]
        out = np.zeros(here.shape)
        for d in range(self.degree):
            share = np.where(self.neighbours[at, d] == WALL, 0.5, 0.25) * self.weights[at, d]
            diff = here - padded[..., self._gather[at, d]]
            out = out + share * diff * diff
        return out

    # ------------------------------------------------------------------ linear waves

    def lam(self, q) -> np.ndarray:
        """The lattice symbol lam(q) = sum_k 2 w_k (1 - cos q.e_k).

        Args:
            q: Bloch numbers: any array for the chain; a pair (q1, q2) (first axis of length 2) in 2D.
        """
        q = np.asarray(q, dtype=np.float64)
        if len(self.shape) == 1:
            q1, q2 = q, 0.0
        elif q.ndim >= 1 and q.shape[0] == 2:
            q1, q2 = q[0], q[1]
        else:
            raise ValueError(f"q must be a pair (q1, q2) for the {self.name} lattice, got shape {q.shape}")
        out = np.zeros(np.broadcast(q1, q2).shape)
        for (e1, e2), w in zip(self.directions, self.direction_weights):
            out = out + 2.0 * w * (1.0 - np.cos(e1 * q1 + e2 * q2))
        return out

    def dispersion(self, q, M: float, K: float) -> tuple[np.ndarray, np.ndarray]:
        """(acoustic, optical) frequencies at Bloch numbers q (``lam``'s q): ``_two_branches`` at K lam(q)."""
        M, K = real_number("M", M, positive=True), real_number("K", K, nonnegative=True)
        return _two_branches(K * self.lam(q), M)

    def band_edges(self, M: float, K: float) -> dict:
        """The infinite lattice's band edges, the keys of ``model.band_edges``; the chain's equal it."""
        M, K = real_number("M", M, positive=True), real_number("K", K, nonnegative=True)
        acoustic_top, optical_top = (float(x) for x in _two_branches(K * self.lam_max, M))
        optical_bottom = math.sqrt((M + 1.0) / M)
        return {
            "acoustic_top": acoustic_top,
            "optical_bottom": optical_bottom,
            "optical_top": optical_top,
            "gap_width": optical_bottom - acoustic_top,
        }

    def stiffness_and_mass(self, M: float, K: float) -> tuple[np.ndarray, np.ndarray]:
        """Linearised stiffness and mass matrices (2n x 2n), ordered (u_0..u_{n-1}, v_0..v_{n-1}) as ``model``'s."""
        M, K = real_number("M", M, positive=True), real_number("K", K, nonnegative=True)
        eye = np.eye(self.n_sites)
        lap = self.laplacian(eye)  # row j is L e_j, L symmetric
        stiff = np.block([[K * lap + eye, -eye], [-eye, eye]])
        mass = np.diag(np.concatenate([np.full(self.n_sites, M), np.ones(self.n_sites)]))
        return stiff, mass

    def linear_modes(self, M: float, K: float) -> tuple[np.ndarray, np.ndarray]:
        """Linear modes about rest, as ``model.linear_modes``: frequencies (2n,) ascending, shapes (2n, 2, n)
        mass-orthonormal, each signed so that its largest-|.| entry is positive."""
        from scipy.linalg import eigh

        n = self.n_sites
        w2, vecs = eigh(*self.stiffness_and_mass(M, K))
        shapes = vecs.T.reshape(2 * n, 2, n)
        for m in range(2 * n):
            flat = shapes[m].ravel()
            if flat[np.argmax(np.abs(flat))] < 0:
                shapes[m] *= -1.0
        return np.sqrt(np.maximum(w2, 0.0)), shapes

    # ------------------------------------------------------------------ geometry

    def distances(self, from_site: int) -> np.ndarray:
        """Euclidean distance of every site from ``from_site`` (positions; minimum image on wrapped axes)."""
        site = whole_number("from_site", from_site, minimum=0)
        if site >= self.n_sites:
            raise ValueError(f"from_site must be a site < {self.n_sites}, got {from_site!r}")
        sizes = np.array(self._grid)
        d = self._coords - self._coords[site]
        wraps = np.array(self._wraps)
        d[:, wraps] = (d[:, wraps] + sizes[wraps] // 2) % sizes[wraps] - sizes[wraps] // 2
        best = np.linalg.norm(d @ self.basis, axis=1)
        # an image nearer than best is within best/sin(angle) of d along each wrapped axis
        sine = abs(np.linalg.det(self.basis)) / np.prod(np.linalg.norm(self.basis, axis=1))
        reach = best.max() / (sizes * np.linalg.norm(self.basis, axis=1) * sine) + 0.5
        ranges = [range(-int(r), int(r) + 1) if wrap else range(1) for r, wrap in zip(reach, wraps)]
        for a in ranges[0]:
            for b in ranges[1]:
                best = np.minimum(best, np.linalg.norm((d + sizes * (a, b)) @ self.basis, axis=1))
        return best

    def _is_automorphism(self, p: np.ndarray) -> bool:
        """Whether site s -> p[s] maps each site's (neighbour, weight) slots onto p[s]'s (WALL, MISSING kept)."""
        if not np.array_equal(np.sort(p), np.arange(self.n_sites)):
            return False
        nb = self.neighbours
        moved = _sorted_slots(np.where(nb >= 0, p[np.maximum(nb, 0)], nb), self.weights)
        target = _sorted_slots(nb[p], self.weights[p])
        return all(np.array_equal(a, b) for a, b in zip(moved, target))

    def symmetries(self) -> dict[str, np.ndarray]:
        """Point symmetries about the geometric centre that map the lattice (boundary and weights) onto itself.

        Returns:
            dict name -> int permutation p (site s goes to p[s]), the identity left out: the chain's
            ``"mirror"`` s -> N - 1 - s (``continuation``'s j -> N + 1 - j); in 2D ``"rot<deg>"`` (rotations)
            and ``"mirror_<deg>"`` (the mirror line's angle: square ``mirror_0`` j -> ny-1-j, ``mirror_90``
            i -> nx-1-i, ``mirror_45`` (i, j) -> (j, i); triangular ``mirror_30`` (i, j) -> (j, i)). The centre
            is ((nx-1)/2, (ny-1)/2): on a torus of even size a rotation that would not map sites to sites
            about it is left out. A permutation equal to an earlier one is listed once.
        """
        if len(self.shape) == 1:
            operations = {"mirror": np.array([[-1, 0], [0, 1]])}
        else:
            operations = _point_operations(self.basis)
        sizes, wraps = np.array(self._grid), np.array(self._wraps)
        twice = 2 * self._coords - (sizes - 1)
        found: dict[str, np.ndarray] = {}
        for name, A in operations.items():
            image = twice @ A.T + (sizes - 1)
            if np.any(image % 2):
                continue
            image //= 2
            image[:, wraps] %= sizes[wraps]
            if np.any((image < 0) | (image >= sizes)):
                continue
            p = image[:, 0] + sizes[0] * image[:, 1]
            if np.array_equal(p, np.arange(self.n_sites)) or any(np.array_equal(p, q) for q in found.values()):
                continue
            if self._is_automorphism(p):
                p.setflags(write=False)
                found[name] = p
        return found

    def colouring(self, distance: int = 2) -> np.ndarray:
        """A colouring in which no two sites within ``distance`` bonds (of weight != 0) share a colour, e.g. to probe
        Jacobian columns together: int colours 0, 1, ..., shape (n_sites,) (``warpchain.colouring``: modular without
        wrapped axes, else greedy); the chain with distance 2 gets s mod 3 (fixed and free ends)."""
        return colouring(self, whole_number("distance", distance, minimum=1))

    def describe(self) -> str:
        """A one-line summary, e.g. ``square 6x6 periodic: 36 sites, degree 4``."""
        size = "x".join(map(str, self.shape))
        text = f"{self.name} {size} {self.boundary}: {self.n_sites} sites, degree {self.degree}"
        if any(w != 1.0 for w in self.direction_weights):
            text += f", weights {tuple(self.direction_weights)}"
        return text

    def __repr__(self) -> str:
        return f"Lattice({self.describe()})"


def _sorted_slots(neighbours: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's (neighbour, weight) pairs in sorted order: the slots as a multiset."""
    order = np.lexsort((weights, neighbours))
    return np.take_along_axis(neighbours, order, 1), np.take_along_axis(weights, order, 1)


def _point_operations(basis: np.ndarray) -> dict[str, np.ndarray]:
    """The rotations and mirrors (multiples of 15 degrees: every 2D point group lies in D4 or D6) that map the
    lattice spanned by ``basis`` onto itself, as integer matrices on the axial coordinates."""
    B = basis.T  # columns a1, a2
    candidates = {}
    for k in range(1, 24):
        c, s = math.cos(math.radians(15 * k)), math.sin(math.radians(15 * k))
        candidates[f"rot{15 * k}"] = np.array([[c, -s], [s, c]])
    for k in range(12):
        c, s = math.cos(math.radians(30 * k)), math.sin(math.radians(30 * k))  # a mirror line at 15 k degrees
        candidates[f"mirror_{15 * k}"] = np.array([[c, s], [s, -c]])
    found = {}
    for name, R in candidates.items():
        A = np.linalg.solve(B, R @ B)
        if np.allclose(A, np.round(A), atol=1e-9):
            found[name] = np.round(A).astype(np.int64)
    return found


def _build(name, shape, boundary, directions, direction_weights, basis, lam_max) -> Lattice:
    """The neighbour table of a grid: slot 2k steps by -e_k, 2k + 1 by +e_k, the edges per ``_EDGES``."""
    if not isinstance(boundary, str) or boundary not in BOUNDARIES:
        raise ValueError(f"boundary must be one of {BOUNDARIES}, got {boundary!r}")
    sizes = (shape + (1,))[:2]
    s = np.arange(sizes[0] * sizes[1])
    coords = (s % sizes[0], s // sizes[0])
    neighbours = np.empty((s.size, 2 * len(directions)), dtype=np.int32)
    weights = np.zeros(neighbours.shape)
    for k, (step, w) in enumerate(zip(directions, direction_weights)):
        for slot, sign in ((2 * k, -1), (2 * k + 1, 1)):
            code = np.zeros(s.size, dtype=np.int64)  # 0: inside; else the slot code of the first edge crossed
            reached = []
            for c, e, size, edge in zip(coords, step, sizes, _EDGES[boundary]):
                c = c + sign * e
                if edge == _WRAP:
                    c = c % size
                else:
                    code = np.where((code == 0) & ((c < 0) | (c >= size)), edge, code)
                reached.append(c)
            neighbours[:, slot] = np.where(code == 0, reached[0] + sizes[0] * reached[1], code)
            weights[:, slot] = np.where(neighbours[:, slot] == MISSING, 0.0, w)
    positions = np.stack(coords, axis=1) @ basis
    return Lattice(name, shape, boundary, neighbours, weights, positions, basis, directions, direction_weights, lam_max)


def _direction_weights(weights, axes: tuple[str, ...]) -> tuple[float, ...]:
    if isinstance(weights, (str, bytes)) or np.ndim(weights) != 1 or len(weights) != len(axes):
        raise ValueError(f"weights must be {len(axes)} numbers, one per direction {axes}, got {weights!r}")
    return tuple(real_number(f"weights[{k}] ({a})", w, nonnegative=True) for k, (a, w) in enumerate(zip(axes, weights)))


def chain(N: int, boundary: str = "fixed", weight: float = 1.0) -> Lattice:
    """The chain of N sites (slot 0 left, slot 1 right): ``model``'s lattice."""
    N = whole_number("N", N, minimum=1)
    w = real_number("weight", weight, nonnegative=True)
    return _build("chain", (N,), boundary, ((1, 0),), (w,), _SQUARE, 4.0 * w)


def square(nx: int, ny: int, boundary: str = "fixed", weights=(1.0, 1.0)) -> Lattice:
    """The nx x ny square lattice; slots -x, +x, -y, +y. ``square(N, 1, b, weights=(1, 0))`` is ``chain(N, b)``
    (its y bonds weigh 0), and weights (1, 0) make ny independent chains along x."""
    nx, ny = whole_number("nx", nx, minimum=1), whole_number("ny", ny, minimum=1)
    w = _direction_weights(weights, ("x", "y"))
    return _build("square", (nx, ny), boundary, ((1, 0), (0, 1)), w, _SQUARE, 4.0 * (w[0] + w[1]))


def triangular(nx: int, ny: int, boundary: str = "fixed", weights=(1.0, 1.0, 1.0)) -> Lattice:
    """The nx x ny rhombic patch of the triangular lattice (DESIGN.md section 8), axial (i, j); slots (-1, 0),
    (1, 0), (0, -1), (0, 1), (-1, 1), (1, -1), weights per direction (1, 0), (0, 1), (1, -1)."""
    nx, ny = whole_number("nx", nx, minimum=1), whole_number("ny", ny, minimum=1)
    w = _direction_weights(weights, ("i", "j", "i-j"))
    return _build("triangular", (nx, ny), boundary, ((1, 0), (0, 1), (1, -1)), w, _TRIANGULAR, _triangular_lam_max(w))


def _triangular_lam_max(w: tuple[float, float, float]) -> float:
    """max lam = 2 (sum w - min F) (module docstring): the critical points of F = sum w_k cos phi_k, sum phi = 0."""
    w1, w2, w3 = w
    candidates = [w1 + w2 + w3, w3 - w1 - w2, w2 - w1 - w3, w1 - w2 - w3]
    if min(w) > 0:
        a, b, c = 1.0 / w1, 1.0 / w2, 1.0 / w3
        if a < b + c and b < a + c and c < a + b:
            candidates.append(-0.5 * (w1 * w2 / w3 + w2 * w3 / w1 + w3 * w1 / w2))
    return 2.0 * (w1 + w2 + w3 - min(candidates))


@dataclasses.dataclass(frozen=True)
class LatticeParams:
    """M and K on any lattice: what ``model.ChainParams`` is for the chain. ``model`` (accelerations, energy),
    the numpy reference and ``ReferenceFlow`` take either; the chain keeps its own fast path there
    (``model.lattice_laplacian``). ``N`` is the number of sites (the state is (4, N) with a site index).

    Args:
        M: mass ratio m1 / m2 (> 0).
        K: coupling ratio k1 / k2 (>= 0), times each bond's weight.
        lattice: the geometry (``chain``, ``square``, ``triangular``).
    """

    M: float
    K: float
    lattice: Lattice

    def __post_init__(self):
        object.__setattr__(self, "M", real_number("LatticeParams.M", self.M, positive=True))
        object.__setattr__(self, "K", real_number("LatticeParams.K", self.K, nonnegative=True))
        if not isinstance(self.lattice, Lattice):
            raise ValueError(
                f"LatticeParams.lattice must be a Lattice (chain, square, triangular), got {self.lattice!r}"
            )

    @property
    def N(self) -> int:
        return self.lattice.n_sites

    @property
    def boundary(self) -> str:
        return self.lattice.boundary

    @property
    def omega0(self) -> float:
        """Linear resonance of one uncoupled site (the optical band's bottom on every lattice)."""
        return math.sqrt((self.M + 1.0) / self.M)

    def replace(self, **changes) -> "LatticeParams":
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return {"M": self.M, "K": self.K, "lattice": self.lattice.describe()}


def neighbour_table(params) -> Lattice | None:
    """The lattice the engine runs from its neighbour table (``LatticeParams``), or None for ``model.ChainParams``
    (the chain's own kernels: two neighbours and the walls of its boundary)."""
    return params.lattice if isinstance(params, LatticeParams) else None


def geometry_key(params) -> tuple | None:
    """None for the chain's own kernels (``ChainParams``), else the neighbour table itself (``Lattice.table_digest``:
    a hand-built table, a removed bond, other weights are other keys): keys the engine's kept runners, whose table is
    uploaded once."""
    table = neighbour_table(params)
    return None if table is None else table.table_digest
