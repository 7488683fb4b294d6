"""Stability atlas: the (K, w_b) plane of the site breather, one frequency branch per K, over Dask (issue #36;
beyond the paper).

For every K of a log-spaced grid (default 41 values in [1, 160]) the scene walks the frequency branch that
``continuation-omega`` walks at K = 160 (``_continuation_common.frequency_problem``): pseudo-arclength in
(positions, w_b) at M = 30, N = 201, from the lowest optical eigenmode down through the gap until a resonator
loses contact (or w_b < ``omega_min``), every stability change bisected, predicted bubbles solved for and the
narrower ones recorded as foam. Each K is one task of a ``sweep`` sweep: the task walks its branch
and writes it into its own chunks of the store, padded along ``point`` to ``max_points`` (NaN fill).

The first point's mode amplitude is ``eigenmode_amplitude`` (0.03, continuation-omega's) at K = 160, scaled by
sqrt(K / 160) below: the start's Newton (``continuation.branch.start_from_eigenmode``) failed at 0.03 for
K = 1, 4 and 20 at N = 101, and at 0.03 sqrt(K / 160) 201 / N for K <= 7.6 at N = 101, while 0.03 sqrt(K / 160)
started every branch tried at N = 101 and 201 (an empirical rule: smaller amplitudes where the optical band
is narrow). A start that fails anyway is tried again at half the amplitude, up to ``START_TRIES`` times; the
amplitude used is stored per K.

Command: ``python -m scenarios run stability-atlas`` (``--quick``: 6 K values at N = 101, resolution 1e-2; a
2-core CPU takes well under 2 min). Workers: by default a local Dask cluster (``pip install -e ".[dask]"``)
of one single-threaded process per usable core on the CPU device; with ``--device cuda`` ``cuda_workers``
processes (default: half the usable cores, at least one per GPU) spread over the GPUs by worker ordinal (the
branch's Newton LU and Floquet eigs are host work: one process per GPU left the GPUs idle). ``--set
workers=W`` sets the count, ``--set scheduler=tcp://HOST:8786`` uses a running cluster (its workers must see
the output folder), ``--set in_process=true`` runs the tasks one after another in this process. Resume: run
the same command again; only the K values not yet completed run (``--set fresh=true`` starts over).

Figures (drawn from the store): ``stability_atlas``: the phase diagram, each branch a vertical strip at its K
coloured by stability and by the kind of the leading instability, with the stability changes, the folds in
w_b, the branch's end (contact loss, omega_min or a failure) and the foam stretches marked, the linear
lattice's band edges as curves; the right panel draws the distance below the optical band edge on a log
axis, where the stability changes crowd. ``stability_atlas_summary``: per K the end frequency, the stable
share of the branch, the stability changes and folds.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import time

import numpy as np

from continuation.events import StopReason, stability_signature
from continuation.floquet import KINDS
from sweep import SweepMismatchError, SweepSpec, Variable, run_sweep
from warpchain import ChainParams, band_edges

from . import continuation_omega
from ._common import Context, Refused, progress_bars, pyplot, read_summary, save_figure
from ._continuation_common import (
    BRANCH_RULES,
    KIND_COLOURS,
    KIND_LABELS,
    BranchParameters,
    frequency_folds,
    frequency_problem,
    step_rule,
)
from ._params import Rule, number, param

#: a rerun of the same command resumes the sweep; ``--resume`` is accepted and does the same
RESUMABLE = True

GROUP = "atlas"
#: the end of a branch, as stored (``end_reason``): StopReason values in this order
END_REASONS = tuple(r.value for r in StopReason)
#: the branch's defaults as continuation-omega has them (the same continuation)
_OMEGA = continuation_omega.Parameters()


@dataclasses.dataclass(frozen=True)
class Parameters(BranchParameters):
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them); steps in arclength, as continuation-omega."""

    K_min: float = param(1.0, "smallest coupling K of the grid", gt=0)
    K_max: float = param(160.0, "largest coupling K of the grid", gt=0)
    n_K: int = param(41, "couplings K, log-spaced from K_min to K_max: one branch (one task) each", ge=1, le=10_000)
    omega_min: float = param(_OMEGA.omega_min, "a floor on w_b; the branches are expected to lose contact first", gt=0)
    eigenmode_amplitude: float = param(
        0.03, "mode amplitude of the first point at K >= 160; below, scaled by sqrt(K / 160)", gt=0
    )
    ds: float = param(_OMEGA.ds, "first step: arclength in the weighted norm, theta = 1 / gap width", gt=0)
    ds_max: float = param(_OMEGA.ds_max, "largest step, arclength", gt=0)
    grow: float = param(_OMEGA.grow, "step growth after an easy Newton solve", ge=1)
    max_points: int = param(
        2000,
        "points stored per branch (the store's point dimension): a branch stops there (end: max_points)",
        ge=2,
        le=1_000_000,
    )
    workers: int = param(
        0,
        "processes of a local Dask cluster; 0: automatic (CPU: one per usable core; GPUs: see cuda_workers)",
        ge=0,
        le=1024,
    )
    cuda_workers: int = param(
        0,
        "processes with --device cuda, spread over the GPUs (at least one per GPU); 0: half the usable cores",
        ge=0,
        le=1024,
    )
    scheduler: str = param("", "address of a running Dask scheduler, e.g. tcp://HOST:8786; empty: none")
    gpus: int = param(
        0, "GPUs the workers use, cuda:k for worker k mod gpus; 0: every GPU Warp sees (CUDA device)", ge=0, le=64
    )
    in_process: bool = param(False, "run the tasks one after another in this process, without Dask")
    fresh: bool = param(False, "start the sweep over instead of resuming it")

    RULES = (
        Rule(("K_min", "K_max", "n_K"), "K_min < K_max, or K_min = K_max with n_K = 1", lambda P: _k_grid_ok(P)),
        Rule(
            ("omega_min", "M"),
            lambda P: (
                f"omega_min < {number(band_edges(P.M, 1.0)['optical_bottom'])}, the optical band bottom of M: every "
                "branch starts at the lowest optical eigenmode and goes down"
            ),
            lambda P: P.omega_min < band_edges(P.M, 1.0)["optical_bottom"],
        ),
        Rule(
            ("workers", "scheduler", "in_process"),
            "at most one of workers > 0, a scheduler and in_process",
            lambda P: sum((P.workers > 0, bool(P.scheduler), P.in_process)) <= 1,
        ),
        *BRANCH_RULES,
        step_rule("omega_min", "K_max"),  # the longest step against the limit: at the largest K, the lowest w_b
    )


QUICK = {"n_K": 6, "N": 101, "resolution": 1e-2, "max_points": 800}


def _k_grid_ok(P) -> bool:
    return P.K_min < P.K_max or (P.K_min == P.K_max and P.n_K == 1)


def k_grid(P: Parameters) -> np.ndarray:
    """The couplings, log-spaced from K_min to K_max."""
    return np.geomspace(P.K_min, P.K_max, P.n_K)


def start_amplitude(P: Parameters, K: float) -> float:
    """The first point's mode amplitude at K (module docstring)."""
    return P.eigenmode_amplitude * min(1.0, math.sqrt(K / 160.0))


# ----------------------------------------------------------------------------- one task: one branch


@contextlib.contextmanager
def _cpu_threads(threads: int | None):
    """WARPCHAIN_CPU_THREADS = ``threads`` inside the block (None: as it is): one per worker process when every
    core runs a worker of its own."""
    if threads is None:
        yield
        return
    before = os.environ.get("WARPCHAIN_CPU_THREADS")
    os.environ["WARPCHAIN_CPU_THREADS"] = str(int(threads))
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("WARPCHAIN_CPU_THREADS", None)
        else:
            os.environ["WARPCHAIN_CPU_THREADS"] = before


#: tries at starting a branch from the eigenmode, the mode amplitude halved after each failure
START_TRIES = 4


def branch_cost(index: dict, *, couplings: tuple) -> float:
    """A branch's expected run time, relative, for handing out the longest first (``run_sweep(cost=...)``). From
    the default grid on an H100 (``benchmarks/results/h100-2026-11-26/64fe2f6.json``, seconds per task): below
    K ~ 1.85 the branch is stable to contact loss in ~15 points (5 s); from there to K ~ 7.2 it crosses the foam
    of finite-size bubbles (350-450 stability changes, 50-80 s); above, 20-40 s, except the few that meet
    ``max_points`` (130-170 s), which no estimate foresees."""
    K = couplings[index["K"]]
    return 0.2 if K < 1.85 else 3.0 if K <= 7.2 else 1.0


def _task(index: dict, device: str, *, config: dict, cpu_threads: int | None = None) -> dict:
    """One K: the frequency branch, walked in memory, as the sweep's variables (padded to max_points)."""
    P = Parameters(**config)
    K = float(k_grid(P)[index["K"]])
    from continuation.driver import continuation

    t0 = time.perf_counter()
    amplitude = start_amplitude(P, K)
    with _cpu_threads(cpu_threads if device == "cpu" else None):
        for _ in range(START_TRIES):
            _, _, settings, problem = frequency_problem(P, device, K=K, eigenmode_amplitude=amplitude)
            branch = continuation(problem, settings, progress=False)
            if branch.points or branch.stop_reason is not StopReason.NEWTON_FAILED:
                break
            amplitude /= 2.0  # the start failed: a smaller first amplitude, nearer the linear mode
    return branch_arrays(branch, P.max_points, amplitude, time.perf_counter() - t0)


def branch_arrays(branch, n: int, amplitude: float, seconds: float) -> dict:
    """The branch as the sweep's variables: per point (padded to ``n``) and per branch."""
    points = branch.points
    m = len(points)
    if m > n:
        raise ValueError(f"the branch has {m} points, more than max_points = {n}")

    def padded(values, fill=np.nan, dtype="float64"):
        out = np.full((n, *np.shape(values)[1:]), fill, dtype=dtype)
        if m:
            out[:m] = values
        return out

    omega = np.array([p.omega for p in points], dtype=float)
    counts = np.array([stability_signature(p) for p in points], dtype=np.int16).reshape(m, len(KINDS))
    lead = [KINDS.index(p.instabilities[0].kind) if p.instabilities else -1 for p in points]
    localized = [int(bool(p.instabilities[0].localized)) if p.instabilities else -1 for p in points]
    foam = np.full(m, np.nan)  # per step i -> i + 1: the predicted unstable fraction of its foam stretch
    stretches = branch.unresolved_bubbles() if m > 1 else []
    for st in stretches:
        ends = np.flatnonzero(omega == st["end"])
        if ends.size:
            j1 = int(ends[-1])  # the stretch's last point; it holds ``points`` points
            foam[max(j1 + 1 - st["points"], 0) : j1] = st["unstable_fraction"]
    # contact: the branch's own event interpolates between the last two points, which after a bisected last step
    # may both lie past the loss; here, between the first point without contact and the one before it
    held = np.array([p.min_contact for p in points], dtype=float) > 0
    kept = int(np.argmin(held)) if m and not held.all() else m  # points before the first without contact
    contact = np.nan
    if 0 < kept < m:
        a, b = points[kept - 1], points[kept]
        contact = a.omega + (b.omega - a.omega) * a.min_contact / (a.min_contact - b.min_contact)
    stats = branch.stats
    return {
        "omega": padded(omega),
        "arclength": padded([p.s for p in points]),
        "energy": padded([p.energy for p in points]),
        "max_modulus_minus_1": padded([p.max_modulus - 1.0 for p in points]),
        "tolerance": padded([p.tolerance for p in points]),
        "stable": padded([-1 if p.stable is None else int(p.stable) for p in points], -1, "int8"),
        "verdict_complete": padded([int(p.complete) for p in points], -1, "int8"),
        "instabilities": padded(counts, -1, "int16"),
        "leading_kind": padded(lead, -1, "int8"),
        "leading_localized": padded(localized, -1, "int8"),
        "min_contact": padded([p.min_contact for p in points]),
        "foam_fraction": padded(foam),
        "end_reason": np.int8(END_REASONS.index(branch.stop_reason.value)),
        "points": np.int32(m),
        "contact_points": np.int32(kept),
        "contact_loss_omega": np.float64(contact),
        "stability_changes": np.int32(len(branch.stability_changes())),
        "foam_stretches": np.int32(len(stretches)),
        "eigenmode_amplitude": np.float64(amplitude),
        "solves": np.int32(stats.get("solves", 0)),
        "seconds": np.float64(seconds),
    }


#: parameters that change how the sweep runs, not what it holds: a stored sweep resumes whatever they are
NOT_IN_THE_STORE = {"workers", "cuda_workers", "scheduler", "gpus", "in_process", "fresh"}


def sweep_spec(P: Parameters) -> SweepSpec:
    per_point = ("K", "point")
    described = {
        "omega": "w_b",
        "arclength": "the continuation coordinate (weighted arclength, theta = 1 / gap width)",
        "energy": "Hamiltonian H",
        "max_modulus_minus_1": "largest nontrivial |Floquet multiplier| - 1",
        "tolerance": "the verdict's tolerance in mu = (l + 1/l) / 2: stable iff every nontrivial mu lies within "
        "it of [-1, 1]; every one of the 2N mu is accounted for where verdict_complete is 1 (dense, or sliced and "
        "counted: the walk takes no other path)",
        "min_contact": "min over the orbit of 1 + u - v",
        "foam_fraction": "the step from this point to the next lies in a foam stretch (bubbles predicted, too "
        "narrow to chase) with this predicted unstable fraction; NaN: none",
    }
    variables = {name: Variable(per_point, attrs={"description": text}) for name, text in described.items()}
    variables["stable"] = Variable(
        per_point, "int8", -1, {"description": "1 stable, 0 unstable, -1 no point or no verdict (verdict_complete 0)"}
    )
    variables["verdict_complete"] = Variable(
        per_point, "int8", -1, {"description": "1: every multiplier accounted for (a verdict); 0: not; -1 no point"}
    )
    variables["instabilities"] = Variable(
        ("K", "point", "kind"), "int16", -1, {"description": "unstable multiplier groups of each kind"}
    )
    variables["leading_kind"] = Variable(
        per_point, "int8", -1, {"description": "index into kind of the leading instability; -1 none", "kinds": KINDS}
    )
    variables["leading_localized"] = Variable(
        per_point, "int8", -1, {"description": "the leading instability's vector is localized (1) or extended (0)"}
    )
    variables["end_reason"] = Variable(
        ("K",), "int8", -1, {"description": "why the branch stopped: index into reasons", "reasons": END_REASONS}
    )
    variables["points"] = Variable(("K",), "int32", -1, {"description": "points of the branch"})
    variables["contact_points"] = Variable(
        ("K",), "int32", -1, {"description": "points before the first without contact (the physical branch)"}
    )
    variables["contact_loss_omega"] = Variable(
        ("K",), attrs={"description": "w_b where contact is lost (interpolated)"}
    )
    variables["stability_changes"] = Variable(("K",), "int32", -1, {"description": "located stability changes"})
    variables["foam_stretches"] = Variable(("K",), "int32", -1, {"description": "stretches of unresolved bubbles"})
    variables["eigenmode_amplitude"] = Variable(("K",), attrs={"description": "mode amplitude of the first point"})
    variables["solves"] = Variable(("K",), "int32", -1, {"description": "Newton solves of the walk"})
    variables["seconds"] = Variable(("K",), attrs={"description": "wall seconds of the task (timing, not science)"})
    coords = {"K": k_grid(P), "point": np.arange(P.max_points), "kind": np.array(KINDS)}
    keep = {k: v for k, v in dataclasses.asdict(P).items() if k not in NOT_IN_THE_STORE}
    attrs = {"parameters": keep, "continuation": "pseudo-arclength in (positions, omega), as continuation-omega"}
    return SweepSpec(group=GROUP, coords=coords, task_dims=("K",), variables=variables, attrs=attrs)


# ----------------------------------------------------------------------------- how the tasks run


def _cuda_count() -> int:
    import warp as wp

    wp.init()
    return int(wp.get_cuda_device_count())


def plan(P: Parameters, device: str, tasks: int) -> dict:
    """How the sweep runs: run_sweep's workers / scheduler / gpus and the CPU threads each task may use."""
    from warpchain.engine.devices import usable_cores

    on_cpu = device == "cpu"
    gpus = 0 if on_cpu else (P.gpus or _cuda_count())
    if P.in_process:
        return {"workers": 0, "scheduler": None, "gpus": gpus, "cpu_threads": None}
    if P.scheduler:
        return {"workers": 0, "scheduler": P.scheduler, "gpus": gpus, "cpu_threads": 1 if on_cpu else None}
    cores = usable_cores()
    if P.workers:
        workers = P.workers
    elif on_cpu:
        workers = cores
    else:
        # the branch's Newton LU and Floquet eigs are host work: half the cores' processes, spread over the GPUs
        workers = max(gpus, P.cuda_workers or max(1, cores // 2))
    workers = max(1, min(workers, tasks))
    try:
        import distributed  # noqa: F401
    except ImportError:
        if P.workers:
            raise
        return {"workers": 0, "scheduler": None, "gpus": gpus, "cpu_threads": None, "no_dask": True}
    return {
        "workers": workers,
        "scheduler": None,
        "gpus": gpus,
        "cpu_threads": max(1, cores // workers) if on_cpu else None,
    }


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    start = time.perf_counter()
    store = ctx.out / "data.zarr"
    spec = sweep_spec(P)
    if P.fresh and store.exists():
        import shutil

        shutil.rmtree(store)
    if not store.exists():
        ctx.store(ChainParams(P.M, P.K_max, P.N))
    how = plan(P, ctx.device, P.n_K)
    if how.pop("no_dask", False):
        ctx.log('dask.distributed is not installed (pip install -e ".[dask]"): the tasks run in this process')
    cpu_threads = how.pop("cpu_threads")
    ctx.log(
        "%d frequency branches, K = %s .. %s (log-spaced), M = %g, N = %d, resolution %g: %s",
        P.n_K,
        number(P.K_min),
        number(P.K_max),
        P.M,
        P.N,
        P.resolution,
        f"scheduler {how['scheduler']}"
        if how["scheduler"]
        else f"a local cluster of {how['workers']} workers"
        if how["workers"]
        else "in this process",
    )
    task = functools.partial(_task, config=dataclasses.asdict(P), cpu_threads=cpu_threads)
    try:
        report = run_sweep(
            store,
            spec,
            task,
            progress=progress_bars(),
            log=ctx.log,
            tasks_per_worker=1,  # a branch keeps its process busy; processes, not threads, run branches at once
            cost=functools.partial(branch_cost, couplings=tuple(float(k) for k in k_grid(P))),
            **how,
        )
    except SweepMismatchError as exc:
        raise Refused(f"{exc} (or --set fresh=true)") from None

    import xarray as xr

    ds = xr.open_zarr(store, group=GROUP).load()  # one read; the rows below index it per K
    summary = {
        "M": P.M,
        "N": P.N,
        "K": [float(k) for k in ds["K"].values],
        "branches": [_branch_summary(ds, i) for i in range(ds.sizes["K"])],
        "sweep": {
            "mode": report.mode,
            "workers": report.workers,
            "ran": report.ran,
            "skipped": report.skipped,
            "wall_seconds": report.wall_seconds,
            "start_seconds": report.start_seconds,
            "idle_seconds": report.idle_seconds,  # per worker: no task of its running (timing, not science)
            "task_seconds_sum": float(sum(report.task_seconds)),
            "task_seconds_max": float(max(report.task_seconds)) if report.task_seconds else None,
        },
    }
    rows = summary["branches"]
    ends = [r["end"] for r in rows]
    summary["ends"] = {reason: ends.count(reason) for reason in END_REASONS if reason in ends}
    summary["all_ended_on_physics"] = all(r["ended_on_physics"] for r in rows)
    summary["stability_changes_total"] = int(sum(r["stability_changes"] for r in rows))
    summary["folds_total"] = int(sum(len(r["folds_at"]) for r in rows))
    summary["branches_with_a_stable_point"] = int(sum(r["stable_points"] > 0 for r in rows))
    summary["wall_seconds"] = time.perf_counter() - start
    ctx.log(
        "atlas: %d branches (%s), %d stability changes, %d folds; %d ran, %d skipped, sweep %.1f s",
        len(rows),
        ", ".join(f"{k}: {v}" for k, v in summary["ends"].items()),
        summary["stability_changes_total"],
        summary["folds_total"],
        report.ran,
        report.skipped,
        report.wall_seconds,
    )
    return summary


def _branch(ds, i: int) -> dict:
    """Branch i of the store up to where contact is lost (the points past it, which the last step's bisection
    may have left, are counted, not returned) and its scalars; ``end_omega``: the interpolated contact loss, or
    the last point."""
    n = int(ds["contact_points"].values[i])
    names = ("omega", "arclength", "energy", "max_modulus_minus_1", "tolerance", "stable", "leading_kind")
    cut = {name: ds[name].values[i, :n] for name in (*names, "min_contact", "foam_fraction", "instabilities")}
    cut["K"] = float(ds["K"].values[i])
    cut["end"] = END_REASONS[int(ds["end_reason"].values[i])]
    for name in (
        "points",
        "contact_loss_omega",
        "stability_changes",
        "foam_stretches",
        "seconds",
        "eigenmode_amplitude",
    ):
        cut[name] = ds[name].values[i].item()
    contact = cut["contact_loss_omega"]
    cut["end_omega"] = contact if math.isfinite(contact) else (float(cut["omega"][-1]) if n else None)
    return cut


def stable_share(omega: np.ndarray, stable: np.ndarray) -> float | None:
    """The share of the branch's path in w_b (sum of |d w_b| over its steps) that is stable: a step counts
    as stable when both its ends are, as half when one is."""
    if len(omega) < 2:
        return None
    dw = np.abs(np.diff(omega))
    weight = 0.5 * (stable[:-1].astype(float) + stable[1:].astype(float))
    return float((weight * dw).sum() / dw.sum()) if dw.sum() > 0 else None


def _branch_summary(ds, i: int) -> dict:
    """One K's row of the summary, from the store (the branch up to contact loss)."""
    b = _branch(ds, i)
    w, stable = b["omega"], b["stable"] == 1
    n = len(w)
    edges = band_edges(float(ds.attrs["parameters"]["M"]), b["K"])
    flips = np.flatnonzero(stable[:-1] != stable[1:]) if n > 1 else np.array([], int)
    foam = np.isfinite(b["foam_fraction"][:-1]) if n > 1 else np.array([], bool)
    return {
        "K": b["K"],
        "end": b["end"],
        "ended_on_physics": StopReason(b["end"]).physical,
        "points": n,
        "points_past_contact_loss": int(b["points"]) - n,
        "end_omega": b["end_omega"],
        "contact_loss_omega": b["contact_loss_omega"] if math.isfinite(b["contact_loss_omega"]) else None,
        "omega_range": [float(w.min()), float(w.max())] if n else None,
        "entered_acoustic_band": bool(n and w.min() <= edges["acoustic_top"]),
        "acoustic_top": edges["acoustic_top"],
        "stable_points": int(stable.sum()),
        "stable_share_of_omega_path": stable_share(w, stable),
        "stability_changes": int(len(flips)),
        "stability_changes_at": [float(0.5 * (w[j] + w[j + 1])) for j in flips],
        "stability_changes_located_by_the_walk": int(b["stability_changes"]),
        "lowest_stable_omega": float(w[stable].min()) if stable.any() else None,
        "folds_at": [float(w[k]) for k in frequency_folds(w)],
        "foam_stretches": int(b["foam_stretches"]),
        "foam_omega_width": float(np.abs(np.diff(w))[foam].sum()) if foam.any() else 0.0,
        "max_modulus_minus_1": float(np.nanmax(b["max_modulus_minus_1"])) if n else None,
        "kinds": [k for j, k in enumerate(KINDS) if n and (b["instabilities"][:, j] > 0).any()],
        "eigenmode_amplitude": b["eigenmode_amplitude"],
        "seconds": b["seconds"],
    }


# ----------------------------------------------------------------------------- figures

#: markers of a branch's end: (marker, colour, label)
END_STYLE = {
    "contact_lost": ("X", "k", "contact lost (end)"),
    "end_reached": ("v", "tab:green", "omega_min reached (end)"),
}
FAIL_STYLE = ("*", "tab:red", "branch failed or cut short (end)")


def _strips(ax, branches, logK, half, y, colours) -> None:
    """The branches as vertical strips at their K (``y``: w_b -> the panel's ordinate), a step coloured by the
    kind of its unstable end's leading instability, foam beside the strip in grey, and the markers."""
    from matplotlib.collections import LineCollection, PolyCollection

    polys, faces, foam_polys, foam_values = [], [], [], []
    changes, folds, ends = [], [], {}
    for k, b in zip(logK, branches):
        w = b["omega"]
        if not len(w):
            continue
        x0, x1 = 10 ** (k - half), 10 ** (k + half)
        xf0, xf1 = 10 ** (k - 1.9 * half), 10 ** (k - 1.2 * half)  # the foam bar, left of the strip
        stable, lead = b["stable"], b["leading_kind"]
        steps = [(w[j], w[j + 1], j, j + 1) for j in range(len(w) - 1)]
        if b["end"] == "contact_lost" and b["end_omega"] is not None:  # on to the loss, as the last point is
            steps.append((w[-1], b["end_omega"], len(w) - 1, len(w) - 1))
        for wa, wb, ja, jb in steps:
            lo, hi = y(wa), y(wb)
            unstable = stable[ja] == 0 or stable[jb] == 0
            kind = int(lead[ja] if stable[ja] == 0 else lead[jb])
            polys.append([(x0, lo), (x1, lo), (x1, hi), (x0, hi)])
            undecided = stable[ja] == -1 or stable[jb] == -1  # no verdict at an end: never drawn as stable
            faces.append(colours[kind] if unstable else ("white" if undecided else colours[-1]))
            if jb > ja and np.isfinite(b["foam_fraction"][ja]):
                foam_polys.append([(xf0, lo), (xf1, lo), (xf1, hi), (xf0, hi)])
                foam_values.append(b["foam_fraction"][ja])
        flips = np.flatnonzero(stable[:-1] != stable[1:])  # a tick right of the strip: the strip stays visible
        changes += [
            [(x1, y(0.5 * (w[j] + w[j + 1]))), (10 ** (k + 1.6 * half), y(0.5 * (w[j] + w[j + 1])))] for j in flips
        ]
        folds += [(10 ** (k + 1.9 * half), y(w[j])) for j in frequency_folds(w)]
        ends.setdefault(b["end"], []).append((10**k, y(b["end_omega"])))
    ax.add_collection(PolyCollection(polys, facecolors=faces, edgecolors=faces, linewidths=0.3))
    if foam_polys:
        ax.add_collection(
            PolyCollection(foam_polys, array=np.array(foam_values), cmap="Greys", clim=(-0.1, 0.3), linewidths=0)
        )
    if changes:
        ax.add_collection(LineCollection(changes, colors="k", linewidths=0.6))
    if folds:
        ax.plot(*zip(*folds), "<", color="tab:brown", ms=4, ls="none")
    for reason, where in ends.items():
        marker, colour, _ = END_STYLE.get(reason, FAIL_STYLE)
        ax.plot(*zip(*where), marker, color=colour, ms=6, ls="none")


def plot(out) -> None:
    import xarray as xr
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    s = read_summary(out)
    ds = xr.open_zarr(out / "data.zarr", group=GROUP).load()
    M = float(ds.attrs["parameters"]["M"])
    Ks = ds["K"].values
    branches = [_branch(ds, i) for i in range(len(Ks))]
    plt = pyplot()
    logK = np.log10(Ks)
    half = 0.25 * (np.min(np.diff(logK)) if len(Ks) > 1 else 0.1)  # a strip's half-width in log10 K
    edge = band_edges(M, float(Ks[0]))["optical_bottom"]
    fine = np.geomspace(Ks[0] / 10 ** (2 * half), Ks[-1] * 10 ** (2 * half), 400)
    acoustic = np.array([band_edges(M, k)["acoustic_top"] for k in fine])
    colours = {-1: "tab:blue", **{j: KIND_COLOURS[k] for j, k in enumerate(KINDS)}}
    ends = [b["end_omega"] for b in branches if b["end_omega"] is not None]
    below = [edge - w for b in branches for w in b["omega"] if edge - w > 0]

    fig, axes = plt.subplots(1, 2, figsize=(14, 6.4), layout="constrained")
    for panel, ax in enumerate(axes):
        if panel == 0:
            ax.plot(fine, acoustic, "-", color="0.3", lw=1.2)
            ax.axhline(edge, color="0.3", lw=1.2, ls="--")
            ax.fill_between(fine, acoustic, edge, color="tab:blue", alpha=0.06, lw=0)
            _strips(ax, branches, logK, half, lambda w: w, colours)
            low = min(ends, default=edge - 0.1)
            ax.set_ylim(low - 0.05 * (edge - low), edge + 0.05 * (edge - low))
            ax.set_ylabel(r"breather frequency $\omega_b$")
            ax.set_title(r"(a) the (K, $\omega_b$) plane: one frequency branch per K (shaded: the gap)", fontsize=10)
        else:
            floor = max(min(below, default=1e-6) / 2, 1e-9)
            ax.plot(fine, edge - acoustic, "-", color="0.3", lw=1.2)
            _strips(ax, branches, logK, half, lambda w: max(edge - w, floor), colours)
            ax.set_yscale("log")
            top = max([edge - w for w in ends] + [floor * 10])
            ax.set_ylim(top * 1.5, floor)  # inverted: the band edge (0) up, as in (a)
            ax.set_ylabel(r"distance below the optical band edge, $\omega_{ob} - \omega_b$")
            ax.set_title("(b) the same on a log distance below the optical band edge", fontsize=10)
        ax.set_xscale("log")
        ax.set_xlim(fine[0], fine[-1])
        ax.set_xlabel("coupling K")
    keys = [Patch(color=colours[-1], label="stable")]
    keys += [Patch(color=KIND_COLOURS[k], label=f"unstable: {KIND_LABELS[k]}") for k in KINDS]
    keys += [Patch(color="0.6", label="foam: bubbles predicted too narrow to chase (darker: larger unstable fraction)")]
    keys += [
        Line2D(
            [], [], color="k", marker="_", ls="none", ms=8, mew=0.8, label="stability change (tick right of the strip)"
        )
    ]
    keys += [Line2D([], [], color="tab:brown", marker="<", ls="none", label=r"fold in $\omega_b$")]
    shown = {b["end"] for b in branches}
    for style in dict.fromkeys(END_STYLE.get(reason, FAIL_STYLE) for reason in END_REASONS if reason in shown):
        marker, colour, label = style
        keys.append(Line2D([], [], color=colour, marker=marker, ls="none", label=label))
    keys += [
        Line2D([], [], color="0.3", label="acoustic band top"),
        Line2D([], [], color="0.3", ls="--", label="optical band bottom"),
    ]
    fig.legend(handles=keys, loc="outside lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(
        f"stability atlas of the site breather: M = {M:g}, N = {s['N']}, {len(Ks)} couplings "
        f"K = {Ks[0]:.3g} .. {Ks[-1]:.3g}; each branch up to where contact is lost",
        fontsize=11,
    )
    save_figure(fig, out, "stability_atlas")

    rows = s["branches"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4), layout="constrained")
    K = np.array([r["K"] for r in rows])
    axes[0].plot(fine, acoustic, "-", color="0.3", lw=1, label="acoustic band top")
    axes[0].axhline(edge, color="0.3", lw=1, ls="--", label="optical band bottom")
    axes[0].plot(K, [np.nan if r["end_omega"] is None else r["end_omega"] for r in rows], "X-", ms=4, color="k")
    axes[0].lines[-1].set_label("end of the branch")
    low = [np.nan if r["lowest_stable_omega"] is None else r["lowest_stable_omega"] for r in rows]
    axes[0].plot(K, low, "s", ms=3, color="tab:blue", label="lowest stable point")
    span = [v for r in rows for v in (r["end_omega"], r["lowest_stable_omega"]) if v is not None] or [edge - 0.1]
    axes[0].set_ylim(min(span) - 0.1 * (edge - min(span)), edge + 0.1 * (edge - min(span)))
    axes[0].set(xscale="log", xlabel="K", ylabel=r"$\omega_b$")
    axes[0].set_title("where the branches end", fontsize=10)
    axes[0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.18), ncol=2, frameon=False)
    share = [np.nan if r["stable_share_of_omega_path"] is None else r["stable_share_of_omega_path"] for r in rows]
    axes[1].plot(K, share, "o-", ms=3, color="tab:blue")
    axes[1].set(xscale="log", xlabel="K", ylabel=r"stable share of the path in $\omega_b$", ylim=(-0.03, 1.03))
    axes[1].set_title("stable share of each branch (to contact loss)", fontsize=10)
    axes[2].plot(K, [r["stability_changes"] for r in rows], "o-", ms=3, label="stability changes")
    axes[2].plot(K, [len(r["folds_at"]) for r in rows], "s-", ms=3, label=r"folds in $\omega_b$")
    axes[2].plot(K, [r["foam_stretches"] for r in rows], "^-", ms=3, label="foam stretches")
    axes[2].set(xscale="log", xlabel="K", ylabel="count per branch")
    axes[2].set_title("changes along each branch (to contact loss)", fontsize=10)
    axes[2].legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.18), ncol=3, frameon=False)
    save_figure(fig, out, "stability_atlas_summary")
