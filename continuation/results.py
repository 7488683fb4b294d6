"""What the continuation driver and its problems hand one another and the caller: the records of a walk.

A corrector (``continuation.branch``) returns a ``Solution`` or a ``Failure``; the driver
(``continuation.driver``) analyses a solution into a ``BranchPoint``, returns the finished ``Branch`` and reports a
``WalkState`` after every completed step (enough to continue the walk exactly); ``continuation.branch_store``
stores and loads them. Frozen records, no solving; every name is also importable from ``continuation.driver``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from warpchain import ChainParams

from . import events as ev
from .events import StopReason


@dataclasses.dataclass(frozen=True)
class BranchPoint:
    """One solution on a branch, with its multipliers (all that is needed to restart from it).

    Attributes:
        parameters: the point's parameters by name: ``"K"`` (the chain's coupling) and ``"omega"`` (the
            breather's frequency), whichever the continuation moves (``branch.ParameterAxis.name``); also
            ``point.K``, ``point.omega``, ``point.value(name)``.
        state: the orbit's start (4, N) (at rest).
        energy, min_contact: Hamiltonian; min over the orbit of 1 + u - v.
        iterations, residual_history: the corrector's Newton iterations and residual norms.
        multipliers: all 4N Floquet multipliers; mu: (l + 1/l)/2 of each pair (2N), or NaN
            without Floquet; signature, parity: per mu (events module).
        max_modulus, tolerance, stable, instabilities: the Floquet verdict (``floquet`` module); ``stable`` is
            None (not decided) without Floquet (``ContinuationSettings.floquet`` False).
        complete: every multiplier accounted for (True wherever Floquet ran: the walk takes complete paths only).
        harmonics_in_bands: harmonics n of omega inside a phonon band.
        s: the continuation coordinate (log10 K or arclength).
        central_weight: per mu, the fraction of its Floquet vector on the central sites (None without Floquet).
    """

    parameters: dict
    state: np.ndarray
    energy: float
    iterations: int
    residual_history: tuple
    multipliers: np.ndarray
    mu: np.ndarray | None
    signature: np.ndarray | None
    parity: np.ndarray | None
    participation: np.ndarray | None
    max_modulus: float
    tolerance: float
    stable: bool | None
    instabilities: tuple
    min_contact: float
    harmonics_in_bands: tuple
    s: float = float("nan")
    central_weight: np.ndarray | None = None
    complete: bool = True

    @property
    def K(self) -> float:
        return self.parameters["K"]

    @property
    def omega(self) -> float:
        return self.parameters["omega"]

    def value(self, name: str) -> float:
        """The parameter ``name`` at this point (a ``ParameterAxis.name``)."""
        return self.parameters[name]

    @property
    def pairing_error(self) -> float:  # the reduced path's spectrum is paired by construction
        return 0.0

    def summary(self) -> dict:
        lead = self.instabilities[0] if self.instabilities else None
        return {
            "K": self.K,
            "omega": self.omega,
            "energy": self.energy,
            "max_floquet_modulus": self.max_modulus,
            "stable": self.stable,
            "complete": self.complete,
            "kinds": sorted({i.kind for i in self.instabilities}),
            "leading_localized": None if lead is None else lead.localized,
            "min_contact": self.min_contact,
            "newton_iterations": self.iterations,
        }


@dataclasses.dataclass(frozen=True)
class Solution:
    """What a corrector returns: the converged orbit and the linearization it ended on."""

    params: ChainParams
    omega: float
    state: np.ndarray
    iterations: int
    residual_history: tuple
    linearization: object
    s: float


@dataclasses.dataclass(frozen=True)
class Failure:
    """A corrector that did not converge, and why."""

    message: str


@dataclasses.dataclass(frozen=True)
class Branch:
    """A computed branch: its points, events and why it stopped.

    Attributes:
        points: the branch points in order (tuple of BranchPoint).
        stop_reason: a StopReason; message: what happened, with the parameter where it happened.
        events: dicts (``type``: stability_change, krein_crossing, contact_lost, harmonic_in_band, ...).
        parameter: ``"K"`` or ``"omega"``.
        stats: counters (points, solves, failed solves, bisection solves, wall_seconds, per point).
    """

    points: tuple
    stop_reason: StopReason
    message: str
    events: tuple
    parameter: str
    stats: dict

    @property
    def wall_seconds(self) -> float:
        return self.stats.get("wall_seconds", float("nan"))

    def column(self, name: str) -> np.ndarray:
        return np.array([getattr(p, name) for p in self.points])

    def unstable_intervals(self) -> list:
        return ev.unstable_intervals(list(self.points), self.parameter)

    def unresolved_bubbles(self) -> list:
        """Stretches with predicted bubbles too narrow to chase (``events.unresolved_bubbles``)."""
        return ev.unresolved_bubbles(list(self.points), self.events, self.parameter)

    def stability_changes(self) -> list:
        return [
            {"bracket": e["bracket"], "from_stable": e["from_stable"], "kinds": e["kinds"], "localized": e["localized"]}
            for e in self.events
            if e["type"] == "stability_change" and e["from_stable"] != e["to_stable"]
        ]


@dataclasses.dataclass(frozen=True)
class WalkState:
    """Where a walk stood after a completed step: with the points, enough to continue it exactly.

    Attributes:
        points: points accepted so far (a store may hold more: the unfinished step's, redone on resume).
        walk: indices of the points the driver stepped to (their secant sets the predictor; the points
            that bisection and bubble solves put between them are not on it).
        h: the next step's length.
        events: every event noted so far.
        stats: the counters so far.
        chord: how many Jacobians the corrector remembered after the last point's (it keeps the last few
            analysed, for its chord steps), None when it no longer held it: a resume restores the same.
    """

    points: int
    walk: tuple
    h: float
    events: tuple
    stats: dict
    chord: int | None = 0

    def as_dict(self) -> dict:
        """Everything but the events themselves (``events`` counts them: a store keeps the branch's events
        apart, and those of a step cut off by ``max_points`` may follow this state's)."""
        d = {
            "points": self.points,
            "walk": list(self.walk),
            "h": self.h,
            "stats": dict(self.stats),
            "chord": self.chord,
        }
        return dict(d, events=len(self.events))

    def check(self, n_points: int) -> None:
        """ValueError unless this state fits a branch of ``n_points`` stored points."""
        if not 0 < self.points <= n_points or not self.walk or self.walk[-1] >= self.points:
            raise ValueError(
                f"walk state after {self.points} points (walk ending at point {list(self.walk[-1:])}) does not fit "
                f"the {n_points} stored points"
            )

    @classmethod
    def from_dict(cls, d: dict, events) -> "WalkState":
        """The state ``as_dict`` gave, with the branch's events (the first ``d["events"]`` of them are its)."""
        n = int(d["events"])
        if n > len(events):
            raise ValueError(f"the walk state counts {n} events, {len(events)} given")
        walk = tuple(int(i) for i in d["walk"])
        return cls(int(d["points"]), walk, float(d["h"]), tuple(events[:n]), dict(d["stats"]), d["chord"])
