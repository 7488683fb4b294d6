"""What the two branch scenes share: running a branch into its store (fresh or resumed), the
summary fields, and the stability strip of the figures."""

from __future__ import annotations

import dataclasses

import numpy as np

from continuation.branch import PseudoArclength
from continuation.driver import AUTO_ALL_SITES, KREIN_MODES, Branch, ContinuationSettings, WalkState, continuation
from continuation.floquet import KINDS
from warpchain import ChainParams, Flow

from continuation.branch_store import BranchStore, StoreError, load_branch
from ._common import BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, PAPER_M, PAPER_N, Refused, progress_bars, verdicts
from ._params import DENSE_MAX_SITES, Rule, min_steps_per_period, number, param, splitting_methods, stability_dt


@dataclasses.dataclass(frozen=True)
class BranchParameters:
    """What both branch scenes share; each scene's ``Parameters`` adds its own fields, defaults and ``RULES``.
    Steps and the resolution are in the scene's continuation coordinate."""

    N: int = param(
        PAPER_N, "sites of the chain; N = 1 has no odd mode for the multipliers' parity split", ge=2, le=DENSE_MAX_SITES
    )
    M: float = param(PAPER_M, "mass ratio m1 / m2", gt=0)
    ds: float = param(0.05, "first step", gt=0)
    ds_max: float = param(0.5, "largest step", gt=0)
    ds_min: float = param(1e-4, "smallest step: a point that fails below it ends the branch", gt=0)
    grow: float = param(1.5, "step growth after an easy Newton solve", ge=1)
    resolution: float = param(1e-3, "smallest bracket of a stability change (float64 resolves >= 1e-12)", ge=1e-12)
    max_newton: int = param(8, "Newton iterations per point", ge=1, le=100)
    max_points: int | None = param(None, "stop after this many points; none: no limit", ge=1, le=1_000_000)
    method: str = param(
        BREATHER_METHOD,
        "integrator: a palindromic splitting method, as the reduced Floquet analysis needs a time-reversible map",
        choices=splitting_methods,
    )
    steps_per_period: int = param(
        BREATHER_STEPS_PER_PERIOD,
        "integrator steps per period, even so that the half period is whole steps",
        ge=2,
        multiple_of=2,
        le=65536,
    )
    max_seconds: float | None = param(None, "opt-in time budget in seconds; none: no limit", gt=0)
    bisect_krein: str = param(
        "auto",
        f"passes of opposite Krein signature bisected: auto is all for N <= {AUTO_ALL_SITES}, predict above",
        choices=KREIN_MODES,
    )

    floquet_solver: str = param(
        "auto",
        "every multiplier at each point: dense (4N tangent columns), sliced (the probed sparse Mu by shift-invert "
        "slices, counted: continuation.slicing), probed (the same Mu by a dense eig per parity block, on the GPU "
        "with CuPy, counted) or auto (from 1601 sites: probed on a GPU with CuPy or below 2000 sites, else sliced)",
        choices=("auto", "dense", "sliced", "probed"),
    )

    def settings(self) -> ContinuationSettings:
        return ContinuationSettings(
            ds=self.ds,
            ds_min=self.ds_min,
            ds_max=self.ds_max,
            grow=self.grow,
            resolution=self.resolution,
            max_newton=self.max_newton,
            max_points=self.max_points,
            max_seconds=self.max_seconds,
            bisect_krein=self.bisect_krein,
            floquet_solver=self.floquet_solver,
        )

    def flow(self, device) -> Flow:
        return Flow(self.method, self.steps_per_period, device)


def frequency_problem(P, device: str, K: float | None = None, eigenmode_amplitude: float | None = None) -> tuple:
    """The frequency branch the ``continuation-omega`` scene walks, for the parameters ``P`` (a ``BranchParameters``
    with ``omega_min``; ``K``: the coupling, default ``P.K``): pseudo-arclength in (positions, w_b) from the lowest
    optical eigenmode (first point at mode amplitude ``eigenmode_amplitude``; None: the problem's default) down
    until contact is lost or w_b < omega_min. Returns (chain, flow, settings, problem)."""
    params = ChainParams(P.M, P.K if K is None else K, P.N)
    flow = P.flow(device)
    settings = P.settings()
    start = {} if eigenmode_amplitude is None else {"eigenmode_amplitude": eigenmode_amplitude}
    problem = PseudoArclength(params, flow, None, omega_min=P.omega_min, **start)
    return params, flow, settings, problem


def frequency_folds(omegas) -> list[int]:
    """Indices of the points of a branch (in the order walked) where w_b turns back: the step into the point and
    the step out of it change w_b with opposite signs (d w_b / d arclength changes sign)."""
    dw = np.diff(np.asarray(omegas, dtype=float))
    return [i + 1 for i in range(len(dw) - 1) if dw[i] * dw[i + 1] < 0]


def step_rule(omega: str, K: str) -> Rule:
    """steps_per_period, method: the step 2 pi / (w_b steps_per_period) below the method's linear stability
    limit where it is longest against it on the branch: at the frequency ``omega`` and the coupling ``K`` (names
    of fields)."""

    def needed(P) -> int:
        return min_steps_per_period(P.method, P.M, getattr(P, K), getattr(P, omega), multiple_of=2)

    def wording(P) -> str:
        return (
            f"steps_per_period >= {needed(P)} for {P.method} at w_b = {omega} = {number(getattr(P, omega))} and "
            f"{K} = {number(getattr(P, K))}: a step below its linear stability limit dt < "
            f"{number(stability_dt(P.method, P.M, getattr(P, K)))}"
        )

    return Rule(("steps_per_period", "method", omega, K), wording, lambda P: P.steps_per_period >= needed(P))


#: the rules across fields every branch scene has (its ``RULES`` add a ``step_rule`` after its own)
BRANCH_RULES = (Rule(("ds", "ds_min", "ds_max"), "ds_min <= ds <= ds_max", lambda P: P.ds_min <= P.ds <= P.ds_max),)


KIND_COLOURS = {"real_pair": "tab:red", "period_doubling": "tab:purple", "complex_quadruplet": "tab:orange"}
KIND_LABELS = {
    "real_pair": "real pair (through +1)",
    "period_doubling": "period doubling (through -1)",
    "complex_quadruplet": "Krein quadruplet",
}


def run_branch(
    ctx,
    problem,
    settings,
    params,
    attrs,
    *,
    group: str = "branch",
    new_store: bool = True,
    progress: bool | None = None,
) -> Branch:
    """Run (or with ``ctx.resume`` continue) the branch, streaming points into OUT/data.zarr (group
    ``group``; ``new_store=False`` adds it to the scene's existing store)."""
    path = ctx.out / "data.zarr"
    resume, state = None, None
    if ctx.resume:
        try:
            stored_params, resume, stored_attrs = load_branch(path, group)
        except StoreError as exc:  # refused before anything is written: the folder (its summary) stays as it was
            raise ResumeRefused(str(exc)) from None
        _check_resume(path, group, stored_params, stored_attrs, params, attrs)
        if not resume and not isinstance(stored_attrs.get("walk_state"), dict):  # killed before its first write
            ctx.log("resume: %s holds no points yet (the run was stopped before its first write): starting anew", path)
            resume = None
        else:
            state = _walk_state(path, group, stored_attrs, resume)
            resume = resume[: state.points]
            ctx.log(
                "resuming from %d stored points (%s at %s)",
                len(resume),
                stored_attrs.get("stop_reason"),
                problem.describe(resume[-1]),
            )
    elif new_store:
        _warn_if_interrupted(ctx, path, group)
    store = BranchStore(
        path,
        group,
        params,
        attrs,
        max_newton=3 * settings.max_newton,
        resume=bool(resume),
        keep=state.points if state else None,
        device=ctx.device,
        new_store=new_store,
    ).background()  # points are written while the next one is computed
    from tqdm.contrib.logging import logging_redirect_tqdm

    try:
        with logging_redirect_tqdm():  # log lines above the progress bar, not glued onto it
            branch = continuation(
                problem,
                settings,
                resume=resume,
                resume_state=state,
                on_point=store.append,
                on_step=store.step,
                log=ctx.log,
                progress=progress_bars() if progress is None else progress,
            )
        store.finish(branch)  # inside: an interrupt while the writer catches up still marks the store interrupted
    except KeyboardInterrupt:
        store.interrupted("interrupted (Ctrl-C or SIGTERM); the stored points are complete: resume with --resume")
        raise
    except Exception as exc:
        store.interrupted(f"stopped by {type(exc).__name__}: {exc}; the stored points are complete")
        raise
    ctx.log(
        "%s: stop: %s (%d points, %.0f s, %.2f s per point)",
        group,
        branch.message,
        len(branch.points),
        branch.wall_seconds,
        branch.stats["seconds_per_point"],
    )
    if not branch.points:
        raise RuntimeError(
            f"{group}: the branch's first point failed ({branch.message}); a smaller start (for a frequency branch "
            "--set eigenmode_amplitude=..., the optical mode's amplitude) or a finer time grid may start it"
        )
    return branch


def _walk_state(path, group: str, stored_attrs: dict, points: list) -> WalkState:
    """The stored walk state, checked against the stored points (ResumeRefused when it is missing or damaged)."""
    if not isinstance(stored_attrs.get("walk_state"), dict):
        raise ResumeRefused(
            f"{path} (group '{group}') holds points but no record of a completed step: run without --resume"
        )
    try:
        state = WalkState.from_dict(stored_attrs["walk_state"], stored_attrs.get("events") or [])
    except (KeyError, TypeError, ValueError) as exc:
        raise ResumeRefused(f"{path} (group '{group}'): damaged walk_state ({exc!r}): run without --resume") from None
    try:
        state.check(len(points))
    except ValueError as exc:
        raise ResumeRefused(f"{path} (group '{group}'): {exc}: run without --resume") from None
    return state


class ResumeRefused(StoreError, Refused):
    """A resume refused before anything was written (``_check_resume``)."""


#: settings that do not define a branch (where it stops, how long it may take, host threads): a resume may change them
RESUME_MAY_CHANGE = frozenset({"max_points", "max_seconds", "blas_threads"})


def _warn_if_interrupted(ctx, path, group: str) -> None:
    """A fresh run replaces the store: say so first when it holds a branch that ``--resume`` would continue."""
    import zarr

    try:
        attrs = dict(zarr.open_group(str(path), mode="r")[group].attrs)
    except Exception:  # no store, or one that is not a branch store: nothing a resume could continue
        return
    n = attrs.get("n_points")
    if attrs.get("complete") is False and isinstance(n, int) and n > 0:
        ctx.log(
            "replacing %s: it held an unfinished branch of %d points (%s) that --resume would have continued",
            path,
            n,
            attrs.get("stop_reason") or "killed",
        )


def _check_resume(path, group: str, stored_params, stored_attrs: dict, params, attrs: dict) -> None:
    """Refuse to continue a stored branch with other values of what defines it: the chain (N, M, boundary, and
    K where it is not the continued parameter), and every attribute the scene stores with it (w_b or K, method,
    steps per period, the continuation settings but for ``RESUME_MAY_CHANGE``). One error names them all."""
    from warpchain.store import jsonable

    differ = []
    for name in ("N", "M", "boundary") + (("K",) if "K" in attrs else ()):
        a, b = getattr(stored_params, name), getattr(params, name)
        if a != b:
            differ.append(f"{name} = {a} (stored) vs {b}")
    new = jsonable(attrs)
    for key, value in new.items():
        if key not in stored_attrs or key in ("N", "M", "boundary", "K"):  # the chain's: compared above
            continue
        old = stored_attrs[key]
        if isinstance(value, dict) and isinstance(old, dict):
            for k in sorted(set(value) | set(old)):
                if k not in RESUME_MAY_CHANGE and value.get(k) != old.get(k):
                    differ.append(f"{key}.{k} = {old.get(k)!r} (stored) vs {value.get(k)!r}")
        elif value != old:
            differ.append(f"{key} = {old!r} (stored) vs {value!r}")
    if differ:
        raise ResumeRefused(
            f"{path}, group {group}: the stored branch was computed with other settings: {'; '.join(differ)}. "
            "Resume with the stored run's --set values, or run without --resume into another --out"
        )


def branch_summary(branch: Branch, parameter: str) -> dict:
    """The summary fields both branch scenes write."""
    events = list(branch.events)
    return {
        "points": [p.summary() for p in branch.points],
        "stop_reason": branch.stop_reason.value,
        "message": branch.message,
        "ended_on_physics": branch.stop_reason.physical,
        "unstable_intervals": branch.unstable_intervals(),
        "stability_changes": branch.stability_changes(),
        "unresolved_bubbles": branch.unresolved_bubbles(),
        "krein_crossings_recorded": sum(1 for e in events if e["type"] == "krein_crossing"),
        "events": [e for e in events if e["type"] not in ("krein_crossing", "bubble_foam")],
        "branch_stats": branch.stats,
        "branch_seconds": branch.wall_seconds,
    }


def stability_strip(ax, points, parameter: str, log: bool = False, unresolved=(), legend: bool = True):
    """max |l| - 1 along the branch on a log axis, coloured by the leading instability's kind;
    ``unresolved``: the summary's ``unresolved_bubbles`` stretches, shaded (predicted bubbles too narrow
    to chase, where the branch states a predicted unstable fraction instead of a verdict), the shade darker
    the larger that fraction. Returns the fraction's colour mapping (for a colour bar; None without
    stretches); ``legend=False`` leaves the key to the caller."""
    from matplotlib import cm, colors
    from matplotlib import pyplot as plt

    x = np.array([p.value(parameter) for p in points])
    shade = None
    fractions = [st.get("unstable_fraction") for st in unresolved]
    known = [f for f in fractions if f is not None and f > 0]
    if unresolved:  # log scale from the smallest fraction's decade up to the largest fraction
        top = max(known, default=1e-2)
        low = 10.0 ** np.floor(np.log10(max(min(known, default=top / 100), 1e-8)))
        pale_to_dark = colors.ListedColormap(plt.get_cmap("Greys")(np.linspace(0.06, 0.45, 256)))
        shade = cm.ScalarMappable(colors.LogNorm(min(low, top / 10), top), pale_to_dark)
    for st, f in zip(unresolved, fractions):
        colour = shade.to_rgba(max(f, shade.norm.vmin)) if f is not None else "0.8"
        ax.axvspan(min(st["start"], st["end"]), max(st["start"], st["end"]), color=colour, lw=0)
    if shade is not None:  # the key's swatch: a mid shade
        ax.fill_between(
            [np.nan],
            [np.nan],
            color=shade.cmap(0.5),
            lw=0,
            label="bubbles below the chase width (predicted, not solved)",
        )
    dev = np.array([p.max_modulus - 1.0 for p in points])
    floor = 1e-9
    ax.plot(x, np.maximum(dev, floor), "-", color="0.75", lw=0.8)
    stable = verdicts(points)[0]
    ax.plot(x[stable], np.full(stable.sum(), floor), "|", color="tab:blue", ms=6, label="stable")
    for kind in KINDS:
        sel = np.array([bool(p.instabilities) and p.instabilities[0].kind == kind for p in points])
        if sel.any():
            ax.plot(x[sel], np.maximum(dev[sel], floor), "o", ms=3, color=KIND_COLOURS[kind], label=KIND_LABELS[kind])
    if log:
        ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(floor / 3, max(1e-2, np.nanmax(dev) * 3) if np.isfinite(dev).any() else 1e-2)
    ax.set_ylabel(r"max $|\lambda|$ - 1")
    ax.set_xlabel({"K": "K", "omega": r"$\omega_b$"}[parameter])
    if legend:  # outside: no data hidden
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0), borderaxespad=0.0)
    return shade
