"""Branches of breathers: natural-parameter continuation in the coupling K, pseudo-arclength
continuation in the frequency, events along the way, and a resumable zarr store.

* ``continue_in_coupling``: fixed w_b; secant predictor in K (or log K); adaptive steps (halved when
  Newton fails, grown by 1.5 after an easy solve); lands exactly on requested ``targets``.
* ``continue_in_frequency``: unknowns (positions q, w_b), tangent (secant) predictor, corrector
  Newton on [R(q, w); <tau, y - y_pred>_W = 0] with the weighted inner product
  <a, b>_W = a_q . b_q + theta^2 a_w b_w, theta = 1 / (gap width), so that crossing the gap counts
  like a unit change of the profile. The half period keeps a fixed number of steps (dt follows w);
  dR/dw is a central difference in w (two extra base runs per iteration).

Events: a change of the stability verdict between two points is located by bisection with the
multipliers recomputed at every trial point; a harmonic n w_b entering a phonon band is flagged;
loss of contact (min over the orbit of 1 + u - v <= 0) stops a branch; Newton failures shrink the
step, and a step below ``min_step`` stops the branch with the last Newton message.

Every point keeps its state, K, w_b, energy, all multipliers and the Newton history; with
``store=`` the branch is written point by point, and ``resume=`` continues from a stored branch.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from warpchain import ChainParams, band_edges, energy, simulate
from warpchain.store import consolidate, jsonable, open_store, provenance

from .floquet import analyse_multipliers, monodromy
from .shooting import (DEFAULT_METHOD, DEFAULT_STEPS_PER_PERIOD, ShootingStatus, _PeriodMap,
                       find_breather, frequency_report, newton, time_grid)

STOP_REASONS = {
    "reached_end": "the branch reached its end parameter",
    "contact_lost": "a resonator lost contact (min over the orbit of 1 + u - v <= 0)",
    "step_underflow": "Newton kept failing and the step fell below its minimum",
    "left_range": "the branch left the requested parameter range",
    "max_points": "the maximum number of points was reached",
    "time_budget": "the time budget was spent before the branch ended (resume it from its store to go on)",
    "start_failed": "Newton failed at the first point",
}


@dataclasses.dataclass
class BranchPoint:
    """One solution on a branch (all that is needed to restart from it)."""

    K: float
    omega: float
    state: np.ndarray
    energy: float
    iterations: int
    residual_history: tuple
    multipliers: np.ndarray
    max_modulus: float
    pairing_error: float
    stable: bool
    min_contact: float
    harmonics_in_bands: tuple

    def summary(self) -> dict:
        return {"K": self.K, "omega": self.omega, "energy": self.energy, "max_floquet_modulus": self.max_modulus,
                "stable": self.stable, "min_contact": self.min_contact, "newton_iterations": self.iterations,
                "pairing_error": self.pairing_error}


@dataclasses.dataclass
class Branch:
    """A computed branch: its points, events and why it stopped."""

    points: list
    stop_reason: str
    message: str
    events: list
    wall_seconds: float

    def column(self, name: str) -> np.ndarray:
        return np.array([getattr(p, name) for p in self.points])


# ----------------------------------------------------------------------------- analysis of one point


def orbit_min_contact(params, state, n_half, dt, method, device) -> float:
    """min over one period and all sites of 1 + u - v."""
    run = simulate(params, state, 2 * n_half * dt, dt, method=method, device=device, save_every=1,
                   max_energy_error=None, chunks=1)
    return float(run.min_contact[0])


def analyse_point(params: ChainParams, omega: float, state, n_half: int, method: str, device, iterations: int,
                  history, with_floquet: bool = True) -> BranchPoint:
    dt = math.pi / omega / n_half
    if with_floquet:
        lam = np.linalg.eigvals(monodromy(params, state, 2 * n_half, dt, method=method, device=device))
        info = analyse_multipliers(lam)
    else:
        lam = np.full(4 * params.N, np.nan + 0j)
        info = {"max_modulus": float("nan"), "pairing_error": float("nan"), "stable": False}
    return BranchPoint(K=params.K, omega=float(omega), state=np.array(state), energy=float(energy(params, state)[0]),
                       iterations=int(iterations), residual_history=tuple(history), multipliers=lam,
                       max_modulus=info["max_modulus"], pairing_error=info["pairing_error"], stable=info["stable"],
                       min_contact=orbit_min_contact(params, state, n_half, dt, method, device),
                       harmonics_in_bands=tuple(frequency_report(params, omega)["harmonics_in_bands"]))


# ----------------------------------------------------------------------------- store


class BranchStore:
    """Writes a branch to a zarr group point by point (each point is one whole chunk)."""

    SCALARS = ("K", "omega", "energy", "max_modulus", "pairing_error", "min_contact", "iterations")

    def __init__(self, path, group: str, params: ChainParams, attrs: dict, max_newton: int, mode: str = "w",
                 device=None):
        self.path, self.params, self.max_newton = Path(path), params, max_newton
        root = open_store(self.path, params=params.as_dict(), provenance_info=provenance(device),
                          mode="a" if self.path.exists() else "w")
        N = params.N
        g = root.require_group(group)
        self.group = g
        spec = {name: ((), "f8") for name in self.SCALARS}
        spec.update({"stable": ((), "i1"), "state": ((4, N), "f8"), "multipliers_real": ((4 * N,), "f8"),
                     "multipliers_imag": ((4 * N,), "f8"), "newton_residuals": ((max_newton + 1,), "f8")})
        dims = {"state": ("point", "component", "site"), "multipliers_real": ("point", "multiplier"),
                "multipliers_imag": ("point", "multiplier"), "newton_residuals": ("point", "newton_iteration")}
        self.arrays = {}
        existing = set(g.array_keys()) if mode == "a" else set()
        for name, (shape, dtype) in spec.items():
            if name in existing:
                self.arrays[name] = g[name]
            else:
                self.arrays[name] = g.create_array(name, shape=(0, *shape), chunks=(1, *shape), dtype=dtype,
                                                   dimension_names=dims.get(name, ("point",)), overwrite=True)
        if mode == "w":
            g.attrs.update({**attrs, "complete": False, "n_points": 0, "events": [], "stop_reason": None})
        consolidate(self.path)

    @property
    def n_points(self) -> int:
        return int(self.arrays["K"].shape[0])

    def append(self, point: BranchPoint) -> None:
        n = self.n_points
        values = {name: getattr(point, name) for name in self.SCALARS}
        values["stable"] = int(point.stable)
        values["state"] = point.state
        values["multipliers_real"] = point.multipliers.real
        values["multipliers_imag"] = point.multipliers.imag
        hist = np.full(self.max_newton + 1, np.nan)
        h = np.asarray(point.residual_history)[: self.max_newton + 1]
        hist[: len(h)] = h
        values["newton_residuals"] = hist
        for name, arr in self.arrays.items():
            arr.resize((n + 1, *arr.shape[1:]))
            arr[n] = values[name]
        self.group.attrs.update({"n_points": n + 1})
        consolidate(self.path)

    def finish(self, branch: Branch) -> None:
        self.group.attrs.update({"complete": True, "stop_reason": branch.stop_reason, "message": branch.message,
                                 "events": jsonable(branch.events)})
        consolidate(self.path)




def load_branch(path, group: str) -> tuple[ChainParams, list, dict]:
    """Read a stored branch: (params, points, group attributes)."""
    import zarr

    root = zarr.open_group(str(path), mode="r", zarr_format=3, use_consolidated=False)
    p = dict(root.attrs)["params"]
    params = ChainParams(**p)
    g = root[group]
    a = {name: arr[...] for name, arr in g.arrays()}
    points = []
    for i in range(len(a["K"])):
        hist = a["newton_residuals"][i]
        pr = params.replace(K=float(a["K"][i]))
        points.append(BranchPoint(
            K=float(a["K"][i]), omega=float(a["omega"][i]), state=a["state"][i], energy=float(a["energy"][i]),
            iterations=int(a["iterations"][i]), residual_history=tuple(hist[np.isfinite(hist)]),
            multipliers=a["multipliers_real"][i] + 1j * a["multipliers_imag"][i],
            max_modulus=float(a["max_modulus"][i]), pairing_error=float(a["pairing_error"][i]),
            stable=bool(a["stable"][i]), min_contact=float(a["min_contact"][i]),
            harmonics_in_bands=tuple(frequency_report(pr, float(a["omega"][i]))["harmonics_in_bands"])))
    return params, points, dict(g.attrs)


# ----------------------------------------------------------------------------- shared loop pieces


def _bisect_stability(solve_at, a: float, b: float, stable_a: bool, steps: int, log):
    """Locate a change of the stability verdict between parameters a and b by bisection; solve_at(p)
    returns a BranchPoint (or None if Newton fails there)."""
    lo, hi, trials = a, b, []
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        point = solve_at(mid)
        if point is None:
            break
        trials.append({"parameter": mid, "max_modulus": point.max_modulus, "stable": point.stable})
        if point.stable == stable_a:
            lo = mid
        else:
            hi = mid
    if log:
        log(f"stability change located in [{lo:.8g}, {hi:.8g}] after {len(trials)} bisection steps")
    return {"type": "stability_change", "from_stable": stable_a, "bracket": [a, b], "located": [lo, hi],
            "trials": trials}


def _events_between(prev: BranchPoint, point: BranchPoint, parameter: str, solve_at, bisection_steps, log):
    events = []
    if prev.stable != point.stable:
        a, b = getattr(prev, parameter), getattr(point, parameter)
        if bisection_steps:
            events.append(_bisect_stability(solve_at, a, b, prev.stable, bisection_steps, log))
        else:
            events.append({"type": "stability_change", "from_stable": prev.stable, "bracket": [a, b],
                           "located": [a, b], "trials": []})
    new = sorted(set(point.harmonics_in_bands) - set(prev.harmonics_in_bands))
    if new:
        events.append({"type": "harmonic_in_band", "harmonics": new, "at": getattr(point, parameter),
                       "message": f"harmonic(s) {new} of w_b = {point.omega:.6g} entered a phonon band at "
                                  f"{parameter} = {getattr(point, parameter):.6g}"})
        if log:
            log(events[-1]["message"])
    return events


def _contact_event(prev, point, parameter):
    a, b = getattr(prev, parameter), getattr(point, parameter)
    ca, cb = prev.min_contact, point.min_contact
    at = a + (b - a) * ca / (ca - cb) if ca != cb else b
    return {"type": "contact_lost", "bracket": [a, b], "estimate": at,
            "message": f"contact lost between {parameter} = {a:.6g} and {b:.6g} (interpolated {at:.6g})"}


def _finish(points, reason, message, events, start, store, bar) -> Branch:
    """Close the progress bar, build the Branch with its stated stop reason, mark the store complete."""
    if bar:
        bar.close()
    branch = Branch(points, reason, STOP_REASONS[reason] + (f": {message}" if message else ""), events,
                    time.perf_counter() - start)
    if store:
        store.finish(branch)
    return branch


def _progress(total, desc, enabled):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, leave=False, bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} [{elapsed}]")


# ----------------------------------------------------------------------------- continuation in K


def continue_in_coupling(params: ChainParams, omega: float, seed, K_end: float, *, targets=(), log_spacing=True,
                         step: float = 0.15, min_step: float = 1e-3, max_step: float = 0.3, max_points: int = 400,
                         method: str = DEFAULT_METHOD, steps_per_period: int = DEFAULT_STEPS_PER_PERIOD,
                         tol: float = 1e-10, max_newton: int = 8, bisection_steps: int = 4, device=None,
                         store: BranchStore | None = None, resume: list | None = None, progress: bool = False,
                         log=None) -> Branch:
    """Natural-parameter continuation in K at fixed omega, from ``params.K`` to ``K_end``.

    Args:
        seed: state (4, N) near the solution at params.K (e.g. the anti-continuum seed).
        targets: K values the branch must land on exactly (e.g. profiles wanted at K = 5, 20).
        log_spacing: steps (``step``, ``min_step``, ``max_step``) are in log10 K, else in K.
        resume: points of a stored branch to continue from (the last two seed the predictor).
    """
    start = time.perf_counter()
    n_half, _ = time_grid(omega, None, steps_per_period)
    coord = (lambda K: math.log10(K)) if log_spacing else (lambda K: K)
    inv = (lambda s: 10.0 ** s) if log_spacing else (lambda s: s)
    direction = 1.0 if K_end >= params.K else -1.0
    targets = sorted({float(t) for t in targets if (t - params.K) * direction > 0 and (K_end - t) * direction > 0}
                     | {float(K_end)}, reverse=direction < 0)

    def solve(K, guess, max_iter=max_newton):
        pr = params.replace(K=K)
        res = find_breather(pr, omega, guess, method=method, steps_per_period=steps_per_period, tol=tol,
                            max_iterations=max_iter, device=device)
        if not res.success:
            return None, res
        return analyse_point(pr, omega, res.state, n_half, method, device, res.iterations, res.residual_history), res

    events, points = [], list(resume or [])
    if not points:
        first, res = solve(params.K, seed, max_iter=3 * max_newton)
        if first is None:
            return Branch([], "start_failed", f"{STOP_REASONS['start_failed']}: {res.message}", [], 0.0)
        points.append(first)
        if store:
            store.append(first)
    bar = _progress(abs(coord(K_end) - coord(points[0].K)), f"K-continuation w_b={omega}", progress)
    reason, message = "reached_end", ""
    while True:
        last = points[-1]
        if log:
            log(f"K = {last.K:.6g}: E = {last.energy:.8f}, max|l| = {last.max_modulus:.8f}, "
                f"{'stable' if last.stable else 'unstable'}, newton {last.iterations}, step {step:.3g}")
        if bar:
            bar.n = abs(coord(last.K) - coord(points[0].K))
            bar.refresh()
        if abs(last.K - K_end) <= 1e-12 * max(1.0, abs(K_end)):
            break
        if last.min_contact <= 0:
            reason, message = "contact_lost", _contact_event(points[-2], last, "K")["message"] if len(points) > 1 else ""
            break
        if len(points) >= max_points:
            reason = "max_points"
            break
        s_last = coord(last.K)
        target = next(t for t in targets if (t - last.K) * direction > 1e-12 * max(1.0, abs(t)))
        s_new = s_last + direction * step
        if (coord(target) - s_new) * direction <= 0:
            s_new = coord(target)
        K_new = target if s_new == coord(target) else inv(s_new)
        if len(points) >= 2:  # secant predictor in the continuation coordinate
            s_prev = coord(points[-2].K)
            guess = last.state + (last.state - points[-2].state) * (s_new - s_last) / (s_last - s_prev)
        else:
            guess = last.state
        point, res = solve(K_new, guess)
        if point is None:
            step *= 0.5
            if log:
                log(f"K = {K_new:.6g}: {res.status.value}; step halved to {step:.3g}")
            if step < min_step:
                reason, message = "step_underflow", res.message
                break
            continue
        solve_at = lambda K, a=last: solve(K, a.state)[0]  # noqa: E731
        events += _events_between(last, point, "K", solve_at, bisection_steps, log)
        points.append(point)
        if store:
            store.append(point)
        if point.iterations <= 3:
            step = min(step * 1.5, max_step)
    return _finish(points, reason, message, events, start, store, bar)


# ----------------------------------------------------------------------------- continuation in frequency


class _ArclengthCorrector:
    """Newton on [R(q, w); <tau, y - y_pred>_W] for y = (q, w) at fixed K (q: positions, 2N)."""

    def __init__(self, params, method, n_half, W, device, tol, max_newton, delta=1e-6):
        self.params, self.method, self.n_half, self.W, self.device = params, method, n_half, W, device
        self.tol, self.max_newton, self.delta = tol, max_newton, delta

    def period_map(self, omega):
        return _PeriodMap(self.params, omega, "reversible", self.method, self.n_half, math.pi / omega / self.n_half,
                          "tangent", 0.0, self.device, None)

    def correct(self, y_pred, tau):
        W, N2, delta = self.W, 2 * self.params.N, self.delta

        def residual(yy):
            r = self.period_map(yy[-1]).residual(yy[:-1])
            return np.append(r, np.sum(W * tau * (yy - y_pred)))

        def residual_and_jacobian(yy):
            q, omega = yy[:-1], yy[-1]
            r, J, _ = self.period_map(omega).residual_and_jacobian(q)
            dr = (self.period_map(omega + delta).residual(q) - self.period_map(omega - delta).residual(q)) / (2 * delta)
            Jfull = np.zeros((N2 + 1, N2 + 1))
            Jfull[:N2, :N2] = J
            Jfull[:N2, -1] = dr
            Jfull[-1] = W * tau
            return np.append(r, np.sum(W * tau * (yy - y_pred))), Jfull

        return newton(y_pred, residual_and_jacobian, residual, tol=self.tol, max_iterations=self.max_newton)


def _weights(params, theta):
    edges = band_edges(params.M, params.K)
    theta = (1.0 / edges["gap_width"]) if theta is None else theta
    return np.concatenate([np.ones(2 * params.N), [theta ** 2]])


def _state_of(params, y):
    state = np.zeros((4, params.N))
    state[:2] = y[:-1].reshape(2, params.N)
    return state


def start_from_eigenmode(params: ChainParams, amplitude: float = 0.03, *, method=DEFAULT_METHOD,
                         steps_per_period=DEFAULT_STEPS_PER_PERIOD, theta=None, tol: float = 1e-10, device=None,
                         log=None) -> tuple:
    """Two small-amplitude points of the breather branch that bifurcates from the lowest optical
    eigenmode, with max |u - v| = ``amplitude`` and 2 ``amplitude``.

    Fixed-frequency Newton is nearly singular next to the linear mode (the finite chain's optical
    modes are ~1e-4 apart), so these points come from the arclength corrector itself: the
    constraint fixes the projection on the mode, the frequency is an unknown, and its predictor is
    the single-mode Lindstedt estimate dw / w = (1/24) A^2 sum(phi^4) / sum(phi^2) for z = A phi.

    Returns:
        two ``BranchPoint``-ready tuples (state, omega, iterations, residual history).
    """
    from warpchain import lowest_optical_mode

    w_lin, shape = lowest_optical_mode(params)
    z = shape[0] - shape[1]
    shape = shape / np.max(np.abs(z))
    phi = z / np.max(np.abs(z))
    ratio = np.sum(phi ** 4) / np.sum(phi ** 2)
    W = _weights(params, theta)
    n_half, _ = time_grid(w_lin, None, steps_per_period)
    corrector = _ArclengthCorrector(params, method, n_half, W, device, tol, max_newton=30)
    direction = np.concatenate([shape.ravel(), [0.0]])
    tau = direction / math.sqrt(np.sum(W * direction * direction))
    out = []
    for A in (amplitude, 2.0 * amplitude):
        y_pred = np.concatenate([A * shape.ravel(), [w_lin * (1.0 - A * A * ratio / 24.0)]])
        res = corrector.correct(y_pred, tau)
        if log:
            log(f"start at mode amplitude {A:g}: w = {res.unknowns[-1]:.8f}, {res.status.value} in "
                f"{res.iterations} iterations (residual {res.history[-1]:.2e})")
        if res.status is not ShootingStatus.CONVERGED:
            raise RuntimeError(f"could not start the frequency branch from the eigenmode at amplitude {A}: "
                               f"{res.message}")
        out.append((_state_of(params, res.unknowns), float(res.unknowns[-1]), res.iterations, res.history))
    return tuple(out)


def continue_in_frequency(params: ChainParams, start_points, *, method: str = DEFAULT_METHOD,
                          steps_per_period: int = DEFAULT_STEPS_PER_PERIOD, omega_min: float = 0.5, ds: float = 0.05,
                          min_ds: float = 1e-4, max_ds: float = 0.6, max_points: int = 400, theta: float | None = None,
                          tol: float = 1e-10, max_newton: int = 8, bisection_steps: int = 3, device=None,
                          store: BranchStore | None = None, resume: list | None = None, progress: bool = False,
                          max_seconds: float | None = None, log=None) -> Branch:
    """Pseudo-arclength continuation in (q, w_b) at fixed K from two solutions (which set the
    direction; e.g. ``start_from_eigenmode``), until contact is lost, w_b < omega_min, or a failure.

    Args:
        start_points: two (state, omega, iterations, residual history) tuples.
        ds: initial arclength step in the weighted norm (theta defaults to 1 / gap width).
        resume: stored points to continue from (the last two set the secant); start_points unused.
    """
    start = time.perf_counter()
    edges = band_edges(params.M, params.K)
    W = _weights(params, theta)
    n_half = math.ceil(int(steps_per_period) / 2)
    corrector = _ArclengthCorrector(params, method, n_half, W, device, tol, max_newton)

    def pack(state, omega):
        return np.concatenate([state[:2].ravel(), [omega]])

    def solve_fixed(omega, guess_state):
        res = find_breather(params, omega, guess_state, method=method, steps_per_period=steps_per_period, tol=tol,
                            max_iterations=max_newton, device=device)
        if not res.success:
            return None
        return analyse_point(params, omega, res.state, n_half, method, device, res.iterations, res.residual_history)

    events = []
    if resume:
        points = list(resume)
    else:
        points = [analyse_point(params, w, x, n_half, method, device, it, hist) for x, w, it, hist in start_points]
        if store:
            for p in points:
                store.append(p)
    y = [pack(p.state, p.omega) for p in points]
    reason, message = "left_range", ""
    bar = _progress(points[-1].omega - omega_min, "frequency continuation", progress)
    while True:
        last = points[-1]
        if log:
            log(f"w = {last.omega:.7f}: E = {last.energy:.8f}, max|l| = {last.max_modulus:.8f}, "
                f"min contact {last.min_contact:.4f}, newton {last.iterations}, ds {ds:.3g}")
        if bar:
            bar.n = points[0].omega - last.omega
            bar.refresh()
        if last.min_contact <= 0:
            ev = _contact_event(points[-2], last, "omega")
            events.append(ev)
            reason, message = "contact_lost", ev["message"]
            break
        if last.omega < omega_min or last.omega > edges["optical_bottom"] + 0.5 * edges["gap_width"]:
            reason, message = "left_range", f"w_b = {last.omega:.6g} outside [{omega_min}, optical band]"
            break
        if len(points) >= max_points:
            reason = "max_points"
            break
        if max_seconds is not None and time.perf_counter() - start > max_seconds:
            recent = points[-10:]
            reason = "time_budget"
            message = (f"stopped after {max_seconds:g} s at w_b = {last.omega:.6g} "
                       f"({frequency_report(params, last.omega)['location']}), min contact {last.min_contact:.3f}, "
                       f"E = {last.energy:.4g}; over the last {len(recent)} points w_b moved by "
                       f"{recent[0].omega - last.omega:.2e} while E grew by {last.energy - recent[0].energy:.3g}")
            if last.omega <= edges["acoustic_top"]:
                message += (": inside the acoustic band the branch follows resonances with the finite chain's "
                            "phonon modes, energy flowing into oscillating tails at nearly fixed frequency")
            break
        d = y[-1] - y[-2]
        tau = d / math.sqrt(np.sum(W * d * d))
        y_pred = y[-1] + ds * tau

        out = corrector.correct(y_pred, tau)
        if out.status is not ShootingStatus.CONVERGED:
            ds *= 0.5
            if log:
                log(f"arclength step failed ({out.status.value}: {out.message}); ds halved to {ds:.3g}")
            if ds < min_ds:
                reason = "step_underflow"
                message = (f"{out.message} near w_b = {last.omega:.6g} "
                           f"({frequency_report(params, last.omega)['location']})")
                break
            continue
        step_taken = out.unknowns - y[-1]
        if np.sum(W * step_taken * d) <= 0:
            # the corrector landed behind the last point (backtracking, typical next to a resonance):
            # not progress along the branch, so retry with a shorter step
            ds *= 0.5
            if log:
                log(f"corrector went backwards along the branch; ds halved to {ds:.3g}")
            if ds < min_ds:
                reason = "step_underflow"
                message = f"the corrector kept turning back near w_b = {last.omega:.6g}"
                break
            continue
        omega_new = float(out.unknowns[-1])
        state = _state_of(params, out.unknowns)
        point = analyse_point(params, omega_new, state, n_half, method, device, out.iterations, out.history)
        solve_at = lambda w, a=last: solve_fixed(w, a.state)  # noqa: E731
        events += _events_between(last, point, "omega", solve_at, bisection_steps, log)
        points.append(point)
        y.append(out.unknowns)
        if store:
            store.append(point)
        if out.iterations <= 3:
            ds = min(ds * 1.3, max_ds)
    return _finish(points, reason, message, events, start, store, bar)
