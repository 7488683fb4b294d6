"""The physical system behind the chain: material estimates, the continuous surface-wave model,
and the fit of the discrete model's M and K to it (paper section "Parameter Fitting", Fig. 2 and
Appendices A and B). All inputs and outputs in SI units (angular frequencies in rad/s).

**Continuous model.** An isotropic elastic half-space z < 0 (longitudinal and transverse speeds c_L,
c_T, density rho) whose free surface carries a monolayer of spheres, each a point mass m on a
vertical spring of resonance w_0, one sphere per cell of area A_c (close packing:
A_c = sqrt(3) D^2 / 2). With potentials phi = A exp(q z), psi = B exp(s z) (times exp(i(kx - wt))),
q = sqrt(k^2 - w^2/c_L^2), s = sqrt(k^2 - w^2/c_T^2), the surface displacement is
u_z = q A + i k B, and the boundary conditions at z = 0 are

    sigma_xz = mu (2 i k q A - (k^2 + s^2) B) = 0                      (no shear traction)
    sigma_zz = mu ((k^2 + s^2) A + 2 i k s B) = Phi(w) u_z              (the springs' pull)

with Phi(w) = (m / A_c) w_0^2 w^2 / (w_0^2 - w^2): a sphere obeys m W'' = -k_2 (W - u_z), so
W - u_z = u_z w^2 / (w_0^2 - w^2), and the spring pulls the surface with k_2 (W - u_z) per cell.
Eliminating B (first row) from the second row and writing xi = w / (c_T k):

    (2 - xi^2)^2 - 4 sqrt(1 - xi^2 c_T^2/c_L^2) sqrt(1 - xi^2)
        = (m / (A_c rho)) w_0^2 w^4 sqrt(1 - w^2/(c_L^2 k^2)) / (c_T^4 k^3 (w^2 - w_0^2)),

the Rayleigh equation (left) with the resonators' load (right; zero for m -> 0). ``boundary_matrix``
keeps the un-eliminated 2x2 system (Lame form of the stresses) so the tests can check the roots
against its determinant. Both sides are real for subsonic phase speeds (w/k < c_T): a lower branch
(0 < w < w_0, phase speed below c_R) and an upper branch (w > w_0) between the c_R and c_T lines,
which ends where it meets the transverse sound line: beyond, the waves leak into the bulk.

**Fit** (``fit_chain``, ``fit_to_substrate``). The discrete chain's long-wave speed is
D w_0 sqrt(K / (M + 1)) (its acoustic branch is w^2 = 2K(1 - cos kD) / (M + 1) + O(k^4)), not the
paper's D w_0 sqrt(K/M); setting it to c_R fixes K/(M + 1). Then K is chosen so that the discrete
optical branch passes through the point where the continuous upper branch meets the c_T line.

**The monolayer** (``monolayer_coupling``). The same surface carries a close-packed monolayer; its discrete model
(``warpchain.lattice``) has lam(q) = kappa |q|^2 D^2 + O(q^4) (kappa = 3/2 on the triangular lattice, 1 on the chain
and the square lattice: ``Lattice.long_wave_curvature``), so its long-wave speed is D w_0 sqrt(kappa K / (M + 1)).
Fitted to the same c_R it keeps M and takes K / kappa: the triangular monolayer of the chain fitted at K is the
lattice at (2/3) K. (The optical-branch point of the chain's fit is not refitted: on the lattice the branch depends
on the direction of k beyond long waves.)

**Appendix estimates** (``estimate_mass_ratio``, ``estimate_stiffness_ratio``): the paper's
order-of-magnitude M and K (a substrate slab of depth ~ one wavelength under each sphere).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import brentq


def _positive(obj=None, *fields, **values):
    """Raise unless every value is a finite number > 0: the keywords, and the named ``fields`` of ``obj``."""
    values.update({name: getattr(obj, name) for name in fields})
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def estimate_mass_ratio(rho_substrate: float, rho_sphere: float, wavelength_over_diameter: float) -> float:
    """Appendix A: M = m1 / m2 = (6/pi)(rho_1 / rho_2)(lambda / D).

    m2 is one sphere, (4/3) pi (D/2)^3 rho_2; m1 the substrate block lambda D^2 rho_1 under it.
    """
    _positive(rho_substrate=rho_substrate, rho_sphere=rho_sphere, wavelength_over_diameter=wavelength_over_diameter)
    return (6.0 / math.pi) * (rho_substrate / rho_sphere) * wavelength_over_diameter


def effective_modulus(E1: float, nu1: float, E2: float, nu2: float) -> float:
    """E* = [(1 - nu1^2)/E1 + (1 - nu2^2)/E2]^-1 of two bodies in Hertzian contact."""
    _positive(E1=E1, E2=E2)
    for name, nu in (("nu1", nu1), ("nu2", nu2)):
        if not -1.0 < nu < 0.5 + 1e-12:
            raise ValueError(f"Poisson ratio {name} must lie in (-1, 0.5], got {nu!r}")
    return 1.0 / ((1.0 - nu1**2) / E1 + (1.0 - nu2**2) / E2)


def hertz_contact(diameter: float, E1: float, nu1: float, E2: float, nu2: float, work_of_adhesion: float) -> dict:
    """Linearised Hertz-DMT contact of a sphere on a flat (Appendix B).

    Returns:
        dict with ``A`` (Hertz coefficient (4/3) E* sqrt(D/2)), ``F_DMT`` (pi w D),
        ``delta0`` (static overlap (F_DMT / A)^{2/3}) and ``k2`` ((3/2) A sqrt(delta0)).
    """
    _positive(diameter=diameter, work_of_adhesion=work_of_adhesion)
    A = (4.0 / 3.0) * effective_modulus(E1, nu1, E2, nu2) * math.sqrt(diameter / 2.0)
    F = math.pi * work_of_adhesion * diameter
    delta0 = (F / A) ** (2.0 / 3.0)
    return {"A": A, "F_DMT": F, "delta0": delta0, "k2": 1.5 * A * math.sqrt(delta0)}


def estimate_stiffness_ratio(
    diameter: float,
    E1: float,
    nu1: float,
    E2: float,
    nu2: float,
    work_of_adhesion: float,
    wavelength_over_diameter: float,
) -> float:
    """Appendix B: K = k1 / k2 with k1 = E1 lambda (substrate block) and k2 the linearised contact.

    For identical materials this equals the paper's closed form
    (8(1 - nu^2)^2 / (3 pi))^{1/3} (E D / (2 w))^{1/3} lambda / D.
    """
    _positive(wavelength_over_diameter=wavelength_over_diameter)
    k1 = E1 * wavelength_over_diameter * diameter
    return k1 / hertz_contact(diameter, E1, nu1, E2, nu2, work_of_adhesion)["k2"]


def stiffness_ratio_closed_form(
    diameter: float, E: float, nu: float, work_of_adhesion: float, wavelength_over_diameter: float
) -> float:
    """The paper's closed form of Appendix B for identical sphere and substrate materials."""
    _positive(diameter=diameter, E=E, work_of_adhesion=work_of_adhesion)
    return (
        (8.0 * (1.0 - nu**2) ** 2 / (3.0 * math.pi)) ** (1.0 / 3.0)
        * (E * diameter / (2.0 * work_of_adhesion)) ** (1.0 / 3.0)
        * wavelength_over_diameter
    )


#: The material set of the Appendix A/B estimates (assumed handbook values for 1 um silica spheres on
#: a silica-like glass; the source paper's exact inputs are not in our reference).
SILICA_ON_GLASS = {
    "diameter": 1.0e-6,  # m
    "rho_sphere": 2000.0,  # kg/m^3 (Stober silica)
    "rho_substrate": 2200.0,  # kg/m^3
    "E_sphere": 73.0e9,  # Pa
    "nu_sphere": 0.17,
    "E_substrate": 73.0e9,  # Pa
    "nu_substrate": 0.17,
    "work_of_adhesion": 0.02,  # J/m^2 (order of magnitude for silica-silica in air)
    "wavelength_over_diameter": 10.0,
}


# ----------------------------------------------------------------------------- elastic substrate


def wave_speeds(E: float, nu: float, rho: float) -> tuple[float, float]:
    """Bulk (c_L, c_T) of an isotropic solid with Young's modulus E, Poisson ratio nu, density rho."""
    _positive(E=E, rho=rho)
    if not -1.0 < nu < 0.5:
        raise ValueError(f"Poisson ratio must lie in (-1, 0.5), got {nu!r}")
    c_T = math.sqrt(E / (2.0 * rho * (1.0 + nu)))
    c_L = math.sqrt(E * (1.0 - nu) / (rho * (1.0 + nu) * (1.0 - 2.0 * nu)))
    return c_L, c_T


def rayleigh_function(xi, speed_ratio: float):
    """R(xi) = (2 - xi^2)^2 - 4 sqrt(1 - xi^2 a) sqrt(1 - xi^2), a = (c_T/c_L)^2, for 0 <= xi <= 1."""
    xi = np.asarray(xi, dtype=float)
    a = speed_ratio**2
    return (2.0 - xi**2) ** 2 - 4.0 * np.sqrt(1.0 - a * xi**2) * np.sqrt(1.0 - xi**2)


def rayleigh_speed(c_L: float, c_T: float) -> float:
    """Rayleigh wave speed c_R: the root xi_R in (0, 1) of the Rayleigh function, times c_T."""
    if not 0 < c_T < c_L:
        raise ValueError(f"need 0 < c_T < c_L, got c_L = {c_L!r}, c_T = {c_T!r}")
    ratio = c_T / c_L
    # R < 0 on (0, xi_R) and R(1) = 1; xi_R > 0.87 for every admissible Poisson ratio
    return c_T * brentq(lambda x: float(rayleigh_function(x, ratio)), 0.5, 1.0, xtol=1e-15, rtol=1e-15)


@dataclasses.dataclass(frozen=True)
class SurfaceResonatorModel:
    """Rayleigh waves on a half-space carrying a monolayer of surface resonators (module docstring).

    Attributes:
        c_L, c_T, rho: the substrate's bulk speeds (m/s) and density (kg/m^3).
        sphere_mass: m (kg); omega0: the resonators' w_0 (rad/s); cell_area: A_c (m^2).
    """

    c_L: float
    c_T: float
    rho: float
    sphere_mass: float
    omega0: float
    cell_area: float

    def __post_init__(self):
        _positive(self, "c_L", "c_T", "rho", "sphere_mass", "omega0", "cell_area")
        if self.c_T >= self.c_L:
            raise ValueError(f"c_T must be below c_L, got c_T = {self.c_T}, c_L = {self.c_L}")

    @property
    def c_R(self) -> float:
        return rayleigh_speed(self.c_L, self.c_T)

    @property
    def coupling_length(self) -> float:
        """m / (A_c rho): the resonators' mass per area over the substrate density (m)."""
        return self.sphere_mass / (self.cell_area * self.rho)

    def load(self, omega, k):
        """Right-hand side of the dispersion relation (the resonators' load)."""
        omega, k = np.asarray(omega, float), np.asarray(k, float)
        return (
            self.coupling_length
            * self.omega0**2
            * omega**4
            * np.sqrt(1.0 - (omega / (self.c_L * k)) ** 2)
            / (self.c_T**4 * k**3 * (omega**2 - self.omega0**2))
        )

    def residual(self, omega, k):
        """Rayleigh function minus the load: zero on the dispersion curves (subsonic, omega != w_0)."""
        omega, k = np.asarray(omega, float), np.asarray(k, float)
        return rayleigh_function(omega / (self.c_T * k), self.c_T / self.c_L) - self.load(omega, k)

    def boundary_matrix(self, omega: float, k: float) -> np.ndarray:
        """The 2x2 system M (A, B) = 0 of the two boundary conditions, with the stresses in Lame form
        (lambda, mu) before any simplification; its determinant vanishes on the dispersion curves."""
        mu = self.rho * self.c_T**2
        lam = self.rho * self.c_L**2 - 2.0 * mu
        q = math.sqrt(k * k - (omega / self.c_L) ** 2)
        s = math.sqrt(k * k - (omega / self.c_T) ** 2)
        phi = self.sphere_mass / self.cell_area * self.omega0**2 * omega**2 / (self.omega0**2 - omega**2)
        # displacements of A exp(qz), B exp(sz): u_x = ik A - s B, u_z = q A + ik B
        # sigma_xz = mu (du_x/dz + du_z/dx); sigma_zz = lam (du_x/dx + du_z/dz) + 2 mu du_z/dz
        shear = [mu * (1j * k * q + 1j * k * q), mu * (-s * s - k * k)]
        normal = [
            lam * (1j * k * 1j * k + q * q) + 2.0 * mu * q * q - phi * q,
            lam * (1j * k * -s + 1j * k * s) + 2.0 * mu * 1j * k * s - phi * 1j * k,
        ]
        return np.array([shear, normal], dtype=complex)

    def branch(self, k, which: str = "lower") -> np.ndarray:
        """omega (rad/s) of the ``lower`` or ``upper`` branch at wavenumbers k (1/m); NaN where the
        branch does not exist as a surface wave (the upper branch above the c_T line)."""
        if which not in ("lower", "upper"):
            raise ValueError(f"which must be 'lower' or 'upper', got {which!r}")
        ratio = self.c_T / self.c_L
        xi_R = self.c_R / self.c_T
        out = np.full(np.shape(k), np.nan)
        for idx, kk in np.ndenumerate(np.asarray(k, float)):
            if not kk > 0:
                continue
            xi0 = self.omega0 / (self.c_T * kk)

            def f(xi, kk=kk):
                return float(rayleigh_function(xi, ratio) - self.load(xi * self.c_T * kk, kk))

            eps = 1e-13
            if which == "lower":
                # at xi_R itself the Rayleigh function is ~0 and the (negative) load makes f > 0
                # (near xi = 0 the Rayleigh function, 2(a - 1) xi^2, is lost to rounding: start above)
                lo, hi = 0.01 * min(xi_R, xi0), (xi_R if xi_R < xi0 else xi0 * (1.0 - eps))
            else:
                lo, hi = max(xi_R, xi0) * (1.0 + eps), 1.0
            if hi <= lo:
                continue
            f_lo, f_hi = f(lo), f(hi)
            if np.sign(f_lo) == np.sign(f_hi):
                continue  # the upper branch does not reach this k (above the c_T line)
            out[idx] = self.c_T * kk * brentq(f, lo, hi, xtol=1e-15, rtol=1e-14)
        return out

    def transverse_line_crossing(self) -> tuple[float, float]:
        """(k_T, omega_T) where the upper branch meets the line omega = c_T k (closed form: on that
        line the Rayleigh function is 1, leaving c_T^2 k^2 - C w_0^2 sqrt(1 - c_T^2/c_L^2) k - w_0^2 = 0
        with C = m / (A_c rho))."""
        b = self.coupling_length * self.omega0**2 * math.sqrt(1.0 - (self.c_T / self.c_L) ** 2)
        k_T = (b + math.sqrt(b * b + 4.0 * self.c_T**2 * self.omega0**2)) / (2.0 * self.c_T**2)
        return k_T, self.c_T * k_T


# ----------------------------------------------------------------------------- the material set


@dataclasses.dataclass(frozen=True)
class MaterialSet:
    """Spheres on a substrate (SI units). ``contact_frequency_hz``: a measured contact resonance f_0;
    when None, w_0 comes from the linearised Hertz-DMT contact (``hertz_contact``)."""

    diameter: float
    rho_sphere: float
    E_sphere: float
    nu_sphere: float
    rho_substrate: float
    E_substrate: float
    nu_substrate: float
    work_of_adhesion: float
    contact_frequency_hz: float | None = None
    name: str = ""

    def __post_init__(self):
        _positive(self, "diameter", "rho_sphere", "E_sphere", "rho_substrate", "E_substrate", "work_of_adhesion")
        if self.contact_frequency_hz is not None:
            _positive(contact_frequency_hz=self.contact_frequency_hz)
        effective_modulus(self.E_substrate, self.nu_substrate, self.E_sphere, self.nu_sphere)  # validates nu

    @property
    def sphere_mass(self) -> float:
        return math.pi / 6.0 * self.diameter**3 * self.rho_sphere

    @property
    def cell_area(self) -> float:
        """Close-packed monolayer: sqrt(3) D^2 / 2 per sphere."""
        return math.sqrt(3.0) / 2.0 * self.diameter**2

    def hertz(self) -> dict:
        return hertz_contact(
            self.diameter, self.E_substrate, self.nu_substrate, self.E_sphere, self.nu_sphere, self.work_of_adhesion
        )

    @property
    def omega0_hertz(self) -> float:
        """w_0 = sqrt(k_2 / m) of the linearised Hertz-DMT contact."""
        return math.sqrt(self.hertz()["k2"] / self.sphere_mass)

    @property
    def omega0(self) -> float:
        if self.contact_frequency_hz is not None:
            return 2.0 * math.pi * self.contact_frequency_hz
        return self.omega0_hertz

    def surface_model(self) -> SurfaceResonatorModel:
        c_L, c_T = wave_speeds(self.E_substrate, self.nu_substrate, self.rho_substrate)
        return SurfaceResonatorModel(
            c_L=c_L,
            c_T=c_T,
            rho=self.rho_substrate,
            sphere_mass=self.sphere_mass,
            omega0=self.omega0,
            cell_area=self.cell_area,
        )

    def replace(self, **changes) -> "MaterialSet":
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


#: The example of the ``dispersion`` scene: 1 um silica (Stober) spheres on soda-lime glass, with the
#: contact resonance the paper quotes as measured (215 MHz). Assumed handbook values: the source
#: paper's exact inputs are not in our reference.
SILICA_SPHERES_ON_GLASS = MaterialSet(
    diameter=1.0e-6,
    rho_sphere=2000.0,
    E_sphere=73.0e9,
    nu_sphere=0.17,
    rho_substrate=2500.0,
    E_substrate=70.0e9,
    nu_substrate=0.22,
    work_of_adhesion=0.1,
    contact_frequency_hz=215.0e6,
    name="1 um silica spheres on soda-lime glass",
)


# ----------------------------------------------------------------------------- the fit


def discrete_long_wave_speed(M: float, K: float, omega0: float, diameter: float, *, exact: bool = True) -> float:
    """Long-wave sound speed (m/s) of the chain with cells of width D: D w_0 sqrt(K/(M+1)) (exact),
    or the paper's D w_0 sqrt(K/M)."""
    return diameter * omega0 * math.sqrt(K / ((M + 1.0) if exact else M))


def monolayer_coupling(K: float, lattice) -> float:
    """K of a lattice (``warpchain.lattice``) with the long-wave speed of the chain at K (module docstring):
    K / ``lattice.long_wave_curvature`` (the triangular monolayer: 2 K / 3)."""
    _positive(K=K)
    return K / lattice.long_wave_curvature


def discrete_optical(q, M: float, K: float):
    """Optical branch w / w_0 of the infinite chain at Bloch numbers q = k D."""
    from .model import dispersion

    return dispersion(q, M, K)[1]


@dataclasses.dataclass(frozen=True)
class ChainFit:
    """M and K of the discrete chain fitted to a long-wave speed and an optical-branch point.

    Attributes:
        M, K: the fitted mass and stiffness ratios.
        omega0: w_0 (rad/s); diameter: the cell width D (m).
        long_wave_speed: the target speed (m/s); crossing_k, crossing_omega: the target point.
        convention: ``"exact"`` (K/(M + 1) from the speed) or ``"paper"`` (K/M).
        speed_residual, crossing_residual: relative misfits of the two criteria at the solution.
    """

    M: float
    K: float
    omega0: float
    diameter: float
    long_wave_speed: float
    crossing_k: float
    crossing_omega: float
    convention: str
    speed_residual: float
    crossing_residual: float


def fit_chain(
    long_wave_speed: float,
    crossing_k: float,
    crossing_omega: float,
    omega0: float,
    diameter: float,
    *,
    convention: str = "exact",
    K_range=(1e-2, 1e6),
) -> ChainFit:
    """Fit (M, K): the chain's long-wave speed equals ``long_wave_speed`` and its optical branch passes
    through (``crossing_k``, ``crossing_omega``) (SI units).

    Raises:
        ValueError: bad input, or no K in ``K_range`` satisfies both criteria (the message says why).
    """
    _positive(
        long_wave_speed=long_wave_speed,
        crossing_k=crossing_k,
        crossing_omega=crossing_omega,
        omega0=omega0,
        diameter=diameter,
    )
    if convention not in ("exact", "paper"):
        raise ValueError(f"convention must be 'exact' or 'paper', got {convention!r}")
    ratio = (long_wave_speed / (omega0 * diameter)) ** 2  # K/(M+1) (exact) or K/M (paper)
    q, target = crossing_k * diameter, crossing_omega / omega0
    if q >= math.pi:
        raise ValueError(f"the crossing point k D = {q:.3g} lies beyond the Brillouin zone (pi)")

    def mass(K):
        return K / ratio - 1.0 if convention == "exact" else K / ratio

    def mismatch(logK):
        K = math.exp(logK)
        return float(discrete_optical(q, mass(K), K)) / target - 1.0

    lo = math.log(max(K_range[0], ratio * (1.0 + 1e-9) if convention == "exact" else K_range[0]))
    grid = np.linspace(lo, math.log(K_range[1]), 400)
    values = [mismatch(g) for g in grid]
    brackets = [i for i in range(len(grid) - 1) if np.sign(values[i]) != np.sign(values[i + 1])]
    if not brackets:
        raise ValueError(
            f"no K in {K_range} puts the optical branch through w/w_0 = {target:.6g} at k D = {q:.4g} "
            f"with K/{'(M+1)' if convention == 'exact' else 'M'} = {ratio:.6g}; the optical branch spans "
            f"{min(values) + 1:.4g}..{max(values) + 1:.4g} of the target there"
        )
    i = brackets[0]
    logK = brentq(mismatch, grid[i], grid[i + 1], xtol=1e-14, rtol=1e-14)
    K = math.exp(logK)
    M = mass(K)
    speed = discrete_long_wave_speed(M, K, omega0, diameter, exact=convention == "exact")
    return ChainFit(
        M=M,
        K=K,
        omega0=omega0,
        diameter=diameter,
        long_wave_speed=long_wave_speed,
        crossing_k=crossing_k,
        crossing_omega=crossing_omega,
        convention=convention,
        speed_residual=abs(speed / long_wave_speed - 1.0),
        crossing_residual=abs(mismatch(logK)),
    )


def fit_to_substrate(materials: MaterialSet, *, convention: str = "exact") -> dict:
    """The paper's fit for a material set: K/(M+1) from c_R, K from the upper branch's meeting with
    the c_T line. Returns a dict with ``M``, ``K``, ``omega0`` (rad/s), ``f0_hz``, the speeds, the
    crossing point, the criteria residuals, and ``lower_branch_misfit``: the RMS relative difference
    of the discrete and continuous lower branches for 0 < k <= k_T (how well the fitted chain follows
    the continuous model where it is meant to)."""
    model = materials.surface_model()
    c_R = model.c_R
    k_T, omega_T = model.transverse_line_crossing()
    fit = fit_chain(c_R, k_T, omega_T, model.omega0, materials.diameter, convention=convention)
    k = np.linspace(k_T / 200.0, k_T, 200)
    from .model import dispersion

    discrete = dispersion(k * materials.diameter, fit.M, fit.K)[0] * model.omega0
    continuous = model.branch(k, "lower")
    misfit = float(np.sqrt(np.mean((discrete / continuous - 1.0) ** 2)))
    return {
        "M": fit.M,
        "K": fit.K,
        "omega0": model.omega0,
        "f0_hz": model.omega0 / (2 * math.pi),
        "c_L": model.c_L,
        "c_T": model.c_T,
        "c_R": c_R,
        "k_T": k_T,
        "omega_T": omega_T,
        "coupling_length": model.coupling_length,
        "convention": convention,
        "speed_residual": fit.speed_residual,
        "crossing_residual": fit.crossing_residual,
        "residual": max(fit.speed_residual, fit.crossing_residual),
        "lower_branch_misfit": misfit,
    }
