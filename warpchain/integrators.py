"""The integrators, registered by name in ``METHODS``.

Two families:

* **splitting** methods for the separable Hamiltonian H = T(p) + V(q): a step is the sequence
  ``kick d_0, drift c_1, kick d_1, ..., drift c_s, kick d_s`` (kick: velocities += d_i dt a(q);
  drift: positions += c_i dt velocities). The acceleration after the last drift is reused by the
  next step's first kick, so a step costs s force evaluations. Velocity Verlet and the symmetric
  compositions of it (Yoshida's triple jump, order 4; Yoshida's 7-stage solution A, order 6) are
  of this form and are symplectic.
* **rk4**: the classical Runge-Kutta method (4 force evaluations, not symplectic), on the numpy reference only.

Each family is a type that owns its coefficients (``SplittingMethod``: drifts and kicks;
``RungeKuttaMethod``: nodes, weights, divisor). The Warp kernels (``warpchain.engine``) receive a splitting
method's coefficients as kernel arguments and the numpy reference (``reference.py``) reads them, so both integrate
the same scheme step for step. The engine steps the splitting methods only (``engine.devices.engine_method``):
RK4 is never cheaper than the best splitting method at any accuracy (the work-precision scene), so it runs on the
reference (``reference.integrate``, ``ReferenceFlow``) as the contrast it is.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from typing import ClassVar

import numpy as np

from .lattice import neighbour_table
from .model import ChainParams, band_edges, real_number


@dataclasses.dataclass(frozen=True)
class Method:
    """One integration scheme (the base of ``SplittingMethod`` and ``RungeKuttaMethod``, which own
    their coefficients).

    Attributes:
        name: registry key.
        order: nominal order of accuracy.
        symplectic: whether the discrete map is symplectic.
        description: one line for listings.
        family: ``"splitting"`` or ``"rk4"`` (a class attribute; code dispatches on the type).
    """

    name: str
    order: int
    symplectic: bool
    description: str = ""
    family: ClassVar[str] = ""

    @property
    def force_evaluations(self) -> int:
        """Force evaluations per step."""
        raise NotImplementedError

    @property
    def stages(self) -> int:
        """Stage states per step whose contact stiffness a tangent run records."""
        return self.force_evaluations

    def history_length(self, nsteps: int) -> int:
        """Contact-stiffness records of a tangent base run of ``nsteps`` steps."""
        raise NotImplementedError

    def harmonic_step_matrix(self, h: float) -> np.ndarray:
        """The one-step map of x'' = -x with step h, as a 2x2 matrix on (x, x')."""
        raise NotImplementedError

    @functools.cached_property
    def stability_bound(self) -> float:
        """Largest h = w dt for which the harmonic step map is stable for all smaller h.

        Found by scanning and bisection of the spectral radius of ``harmonic_step_matrix``; for
        velocity Verlet this is 2, for RK4 2 sqrt(2).
        """

        def stable(h):
            return np.max(np.abs(np.linalg.eigvals(self.harmonic_step_matrix(h)))) <= 1.0 + 1e-12

        grid = np.linspace(1e-3, 6.0, 6000)
        lo = grid[0]
        for h in grid[1:]:
            if not stable(h):
                hi = h
                break
            lo = h
        else:
            return float(grid[-1])
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if stable(mid) else (lo, mid)
        return float(lo)

    def linear_stability_limit(self, omega_max: float) -> float:
        """Largest stable dt for a linear system whose highest frequency is ``omega_max``."""
        return self.stability_bound / omega_max


@dataclasses.dataclass(frozen=True)
class SplittingMethod(Method):
    """A kick-drift splitting: ``kick d_0, drift c_1, kick d_1, ..., drift c_s, kick d_s``.

    Attributes:
        drifts: c_1..c_s.
        kicks: d_0..d_s.
    """

    drifts: tuple = ()
    kicks: tuple = ()
    family: ClassVar[str] = "splitting"

    @property
    def force_evaluations(self) -> int:
        return len(self.drifts)

    def history_length(self, nsteps: int) -> int:
        return nsteps * self.stages + 1  # the start, then after every drift

    def harmonic_step_matrix(self, h: float) -> np.ndarray:
        def kick(d):
            return np.array([[1.0, 0.0], [-d * h, 1.0]])

        def drift(c):
            return np.array([[1.0, c * h], [0.0, 1.0]])

        mat = kick(self.kicks[0]) @ np.eye(2)
        for c, d in zip(self.drifts, self.kicks[1:]):
            mat = kick(d) @ drift(c) @ mat
        return mat


@dataclasses.dataclass(frozen=True)
class RungeKuttaMethod(Method):
    """An explicit Runge-Kutta method whose stage i + 1 is evaluated at x + nodes[i] dt k_i (a
    tableau with one nonzero entry per row, as the classical RK4), and whose step is
    x + (dt / divisor) sum_i weights[i] k_i. The numpy reference reads these (the Warp engine steps splitting
    methods only).

    Attributes:
        nodes: a_21, a_32, a_43 (classical RK4: 1/2, 1/2, 1).
        weights: b_i times ``divisor`` (classical RK4: 1, 2, 2, 1).
        divisor: 6 for the classical RK4.
    """

    nodes: tuple = (0.5, 0.5, 1.0)
    weights: tuple = (1.0, 2.0, 2.0, 1.0)
    divisor: float = 6.0
    family: ClassVar[str] = "rk4"

    def __post_init__(self):
        if len(self.weights) != 4 or len(self.nodes) != 3:
            raise ValueError("the reference implements four-stage Runge-Kutta methods (3 nodes, 4 weights)")

    @property
    def force_evaluations(self) -> int:
        return len(self.weights)

    def history_length(self, nsteps: int) -> int:
        return nsteps * self.stages  # every stage

    def harmonic_step_matrix(self, h: float) -> np.ndarray:
        A = np.array([[0.0, 1.0], [-1.0, 0.0]])
        eye = np.eye(2)
        k = A  # stage derivatives as matrices acting on the start state
        total = self.weights[0] * k
        for a, w in zip(self.nodes, self.weights[1:]):
            k = A @ (eye + a * h * k)
            total = total + w * k
        return eye + (h / self.divisor) * total


def _composition(weights) -> tuple[tuple, tuple]:
    """Drift and kick coefficients of a composition of velocity Verlet with the given weights."""
    weights = [float(w) for w in weights]
    drifts = tuple(weights)
    kicks = [0.5 * weights[0]]
    for a, b in zip(weights[:-1], weights[1:]):
        kicks.append(0.5 * (a + b))
    kicks.append(0.5 * weights[-1])
    return drifts, tuple(kicks)


_CBRT2 = 2.0 ** (1.0 / 3.0)
_Y4_OUTER = 1.0 / (2.0 - _CBRT2)
_Y4 = (_Y4_OUTER, -_CBRT2 * _Y4_OUTER, _Y4_OUTER)
# Yoshida (1990), Phys. Lett. A 150, 262, solution A of the 7-stage 6th-order composition.
_Y6_W1, _Y6_W2, _Y6_W3 = -1.17767998417887, 0.235573213359357, 0.784513610477560
_Y6_W0 = 1.0 - 2.0 * (_Y6_W1 + _Y6_W2 + _Y6_W3)
_Y6 = (_Y6_W3, _Y6_W2, _Y6_W1, _Y6_W0, _Y6_W1, _Y6_W2, _Y6_W3)


def _symmetric(half, middle):
    """Weights of a symmetric composition from its first half and middle weight."""
    return tuple(half) + (middle,) + tuple(reversed(half))


# Kahan & Li (1997), Math. Comp. 66, 1089: optimised symmetric compositions of a 2nd-order
# method, s9odr6a (9 stages, order 6) and s15odr8 (15 stages, order 8); far smaller error
# constants than Yoshida's per force evaluation.
_KL6 = _symmetric(
    (0.39216144400731413928, 0.33259913678935943860, -0.70624617255763935981, 0.082213596293550800230),
    0.79854399093482996340,
)
_KL8 = _symmetric(
    (
        0.74167036435061295345,
        -0.40910082580003159400,
        0.19075471029623837995,
        -0.57386247111608226666,
        0.29906418130365592384,
        0.33462491824529818378,
        0.31529309239676659663,
    ),
    -0.79688793935291635402,
)


def _splitting(name, order, weights, description):
    drifts, kicks = _composition(weights)
    return SplittingMethod(name, order, True, description, drifts, kicks)


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        _splitting("verlet", 2, (1.0,), "velocity Verlet (kick-drift-kick), order 2, symplectic"),
        _splitting("yoshida4", 4, _Y4, "Yoshida triple-jump composition of Verlet, order 4, symplectic"),
        _splitting("yoshida6", 6, _Y6, "Yoshida 7-stage composition (solution A), order 6, symplectic"),
        _splitting("kahan6", 6, _KL6, "Kahan-Li s9odr6a 9-stage composition of Verlet, order 6, symplectic"),
        _splitting("kahan8", 8, _KL8, "Kahan-Li s15odr8 15-stage composition of Verlet, order 8, symplectic"),
        RungeKuttaMethod("rk4", 4, False, "classical Runge-Kutta, order 4, not symplectic"),
    )
}


def get_method(name: str) -> Method:
    """Look a method up by name, with a helpful error."""
    if isinstance(name, Method):
        return name
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown method {name!r}; choose one of {sorted(METHODS)}") from None


def steps_for(t_final: float, dt: float) -> tuple[int, float]:
    """Whole number of steps to reach t_final with a step no larger than dt.

    Returns:
        (nsteps, dt_used) with nsteps * dt_used == t_final; dt_used == dt when t_final is a
        whole multiple of dt (up to 1e-9 relative).
    """
    if t_final == 0:
        return 0, float(dt)
    nsteps = max(1, int(math.ceil(t_final / dt - 1e-9)))
    return nsteps, float(t_final) / nsteps


# ----------------------------------------------------------------------------- stability limits


class StepSizeError(ValueError):
    """A step above the method's linear stability limit was refused before the run started."""


class IntegrationError(RuntimeError):
    """A run blew up (non-finite state or energy error past its bound).

    Attributes:
        method, dt, stability_limit: the scheme, its step, and its linear stability limit.
        failed: indices of the failing lattices.
        t: time reached when the failure was detected.
    """

    def __init__(self, message, *, method, dt, stability_limit, failed, t):
        super().__init__(message)
        self.method = method
        self.dt = dt
        self.stability_limit = stability_limit
        self.failed = failed
        self.t = t


def stability_limit(method: Method | str, params: ChainParams, M=None, K=None) -> float:
    """Linear stability limit on dt of ``method`` for these parameters (smallest over a batch),
    from the top of the optical band, w_max: dt < bound / w_max (bound = 2 for Verlet)."""
    method = get_method(method)
    table = neighbour_table(params)
    if table is not None:  # a lattice given as a table: its own optical top (lam_max)
        Ms = np.atleast_1d(params.M if M is None else M).astype(float)
        Ks = np.atleast_1d(params.K if K is None else K).astype(float)
        pairs = np.unique(np.stack(np.broadcast_arrays(Ms, Ks), axis=-1).reshape(-1, 2), axis=0)
        return method.linear_stability_limit(max(table.band_edges(m, k)["optical_top"] for m, k in pairs))
    if M is None and K is None:  # one chain for the whole batch (simulate's set-up: kept per chain)
        return method.linear_stability_limit(_optical_top(params.M, params.K))
    Ms = np.atleast_1d(params.M if M is None else M).astype(float)
    Ks = np.atleast_1d(params.K if K is None else K).astype(float)
    Ms, Ks = np.broadcast_arrays(Ms, Ks)
    if Ms.min() == Ms.max() and Ks.min() == Ks.max():
        pairs = [(Ms.flat[0], Ks.flat[0])]  # one chain for the whole batch
    else:
        pairs = np.unique(np.stack([Ms.ravel(), Ks.ravel()], axis=1), axis=0)
    w_max = max(band_edges(float(m), float(k))["optical_top"] for m, k in pairs)
    return method.linear_stability_limit(w_max)


@functools.lru_cache(maxsize=256)
def _optical_top(M: float, K: float) -> float:
    return band_edges(M, K)["optical_top"]


def check_step(method: Method, params, dt, M, K, allow_unstable_step: bool) -> float:
    dt = real_number("dt", dt, positive=True)
    limit = stability_limit(method, params, M, K)
    if dt >= limit:
        message = (
            f"dt = {dt:g} is above the linear stability limit {limit:.6g} of method '{method.name}' "
            f"for these parameters (bound {method.stability_bound:.4f} / optical band top); "
            f"use dt < {limit:.6g}"
        )
        if not allow_unstable_step:
            raise StepSizeError(message + " or pass guard=Guard(allow_unstable_step=True) to run anyway")
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    return limit
