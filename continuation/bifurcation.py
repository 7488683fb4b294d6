"""Branch points: detection, location, classification and branch switching; finite-size checks.

**Which multipliers make a branch point.** Reversible shooting solves R(q; p) = q'(T/2) = 0 for the
positions q at t = 0 (``shooting``), with Jacobian J = dR/dq = A21, the velocity rows of the position
columns of the half-period map A. J a = 0 means a perturbation of the positions whose velocities
vanish at T/2: a T-periodic reversible solution of the linearization, i.e. a Floquet multiplier +1
beyond the trivial pair (whose direction is a time shift, a velocity perturbation, and does not enter
J). In the reduced problem (``floquet``) that is mu = (l + 1/l) / 2 = 1, with the position part of
the Floquet vector as eigenvector of Mu. A simple mu is analytic in the parameter, so a real pair
leaving the unit circle through +1 is a simple zero of mu - 1 (mu goes from elliptic, mu < 1, to
real, mu > 1): the test function of the locator.

**Pitchfork (Z2 symmetry breaking).** A site-centred orbit is mirror symmetric (P q = q, P: j -> N + 1 - j
on u and v), so J commutes with P and splits into even and odd blocks. When an *odd* mu passes 1, the
odd block is singular and, by equivariance (R(Pq) = P R(q)), a family of asymmetric orbits is born:
q = q* + a phi + O(a^2), p - p* = c a^2 + O(a^3) (p is even in a because a and -a are mirror images),
so its distance from the symmetric family grows like sqrt(|p - p*|). phi is the eigenvector of Mu at
mu = 1. The switcher fixes a (the constraint <phi, q - q*> = a, ``branch.ArclengthCorrector`` with
tau = (phi, 0)) and solves for (q, p) without the symmetry projection, at a = h and 2h; those two
points start a pseudo-arclength branch in log10 K (``branch.CouplingAxis``) that follows the new
family through folds.

**What is not a bifurcation of the breather.** mu = 1 also occurs whenever a phonon of the finite chain
passes a harmonic, w_k = n w_b (l = exp(i w_k T) = 1): such a mu has an extended Floquet vector and
touches 1 (mu = cos(w_k T)) without creating a localized family; its bubbles shrink with N. So the
detector counts only *localized* real pairs (participation below ``floquet.LOCALIZED_FRACTION`` N),
per parity; extended instabilities are classified by ``finite_size_check``: re-solved at ~2N sites
(the profile padded with zeros), an intrinsic instability keeps its modulus, a finite-size resonance
moves or vanishes.

Period doubling (mu through -1) and Krein collisions (quadruplets) are reported from the branch's
stability-change events and not followed.

The generic pieces (``locate_zero``, ``brackets``, ``switch_branch``) know nothing of breathers; the
tests feed them the closed-form pitchfork of a two-variable problem.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from warpchain import ChainParams, Flow, energy

from .branch import ArclengthCorrector, CouplingAxis
from .floquet import (
    central_weight,
    energy_centre,
    half_period_map,
    participation,
    reduced_floquet,
    vector_parity,
)
from .newton import NewtonSettings
from .results import Failure
from .shooting import find_breather, is_mirror_symmetric


class NotLocated(ValueError):
    """A branch point that is not there to locate, by the mathematics: the test function does not change
    sign in the bracket, it jumps from one sign to the other (its multiplier changed identity) instead of
    passing zero, or there is no real multiplier of the parity to follow. Every other error while locating
    (a solve that fails, an engine error) is not this: a scene retries it once and otherwise fails."""


__all__ = [
    "BifurcationPoint",
    "Located",
    "NotLocated",
    "brackets",
    "central_weight",
    "energy_centre",
    "finite_size_check",
    "locate_real_pair",
    "locate_zero",
    "localized_real_pairs",
    "pinning_value",
    "suspect_steps",
    "pad_chain",
    "switch_branch",
    "switch_to_asymmetric",
    "unlocated",
]

#: a located zero of mu - 1 farther from 0 than this is a jump of the test function (the pinning mode
#: changed identity), not a crossing; located crossings have |mu - 1| ~ 1e-13
JUMP_TOLERANCE = 1e-8


# ----------------------------------------------------------------------------- generic pieces


@dataclasses.dataclass(frozen=True)
class Located:
    """A zero of a test function located in a bracket.

    Attributes:
        value: the parameter at the zero (the last secant estimate).
        bracket: (lo, hi), the final sign-change bracket.
        test: the test function's value at ``value``.
        evaluations: test function evaluations used.
        converged: the bracket (or the last secant step) is below the tolerance.
        payload: what the test function returned with its value at ``value``.
    """

    value: float
    bracket: tuple
    test: float
    evaluations: int
    converged: bool
    payload: object = None


def locate_zero(
    f: Callable[[float], tuple],
    a: float,
    b: float,
    *,
    atol: float = 1e-9,
    max_evaluations: int = 60,
) -> Located:
    """Zero of a continuous test function in [a, b] by Brent's method (scipy's ``brentq``: inverse
    quadratic and secant steps inside a sign-change bracket, bisection when they stall), to a final
    bracket of ``atol``. A plain secant or regula falsi stops on a short step while one end is stuck,
    which on the flat test functions of weak exchanges of stability (mu - 1 changes by ~1e-5 per unit
    of K) left the estimate 1e-6 off; Brent's bracket cannot.

    Args:
        f: p -> (test value, payload).
        a, b: the bracket.
        atol: the final bracket's width (in p).
        max_evaluations: give up (``converged`` False) after this many evaluations.

    Raises:
        NotLocated: no sign change in [a, b].
    """
    from scipy.optimize import brentq

    seen: dict = {}

    def value(x):
        if x not in seen:
            seen[x] = f(x)
        return seen[x][0]

    fa, fb = value(a), value(b)
    if fa == 0.0 or fb == 0.0:
        x = a if fa == 0.0 else b
        return Located(x, (x, x), 0.0, len(seen), True, seen[x][1])
    if np.sign(fa) == np.sign(fb):
        raise NotLocated(f"no sign change of the test function in [{a:.10g}, {b:.10g}] ({fa:.3g}, {fb:.3g})")
    x, info = brentq(
        value, a, b, xtol=atol, rtol=4 * np.finfo(float).eps, maxiter=max_evaluations, full_output=True, disp=False
    )
    fx = value(x)
    # the final bracket: the closest evaluated points on either side of x with opposite signs
    xs = sorted(seen)
    left = max((p for p in xs if p <= x and np.sign(seen[p][0]) != np.sign(fb if b > a else fa)), default=min(a, b))
    right = min((p for p in xs if p >= x and np.sign(seen[p][0]) != np.sign(fa if b > a else fb)), default=max(a, b))
    return Located(float(x), (left, right), float(fx), len(seen), bool(info.converged), seen[x][1])


def brackets(items, signature: Callable[[object], object]) -> list:
    """Indices (i, i + 1) of consecutive items whose ``signature`` differs (where a branch point
    lies between them)."""
    sig = [signature(x) for x in items]
    return [(i, i + 1) for i in range(len(sig) - 1) if sig[i] != sig[i + 1]]


def switch_branch(corrector, y_star: np.ndarray, phi: np.ndarray, amplitudes=(1.0, 2.0)) -> list:
    """Points of the family that bifurcates at ``y_star`` = (x*, p*) along the null direction ``phi``
    (on x only): for each amplitude a, Newton on [F(x, p) = 0; <phi, x - x*> = a], started at
    (x* + a phi, p*). ``corrector.correct(y_pred, tau)`` is that bordered Newton (e.g.
    ``branch.ArclengthCorrector`` with no weight on p; the tests use a closed-form one).

    Returns:
        one corrector outcome per amplitude (NewtonOutcome, or the corrector's Failure).
    """
    phi = np.asarray(phi, dtype=float)
    tau = np.append(phi / np.linalg.norm(phi), 0.0)
    y_star = np.asarray(y_star, dtype=float)
    return [corrector.correct(y_star + a * tau, tau) for a in amplitudes]


# ----------------------------------------------------------------------------- breathers


def localized_real_pairs(point, parity: int | None = None) -> int:
    """How many localized real pairs (mu > 1, participation < LOCALIZED_FRACTION N) a branch point
    has (of the given parity when not None). Not the detector's test (``pinning_value`` is: this count
    also changes when a real pair's mode crosses the localization limit); kept as a cross-check."""
    return sum(
        1
        for i in point.instabilities
        if i.kind == "real_pair" and i.localized and (parity is None or i.parity == parity)
    )


@dataclasses.dataclass(frozen=True)
class BifurcationPoint:
    """A located branch point of a breather family.

    Attributes:
        family: the family it lies on (e.g. ``"site"``, ``"bond-in-phase"``).
        kind: ``"symmetry_breaking_pitchfork"`` (an odd localized real pair through +1 on a mirror-
            symmetric family), ``"branch_point"`` (a localized real pair through +1 elsewhere),
            ``"period_doubling"`` or ``"krein_collision"`` (reported, not followed).
        K, omega: where it is; bracket: the final bracket in K; evaluations: solves used.
        direction: ``"gained"`` / ``"lost"``: whether the family gains or loses the real pair with growing K.
        state: the orbit at the point (4, N); null_vector: the Floquet vector at mu = 1 (positions, 2N).
        participation, central_weight: of the null vector (sites; fraction on the central 2 CENTRAL_SITES + 1).
        energy: of the orbit; test: mu - 1 at the located point.
        slope: d(mu - 1)/dK across the located bracket's first step (a secant).
        K_error: the location's uncertainty, the measured noise of mu (the trivial mu's distance
            from 1, or |test| if larger) over |slope|: flat test functions locate worse.
    """

    family: str
    kind: str
    K: float
    omega: float
    bracket: tuple
    evaluations: int
    direction: str
    state: np.ndarray = dataclasses.field(repr=False)
    null_vector: np.ndarray = dataclasses.field(repr=False)
    participation: float
    central_weight: float
    energy: float
    test: float
    slope: float = float("nan")
    K_error: float = float("nan")

    def as_dict(self) -> dict:
        return {
            "K": self.K,
            "kind": self.kind,
            "family": self.family,
            "omega": self.omega,
            "bracket": list(self.bracket),
            "direction": self.direction,
            "participation": self.participation,
            "central_weight": self.central_weight,
            "energy": self.energy,
            "test_mu_minus_1": self.test,
            "slope": self.slope,
            "K_error": self.K_error,
            "relative_error": self.K_error / self.K,
            "evaluations": self.evaluations,
        }


def _mu_and_vectors(result):
    """Reduced Floquet eigenpairs of a converged ShootingResult and each vector's parity: exact, from the
    even and odd blocks, on a mirror-symmetric orbit (``floquet.parity_blocks``: ~4x less work than the
    whole Mu); read off the vectors otherwise."""
    fl = reduced_floquet(half_period_map(result.linearization()), result.params.M, result.state)
    parity = fl.parity if fl.spectral.parities == (1, -1) else vector_parity(fl.vectors)
    return fl.mu, fl.vectors, parity


def _pinning_index(mu, parity_of_mu, central, parity: int | None):
    """Index of the nontrivial real mu (of the given parity) whose Floquet vector has the largest
    weight on the orbit's central sites (the pinning mode), or None. (Not the smallest participation:
    near the anti-continuum limit every phonon mode sits on one or two sites.)"""
    mu = np.asarray(mu)
    trivial = int(np.argmin(np.abs(mu - 1.0)))
    real = np.abs(mu.imag) < 1e-9 * np.maximum(1.0, np.abs(mu.real))
    real[trivial] = False
    if parity is not None:
        real &= np.asarray(parity_of_mu) == parity
    if not real.any():
        return None
    return int(np.flatnonzero(real)[np.argmax(np.asarray(central)[real])])


def pinning_value(point, parity: int | None = None) -> float:
    """The detector's test function at a branch point, from its stored multipliers: mu - 1 of the
    nontrivial real mu (of the given parity) with the largest central weight: the breather's pinning
    mode, whose mu passes +1 where the family gains or loses its localized real pair. NaN without
    multipliers."""
    central = getattr(point, "central_weight", None)
    if point.mu is None or central is None or not np.all(np.isfinite(point.mu)):
        return float("nan")
    k = _pinning_index(point.mu, point.parity, central, parity)
    return float("nan") if k is None else float(point.mu[k].real - 1.0)


def suspect_steps(points, parity: int | None = None) -> list:
    """Steps of a branch across which the pinning mode's mu may have passed +1.

    A step is suspect when ``pinning_value`` changes sign across it (one crossing, or an odd number),
    or when it does not but the parabola through the step's ends and a neighbour (in log10 K) has its
    vertex inside the step on the other side of zero (two crossings inside one step: a window of
    the localized real pair narrower than the step).

    Returns:
        (i, i + 1, vertex) per suspect step: vertex is None for a sign change, else the log10 K of the
        parabola's vertex, where the locator looks for the sign change first.
    """
    f = np.array([pinning_value(p, parity) for p in points])
    c = np.array([math.log10(p.K) for p in points])
    out = []
    for i in range(len(points) - 1):
        if not (np.isfinite(f[i]) and np.isfinite(f[i + 1])) or c[i] == c[i + 1]:
            continue
        if np.sign(f[i]) != np.sign(f[i + 1]):
            out.append((i, i + 1, None))
            continue
        for trio in ((i - 1, i, i + 1), (i, i + 1, i + 2)):
            if min(trio) < 0 or max(trio) >= len(points) or not np.all(np.isfinite(f[list(trio)])):
                continue
            x, y = c[list(trio)], f[list(trio)]
            if len(set(x)) < 3:
                continue
            a2, a1, _ = np.polyfit(x - c[i], y, 2)
            if a2 == 0.0:
                continue
            vertex = c[i] - a1 / (2 * a2)
            if min(c[i], c[i + 1]) < vertex < max(c[i], c[i + 1]):
                value = float(np.polyval(np.polyfit(x - c[i], y, 2), vertex - c[i]))
                if np.sign(value) != np.sign(f[i]):
                    out.append((i, i + 1, float(vertex)))
                    break
    return out


def _kind(a, b, parity: int | None) -> str:
    """The kind of branch point a localized real pair through +1 makes between branch points a and b."""
    symmetric = is_mirror_symmetric(a.state, 1e-9) and is_mirror_symmetric(b.state, 1e-9)
    return "symmetry_breaking_pitchfork" if symmetric and parity == -1 else "branch_point"


#: a sign change of the test function across a step whose ends differ in magnitude by more than this
#: factor is a change of identity (the mode with the largest central weight is another one at one end),
#: not a crossing: on site-bond's bond-centred families above K ~ 30 the pinning pair sits at |mu - 1| ~ 1e-8,
#: the phase pair's rounding, next to modes at 2e-2 (ratios 3e6). The real crossings of those families had
#: ratios of at most 24 (2026-11-25 CPU run), and a crossing within 1e-4 of a step's length from its end
#: is the only real one this misreads.
JUMP_RATIO = 1e4


def unlocated(family: str, a, b, vertex: float | None, parity: int | None = None) -> dict:
    """The summary record of a step flagged by ``suspect_steps`` that is not located: its bracket, and
    ``test_function_jump`` when the test function's magnitudes at the ends differ by more than
    ``JUMP_RATIO`` (a change of identity at rounding level: whether the step is flagged at all then depends
    on the sign of a value at rounding level, so such a record is a remark, not a branch point)."""
    fa, fb = abs(pinning_value(a, parity)), abs(pinning_value(b, parity))
    jump = bool(vertex is None and min(fa, fb) * JUMP_RATIO < max(fa, fb))
    return {
        "K": math.sqrt(a.K * b.K),
        "kind": _kind(a, b, parity),
        "family": family,
        "bracket": sorted([a.K, b.K]),
        "located": False,
        "window_inside_step": vertex is not None,
        "test_function_jump": jump,
    }


def locate_real_pair(
    family: str,
    params: ChainParams,
    omega: float,
    a,
    b,
    flow: Flow,
    *,
    parity: int | None = None,
    vertex: float | None = None,
    atol: float = 1e-9,
    tol: float = 1e-11,
) -> list:
    """Locate where the pinning mode's mu passes +1 between branch points ``a`` and ``b`` (a step of
    ``suspect_steps``) by Brent's method on mu - 1 of the most localized real mu of the given
    parity, in log10 K. Each evaluation is a Newton solve (started from the interpolated profiles,
    kept symmetric when both ends are) and a reduced Floquet analysis.

    Args:
        family: name of the family (for the record).
        params: the chain (any K); omega: the frequency.
        a, b: branch points (BranchPoint).
        flow: the integrator.
        parity: -1 for odd modes of a symmetric family, None for any.
        vertex: for a step without sign change, where (log10 K) to look for the other sign first.
        atol: in log10 K (1e-9: 2.3e-9 relative in K).

    Returns:
        the BifurcationPoints found (none, one, or two for a window inside the step).

    Raises:
        RuntimeError: a solve inside the bracket failed.
        NotLocated: no sign change where the step said there was one, the test function jumps there
            (its mode changed identity) instead of passing zero, or it has no real multiplier of the parity.
    """
    ca, cb = math.log10(a.K), math.log10(b.K)
    symmetric = is_mirror_symmetric(a.state, 1e-9) and is_mirror_symmetric(b.state, 1e-9)
    centre = energy_centre(a.state)

    cache: dict = {}

    def test(c):
        if c in cache:
            return cache[c]
        t = (c - ca) / (cb - ca)
        guess = (1.0 - t) * a.state + t * b.state
        res = find_breather(params.replace(K=10.0**c), omega, guess, flow=flow, tol=tol, symmetric=symmetric)
        if not res.success:
            raise RuntimeError(f"locating the branch point of the {family} family: {res.message}")
        mu, vec, vec_parity = _mu_and_vectors(res)
        k = _pinning_index(mu, vec_parity, central_weight(vec, params.M, energy_centre(res.state)), parity)
        if k is None:
            raise NotLocated(f"no real multiplier of parity {parity} near K = {10**c:.8g} on the {family} family")
        pr = float(participation(vec[:, k : k + 1], params.M)[0])
        noise = float(np.min(np.abs(mu - 1.0)))  # the trivial mu's distance from 1
        cache[c] = (float(mu[k].real - 1.0), (res, np.real(vec[:, k]), pr, noise))
        return cache[c]

    kind = _kind(a, b, parity)
    if vertex is None:
        intervals = [(ca, cb)]
    else:
        fa, fv = test(ca)[0], test(vertex)[0]
        if np.sign(fa) == np.sign(fv):
            return []  # the parabola's near miss was a miss
        intervals = [(ca, vertex), (vertex, cb)]
    out = []
    for lo, hi in intervals:
        loc = locate_zero(test, lo, hi, atol=atol)
        if not abs(loc.test) <= JUMP_TOLERANCE:
            raise NotLocated(
                f"mu - 1 jumps from one sign to the other at K = {10**loc.value:.10g} (|mu - 1| = {abs(loc.test):.2g} "
                "there): the most central real multiplier changed identity; no crossing of +1"
            )
        res, phi, pr, noise = loc.payload
        phi = phi / np.linalg.norm(phi)
        slope = (test(hi)[0] - test(lo)[0]) / (10.0**hi - 10.0**lo)
        # gained (with growing K) when mu - 1 goes from negative to positive
        gained = (test(lo)[0] < 0) == (hi > lo)
        out.append(
            BifurcationPoint(
                family=family,
                kind=kind,
                K=10.0**loc.value,
                omega=float(omega),
                bracket=tuple(sorted((10.0 ** loc.bracket[0], 10.0 ** loc.bracket[1]))),
                evaluations=loc.evaluations,
                direction="gained" if gained else "lost",
                state=res.state,
                null_vector=phi,
                participation=pr,
                central_weight=float(central_weight(phi[:, None], params.M, centre)[0]),
                energy=float(res.energy),
                test=float(loc.test),
                slope=float(slope),
                K_error=max(noise, abs(loc.test)) / abs(slope) if slope else float("inf"),
            )
        )
    return out


def switch_to_asymmetric(
    bif: BifurcationPoint,
    params: ChainParams,
    flow: Flow,
    amplitude: float,
    *,
    toward: float | None = None,
    tol: float = 1e-10,
    max_newton: int = 12,
) -> tuple:
    """The first two points of the family born at ``bif`` (amplitudes ``amplitude`` and twice it
    along the null vector), as start points for ``branch.PseudoArclength(axis=CouplingAxis(...))``.

    Args:
        toward: the sign of the null vector is chosen so that the energy centre moves toward this
            site position (default: the right-hand neighbour bond, centre + 1/2).

    Returns:
        two (state, log10 K, iterations, residual history, linearization) tuples.

    Raises:
        RuntimeError: the bordered Newton failed (with its message).
    """
    axis = CouplingAxis(params, bif.omega)
    W = np.ones(2 * params.N + 1)
    corrector = ArclengthCorrector(axis, flow, W, NewtonSettings(tol=tol, max_iterations=max_newton))
    q_star = bif.state[:2].ravel()
    phi = bif.null_vector
    centre = energy_centre(bif.state)
    toward = centre + 0.5 if toward is None else toward
    trial = np.zeros_like(bif.state)
    trial[:2] = (q_star + 1e-3 * np.max(np.abs(q_star)) * phi).reshape(2, -1)
    if (energy_centre(trial) - centre) * (toward - centre) < 0:
        phi = -phi
    y_star = np.append(q_star, math.log10(bif.K))
    out = []
    for outcome in switch_branch(corrector, y_star, phi, (amplitude, 2.0 * amplitude)):
        if isinstance(outcome, Failure) or not outcome.success:
            raise RuntimeError(f"branch switching at K = {bif.K:.8g} failed: {outcome.message}")
        y = outcome.unknowns
        state = np.zeros_like(bif.state)
        state[:2] = y[:-1].reshape(2, -1)
        out.append((state, float(y[-1]), outcome.iterations, outcome.history, outcome.evaluation.linearization))
    return tuple(out)


# ----------------------------------------------------------------------------- finite-size check


def pad_chain(state, N_new: int) -> np.ndarray:
    """The (4, N) state centred in a chain of N_new >= N sites, zeros outside (N_new - N even keeps a
    site-centred profile's centre site in the middle)."""
    state = np.asarray(state)
    N = state.shape[1]
    if N_new < N or (N_new - N) % 2:
        raise ValueError(f"pad to N_new >= N with N_new - N even, got N = {N}, N_new = {N_new}")
    out = np.zeros((4, N_new))
    k = (N_new - N) // 2
    out[:, k : k + N] = state
    return out


def _instability_table(fl, vectors, M, centre) -> tuple:
    """Per unstable multiplier: its row (kind, |l|, participation, central weight, localized, parity)
    and its Floquet vector's normalised site weights (M |a_u|^2 + |a_v|^2), shape (n, N)."""
    rows, weights = [], []
    n = vectors.shape[0] // 2
    for inst in fl.instabilities:
        k = int(np.argmin(np.abs(fl.mu - inst.mu)))
        rows.append(dict(inst.as_dict(), central_weight=float(central_weight(vectors[:, k : k + 1], M, centre)[0])))
        w = M * np.abs(vectors[:n, k]) ** 2 + np.abs(vectors[n:, k]) ** 2
        weights.append(w / np.sum(w))
    return rows, np.array(weights).reshape(len(rows), n)


def finite_size_check(
    params: ChainParams, omega: float, state, flow: Flow, *, N_new: int | None = None, tol: float = 1e-10
) -> dict:
    """Re-solve an orbit on a chain about twice as long (2N - 1 sites for odd N, so the centre site
    stays the centre; the profile padded with zeros) and compare the unstable multipliers.

    An unstable multiplier *persists* when the longer chain has one of the same kind and parity
    whose |l| - 1 agrees to 10 % (and 1e-9); a localized one that persists is ``intrinsic``,
    anything else ``finite-size`` (N-dependent: a resonance with the finite chain's phonons; an
    extended one whose modulus happens to recur at ~2N has a participation that grew with N, see
    ``participation_new``).

    Returns:
        dict with ``N``, ``N_new``, ``tables`` ({N: [rows]}, each row an instability with its
        ``central_weight``), ``classification`` (per instability of the N chain: ``persists``,
        ``modulus_new``, ``class``), ``weights`` ({N: (n_unstable, N) normalised site weights of the
        unstable Floquet vectors}), ``energy`` ({N: E}) and the new orbit's ``state``.
    """
    N = params.N
    N_new = (2 * N - 1 if N % 2 else 2 * N) if N_new is None else int(N_new)
    tables, weights, energies, states = {}, {}, {}, {}
    for n, guess in ((N, np.asarray(state)), (N_new, pad_chain(state, N_new))):
        pn = params.replace(N=n)
        res = find_breather(pn, omega, guess, flow=flow, tol=tol)
        if not res.success:
            raise RuntimeError(f"finite-size check: the orbit could not be re-solved at N = {n}: {res.message}")
        fl = reduced_floquet(half_period_map(res.linearization()), params.M, res.state)
        tables[n], weights[n] = _instability_table(fl, fl.vectors, params.M, energy_centre(res.state))
        energies[n], states[n] = float(energy(pn, res.state)[0]), res.state
    classification = []
    for row in tables[N]:
        growth = row["modulus"] - 1.0
        match = [
            r
            for r in tables[N_new]
            if r["kind"] == row["kind"]
            and r["parity"] == row["parity"]
            and abs((r["modulus"] - 1.0) - growth) <= max(0.1 * growth, 1e-9)
        ]
        persists = bool(match)
        classification.append(
            dict(
                row,
                persists=persists,
                modulus_new=match[0]["modulus"] if match else None,
                participation_new=match[0]["participation"] if match else None,
                **{"class": "intrinsic" if persists and row["localized"] else "finite-size"},
            )
        )
    return {
        "N": N,
        "N_new": N_new,
        "tables": tables,
        "weights": weights,
        "classification": classification,
        "energy": energies,
        "state": states[N_new],
    }
