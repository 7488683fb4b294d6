"""warpchain: discrete breathers in a mass-in-mass chain with Hertzian local resonators.

The model (``model``), float64 Warp integrators of ensembles of lattices (``simulate`` with its option objects
``Record``, ``Guard``, ``Placement``; ``propagate_tangent``; the ``Flow`` that continuation uses), the numpy
reference of every scheme (``reference``), losses (``losses``), observables reduced on the device
(``observe``), and zarr output (``store``). The engine behind them lives in ``warpchain.engine``.
"""

from .engine.devices import DeviceState
from .ensemble import (
    IntegrationError,
    SimulationResult,
    StepSizeError,
    available_devices,
    frame_buffers,
    resolve_device,
    simulate,
    stability_limit,
)
from .observe import Observation, ObservedRun, observe
from .tangent import TangentResult, propagate_tangent
from .options import Guard, Placement, Record
from .flow import Flow, Linearization, ReferenceFlow, Trajectory
from .integrators import METHODS, Method, RungeKuttaMethod, SplittingMethod, get_method
from .losses import Damping
from .model import (
    BOUNDARIES,
    ChainParams,
    accelerations,
    band_edges,
    contact_force,
    contact_stiffness,
    dispersion,
    dispersion_long_wave,
    energy,
    linear_modes,
    long_wave_speed,
    lowest_optical_mode,
    min_contact,
    state_from_positions,
)

from .reader import read_store
from .store import StoreError

__version__ = "0.1.0"

__all__ = [
    "BOUNDARIES",
    "ChainParams",
    "Damping",
    "DeviceState",
    "Observation",
    "ObservedRun",
    "RungeKuttaMethod",
    "SplittingMethod",
    "Flow",
    "Guard",
    "Placement",
    "Record",
    "IntegrationError",
    "Linearization",
    "ReferenceFlow",
    "Trajectory",
    "METHODS",
    "Method",
    "SimulationResult",
    "StepSizeError",
    "StoreError",
    "TangentResult",
    "accelerations",
    "available_devices",
    "band_edges",
    "contact_force",
    "contact_stiffness",
    "dispersion",
    "dispersion_long_wave",
    "energy",
    "frame_buffers",
    "get_method",
    "read_store",
    "linear_modes",
    "long_wave_speed",
    "lowest_optical_mode",
    "min_contact",
    "observe",
    "propagate_tangent",
    "resolve_device",
    "simulate",
    "stability_limit",
    "state_from_positions",
]
