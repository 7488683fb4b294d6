"""Floquet analysis: the full monodromy of a periodic orbit, its multipliers, and stability.

The monodromy V(T) (4N x 4N) is built from 4N tangent columns of the same discrete integrator
over one period. Hamiltonian structure: multipliers come in quadruplets (l, 1/l, conj(l),
1/conj(l)), and a pair sits at +1 (phase and energy directions, a Jordan block, which the eigen
solver splits by about sqrt(machine eps * ||V||)).

**Accuracy gauge and tolerance.** The pairing error is max_i min_j |l_i - 1 / l_j|: how far the
computed spectrum is from being closed under l -> 1/l (conj pairs are exact for a real matrix).
For the symplectic integrators the discrete monodromy is exactly symplectic, so the pairing error
measures the eigen solver's accuracy; for RK4 it also contains the integrator's departure from
symplecticity. A multiplier is counted on the unit circle when ||l| - 1| <= tol with

    tol = max(10 * pairing_error, 1e-12),

i.e. a deviation must exceed ten times what the computation demonstrably cannot resolve before it
is called an instability. The trivial pair (the two multipliers closest to +1) is excluded.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from warpchain import ChainParams, propagate_tangent

from .shooting import ShootingResult


@dataclasses.dataclass(frozen=True)
class FloquetResult:
    """Multipliers of a periodic orbit and the stability verdict.

    Attributes:
        multipliers: all 4N multipliers, complex, shape (4N,).
        trivial: indices of the trivial pair (closest to +1).
        max_modulus: largest |l| excluding the trivial pair.
        pairing_error: the accuracy gauge (module docstring).
        tolerance: the tolerance used for the verdict.
        stable: every nontrivial multiplier within tolerance of the unit circle.
        symplecticity_error: || V^T J V - J || / ||V||^2 in mass-weighted coordinates.
        monodromy: V (4N x 4N), when kept.
        wall_seconds: time for the tangent run and the eigenvalues.
    """

    multipliers: np.ndarray
    trivial: np.ndarray
    max_modulus: float
    pairing_error: float
    tolerance: float
    stable: bool
    symplecticity_error: float
    monodromy: np.ndarray | None
    wall_seconds: float

    @property
    def nontrivial(self) -> np.ndarray:
        mask = np.ones(len(self.multipliers), bool)
        mask[self.trivial] = False
        return self.multipliers[mask]


def monodromy(params: ChainParams, state, period_steps: int, dt: float, *, method: str, device=None) -> np.ndarray:
    """V with V[:, i] the end-of-period derivative along the i-th state coordinate (4N x 4N)."""
    n = 4 * params.N
    tan = propagate_tangent(params, state, np.eye(n).reshape(n, 4, params.N), period_steps, dt, method=method,
                            device=device)
    return tan.columns.reshape(n, n).T


def pairing_error(multipliers: np.ndarray) -> float:
    """max_i min_j |l_i - 1/l_j| of a spectrum (0 for an exactly symplectic one)."""
    lam = np.asarray(multipliers)
    inv = 1.0 / lam
    return float(np.max(np.min(np.abs(lam[:, None] - inv[None, :]), axis=1)))


def symplecticity_error(V: np.ndarray, M: float) -> float:
    """Departure of V from symplecticity for H with momenta (M u', v')."""
    n = V.shape[0] // 4
    scale = np.concatenate([np.ones(2 * n), np.full(n, M), np.ones(n)])
    W = scale[:, None] * V / scale[None, :]  # V in (q, p) coordinates
    Jmat = np.block([[np.zeros((2 * n, 2 * n)), np.eye(2 * n)], [-np.eye(2 * n), np.zeros((2 * n, 2 * n))]])
    return float(np.max(np.abs(W.T @ Jmat @ W - Jmat)) / max(np.max(np.abs(W)) ** 2, 1.0))


def analyse_multipliers(multipliers: np.ndarray, tolerance: float | None = None) -> dict:
    """Trivial pair, pairing error, tolerance, largest nontrivial modulus and the verdict."""
    lam = np.asarray(multipliers)
    trivial = np.argsort(np.abs(lam - 1.0))[:2]
    mask = np.ones(len(lam), bool)
    mask[trivial] = False
    err = pairing_error(lam)
    tol = max(10.0 * err, 1e-12) if tolerance is None else tolerance
    nontrivial = lam[mask]
    max_mod = float(np.max(np.abs(nontrivial))) if nontrivial.size else 1.0
    stable = bool(np.all(np.abs(np.abs(nontrivial) - 1.0) <= tol))
    return {"trivial": trivial, "pairing_error": err, "tolerance": tol, "max_modulus": max_mod, "stable": stable}


def floquet(breather: ShootingResult, *, method: str | None = None, device=None, keep_monodromy: bool = False,
            tolerance: float | None = None) -> FloquetResult:
    """Floquet multipliers of a converged breather over one full period (same integrator and
    step as its shooting unless ``method`` is given)."""
    start = time.perf_counter()
    params = breather.params
    half_steps = breather.nsteps if breather.formulation == "reversible" else breather.nsteps // 2
    V = monodromy(params, breather.state, 2 * half_steps, breather.dt, method=method or breather.method, device=device)
    lam = np.linalg.eigvals(V)
    info = analyse_multipliers(lam, tolerance)
    return FloquetResult(multipliers=lam, monodromy=V if keep_monodromy else None,
                         symplecticity_error=symplecticity_error(V, params.M),
                         wall_seconds=time.perf_counter() - start, **info)
