"""Order-of-magnitude estimates of M and K from material properties (paper Appendices A and B).

All inputs in SI units. These are the paper's rough estimates (a substrate slab of depth ~ one
wavelength under each sphere), not the fit of the dispersion curves.
"""

from __future__ import annotations

import math


def _positive(**values):
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
    return 1.0 / ((1.0 - nu1 ** 2) / E1 + (1.0 - nu2 ** 2) / E2)


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


def estimate_stiffness_ratio(diameter: float, E1: float, nu1: float, E2: float, nu2: float,
                             work_of_adhesion: float, wavelength_over_diameter: float) -> float:
    """Appendix B: K = k1 / k2 with k1 = E1 lambda (substrate block) and k2 the linearised contact.

    For identical materials this equals the paper's closed form
    (8(1 - nu^2)^2 / (3 pi))^{1/3} (E D / (2 w))^{1/3} lambda / D.
    """
    _positive(wavelength_over_diameter=wavelength_over_diameter)
    k1 = E1 * wavelength_over_diameter * diameter
    return k1 / hertz_contact(diameter, E1, nu1, E2, nu2, work_of_adhesion)["k2"]


def stiffness_ratio_closed_form(diameter: float, E: float, nu: float, work_of_adhesion: float,
                                wavelength_over_diameter: float) -> float:
    """The paper's closed form of Appendix B for identical sphere and substrate materials."""
    _positive(diameter=diameter, E=E, work_of_adhesion=work_of_adhesion)
    return ((8.0 * (1.0 - nu ** 2) ** 2 / (3.0 * math.pi)) ** (1.0 / 3.0)
            * (E * diameter / (2.0 * work_of_adhesion)) ** (1.0 / 3.0) * wavelength_over_diameter)


#: An illustrative material set: 1 um silica spheres on a silica-like glass substrate (assumed
#: handbook values; the source paper's exact inputs are not in our reference).
SILICA_ON_GLASS = {
    "diameter": 1.0e-6,        # m
    "rho_sphere": 2000.0,      # kg/m^3 (Stober silica)
    "rho_substrate": 2200.0,   # kg/m^3
    "E_sphere": 73.0e9,        # Pa
    "nu_sphere": 0.17,
    "E_substrate": 73.0e9,     # Pa
    "nu_substrate": 0.17,
    "work_of_adhesion": 0.02,  # J/m^2 (order of magnitude for silica-silica in air)
    "wavelength_over_diameter": 10.0,
}
