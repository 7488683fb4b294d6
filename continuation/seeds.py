"""Initial guesses for breathers: anti-continuum, linear eigenmode and NLS seeds.

All seeds are time-reversible states at a turning point: positions (u, v) with zero velocities,
returned as a (4, N) state.

**NLS coefficients** (derived here again; the paper's appendix has typos). With z = u - v and
w = M u + v the continuum equations (x = j / sqrt(K)) read exactly

    z_tt + w0^2 g(z) = u_xx / M,   w_tt = u_xx,   u = (w + z) / (M + 1),
    g(z) = z + z^2/4 - z^3/24 + ...,  w0^2 = (M + 1) / M.

Multiple scales with z = eps (A(X, T) e^{i w0 t} + c.c.) + eps^2 z2 + ..., X = eps x, T = eps^2 t
give at O(eps^2) z2 = (A^2 e^{2 i w0 t} + c.c.) / 12 - |A|^2 / 2 (w carries no oscillating part
at this order) and, from the secular terms at O(eps^3),

    2 i w0 A_T = D A_XX + G |A|^2 A,   D = 1 / (M (M + 1)),   G = w0^2 / 3.

With A = B(X) e^{-i nu T} (frequency w_b = w0 - eps^2 nu): D B'' = 2 w0 nu B - G B^3, whose
bright soliton is B = alpha sech(beta X), beta^2 = 2 w0 nu / D, alpha^2 = 2 beta^2 D / G = 12 nu / w0.
Undoing the scalings (Delta = w0 - w_b = eps^2 nu):

    z(j, t) ~ 2 sqrt(12 Delta / w0) sech(kappa j) cos(w_b t),   kappa = sqrt(2 w0 Delta M (M + 1) / K),
    u ~ z / (M + 1),  v ~ -M z / (M + 1)   (plus the O(eps^2) terms above).

Two independent checks (tests/test_seeds.py): the uniform case gives the single oscillator's
frequency shift, w = w0 (1 - a^2 / 24) for amplitude a (Lindstedt), and D is the curvature of the
optical band at q = 0, w ~ w0 + K D q^2 / (2 w0) ... i.e. d(w^2)/d(k^2) = D with k^2 = K q^2.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from warpchain.model import ChainParams, contact_force, lowest_optical_mode, state_from_positions


# ----------------------------------------------------------------------------- anti-continuum


@dataclasses.dataclass(frozen=True)
class OscillatorOrbit:
    """A periodic orbit of one uncoupled site, z'' = -w0^2 f(z) (K = 0).

    Attributes:
        omega: frequency; period: 2 pi / omega.
        z_max, z_min: turning points (z_max at t = 0, z_min at t = T/2).
        t, z: one period sampled (for plots).
    """

    omega: float
    period: float
    z_max: float
    z_min: float
    t: np.ndarray
    z: np.ndarray


def _half_period(z0: float, omega0: float, dense: bool = False):
    """Time from the turning point z0 > 0 (at rest) to the next turning point."""

    def rhs(t, y):
        return [y[1], -(omega0**2) * float(contact_force(y[0]))]

    def turning(t, y):
        return y[1]

    turning.direction = 1.0  # z' goes from negative to zero at the lower turning point
    turning.terminal = True
    sol = solve_ivp(
        rhs,
        (0.0, 100.0 / omega0),
        [z0, 0.0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-14,
        events=turning,
        dense_output=dense,
    )
    if not sol.t_events[0].size:
        raise RuntimeError(f"no turning point found from z0 = {z0}")
    return sol.t_events[0][0], sol.y_events[0][0][0], sol


def oscillator_frequency(z_max: float, M: float) -> float:
    """Frequency of the K = 0 site oscillation with upper turning point ``z_max`` > 0."""
    omega0 = math.sqrt((M + 1.0) / M)
    half, _, _ = _half_period(z_max, omega0)
    return math.pi / half


def anticontinuum_orbit(omega: float, M: float, samples: int = 256) -> OscillatorOrbit:
    """The single-site periodic orbit of frequency ``omega`` (0 < omega < w0), solved as the
    one-degree-of-freedom problem it is: the upper turning point is found by root finding on the
    period (the oscillator softens, so its frequency falls monotonically with amplitude).

    Raises:
        ValueError: omega outside (0, w0), or too low to be reached.
    """
    omega0 = math.sqrt((M + 1.0) / M)
    if not 0.0 < omega < omega0:
        raise ValueError(
            f"the anti-continuum orbit needs 0 < omega < w0 = {omega0:.6f} (the oscillator softens); "
            f"got omega = {omega}"
        )
    target = lambda z0: oscillator_frequency(z0, M) - omega  # noqa: E731
    lo, hi = 1e-6, 0.5
    while target(hi) > 0:
        hi *= 2.0
        if hi > 1e3:
            raise ValueError(f"omega = {omega} is below the frequencies this oscillator reaches")
    z_max = brentq(target, lo, hi, xtol=1e-14, rtol=1e-14)
    half, z_min, sol = _half_period(z_max, omega0, dense=True)
    t = np.linspace(0.0, 2 * half, samples)
    first = sol.sol(np.minimum(t, half))[0]
    # the second half is the time reverse of the first (reversible oscillator)
    z = np.where(t <= half, first, sol.sol(np.clip(2 * half - t, 0, half))[0])
    return OscillatorOrbit(omega=omega, period=2 * half, z_max=z_max, z_min=z_min, t=t, z=z)


def anticontinuum_seed(params: ChainParams, omega: float, kind: str = "site", centre: int | None = None) -> np.ndarray:
    """Anti-continuum seed: the single-oscillator orbit on one site (``"site"``), or on two
    neighbouring sites in phase (``"bond-in-phase"``) or out of phase (``"bond-out-of-phase"``),
    with M u + v = 0 on the excited sites and rest elsewhere.

    Returns:
        state (4, N) at t = 0 (turning point, zero velocities).
    """
    kinds = ("site", "bond-in-phase", "bond-out-of-phase")
    if kind not in kinds:
        raise ValueError(f"kind must be one of {kinds}, got {kind!r}")
    orbit = anticontinuum_orbit(omega, params.M)
    N = params.N
    j0 = N // 2 if centre is None else int(centre)
    if not 0 <= j0 < N - (0 if kind == "site" else 1):
        raise ValueError(f"centre {j0} is outside the chain of N = {N}")
    z = np.zeros(N)
    z[j0] = orbit.z_max
    if kind == "bond-in-phase":
        z[j0 + 1] = orbit.z_max
    elif kind == "bond-out-of-phase":
        z[j0 + 1] = orbit.z_min  # half a period later on the neighbour
    return state_from_positions(z / (params.M + 1.0), -params.M * z / (params.M + 1.0))


# ----------------------------------------------------------------------------- eigenmode


def eigenmode_seed(params: ChainParams, amplitude: float, centre_component: str = "v") -> np.ndarray:
    """The finite chain's lowest optical eigenmode at rest, scaled so that |v| (or |u|, |z|) at the
    centre site equals ``amplitude``.

    Returns:
        state (4, N).
    """
    _, shape = lowest_optical_mode(params)
    c = params.N // 2
    ref = {"v": shape[1, c], "u": shape[0, c], "z": shape[0, c] - shape[1, c]}[centre_component]
    shape = shape * (amplitude / abs(ref))
    return state_from_positions(shape[0], shape[1])


# ----------------------------------------------------------------------------- NLS


@dataclasses.dataclass(frozen=True)
class NLSBreather:
    """The NLS approximation of the standing breather (module docstring).

    Attributes:
        omega: breather frequency; delta: w0 - omega.
        dispersion, nonlinearity: D and G of 2 i w0 A_T = D A_XX + G |A|^2 A.
        amplitude: peak of z at t = 0 (first order), 2 sqrt(12 delta / w0).
        kappa: inverse width in sites.
    """

    M: float
    K: float
    omega: float
    delta: float
    dispersion: float
    nonlinearity: float
    amplitude: float
    kappa: float

    def positions(self, N: int, centre: int | None = None, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """u and v profiles at t = 0 on N sites."""
        c = N // 2 if centre is None else centre
        j = np.arange(N) - c
        with np.errstate(over="ignore"):  # cosh overflows far out on long chains: the profile is 0 there
            b = 0.5 * self.amplitude / np.cosh(self.kappa * j)
        return envelope_positions(b, self.M, order)


def envelope_positions(b, M: float, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """u and v at t = 0 of an optical-band-edge packet z = 2 b cos(w t) with envelope b (any lattice): the spheres
    against the substrate in the ratio -M : 1, and with ``order`` 2 the second harmonic b^2 / 6 and the mean shift
    b^2 / 2 on the resonators (u's mean is zero)."""
    z_osc = 2.0 * b + (b * b / 6.0 if order >= 2 else 0.0)
    u = z_osc / (M + 1.0)
    v = -M * z_osc / (M + 1.0)
    if order >= 2:
        v = v + b * b / 2.0
    return u, v


def _gap(who: str, M: float, K: float, omega: float) -> float:
    """w0 = sqrt((M + 1) / M), after checking that omega lies below it and K > 0 (the NLS needs both)."""
    omega0 = math.sqrt((M + 1.0) / M)
    if not 0.0 < omega < omega0:
        raise ValueError(f"{who} needs omega below the optical band edge w0 = {omega0:.6f}; got {omega}")
    if K <= 0:
        raise ValueError(f"{who} needs K > 0")
    return omega0


def nls_coefficients(M: float) -> tuple[float, float]:
    """(D, G) of the NLS 2 i w0 A_T = D A_XX + G |A|^2 A for the optical band edge at q = 0."""
    omega0_sq = (M + 1.0) / M
    return 1.0 / (M * (M + 1.0)), omega0_sq / 3.0


def nls_breather(M: float, K: float, omega: float) -> NLSBreather:
    """NLS approximation of the band-gap breather of frequency omega < w0 (needs K > 0)."""
    omega0 = _gap("the NLS breather (a continuum approximation)", M, K, omega)
    D, G = nls_coefficients(M)
    delta = omega0 - omega
    amplitude = 2.0 * math.sqrt(12.0 * delta / omega0)
    kappa = math.sqrt(2.0 * omega0 * delta / D / K)
    return NLSBreather(
        M=M, K=K, omega=omega, delta=delta, dispersion=D, nonlinearity=G, amplitude=amplitude, kappa=kappa
    )


#: the 2D cubic NLS's Townes soliton norm, the integral of R^2 over the plane for R'' + R' / r - R + R^3 = 0
TOWNES_NORM = 11.700896


def _dnls_newton(lattice):
    """Newton for the C = 1 DNLS soliton -L phi - r phi + phi^3 = 0 on ``lattice`` (``dnls_threshold``'s equation),
    its single-site start at r = 4 degree (phi^2 = r + degree at the centre) and the degree."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    L = sp.csr_matrix(lattice.laplacian_matrix())
    n, centre = L.shape[0], lattice.centre
    identity = sp.identity(n, format="csr")

    def newton(r, phi):
        for _ in range(60):
            F = -(L @ phi) - r * phi + phi**3
            step = spsolve((-L - r * identity + sp.diags(3.0 * phi * phi)).tocsc(), F)
            phi = phi - step
            if float(np.max(np.abs(step))) < 1e-13 * max(1.0, float(np.max(np.abs(phi)))):
                return phi
        raise RuntimeError(f"the discrete NLS: Newton did not converge at r = {r:g}")

    degree = float(L.diagonal().max())
    phi = np.zeros(n)
    phi[centre] = math.sqrt(4.0 * degree + degree)
    return newton, phi, degree


def dnls_seed(params, omega: float, order: int = 2) -> np.ndarray:
    """A seed state (4, N) at t = 0 for a lattice's site breather of frequency ``omega`` near the optical bottom: the
    discrete NLS soliton of ``dnls_threshold`` at r = 2 w0 (w0 - omega) / (D K) (continued from the single-site limit
    in r), a_j = sqrt(4 D K / G) phi_j the amplitude of z_j, and (u, v) from it as ``nls_seed`` builds them on the
    chain (``order`` 2: the second-harmonic and mean corrections). Where the anti-continuum seed needs a long walk
    (wide breathers near the band edge), Newton starts here."""
    M, K = params.M, params.K
    w0 = _gap("dnls_seed", M, K, omega)
    D, G = nls_coefficients(M)
    r = 2.0 * w0 * (w0 - omega) / (D * K)
    newton, phi, degree = _dnls_newton(params.lattice)
    start = 4.0 * degree
    for rr in np.geomspace(start, r, max(2, int(20 * abs(math.log(start / r))) + 1)) if r < start else [r]:
        phi = newton(rr, phi)
    b = 0.5 * math.sqrt(4.0 * D * K / G) * phi  # z = 2 b cos(w t)
    return state_from_positions(*envelope_positions(b, M, order))


def dnls_threshold(lattice, M: float, K: float) -> dict:
    """The small-amplitude prediction of a lattice breather's energy threshold: the discrete NLS of the optical band
    bottom (module docstring, the X derivative replaced by the lattice's Laplacian L, ``Lattice.laplacian_matrix``)
    for the amplitude a_j of z_j ~ a_j cos(w_b t),

        -D K (L a)_j - 2 w0 Delta a_j + (G / 4) a_j^3 = 0,   Delta = w0 - w_b,

    is, with a = sqrt(4 C / G) phi and C = D K, the C = 1 DNLS -L phi - r phi + phi^3 = 0 at r = 2 w0 Delta / C. The
    energy of a small-amplitude breather is (1/2) sum a_j^2 (checked on the chain: the continuum soliton's a0^2 /
    kappa is the Newton breather's energy within 0.6 % at K = 4 near the edge), so E = (2 D K / G) p(r) with
    p = sum phi^2. In two dimensions p(r) has a positive minimum (Weinstein's excitation threshold; Flach, Kladko
    and MacKay 1997) and tends to the Townes norm times the area per site and L's curvature as r -> 0 (the continuum
    limit). Found here by Newton continuation of the site-centred solution from the single-site limit and Brent's
    minimisation in r, on the lattice as given (its walls included).

    Returns:
        {"norm": p at the minimum, "ratio": r there, "energy": (2 D K / G) p, "omega": w0 - r D K / (2 w0),
        "townes_energy": the continuum limit's (2 D K / G) p, the norm p of the Townes soliton on the lattice}.
    """
    from scipy.optimize import minimize_scalar

    newton, phi, degree = _dnls_newton(lattice)
    path = []
    for r in np.geomspace(4.0 * degree, 0.05 * degree, 80):
        phi = newton(r, phi)
        path.append((r, float(phi @ phi), phi))
    norms = np.array([norm for _, norm, _ in path])
    low = int(np.argmin(norms))
    if not 0 < low < len(path) - 1:
        raise RuntimeError("dnls_threshold: the norm has no minimum along the branch (a one-dimensional lattice?)")

    def norm(r):
        nearest = min(path, key=lambda item: abs(math.log(item[0] / r)))
        phi = newton(r, nearest[2])
        return float(phi @ phi)

    best = minimize_scalar(norm, bounds=(path[low + 1][0], path[low - 1][0]), method="bounded", options={"xatol": 1e-7})
    D, G = nls_coefficients(M)
    w0 = math.sqrt((M + 1.0) / M)
    # the continuum limit: L ~ -div(T grad) with T = sum_k w_k b_k b_k^T (b_k: direction k in the plane), so
    # sum_j phi_j^2 -> (sites per area) sqrt(det T) TOWNES_NORM
    bonds = np.asarray(lattice.directions, float) @ np.asarray(lattice.basis, float)
    T = sum(w * np.outer(b, b) for b, w in zip(bonds, lattice.direction_weights))
    townes = TOWNES_NORM * math.sqrt(abs(np.linalg.det(T))) / abs(np.linalg.det(lattice.basis))
    return {
        "norm": float(best.fun),
        "ratio": float(best.x),
        "energy": 2.0 * D * K / G * float(best.fun),
        "omega": w0 - float(best.x) * D * K / (2.0 * w0),
        "townes_energy": float(2.0 * D * K / G * townes),
    }


def nls_seed(params: ChainParams, omega: float, order: int = 2, centre: int | None = None) -> np.ndarray:
    """NLS seed state (4, N) at t = 0 for the chain's M, K.

    Warns (RuntimeWarning) when omega lies in the acoustic band: the NLS profile exists there but no
    breather is expected to (a phonon resonance), so Newton from it will most likely fail.
    """
    from warpchain import band_edges

    edges = band_edges(params.M, params.K)
    if omega <= edges["acoustic_top"]:
        import warnings

        warnings.warn(
            f"omega = {omega:g} lies in the acoustic band (top {edges['acoustic_top']:.6f}): the NLS seed "
            "is built, but band-gap breathers live in ({:.6f}, {:.6f})".format(
                edges["acoustic_top"], edges["optical_bottom"]
            ),
            RuntimeWarning,
            stacklevel=2,
        )
    u, v = nls_breather(params.M, params.K, omega).positions(params.N, centre, order)
    return state_from_positions(u, v)
