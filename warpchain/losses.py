"""Losses: linear damping of the contact and of the substrate, as an exact sub-flow of every
splitting method.

Equations (our notation, ``DESIGN.md`` section 1, with mu = M / (M + 1) the pair's reduced mass)::

    M u_j'' + K (2 u_j - u_{j-1} - u_{j+1}) + f(z_j) = - M gamma_s u_j' - mu gamma_c (u_j' - v_j')
      v_j''                                 - f(z_j) =                 + mu gamma_c (u_j' - v_j')

* ``gamma_c`` (contact): dissipation at the contact, on the relative velocity z' = u' - v'. The
  relative coordinate then obeys z'' = ... - gamma_c z' (the force is mu gamma_c z' and
  1/M + 1 = 1/mu), so an isolated pair (K = 0, or the uniform optical mode: centre of mass at rest)
  rings down as exp(-gamma_c t / 2) in amplitude: its quality factor is Q_c = w_0 / gamma_c with
  w_0 = sqrt((M + 1) / M). (A resonator on a substrate held still decays at mu gamma_c instead.)
* ``gamma_s`` (substrate): u'' = ... - gamma_s u', standing for radiation into the bulk (a free
  substrate velocity decays as exp(-gamma_s t)).

The power lost is P = sum_j [M gamma_s u_j'^2 + mu gamma_c (u_j' - v_j')^2] >= 0 (``dissipation``).

**The scheme.** A splitting method composes the exact flows of a drift (q' = w, w' = 0) and a kick
(q' = 0, w' = a(q)), w = (u', v'). With losses the kick's velocity equation gains -G w::

    w' = a(q) - G w,   G = [[gamma_s + gamma_c / (M + 1), -gamma_c / (M + 1)],
                            [-mu gamma_c,                  mu gamma_c       ]]

and during a kick q, hence a(q), is constant, so this linear equation is still solved exactly:
w(h) = E w + F a with E = exp(-G h) and F = int_0^h exp(-G s) ds, both 2 x 2 per lattice and per
kick coefficient h = d_i dt (``kick_matrices``, from the exponential of the 4 x 4 matrix
[[-G, I], [0, 0]] h, whose top row of blocks is [E, F]). Both parts remain exact flows, so every
composition keeps its order (Yoshida's and Kahan-Li's order conditions hold for any split into
exactly solved parts), and the damping adds no step-size limit of its own. Negative kick
coefficients (the high-order compositions have them) run the damped flow backwards, exactly.

At zero damping E = I and F = h I exactly, and the kernels and the numpy reference then take the
plain kick (``w += h a``): the lossless scheme, bit for bit. RK4 has no sub-flow to add this to and
rejects losses; tangent runs (Newton, Floquet) are for the conservative orbits and reject them too.

**The energy a kick dissipates, exactly.** During a kick the positions, hence the potential energy, stay
put, and the Hamiltonian changes only through the kinetic energy T = sum_j (M u_j'^2 + v_j'^2) / 2:
dT/dt = f . w - P(w), with f = (M a_u, a_v) the conservative force (constant) and P the power lost
(``dissipation``; diag(M, 1) G is P's matrix). So the energy lost in the kick is

    D = f . int_0^h w dt - (T(w(h)) - T(w(0))),   int_0^h w dt = F w(0) + H a,

with H = int_0^h F(t) dt, the third block of the exponential of [[-G, I, 0], [0, 0, I], [0, 0, 0]] h
(Van Loan). It is exact for the exact sub-flow (no quadrature), so E + D - E0 converges at the
scheme's own order (the trapezoid rule used before made D second order whatever the scheme). The
kinetic difference is formed as (M du (u'_1 + u'_0) + dv (v'_1 + v'_0)) / 2, so that no large terms
cancel (``kick_dissipation``; ``observe``'s kernels do the same per site, ``kernels.kick_loss``).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .model import _per_lattice, real_number

#: entries of one kick's coefficients, in this order: E00, E01, E10, E11, F00, F01, F10, F11, and H00, H01,
#: H10, H11 (only for the energy it dissipates)
KICK_ENTRIES = 12


@dataclasses.dataclass(frozen=True)
class Damping:
    """Loss rates, scalars or one per lattice (shape (batch,)).

    Attributes:
        contact: gamma_c, the contact damping rate (relative velocity; Q_c = w_0 / gamma_c).
        substrate: gamma_s, the substrate damping rate (u').
    """

    contact: float | np.ndarray = 0.0
    substrate: float | np.ndarray = 0.0

    def per_lattice(self, batch: int) -> tuple[np.ndarray, np.ndarray]:
        """(gamma_c, gamma_s), each shape (batch,), validated (finite, >= 0)."""
        out = []
        for name, value in (("contact", self.contact), ("substrate", self.substrate)):
            arr = _per_lattice(value, batch)[:, 0]
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"damping {name} rates must be finite and >= 0; got {value!r}")
            out.append(arr)
        return out[0], out[1]

    def any(self) -> bool:
        """Whether any lattice has a nonzero rate."""
        return bool(np.any(np.asarray(self.contact) != 0) or np.any(np.asarray(self.substrate) != 0))


def as_damping(damping) -> Damping | None:
    """None, a ``Damping``, or a (contact, substrate) pair; None when every rate is zero."""
    if damping is None:
        return None
    if not isinstance(damping, Damping):
        try:
            contact, substrate = damping
        except (TypeError, ValueError):
            raise ValueError(f"damping must be a Damping or a (contact, substrate) pair, got {damping!r}") from None
        damping = Damping(contact, substrate)
    if np.ndim(damping.contact) or np.ndim(damping.substrate):  # lists and arrays: per lattice
        damping = Damping(
            np.asarray(damping.contact, dtype=np.float64), np.asarray(damping.substrate, dtype=np.float64)
        )
    if not isinstance(damping.contact, np.ndarray):
        real_number("damping.contact", damping.contact, nonnegative=True)
    if not isinstance(damping.substrate, np.ndarray):
        real_number("damping.substrate", damping.substrate, nonnegative=True)
    return damping if damping.any() else None


def require_splitting(method, why: str = "losses enter the splitting methods as an exact sub-flow") -> None:
    """Raise unless ``method`` is a splitting method (``why``: what needs one; losses enter only those)."""
    from .integrators import SplittingMethod

    if not isinstance(method, SplittingMethod):
        raise ValueError(
            f"{why}; {method.name!r} is not one: choose a splitting method (verlet, yoshida4, kahan6, ...)"
        )


def damping_matrix(M: float, gamma_c: float, gamma_s: float) -> np.ndarray:
    """G of one lattice (2 x 2, on w = (u', v'))."""
    mu = M / (M + 1.0)
    return np.array([[gamma_s + gamma_c / (M + 1.0), -gamma_c / (M + 1.0)], [-mu * gamma_c, mu * gamma_c]])


def _expm(a: np.ndarray) -> np.ndarray:
    from scipy.linalg import expm

    return expm(a)


def kick_matrices(kicks, dt: float, M, damping: Damping, batch: int) -> np.ndarray:
    """The damped kicks' (E, F) of every lattice and kick coefficient.

    Args:
        kicks: the method's kick coefficients d_0..d_s.
        dt: the step.
        M: masses, shape (batch,).
        damping: the rates.

    Returns:
        array (batch, len(kicks), 12) of E00, E01, E10, E11, F00, F01, F10, F11, H00, H01, H10, H11 for
        h = d_i * dt; a lattice without losses gets E = I and F = h I exactly (h rounded as the kernels
        round it), and H = h^2 / 2 I.
    """
    gamma_c, gamma_s = damping.per_lattice(batch)
    M = np.broadcast_to(np.asarray(M, dtype=np.float64), (batch,))
    out = np.zeros((batch, len(kicks), KICK_ENTRIES))
    kicks = tuple(float(d) for d in kicks)
    for b in range(batch):
        out[b] = _kick_rows(kicks, float(dt), float(M[b]), float(gamma_c[b]), float(gamma_s[b]))
    return out


@functools.lru_cache(maxsize=4096)
def _kick_rows(kicks: tuple, dt: float, M: float, gamma_c: float, gamma_s: float) -> np.ndarray:
    G = damping_matrix(M, gamma_c, gamma_s)
    rows = []
    for d in kicks:
        h = d * dt
        if gamma_c == 0 and gamma_s == 0:
            E, F, H = np.eye(2), h * np.eye(2), 0.5 * h * h * np.eye(2)
        else:
            aug = np.zeros((4, 4))
            aug[:2, :2] = -G * h
            aug[:2, 2:] = np.eye(2) * h
            ex = _expm(aug)
            E, F = ex[:2, :2], ex[:2, 2:]
            big = np.zeros((6, 6))  # H from its own exponential: E and F keep the bits of the 4 x 4 one
            big[:4, :4] = aug
            big[2:4, 4:] = np.eye(2) * h
            H = _expm(big)[:2, 4:]
        rows.append(np.concatenate([E.ravel(), F.ravel(), H.ravel()]))
    out = np.array(rows)
    out.flags.writeable = False
    return out


def lossless(coefficients: np.ndarray) -> np.ndarray:
    """Per lattice, whether its kick coefficients are the plain kick (E = I, F = h I, F's off-diagonal
    zero and its diagonal equal): shape (batch,)."""
    E = coefficients[..., :4]
    F = coefficients[..., 4:8]
    eye = np.array([1.0, 0.0, 0.0, 1.0])
    plain_E = np.all(E == eye, axis=(-1, -2))
    plain_F = np.all((F[..., 1] == 0) & (F[..., 2] == 0) & (F[..., 0] == F[..., 3]), axis=-1)
    return plain_E & plain_F


def dissipation(x, M, damping: Damping) -> np.ndarray:
    """Power lost, sum_j [M gamma_s u_j'^2 + mu gamma_c (u_j' - v_j')^2], per lattice: shape (batch,).

    Args:
        x: states, shape (batch, 4, N).
    """
    x = np.asarray(x, dtype=np.float64)
    return power(x, power_coefficients(M, damping, x.shape[0]))


def kick_dissipation(w0, acc, coefficients, M) -> np.ndarray:
    """The energy one damped kick dissipates, exactly (module docstring), per lattice: shape (batch,).

    Args:
        w0: velocities before the kick, (batch, 2, N) (u', v').
        acc: accelerations at the kick's positions, (batch, 2, N).
        coefficients: the kick's (E, F, H) entries from ``kick_matrices``, (batch, 12).
        M: masses, (batch,).
    """
    c = [coefficients[:, i, None] for i in range(KICK_ENTRIES)]
    pu, pv, au, av = w0[:, 0], w0[:, 1], acc[:, 0], acc[:, 1]
    m = np.asarray(M, dtype=np.float64)[:, None]
    pu1 = c[0] * pu + c[1] * pv + (c[4] * au + c[5] * av)
    pv1 = c[2] * pu + c[3] * pv + (c[6] * au + c[7] * av)
    iu = c[4] * pu + c[5] * pv + (c[8] * au + c[9] * av)  # int_0^h u' dt
    iv = c[6] * pu + c[7] * pv + (c[10] * au + c[11] * av)
    work = m * au * iu + av * iv
    kinetic = 0.5 * (m * (pu1 - pu) * (pu1 + pu) + (pv1 - pv) * (pv1 + pv))
    return np.sum(work - kinetic, axis=-1)


def power(x, coefficients) -> np.ndarray:
    """Power lost per lattice, sum_j c_s u_j'^2 + c_c (u_j' - v_j')^2, from ``power_coefficients``
    (batch, 2) and states x (batch, 4, N)."""
    pu, pv = x[:, 2], x[:, 3]
    rel = pu - pv
    return np.sum(coefficients[:, 0:1] * (pu * pu) + coefficients[:, 1:2] * (rel * rel), axis=-1)


def power_coefficients(M, damping: Damping, batch: int) -> np.ndarray:
    """(M gamma_s, mu gamma_c) per lattice, shape (batch, 2): P = c_s u'^2 + c_c (u' - v')^2 per site."""
    gamma_c, gamma_s = damping.per_lattice(batch)
    M = np.broadcast_to(np.asarray(M, dtype=np.float64), (batch,))
    return np.stack([M * gamma_s, M / (M + 1.0) * gamma_c], axis=1)


def rhs_flat(params, M, K, gamma_c: float, gamma_s: float):
    """Right-hand side f(t, y) of one damped lattice, y the flattened (4, N) state (for scipy's
    DOP853: the independent check of the damped schemes)."""
    from . import model

    N = params.N
    G = damping_matrix(float(params.M if M is None else M), gamma_c, gamma_s)

    def f(t, y):
        x = y.reshape(1, 4, N)
        out = np.empty((4, N))
        out[:2] = x[0, 2:]
        acc = model.accelerations(params, x, M, K)[0]
        out[2] = acc[0] - (G[0, 0] * x[0, 2] + G[0, 1] * x[0, 3])
        out[3] = acc[1] - (G[1, 0] * x[0, 2] + G[1, 1] * x[0, 3])
        return out.ravel()

    return f
