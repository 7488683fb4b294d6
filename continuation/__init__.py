"""Breathers: seeds, Newton shooting on the period map, Floquet stability and continuation.

Knows nothing of Warp beyond warpchain's ensemble API (``simulate``, ``propagate_tangent``).
"""

from .floquet import FloquetResult, analyse_multipliers, floquet, monodromy, pairing_error
from .seeds import (
    NLSBreather,
    OscillatorOrbit,
    anticontinuum_orbit,
    anticontinuum_seed,
    eigenmode_seed,
    nls_breather,
    nls_coefficients,
    nls_seed,
    oscillator_frequency,
)
from .shooting import (
    ShootingError,
    ShootingResult,
    ShootingStatus,
    find_breather,
    frequency_report,
    require,
    time_grid,
)

__all__ = [
    "FloquetResult", "NLSBreather", "OscillatorOrbit", "ShootingError", "ShootingResult", "ShootingStatus",
    "analyse_multipliers", "anticontinuum_orbit", "anticontinuum_seed", "eigenmode_seed", "find_breather", "floquet",
    "frequency_report", "monodromy", "nls_breather", "nls_coefficients", "nls_seed", "oscillator_frequency",
    "pairing_error", "require", "time_grid",
]
