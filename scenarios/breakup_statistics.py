"""Breakup statistics: does a large impulsive spot filament into breathers, and how much loss does it survive?

Command: ``python -m scenarios run breakup-statistics`` (default CPU grid, 3 000 lattices of 201 sites x
200 periods: about 3 min on a 2-core CPU; ``--quick`` about 20 s). On GPUs the full grid (about 1e5
lattices): ``--set grid=full``; through Dask ``--set workers=2 --set gpus=2`` (a local cluster, one
worker per GPU) or ``--set scheduler=tcp://HOST:8786`` (a running cluster). An interrupted sweep resumes
when the same command is run again (``--set fresh=true`` starts over).

The paper's Fig. 9c: a long-wave excitation at high amplitude self-localizes and breaks up into many
small moving breathers, proposed as the way to see breathers in experiments (excite a large spot
impulsively, watch it filament), with the warning that losses may decide whether it works. Here each
lattice starts with the substrate at rest in place and a Gaussian velocity impulse (or, ``impulse =
displacement``, a displacement) of amplitude A and width W sites at the centre, the spheres at rest,
times (1 + ``noise`` xi_j) with xi_j standard normal from ``np.random.default_rng((seed, r))`` for
realisation r (the same draw at every A, W and damping: paired comparisons). Losses (``warpchain.losses``):
contact damping gamma_c (a resonator rings down as exp(-gamma_c t / 2), Q = w_0 / gamma_c) and
substrate damping gamma_s (u' decays at gamma_s: radiation into the bulk).

Observables are reduced on the device (``warpchain.observe``) once per period: peaks of the
period's |z| envelope above ``threshold`` (a peak is the largest value within ``radius`` sites),
participation ratio, energy inside |j - c| <= W, max envelope, min contact, energy. A lattice has
*broken up* when the median of its peak count over the last ``final_frames`` periods is >= 2; that
median is its number of breathers. Time to breakup: the first period that starts ``persist_frames``
periods in a row with two peaks or more. Positions, amplitudes and drift velocities of the final
peaks come from the envelope profiles ``velocity_lag`` periods apart (each final peak matched with
the mutually nearest peak within ``max_speed`` x the lag). Breakup probabilities carry 95 % Wilson
score intervals. These reductions are in ``_breakup_measures``.

Theory compared: a wide packet z = a cos(w_0 t) at the optical band edge obeys the focusing NLS
2 i w_0 A_T = D A_XX + G |A|^2 A (``continuation.seeds.nls_coefficients``, X = j / sqrt(K), z = 2 Re A
e^{i w_0 t}); its modulational instability grows at most at Gamma = G |A|^2 / (2 w_0) = w_0 a^2 / 24,
at the wavelength 2 pi sqrt(K D / (2 w_0 Gamma)) sites. If MI drives the breakup, Gamma t_breakup is
about constant (the log of the amplitude over the seed noise) as A varies.

Accuracy: Kahan-Li's 6th-order composition (kahan6) with 32 steps per period by default. Near the band
edge the scheme's own dispersion matters: velocity Verlet at 32 steps per period shifts the linear
frequencies by ~(w dt)^2 / 24 = 1.6e-3, a quarter of the nonlinear shift that drives the breakup, and
moved the breakup threshold (at W = 20, A = 0.4: P = 0.88 against 0.50 with kahan8; 16 realisations).
kahan6/32, kahan8/32 and kahan8/64 gave the same probabilities on that test. The scene re-runs the
lossless lattices of one W column with ``check_method`` at ``check_steps_per_period`` (kahan8/64) and
reports how the breakup probability and the mean count change.
Checks recorded in ``summary.json``: zero damping reproduces the direct-simulation engine
(``simulate``) bit for bit on Fig. 9's eigenmode-high state; a damped lattice against DOP853 of the
damped equations; halving the realisations against the error bars.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np

from sweep import SweepSpec, Variable, run_sweep
from warpchain import Record
from warpchain import ChainParams, simulate
from warpchain.losses import Damping, rhs_flat
from warpchain.observe import OBSERVABLES, Observation, observe, peak_tracks
from warpchain.store import FieldWriter, open_store, provenance

from ._breakup_measures import breakup_times, distribution, final_counts, mi_summary, omega0, wilson_interval
from ._common import (
    progress_bars,
    PAPER_K,
    PAPER_M,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    period_envelope,
    pyplot,
    read_summary,
    save_figure,
)
from ._params import Rule, min_steps_per_period, number, param, splitting_methods, stability_dt

GROUP = "observables"
#: the zero-damping check's bound on |observe(damping=0) - simulate| (states of order 1; the GPU's two kernels
#: differ by 1e-15 .. 1e-13, benchmarks/results/h200-2026-11-22c.json): rounding, not a different scheme
ZERO_DAMPING_ROUNDING = 1e-12
#: named grids: (A values, W values, damping cases (gamma_c, gamma_s), realisations)
GRIDS = {
    "quick": ((0.3, 0.45, 0.6), (5.0, 40.0), ((0.0, 0.0), (1e-3, 0.0)), 4),
    "cpu": (
        (0.1, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6),
        (5.0, 10.0, 20.0, 40.0),
        ((0.0, 0.0), (1e-4, 0.0), (1e-3, 0.0), (1e-2, 0.0), (0.0, 1e-2)),
        16,
    ),
    "full": (
        (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6),
        (5.0, 10.0, 15.0, 20.0, 30.0, 40.0),
        ((0.0, 0.0), (1e-4, 0.0), (1e-3, 0.0), (1e-2, 0.0), (0.0, 1e-2)),
        304,
    ),
}


def _stable_steps(method: str) -> int:
    """The fewest steps per period T = 2 pi / 1.01 below the method's linear stability limit on the chain."""
    return min_steps_per_period(method, PAPER_M, PAPER_K, PAPER_OMEGA)


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    grid: str = param(
        "cpu",
        "named grid of A, W, damping and realisations: quick is --quick's; cpu, the default, 8 A x 4 W x 5 damping x "
        "16 = 2 560 lattices; full, for GPUs, 100 320",
        choices=GRIDS,
    )
    realisations: int = param(0, "realisations per cell; 0: the grid's own count", ge=0, le=10_000_000)
    periods: int = param(200, "periods of T = 2 pi / 1.01 simulated, as Fig. 9", ge=1, le=100_000)
    steps_per_period: int = param(32, "integrator steps per period", ge=1, le=65536)
    method: str = param(
        "kahan6",
        "integrator, a splitting method as observe runs: kahan6 is Kahan-Li order 6, 9 force evaluations per step",
        choices=splitting_methods,
    )
    impulse: str = param(
        "velocity",
        "what the Gaussian impulse sets: the substrate's velocity or displacement",
        choices=("velocity", "displacement"),
    )
    noise: float = param(0.02, "relative per-site perturbation of the impulse", ge=0, le=1)
    seed: int = param(
        20261122, "seed of the noise: realisation r draws from numpy's default_rng of [seed, r]", ge=0, le=2**63 - 1
    )
    threshold: float = param(0.1, "envelope |z| above which a peak counts as a breather", gt=0)
    radius: int = param(
        10, "a peak is the largest envelope within this many sites, and localized within them", ge=1, lt=PAPER_N
    )
    contrast: float = param(0.5, "localized: the envelope falls to this fraction of the peak on both sides", gt=0, le=1)
    final_frames: int = param(10, "periods over which the final count is a median", ge=1, le=10_000)
    persist_frames: int = param(
        3, "time to breakup: the first of this many periods in a row with >= 2 peaks", ge=1, le=10_000
    )
    velocity_lag: int = param(
        4, "periods between the envelope profiles that give the drift velocities", ge=1, le=10_000
    )
    max_speed: float = param(0.25, "sites per unit time: the farthest a peak is matched over the lag", gt=0)
    max_peaks: int = param(24, "peaks stored per lattice at the end", ge=1, le=10_000)
    check_method: str = param(
        "kahan8", "integrator of the accuracy re-run of one lossless W column", choices=splitting_methods
    )
    check_steps_per_period: int = param(64, "steps per period of that re-run", ge=1, le=65536)
    fields: bool = param(True, "store the full fields of two representative lattices")
    checks: bool = param(True, "run the accuracy checks: zero damping, DOP853, the step")
    mi_min_width: float = param(
        20.0, "spots at least this wide, in sites, are compared with the MI rate of a wide packet", ge=0
    )
    workers: int = param(0, "a local Dask cluster of this many workers; 0: none", ge=0, le=1024)
    scheduler: str = param("", "address of a running Dask scheduler, e.g. tcp://HOST:8786; empty: none")
    gpus: int = param(0, "GPUs the workers share, cuda:k for worker k mod gpus; 0 with a CUDA device: 1", ge=0, le=64)
    fresh: bool = param(False, "start the sweep over instead of resuming it")

    RULES = (
        *(
            Rule((name, "periods"), f"{name} <= periods", lambda P, name=name: getattr(P, name) <= P.periods)
            for name in ("final_frames", "persist_frames", "velocity_lag")
        ),
        Rule(
            ("steps_per_period", "method"),
            lambda P: (
                f"steps_per_period >= {_stable_steps(P.method)}: the step T / steps_per_period below "
                f"{P.method}'s linear stability limit {number(stability_dt(P.method, PAPER_M, PAPER_K))}"
            ),
            lambda P: P.steps_per_period >= _stable_steps(P.method),
        ),
        Rule(
            ("check_steps_per_period", "check_method", "checks"),
            lambda P: (
                f"check_steps_per_period >= {_stable_steps(P.check_method)} with checks on: the step below "
                f"{P.check_method}'s linear stability limit {number(stability_dt(P.check_method, PAPER_M, PAPER_K))}"
            ),
            lambda P: not P.checks or P.check_steps_per_period >= _stable_steps(P.check_method),
        ),
        Rule(
            ("steps_per_period", "fields"),
            "steps_per_period a multiple of 4 with fields on: the fields are stored every quarter period",
            lambda P: not P.fields or P.steps_per_period % 4 == 0,
        ),
        Rule(
            ("workers", "scheduler"),
            "workers = 0 or no scheduler: a local cluster or a running one, not both",
            lambda P: not (P.workers and P.scheduler),
        ),
    )


QUICK = {"grid": "quick", "periods": 80, "final_frames": 5, "check_steps_per_period": 32}


def grid(P: Parameters):
    if P.grid not in GRIDS:
        raise ValueError(f"grid must be one of {sorted(GRIDS)}, got {P.grid!r}")
    A, W, damping, R = GRIDS[P.grid]
    return np.array(A), np.array(W), np.array(damping, dtype=float), P.realisations or R


def initial_states(N: int, A: float, widths, realisations: int, P: Parameters) -> np.ndarray:
    """States (len(widths) * realisations, 4, N): W-major, realisation-minor."""
    j = np.arange(N)
    c = N // 2
    row = 2 if P.impulse == "velocity" else 0
    if P.impulse not in ("velocity", "displacement"):
        raise ValueError(f"impulse must be velocity or displacement, got {P.impulse!r}")
    xi = np.stack([np.random.default_rng((P.seed, r)).standard_normal(N) for r in range(realisations)])
    profiles = A * np.exp(-0.5 * ((j[None, :] - c) / np.asarray(widths, dtype=float)[:, None]) ** 2)  # (W, N)
    x = np.zeros((len(widths), realisations, 4, N))
    x[:, :, row] = profiles[:, None, :] * (1.0 + P.noise * xi[None, :, :])
    return x.reshape(-1, 4, N)


def _task(index: dict, device: str, *, config: dict) -> dict:
    """One (A, damping) task: every W and realisation in one launch; returns the variables' regions."""
    P = Parameters(**config)
    A_values, widths, damping_cases, R = grid(P)
    gc, gs = damping_cases[index["damping"]]
    return observe_batch(P, float(A_values[index["A"]]), widths, R, float(gc), float(gs), device)


def _warm_up(device: str, *, config: dict) -> None:
    """Loads the task's kernels on ``device`` and fills its memory pool: one task's launch (every W and
    realisation, a lossless and a damped case) for 2 periods instead of ``periods``."""
    P = dataclasses.replace(Parameters(**config), periods=2)
    A_values, widths, damping_cases, R = grid(P)
    for gc, gs in {(0.0, 0.0), tuple(damping_cases[-1])}:
        observe_batch(P, float(A_values[0]), widths, R, float(gc), float(gs), device)


def observe_batch(P: Parameters, A: float, widths, R: int, gc: float, gs: float, device: str) -> dict:
    """Every W (of ``widths``) and realisation of one (A, damping) in one ``observe`` launch; arrays shaped
    (W, realisation, ...) for the sweep's variables."""
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    widths = np.asarray(widths, dtype=float)
    x0 = initial_states(params.N, A, widths, R, P)
    T = 2 * np.pi / PAPER_OMEGA
    observation = Observation(
        frame_every=P.steps_per_period,
        threshold=P.threshold,
        radius=P.radius,
        contrast=P.contrast,
        spot=np.repeat(widths, R),
        lag_frames=P.velocity_lag,
    )
    run = observe(
        params,
        x0,
        P.periods * T,
        T / P.steps_per_period,
        observation=observation,
        method=P.method,
        damping=Damping(gc, gs),
        device=device,
    )
    shape = (len(widths), R)
    out = {name: run[name].T.reshape(*shape, -1) for name in OBSERVABLES}
    tracks = peak_tracks(
        run.envelope_lag, run.envelope, run.t[-1] - run.t_lag, observation, P.max_speed, max_peaks=P.max_peaks
    )
    for name, values in zip(("peak_position", "peak_amplitude", "peak_velocity"), tracks):
        out[name] = values.reshape(*shape, P.max_peaks)
    out["contact_loss_time"] = run.first_contact_loss().reshape(shape)
    return out


#: parameters that change how the sweep runs or what is made of the store, not what it holds: a stored sweep
#: resumes whatever they are (the others must match, or the runner refuses the store)
NOT_IN_THE_STORE = {
    "workers",
    "scheduler",
    "gpus",
    "fresh",
    "checks",
    "fields",
    "check_method",
    "check_steps_per_period",
    "mi_min_width",
    "persist_frames",
    "final_frames",
}


def sweep_spec(P: Parameters) -> SweepSpec:
    A, W, damping, R = grid(P)
    frames = P.periods + 1
    per_frame = ("A", "damping", "W", "realisation", "frame")
    per_peak = ("A", "damping", "W", "realisation", "peak")
    variables = {name: Variable(per_frame) for name in OBSERVABLES}
    variables.update({name: Variable(per_peak) for name in ("peak_position", "peak_amplitude", "peak_velocity")})
    variables["contact_loss_time"] = Variable(("A", "damping", "W", "realisation"))
    coords = {
        "A": A,
        "damping": np.arange(len(damping)),
        "W": W,
        "realisation": np.arange(R),
        "frame": np.arange(frames),
        "peak": np.arange(P.max_peaks),
    }
    keep = {k: v for k, v in dataclasses.asdict(P).items() if k not in NOT_IN_THE_STORE}
    attrs = {
        "parameters": keep,
        "damping_rates": damping.tolist(),
        "period": 2 * np.pi / PAPER_OMEGA,
        "seed_rule": "realisation r: xi = np.random.default_rng((seed, r)).standard_normal(N)",
        "observables": list(OBSERVABLES),
    }
    return SweepSpec(group=GROUP, coords=coords, task_dims=("A", "damping"), variables=variables, attrs=attrs)


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    start = time.perf_counter()
    A, W, damping, R = grid(P)
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    T = 2 * np.pi / PAPER_OMEGA
    store = ctx.out / "data.zarr"
    if P.fresh and store.exists():  # (a resumed sweep with other parameters is refused by the runner)
        import shutil

        shutil.rmtree(store)
    if not store.exists():
        open_store(store, params=params.as_dict(), provenance_info=provenance(ctx.device))
    gpus = P.gpus or (1 if ctx.device != "cpu" else 0)
    n_lattices = len(A) * len(W) * len(damping) * R
    ctx.log(
        "%d lattices (A %d x W %d x damping %d x %d realisations) x %d periods, %s with %d steps per period",
        n_lattices,
        len(A),
        len(W),
        len(damping),
        R,
        P.periods,
        P.method,
        P.steps_per_period,
    )
    spec = sweep_spec(P)
    task = functools.partial(_task, config=dataclasses.asdict(P))
    report = run_sweep(
        store,
        spec,
        task,
        warm_up=functools.partial(_warm_up, config=dataclasses.asdict(P)),
        workers=P.workers,
        scheduler=P.scheduler or None,
        gpus=gpus if ctx.device != "cpu" else 0,
        processes=ctx.device == "cpu",  # GPU tasks: local workers as threads (sweep.run_sweep)
        progress=progress_bars(),
        log=ctx.log,
    )
    sweep_seconds = report.wall_seconds
    ctx.log("sweep: %d tasks ran, %d skipped, %.1f s (%s)", report.ran, report.skipped, sweep_seconds, report.mode)

    import xarray as xr

    ds = xr.open_zarr(store, group=GROUP)
    peaks = ds["peaks"].values  # (A, damping, W, realisation, frame)
    t = np.arange(peaks.shape[-1]) * T
    count = final_counts(peaks, P.final_frames)  # (A, damping, W, R)
    broken = count >= 2
    prob = broken.mean(axis=-1)
    half = broken[..., : max(1, R // 2)].mean(axis=-1)
    lo, hi = wilson_interval(prob, R)
    t_break = np.where(broken, breakup_times(peaks, t, P.persist_frames), np.nan)  # lattices that broke up
    a_initial = ds["max_envelope"].values[..., 1]  # the first period's envelope: the packet's amplitude a
    gamma = omega0() * a_initial**2 / 24.0
    product = gamma * t_break  # (A, damping, W, R)
    lossless = 0
    wide = W >= P.mi_min_width
    mi = mi_summary(A, W[wide], product[:, lossless, wide], t_break[:, lossless, wide], a_initial[:, lossless, wide])
    mi["widths"] = W[wide].tolist()
    amplitudes = ds["peak_amplitude"].values
    velocities = ds["peak_velocity"].values
    rates = damping.tolist()
    survive = {}
    for d, (gc, gs) in enumerate(rates):
        survive[f"gamma_c={gc:g}, gamma_s={gs:g}"] = {
            "breakup_probability_by_A": prob[:, d].mean(axis=-1).tolist(),
            "mean_breathers_by_A": count[:, d].mean(axis=(-1, -2)).tolist(),
        }
    threshold_A = {}
    for d, (gc, gs) in enumerate(rates):
        for w, width in enumerate(W):
            above = np.flatnonzero(prob[:, d, w] >= 0.5)
            threshold_A[f"d{d}_W{width:g}"] = float(A[above[0]]) if above.size else None
    summary = {
        "grid": {
            "name": P.grid,
            "A": A.tolist(),
            "W": W.tolist(),
            "damping_rates": rates,
            "realisations": R,
            "lattices": n_lattices,
            "periods": P.periods,
            "period": T,
        },
        "parameters": dataclasses.asdict(P),
        "seeds": {"seed": P.seed, "rule": spec.attrs["seed_rule"]},
        "sweep": {
            "mode": report.mode,
            "workers": report.workers,
            "ran": report.ran,
            "skipped": report.skipped,
            "wall_seconds": sweep_seconds,
            "start_seconds": report.start_seconds,  # cluster start and warm-up, inside wall_seconds
            "idle_seconds": report.idle_seconds,  # per worker: no task of its running (timing, not science)
            "lattice_periods_per_second": (n_lattices * P.periods / sweep_seconds)
            if report.ran == report.tasks
            else None,
            "task_seconds_median": float(np.median(report.task_seconds)) if report.task_seconds else None,
        },
        "breakup_probability": prob.tolist(),  # (A, damping, W)
        "breakup_interval_95": [lo.tolist(), hi.tolist()],  # Wilson, each (A, damping, W)
        "mean_breathers": count.mean(axis=-1).tolist(),  # (A, damping, W)
        "breakup_threshold_A": threshold_A,
        "realisation_halving": {  # the first half of the realisations against all of them, per cell
            "max_change": float(np.max(np.abs(half - prob))),
            "cells_within_interval": float(np.mean((half >= lo - 1e-12) & (half <= hi + 1e-12))),
            "interval": "95 % Wilson score interval of the estimate with all realisations",
        },
        "loss_survival": survive,
        "modulational_instability": mi,
        "amplitudes": distribution(amplitudes[:, lossless]),
        "velocities": distribution(np.abs(velocities[:, lossless])),
        "contact_lost_fraction": float(np.isfinite(ds["contact_loss_time"].values).mean()),
    }
    if P.checks:
        summary["checks"] = _checks(ctx, P, params, count, prob, (lo, hi))
    if P.fields:
        summary["fields"] = _fields(ctx, P, params, store)
    summary["wall_seconds"] = time.perf_counter() - start
    ctx.log(
        "breakup (no losses): P = %s over A (W-averaged); wide spots: Gamma t_breakup median %.2f (IQR %.2f)",
        np.round(prob[:, 0].mean(axis=-1), 2).tolist(),
        mi["gamma_t_median"] if mi["gamma_t_median"] is not None else float("nan"),
        mi["gamma_t_iqr"] if mi["gamma_t_iqr"] is not None else float("nan"),
    )
    return summary


def _checks(ctx, P: Parameters, params, count, prob, interval) -> dict:
    """Zero damping = the direct-simulation engine; a damped lattice against DOP853; the step check."""
    from .direct_simulation import initial_conditions
    from ._common import paper_breather

    T = 2 * np.pi / PAPER_OMEGA
    out = {}
    # (1) zero damping reproduces Fig. 9's eigenmode-high run of simulate() (kahan8, the breather's step)
    b = paper_breather(ctx.device, log=lambda m: ctx.log(m))
    high = initial_conditions(params, b.state)["eigenmode-high"]
    periods = 20 if not ctx.quick else 4
    steps = 2 * b.nsteps
    obs = observe(
        params,
        high,
        periods * b.period,
        b.period / steps,
        observation=Observation(frame_every=steps, threshold=P.threshold, radius=P.radius, contrast=P.contrast),
        method=b.method,
        damping=(0.0, 0.0),
        device=ctx.device,
    )
    plain = simulate(params, high, obs.t[-1], obs.dt, method=b.method, device=ctx.device)
    # the same arithmetic in two compiled kernels: bit for bit on the CPU (tests/test_losses.py), within rounding on
    # a GPU (8.7e-15 after 640 kahan8 steps on an H200), so the verdict is the same on every device
    difference = float(np.max(np.abs(obs.x - plain.x)))
    out["zero_damping_vs_simulate"] = {
        "periods": periods,
        "method": b.method,
        "steps": plain.nsteps,
        "within_rounding": difference <= ZERO_DAMPING_ROUNDING,
        "max_abs_difference": difference,
    }
    ctx.log(
        "zero damping vs simulate (eigenmode-high, %d periods): max difference %.1e",
        periods,
        out["zero_damping_vs_simulate"]["max_abs_difference"],
    )
    # (2) a damped lattice against DOP853 of the damped equations (the strongest contact damping of the grid)
    from scipy.integrate import solve_ivp

    _, W, damping, _ = grid(P)
    gc, gs = max(damping.tolist(), key=lambda r: r[0])
    A_check = 0.3
    x0 = initial_states(params.N, A_check, [W[len(W) // 2]], 1, P)
    t_end = 5 * T
    sol = solve_ivp(rhs_flat(params, None, None, gc, gs), (0, t_end), x0[0].ravel(), "DOP853", rtol=1e-12, atol=1e-14)
    exact = sol.y[:, -1].reshape(4, -1)
    diffs = {}
    for method, spp in ((P.method, P.steps_per_period), ("kahan8", 32), ("kahan8", 64)):
        r = simulate(params, x0, t_end, T / spp, method=method, device=ctx.device, damping=(gc, gs))
        diffs[f"{method}/{spp}"] = float(np.max(np.abs(r.x[0] - exact)) / np.max(np.abs(exact)))
    out["damped_vs_dop853"] = {
        "gamma_c": gc,
        "gamma_s": gs,
        "A": A_check,
        "periods": 5,
        "relative_max_difference": diffs,
    }
    ctx.log("damped lattice vs DOP853 (5 periods, gamma_c %g): %s", gc, diffs)
    # (3) the step: the lossless lattices of one W column re-run with the check method (kahan8: Fig. 9's
    # integrator, 15 force evaluations per step), every A, the same seeds
    A, W, damping, R = grid(P)
    w_check = len(W) // 2
    check = dataclasses.replace(P, method=P.check_method, steps_per_period=P.check_steps_per_period)
    counts = np.empty((len(A), R))
    t0 = time.perf_counter()
    for i in range(len(A)):
        res = observe_batch(check, float(A[i]), [W[w_check]], R, 0.0, 0.0, ctx.device)
        counts[i] = final_counts(res["peaks"][0], P.final_frames)
    p_check = (counts >= 2).mean(axis=-1)
    p_main = prob[:, 0, w_check]
    out["step_check"] = {
        "method": check.method,
        "W": float(W[w_check]),
        "damping": [0.0, 0.0],
        "breakup_probability": p_check.tolist(),
        "max_probability_change": float(np.max(np.abs(p_check - p_main))),
        "max_mean_breathers_change": float(np.max(np.abs(counts.mean(axis=-1) - count[:, 0, w_check].mean(axis=-1)))),
        "within_interval": bool(
            np.all((p_check >= interval[0][:, 0, w_check] - 1e-12) & (p_check <= interval[1][:, 0, w_check] + 1e-12))
        ),
        "seconds": time.perf_counter() - t0,
    }
    ctx.log(
        "step check (%s, W = %g): max change of P %.3f",
        check.method,
        W[w_check],
        out["step_check"]["max_probability_change"],
    )
    return out


def _fields(ctx, P: Parameters, params, store) -> dict:
    """Full fields (u, v every period/4) of two representative lattices: the largest A at a middle W,
    without losses and with the strongest contact damping of the grid."""
    A, W, damping, _ = grid(P)
    T = 2 * np.pi / PAPER_OMEGA
    lossy = int(np.argmax(damping[:, 0]))
    cases = {"lossless": (0, 0.0, 0.0), "damped": (lossy, *damping[lossy])}
    w = len(W) // 2
    x0 = initial_states(params.N, float(A[-1]), [W[w]], 1, P)
    root_attrs = {}
    for name, (d, gc, gs) in cases.items():
        save_every = P.steps_per_period // 4
        writer = FieldWriter(
            open_store(store, mode="a"),
            store,
            f"fields_{name}",
            {"u": (params.N,), "v": (params.N,)},
            ("t", "site"),
            chunk_t=64,
            expected_frames=P.periods * 4 + 1,
            attrs={"A": float(A[-1]), "W": float(W[w]), "gamma_c": float(gc), "gamma_s": float(gs), "realisation": 0},
        )
        run_ = simulate(
            params,
            x0,
            P.periods * T,
            T / P.steps_per_period,
            method=P.method,
            device=ctx.device,
            damping=(gc, gs),
            record=Record(
                every=save_every, on_chunk=lambda t, u, v, writer=writer: writer.append(t, u=u[:, 0], v=v[:, 0])
            ),
        )
        writer.close(method=run_.method, dt=run_.dt)
        root_attrs[name] = {
            "group": f"fields_{name}",
            "A": float(A[-1]),
            "W": float(W[w]),
            "gamma_c": gc,
            "gamma_s": gs,
        }
    return root_attrs


# ----------------------------------------------------------------------------- figures


def _legend(ax, **kwargs) -> None:
    """A legend where something was drawn with a label (an empty panel gets none)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kwargs)


def plot(out) -> None:
    import xarray as xr

    s = read_summary(out)
    plt = pyplot()
    ds = xr.open_zarr(out / "data.zarr", group=GROUP)
    A, W = np.array(s["grid"]["A"]), np.array(s["grid"]["W"])
    rates = s["grid"]["damping_rates"]
    R = s["grid"]["realisations"]
    prob = np.array(s["breakup_probability"])
    mean = np.array(s["mean_breathers"])
    lossy = int(np.argmax([r[0] for r in rates]))
    moderate = int(np.argsort([r[0] for r in rates])[-2]) if len(rates) > 2 else lossy

    # (1) the (A, W) plane: breakup probability and mean breathers, without and with losses
    shown = [0, moderate, lossy] if moderate != lossy else [0, lossy]
    fig, axes = plt.subplots(2, len(shown), figsize=(4.2 * len(shown), 7), squeeze=False)
    for col, d in enumerate(shown):
        gc, gs = rates[d]
        for row, (data, label, vmax) in enumerate(
            ((prob[:, d], "breakup probability", 1.0), (mean[:, d], "mean number of breathers", max(1.0, mean.max())))
        ):
            ax = axes[row, col]
            im = ax.pcolormesh(np.arange(len(W) + 1), np.arange(len(A) + 1), data, vmin=0, vmax=vmax, cmap="viridis")
            ax.set_xticks(np.arange(len(W)) + 0.5, [f"{w:g}" for w in W])
            ax.set_yticks(np.arange(len(A)) + 0.5, [f"{a:g}" for a in A])
            ax.set_xlabel("spot width W (sites)")
            ax.set_ylabel("impulse amplitude A")
            ax.set_title(f"{label}\n$\\gamma_c$ = {gc:g}, $\\gamma_s$ = {gs:g}", fontsize=9)
            for i in range(len(A)):
                for k in range(len(W)):
                    ax.text(k + 0.5, i + 0.5, f"{data[i, k]:.2g}", ha="center", va="center", fontsize=6, color="w")
            fig.colorbar(im, ax=ax)
    fig.suptitle(
        f"{R} realisations per cell, {s['grid']['periods']} periods; broken up = median of the last "
        f"{s['parameters']['final_frames']} periods' peak counts >= 2",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, out, "breakup_plane")

    # (2) amplitudes and velocities of the final breathers (no losses), and loss survival
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    amp = ds["peak_amplitude"].values[:, 0]
    vel = ds["peak_velocity"].values[:, 0]
    for i in range(len(A))[::2]:
        a = amp[i][np.isfinite(amp[i])]
        if a.size:
            axes[0].hist(a, bins=40, range=(0, float(np.nanmax(amp))), histtype="step", label=f"A = {A[i]:g}")
        v = vel[i][np.isfinite(vel[i])]
        if v.size:
            vmax = s["parameters"]["max_speed"]
            axes[1].hist(v, bins=41, range=(-vmax, vmax), histtype="step", label=f"A = {A[i]:g}")
    axes[0].set_xlabel("final breather amplitude (max |z| over a period)")
    axes[0].set_ylabel("count")
    _legend(axes[0], fontsize=7)
    axes[0].set_title("amplitudes of the final peaks (no losses)", fontsize=9)
    axes[1].set_xlabel(f"drift velocity (sites per unit time, over {s['parameters']['velocity_lag']} periods)")
    axes[1].set_title("drift velocities (no losses)", fontsize=9)
    _legend(axes[1], fontsize=7)
    for d, (gc, gs) in enumerate(rates):
        pooled = prob[:, d].mean(axis=-1)  # every W and realisation of the row: len(W) * R trials
        lo, hi = wilson_interval(pooled, len(W) * R)
        axes[2].errorbar(
            A,
            pooled,
            yerr=[pooled - lo, hi - pooled],
            marker="o",
            ms=3,
            capsize=2,
            label=f"$\\gamma_c$={gc:g}, $\\gamma_s$={gs:g}",
        )
    axes[2].set_xlabel("impulse amplitude A")
    axes[2].set_ylabel("breakup probability (mean over W)")
    axes[2].set_title("how much loss breakup survives (bars: 95 % Wilson)", fontsize=9)
    _legend(axes[2], fontsize=7)
    fig.tight_layout()
    save_figure(fig, out, "breakup_distributions")

    # (3) time to breakup against the modulational-instability rate
    mi = s["modulational_instability"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    peaks = ds["peaks"].values[:, 0]
    T = s["grid"]["period"]
    t = np.arange(peaks.shape[-1]) * T
    persist, final = s["parameters"]["persist_frames"], s["parameters"]["final_frames"]
    t_break = np.where(final_counts(peaks, final) >= 2, breakup_times(peaks, t, persist), np.nan)
    a0 = ds["max_envelope"].values[:, 0, ..., 1]
    gamma = omega0() * a0**2 / 24
    wide_from = s["parameters"]["mi_min_width"]
    for k, width in enumerate(W):
        ok = np.isfinite(t_break[:, k])
        if ok.any():
            narrow = width < wide_from
            style = {"s": 6, "alpha": 0.25 if narrow else 0.5, "marker": "x" if narrow else "o"}
            label = f"W = {width:g}" + (" (narrow: not MI)" if narrow else "")
            axes[0].scatter(a0[:, k][ok], t_break[:, k][ok] / T, label=label, **style)
            axes[1].scatter(a0[:, k][ok], (gamma * t_break)[:, k][ok], label=label, **style)
    if mi["gamma_t_median"] is not None:
        a = np.linspace(np.nanmin(a0), np.nanmax(a0), 100)
        axes[0].plot(
            a,
            mi["gamma_t_median"] / (omega0() * a**2 / 24) / T,
            "k--",
            lw=1,
            label=f"MI: {mi['gamma_t_median']:.1f} / $\\Gamma_{{max}}$ (W >= {wide_from:g}); "
            f"fit: a^{mi['t_breakup_exponent']:.2f}",
        )
        axes[1].axhline(mi["gamma_t_median"], color="k", ls="--", lw=1)
        _legend(axes[1], fontsize=6)
    axes[0].set_xscale("log")
    axes[0].set_yscale("log")
    axes[0].set_xlabel("packet amplitude a (first period's max |z|)")
    axes[0].set_ylabel("time to breakup (periods)")
    _legend(axes[0], fontsize=7)
    axes[0].set_title("time to breakup (no losses)", fontsize=9)
    axes[1].set_xlabel("packet amplitude a")
    axes[1].set_ylabel(r"$\Gamma_{max}\, t_{breakup}$,  $\Gamma_{max} = w_0 a^2 / 24$")
    axes[1].set_title("MI prediction: constant (log of amplitude over seed noise)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, out, "breakup_time")

    # (4) the representative lattices' envelopes
    if "fields" in s:
        from warpchain.store import read_group

        names = list(s["fields"])
        fig, axes = plt.subplots(1, len(names), figsize=(6 * len(names), 4), squeeze=False)
        for ax, name in zip(axes[0], names):
            data, attrs = read_group(out / "data.zarr", s["fields"][name]["group"])
            env = period_envelope(data["v"] - data["u"], 4)  # frames every quarter period
            n_periods = len(env)
            im = ax.imshow(
                env.T,
                aspect="auto",
                origin="lower",
                cmap="magma",
                interpolation="nearest",
                extent=[0, n_periods, data["site"][0], data["site"][-1]],
            )
            fig.colorbar(im, ax=ax, label="max over a period of |v - u|")
            f = s["fields"][name]
            ax.set_title(
                f"A = {f['A']:g}, W = {f['W']:g}, $\\gamma_c$ = {f['gamma_c']:g}, $\\gamma_s$ = {f['gamma_s']:g}",
                fontsize=9,
            )
            ax.set_xlabel("t / T")
            ax.set_ylabel("site j")
        fig.tight_layout()
        save_figure(fig, out, "breakup_fields")
