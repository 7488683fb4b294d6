"""The dimensionless mass-in-mass chain with Hertzian local resonators.

Notation: sites j = 1..N, chain displacement u_j, resonator displacement v_j,
relative displacement z_j = u_j - v_j (the contact overlap is 1 + z_j)::

    M u_j'' + K (2 u_j - u_{j-1} - u_{j+1}) + f(z_j) = 0
      v_j''                                 - f(z_j) = 0
    f(z) = (2/3) ([1 + z]_+^{3/2} - 1)

A lattice's phase-space state has shape (4, N) ordered (u, v, u', v'); a batch has shape
(batch, 4, N). Everything here is plain numpy, batched, float64.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from .checks import real_number, whole_number  # noqa: F401  (imported from here across the package)
from .lattice import _two_branches, chain

BOUNDARIES = ("fixed", "free", "periodic")
#: Integer codes used by the Warp kernels for each boundary condition.
BOUNDARY_CODES = {name: code for code, name in enumerate(BOUNDARIES)}


@dataclasses.dataclass(frozen=True)
class ChainParams:
    """Parameters of one chain (or one value shared by a whole batch).

    Args:
        M: mass ratio m1 / m2 (> 0).
        K: coupling ratio k1 / k2 (>= 0).
        N: number of unit cells (>= 1).
        boundary: ``"fixed"`` (u_0 = u_{N+1} = 0, wall bonds included), ``"free"`` or
            ``"periodic"``.
    """

    M: float
    K: float
    N: int = 201
    boundary: str = "fixed"

    def __post_init__(self):
        for name in ("M", "K"):
            object.__setattr__(self, name, real_number(f"ChainParams.{name}", getattr(self, name)))
        if self.M <= 0:
            raise ValueError(f"ChainParams.M must be > 0 (mass ratio), got {self.M}")
        if self.K < 0:
            raise ValueError(f"ChainParams.K must be >= 0 (coupling), got {self.K}")
        object.__setattr__(self, "N", whole_number("ChainParams.N", self.N, minimum=1))
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"ChainParams.boundary must be one of {BOUNDARIES}, got {self.boundary!r}")

    @property
    def omega0(self) -> float:
        """Linear resonance of one uncoupled site (optical band bottom), sqrt((M + 1) / M)."""
        return math.sqrt((self.M + 1.0) / self.M)

    @property
    def lattice(self):
        """The chain as data (``warpchain.lattice.chain(N, boundary)``): its Laplacian, linear modes, symmetry."""
        return chain(self.N, self.boundary)

    def replace(self, **changes) -> "ChainParams":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


# ----------------------------------------------------------------------------- forces, energy


def _floating(z):
    """z as a floating array, keeping float32 (the reference's float32 runs) and promoting the rest."""
    z = np.asarray(z)
    return z if z.dtype in (np.float32, np.float64) else z.astype(np.float64)


def contact_force(z):
    """f(z) = (2/3)([1 + z]_+^{3/2} - 1): the Hertzian contact force minus its static preload."""
    z = _floating(z)
    s = np.maximum(1 + z, 0)
    return z.dtype.type(2.0 / 3.0) * (s * np.sqrt(s) - 1)


def contact_stiffness(z):
    """f'(z) = [1 + z]_+^{1/2} (continuous, not Lipschitz where contact is lost)."""
    z = _floating(z)
    return np.sqrt(np.maximum(1 + z, 0))


def contact_potential(z):
    """Per-site contact energy (2/3)((2/5)[1+z]_+^{5/2} - z) - 4/15 (zero at z = 0)."""
    z = np.asarray(z, dtype=np.float64)
    s = np.maximum(1.0 + z, 0.0)
    return (2.0 / 3.0) * (0.4 * s * s * np.sqrt(s) - z) - 4.0 / 15.0


def _per_lattice(value, batch: int) -> np.ndarray:
    """Broadcast a scalar or per-lattice parameter to shape (batch, 1)."""
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (batch,))
    return arr.reshape(batch, 1)


def walls(u: np.ndarray, boundary: str) -> tuple[np.ndarray, np.ndarray]:
    """(the u left of site 0, the u right of site N - 1) along the last axis: 0 at a fixed wall, the site itself at
    a free end, the other end on a ring. The one place the host defines a boundary's values (the kernels':
    ``site.wall_values``); the Laplacian's ends and the energy's wall bonds follow from them."""
    first, last = u[..., 0], u[..., -1]
    if boundary == "fixed":
        return np.zeros_like(first), np.zeros_like(last)
    if boundary == "free":
        return first, last
    if boundary == "periodic":
        return last, first
    raise ValueError(f"unknown boundary {boundary!r}; expected one of {BOUNDARIES}")


def wall_bonds(u: np.ndarray, boundary: str) -> tuple[np.ndarray, np.ndarray]:
    """The squared bond lengths at the chain's ends, (u_0 - left wall)^2 and (right wall - u_{N-1})^2 (``walls``);
    on a ring the left one is the right one, counted there (0 here)."""
    left, right = walls(u, boundary)
    end = (right - u[..., -1]) ** 2
    if boundary == "periodic":
        return np.zeros_like(end), end
    return (u[..., 0] - left) ** 2, end


def laplacian(u: np.ndarray, boundary: str) -> np.ndarray:
    """Discrete 2 u_j - u_{j-1} - u_{j+1} along the last axis for the given boundary (its walls: ``walls``)."""
    left = np.empty_like(u)
    right = np.empty_like(u)
    left[..., 1:] = u[..., :-1]
    right[..., :-1] = u[..., 1:]
    left[..., 0], right[..., -1] = walls(u, boundary)
    return (u - left) + (u - right)


def lattice_laplacian(params, u: np.ndarray) -> np.ndarray:
    """The Laplacian of ``params``' lattice along the last axis: the chain's slices (``laplacian``: fast, any float
    dtype) for ``ChainParams``, the neighbour table (``warpchain.lattice.Lattice.laplacian``) for
    ``LatticeParams``. Both are the same arithmetic on the chain, bit for bit (tests/test_lattice.py)."""
    if isinstance(params, ChainParams):
        return laplacian(u, params.boundary)
    return params.lattice.laplacian(u)


def as_batch(x, N: int | None = None, name: str = "x") -> np.ndarray:
    """Validate a state and return it as a float64 array of shape (batch, 4, N).

    Args:
        x: a state of shape (4, N) (a batch of one) or (batch, 4, N).
        N: expected number of sites, if known.
    """
    if np.iscomplexobj(x):
        raise ValueError(f"{name} must be real; got a complex array (its imaginary part would be dropped)")
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be a real array of shape (4, N) or (batch, 4, N), got {type(x).__name__}"
        ) from None
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1] != 4:
        raise ValueError(f"{name} must have shape (4, N) or (batch, 4, N) ordered (u, v, u', v'); got {np.shape(x)}")
    if N is not None and arr.shape[2] != N:
        raise ValueError(f"{name} has {arr.shape[2]} sites but the chain has N = {N}")
    if arr.shape[0] < 1:
        raise ValueError(f"{name} has an empty batch")
    bad = ~np.isfinite(arr).all(axis=(1, 2))
    if bad.any():
        raise ValueError(f"{name} has non-finite entries in lattice(s) {np.flatnonzero(bad).tolist()}")
    return arr


def accelerations(params: ChainParams, x, M=None, K=None) -> np.ndarray:
    """Accelerations (u'', v'') of a batch.

    Args:
        params: the chain (N, boundary; M, K unless given per lattice).
        x: state, shape (batch, 4, N) or (batch, 2, N) (positions only).
        M, K: optional per-lattice values, shape (batch,).

    Returns:
        array of shape (batch, 2, N).
    """
    x = _floating(x)
    batch = x.shape[0]
    Mb = _per_lattice(params.M if M is None else M, batch).astype(x.dtype)
    Kb = _per_lattice(params.K if K is None else K, batch).astype(x.dtype)
    u, v = x[:, 0], x[:, 1]
    force = contact_force(u - v)
    acc = np.empty((batch, 2, x.shape[-1]), dtype=x.dtype)
    acc[:, 0] = -(Kb * lattice_laplacian(params, u) + force) / Mb
    acc[:, 1] = force
    return acc


def energy(params: ChainParams, x, M=None, K=None) -> np.ndarray:
    """Hamiltonian of each lattice (paper Eq. (3)), with wall bonds for fixed ends.

    Args:
        x: state, shape (4, N) or (batch, 4, N).

    Returns:
        energies, shape (batch,).
    """
    if np.iscomplexobj(x):
        raise ValueError("x must be real; got a complex array")
    shape = np.shape(x)
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[1] != 4 or x.shape[2] != params.N:
        raise ValueError(
            f"x must have shape (4, {params.N}) or (batch, 4, {params.N}) ordered (u, v, u', v') "
            f"for this chain (N = {params.N}); got {shape}"
        )
    batch = x.shape[0]
    Mb = _per_lattice(params.M if M is None else M, batch)[:, 0]
    Kb = _per_lattice(params.K if K is None else K, batch)[:, 0]
    u, v, du, dv = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    kinetic = 0.5 * Mb * np.sum(du * du, axis=-1) + 0.5 * np.sum(dv * dv, axis=-1)
    if isinstance(params, ChainParams):
        bonds = np.diff(u, axis=-1)
        first, last = wall_bonds(u, params.boundary)
        spring = np.sum(bonds * bonds, axis=-1) + first + last
    else:  # sum over bonds of w (u_s - u_t)^2, wall bonds included
        spring = 2.0 * params.lattice.bond_energy(u)
    contact = np.sum(contact_potential(u - v), axis=-1)
    return kinetic + 0.5 * Kb * spring + contact


def site_energies(params: ChainParams, x, M, K) -> np.ndarray:
    """The Hamiltonian site by site, e_j of ``site.site_energy``, for a batch (batch, 4, N): kinetic
    energy, the bond to the right (wall bonds at fixed ends, the bond to site 0 on a ring), the contact energy;
    on a ``LatticeParams`` the bonds a site holds (``held_bonds``: ``site.table_bonds``). Their sum is ``energy``
    (summed in another order); observe's numpy oracle reduces them."""
    x = np.asarray(x, dtype=np.float64)
    batch, _, n = x.shape
    M = np.broadcast_to(np.asarray(M, dtype=np.float64), (batch,))[:, None]
    K = np.broadcast_to(np.asarray(K, dtype=np.float64), (batch,))[:, None]
    u, v, pu, pv = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    if isinstance(params, ChainParams):
        bonds = np.empty_like(u)
        bonds[:, :-1] = (u[:, 1:] - u[:, :-1]) ** 2
        first, bonds[:, -1] = wall_bonds(u, params.boundary)
        bonds[:, 0] += first
    else:
        bonds = held_bonds(params.lattice, u)
    kinetic = 0.5 * M * (pu * pu) + 0.5 * (pv * pv)
    return kinetic + 0.5 * K * bonds + contact_potential(u - v)


def held_bonds(lattice, u) -> np.ndarray:
    """sum w (u_j - u_t)^2 over the bonds site j holds (``site.table_bonds``, operation for operation): its slots
    along +e_k (odd slots: a bond between two sites is held once) and its walls (u_t = 0); u (batch, sites)."""
    from .lattice import WALL

    bonds = np.zeros_like(u)
    for d in range(lattice.neighbours.shape[1]):
        t = lattice.neighbours[:, d]
        other = np.where(t >= 0, u[:, np.maximum(t, 0)], np.where(t == WALL, 0.0, u))
        diff = u - other
        held = (d % 2 == 1) | (t == WALL)
        bonds = np.where(held, bonds + lattice.weights[:, d] * (diff * diff), bonds)
    return bonds


def min_contact(x) -> np.ndarray:
    """min_j (1 + u_j - v_j) of each lattice: <= 0 means a resonator has lost contact."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    return np.min(1.0 + x[:, 0] - x[:, 1], axis=-1)


# ----------------------------------------------------------------------------- linear waves


def dispersion(q, M: float, K: float) -> tuple[np.ndarray, np.ndarray]:
    """Acoustic and optical frequencies of the infinite chain at Bloch numbers q.

    Solves M w^4 - [2K(1 - cos q) + M + 1] w^2 + 2K(1 - cos q) = 0.

    Returns:
        (w_acoustic, w_optical), each of the shape of q.
    """
    s = 2.0 * K * (1.0 - np.cos(np.asarray(q, dtype=np.float64)))
    return _two_branches(s, M)


def dispersion_long_wave(q, M: float, K: float) -> tuple[np.ndarray, np.ndarray]:
    """Long-wave (continuum) limit: 2K(1 - cos q) -> K q^2 (the paper's Eq. (9) with k^2 = K q^2)."""
    s = K * np.asarray(q, dtype=np.float64) ** 2
    return _two_branches(s, M)


def _signed_energy_change(E, E0, N):
    """(E - E0) / |E0|, the denominator floored at 1e-14 N (a lattice at rest): the guard's energy error."""
    scale = np.maximum(np.abs(E0), 1e-14 * N)
    return (E - E0) / scale


def band_edges(M: float, K: float) -> dict:
    """Band edges of the infinite chain (closed forms of the dispersion relation in the module docstring).

    Returns:
        dict with ``acoustic_top``, ``optical_bottom``, ``optical_top``, ``gap_width``.
    """
    M, K = real_number("M", M, positive=True), real_number("K", K, nonnegative=True)
    a = 4.0 * K + M + 1.0
    root = math.sqrt(a * a - 16.0 * K * M)
    acoustic_top = math.sqrt(8.0 * K / (a + root))  # = sqrt((a - root) / (2M)) without cancellation
    optical_bottom = math.sqrt((M + 1.0) / M)
    optical_top = math.sqrt((a + root) / (2.0 * M))
    return {
        "acoustic_top": acoustic_top,
        "optical_bottom": optical_bottom,
        "optical_top": optical_top,
        "gap_width": optical_bottom - acoustic_top,
    }


def long_wave_speed(M: float, K: float) -> float:
    """Exact long-wave sound speed of the discrete chain, sqrt(K / (M + 1)) cells per unit time."""
    return math.sqrt(K / (M + 1.0))


def stiffness_and_mass(params: ChainParams) -> tuple[np.ndarray, np.ndarray]:
    """Linearised stiffness and mass matrices (2N x 2N) in the ordering (u_1..u_N, v_1..v_N): the chain's
    lattice's (``warpchain.lattice.Lattice.stiffness_and_mass``)."""
    return params.lattice.stiffness_and_mass(params.M, params.K)


def linear_modes(params: ChainParams) -> tuple[np.ndarray, np.ndarray]:
    """Linear modes of the finite chain about rest (``warpchain.lattice.Lattice.linear_modes``).

    Returns:
        (frequencies, shapes): frequencies shape (2N,), ascending; shapes shape (2N, 2, N) with
        shapes[m, 0] the u profile and shapes[m, 1] the v profile of mode m, normalised so that
        the modes are mass-orthonormal (sum M u_a u_b + v_a v_b = delta_ab), each signed so that its
        largest-magnitude entry (of u and v together) is positive.
    """
    return params.lattice.linear_modes(params.M, params.K)


def lowest_optical_mode(params: ChainParams) -> tuple[float, np.ndarray]:
    """Frequency and (u, v) shape (2, N) of the lowest optical mode of the finite chain.

    The acoustic branch holds N modes (N - 1 plus a zero mode for free/periodic chains), so
    the lowest optical mode is mode number N in ascending order. The shape is scaled so that
    v at the centre site is negative and u positive there (z = u - v > 0 at t = 0).
    """
    freqs, shapes = linear_modes(params)
    shape = shapes[params.N].copy()
    centre = params.N // 2
    if shape[0, centre] < 0:
        shape *= -1.0
    return float(freqs[params.N]), shape


def state_from_positions(u, v, du=None, dv=None) -> np.ndarray:
    """Stack positions (and optional velocities) into a (4, N) or (batch, 4, N) state."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    du = np.zeros_like(u) if du is None else np.asarray(du, dtype=np.float64)
    dv = np.zeros_like(v) if dv is None else np.asarray(dv, dtype=np.float64)
    return np.stack([u, v, du, dv], axis=-2)


def per_lattice_parameters(params: ChainParams, batch: int, M: Sequence | None, K: Sequence | None):
    """Per-lattice (M, K) arrays of shape (batch,), validated."""
    if M is None and K is None:  # the chain's own values, validated by ChainParams (a fast path: simulate's set-up)
        return np.full(batch, params.M), np.full(batch, params.K)
    out = []
    for name, value, default in (("M", M, params.M), ("K", K, params.K)):
        arr = np.asarray(default if value is None else value, dtype=np.float64)
        if arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] != batch):
            raise ValueError(f"per-lattice {name} must be a scalar or have shape ({batch},); got {arr.shape}")
        arr = np.broadcast_to(arr, (batch,)).copy()
        if not np.isfinite(arr).all():
            raise ValueError(f"per-lattice {name} has non-finite values")
        if name == "M" and (arr <= 0).any():
            raise ValueError("per-lattice M must be > 0")
        if name == "K" and (arr < 0).any():
            raise ValueError("per-lattice K must be >= 0")
        out.append(arr)
    return out[0], out[1]
