"""Breathers: seeds, Newton shooting on the period map, Floquet stability and continuation.

Knows nothing of Warp: the integrator is seen only through a ``warpchain.Flow`` (``run`` and
``linearize``), so every routine here also runs on the numpy reference (``warpchain.ReferenceFlow``).
"""

from . import branch, branch_store, driver, events
from .floquet import (
    FloquetResult,
    Instability,
    analyse_multipliers,
    floquet,
    full_floquet,
    monodromy,
    pairing_error,
    reduced_floquet,
    reduced_matrix,
)
from .newton import NewtonOutcome, NewtonSettings, ShootingStatus, newton
from .seeds import (
    NLSBreather,
    OscillatorOrbit,
    anticontinuum_orbit,
    anticontinuum_seed,
    eigenmode_seed,
    nls_breather,
    dnls_seed,
    dnls_threshold,
    nls_coefficients,
    nls_seed,
    oscillator_frequency,
)
from .shooting import (
    PeriodMap,
    ShootingError,
    ShootingResult,
    find_breather,
    frequency_report,
    make_flow,
    require,
    time_grid,
)

__all__ = [
    "FloquetResult",
    "Instability",
    "NLSBreather",
    "NewtonOutcome",
    "NewtonSettings",
    "OscillatorOrbit",
    "PeriodMap",
    "ShootingError",
    "ShootingResult",
    "ShootingStatus",
    "analyse_multipliers",
    "anticontinuum_orbit",
    "anticontinuum_seed",
    "branch",
    "branch_store",
    "driver",
    "eigenmode_seed",
    "events",
    "find_breather",
    "floquet",
    "frequency_report",
    "full_floquet",
    "make_flow",
    "monodromy",
    "newton",
    "nls_breather",
    "dnls_seed",
    "dnls_threshold",
    "nls_coefficients",
    "nls_seed",
    "oscillator_frequency",
    "pairing_error",
    "reduced_floquet",
    "reduced_matrix",
    "require",
    "time_grid",
]
