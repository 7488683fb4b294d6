"""Continuation in frequency (paper Figs. 7 and 8): M = 30, K = 160, N = 201, pseudo-arclength in
(state, w_b) from the lowest optical eigenmode through the gap into the acoustic band, until a
resonator loses contact.

Command: ``python -m scenarios run continuation-omega`` (CPU: ~30 s on 2 cores; ``--quick``: N = 101
and a short branch). Options: ``--set KEY=VALUE`` (fields of ``Parameters``, e.g. ``--set N=401
--set omega_min=0.99``), ``--resume`` (continue the stored branch).

The branch stops on physics: where min over the orbit of 1 + u - v reaches 0 (contact lost), or at
``omega_min``; ``max_points`` and ``max_seconds`` are opt-in limits. Steps are bounded by the
multipliers' motion and every stability change is bisected (``continuation.driver``).

Figures: energy vs frequency with the gap and stability marked and four labelled points (profiles);
max |l| - 1 along the branch by kind; the multipliers of the labelled points, zoomed where they
leave the unit circle. The breather at exactly w_b = 1.01 is solved from the nearest branch point,
so the branch can be compared with the K-continuation's end point and the ``breather`` scene.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from continuation import find_breather, require
from warpchain import band_edges

from continuation.branch_store import load_branch
from ._common import (
    verdicts,
    PAPER_K,
    PAPER_OMEGA,
    Context,
    pyplot,
    read_summary,
    save_figure,
)
from ._continuation_common import (
    BRANCH_RULES,
    KIND_COLOURS,
    BranchParameters,
    branch_summary,
    frequency_folds,
    frequency_problem,
    run_branch,
    stability_strip,
    step_rule,
)
from ._params import Rule, number, param

RESUMABLE = True


@dataclasses.dataclass(frozen=True)
class Parameters(BranchParameters):
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them); steps in arclength."""

    K: float = param(PAPER_K, "coupling", gt=0)
    omega_min: float = param(0.8, "a floor on w_b; the branch is expected to stop at contact loss first", gt=0)
    ds: float = param(0.05, "first step: arclength in the weighted norm, theta = 1 / gap width", gt=0)
    ds_max: float = param(0.6, "largest step, arclength", gt=0)
    grow: float = param(1.3, "step growth after an easy Newton solve", ge=1)
    eigenmode_amplitude: float = param(
        0.03, "amplitude of the lowest optical mode the first point is solved from (smaller if the start fails)", gt=0
    )

    RULES = (
        Rule(
            ("omega_min", "K", "M"),
            lambda P: (
                f"omega_min < {number(band_edges(P.M, P.K)['optical_bottom'])}, the optical band bottom of M "
                "and K: the branch starts at the lowest optical eigenmode and goes down"
            ),
            lambda P: P.omega_min < band_edges(P.M, P.K)["optical_bottom"],
        ),
        *BRANCH_RULES,
        step_rule("omega_min", "K"),  # the longest step against the limit: at the largest K, the lowest w_b
    )


QUICK = {"N": 101, "omega_min": 1.005, "resolution": 1e-2}


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params, flow, settings, problem = frequency_problem(P, ctx.device, eigenmode_amplitude=P.eigenmode_amplitude)
    attrs = {
        "K": P.K,
        "method": P.method,
        "steps_per_period": P.steps_per_period,
        "continuation": "pseudo-arclength in (positions, omega)",
        "coordinate": "arclength",
        "settings": dataclasses.asdict(settings),
    }
    branch = run_branch(ctx, problem, settings, params, attrs)

    omegas = branch.column("omega")
    energies = branch.column("energy")
    edges = band_edges(P.M, P.K)
    # energy-frequency dependence, computed along the branch (it is parametrised by arclength, so w
    # may turn back): monotonic where every step has dE dw < 0; folds are where dw changes sign
    dw, dE = np.diff(omegas), np.diff(energies)
    in_gap = (omegas[:-1] > edges["acoustic_top"]) & (omegas[1:] > edges["acoustic_top"])
    monotonic_gap = bool(np.all(dE[in_gap] * dw[in_gap] < 0))
    folds = [float(omegas[i]) for i in frequency_folds(omegas)]
    ctx.log(
        "energy vs frequency: monotonic in the gap: %s; %d folds in w_b along the branch", monotonic_gap, len(folds)
    )
    at_101 = None
    if omegas.min() <= PAPER_OMEGA <= omegas.max():
        nearest = branch.points[int(np.argmin(np.abs(omegas - PAPER_OMEGA)))]
        at_101 = require(find_breather(params, PAPER_OMEGA, nearest.state, flow=flow))
        ctx.log("w_b = 1.01 on this branch: E = %.12f", at_101.energy)
    in_band = [p.omega for p in branch.points if p.omega <= edges["acoustic_top"]]
    return {
        "K": P.K,
        "M": P.M,
        "N": P.N,
        **branch_summary(branch, "omega"),
        "energy_monotonic_in_frequency_in_gap": monotonic_gap,
        "frequency_folds_at": folds,
        "energy_at_omega_1_01": None if at_101 is None else at_101.energy,
        "omega_range": [float(omegas.min()), float(omegas.max())],
        "end_omega": float(omegas[-1]),
        "end_min_contact": float(branch.points[-1].min_contact),
        "entered_acoustic_band": bool(in_band),
        "lowest_omega": float(omegas.min()),
        **{f"band_{k}": v for k, v in edges.items()},
        "method": P.method,
        "steps_per_period": P.steps_per_period,
    }


def _labelled(points):
    """Four points across the branch: near the band edge, w_b ~ 1.01, deep in the gap, last."""
    omegas = np.array([p.omega for p in points])
    wanted = [omegas.max() - 0.15 * (omegas.max() - 1.01), 1.01, 1.0005]
    idx = []
    for w in wanted:
        i = int(np.argmin(np.abs(omegas - w)))
        if i not in idx:
            idx.append(i)
    if len(points) - 1 not in idx:
        idx.append(len(points) - 1)
    return idx


def plot(out) -> None:
    _, points, attrs = load_branch(out / "data.zarr", "branch")
    s = read_summary(out)
    w = np.array([p.omega for p in points])
    E = np.array([p.energy for p in points])
    stable, unstable, _ = verdicts(points)
    labels = _labelled(points)
    names = "bcde"
    plt = pyplot()
    gap = dict(color="tab:blue", alpha=0.10, label="band gap")

    fig = plt.figure(figsize=(12, 7.5))
    ax = fig.add_subplot(2, 1, 1)
    ax.axvspan(s["band_acoustic_top"], s["band_optical_bottom"], **gap)
    # the curve coloured by stability (a segment is stable or unstable where both its ends are); the
    # bubbles narrower than a line width are ticks under the curve, so that none hides and none covers
    # the stable stretch around it
    ax.plot(w, E, "-", color="0.75", lw=0.8)
    for flag, colour, label in ((False, "tab:red", "unstable"), (True, "tab:blue", "stable")):
        mask = stable if flag else unstable  # a point not decided is neither
        both = mask[:-1] & mask[1:]
        seg = np.where(both[:, None], np.stack([w[:-1], w[1:]], 1), np.nan)
        segE = np.where(both[:, None], np.stack([E[:-1], E[1:]], 1), np.nan)
        ax.plot(
            np.column_stack([seg, np.full(len(seg), np.nan)]).ravel(),
            np.column_stack([segE, np.full(len(seg), np.nan)]).ravel(),
            "-",
            lw=2.2,
            color=colour,
            label=label,
        )
    narrow = [iv for iv in s["unstable_intervals"] if abs(iv["start"] - iv["end"]) < 2e-4]
    floor = E.min() / 2.0
    if narrow:
        ax.plot(
            [0.5 * (iv["start"] + iv["end"]) for iv in narrow],
            np.full(len(narrow), floor),
            "|",
            ms=14,
            color="tab:red",
            label=f"{len(narrow)} instability bubbles < 2e-4 wide",
        )
    ax.set_ylim(floor / 1.6, E.max() * 2.0)
    for n, i in zip(names, labels):  # E falls with w_b: below left of a point is clear of the curve and the star
        left = w[i] - w.min() > 0.02 * np.ptp(w)  # but the branch's left end is labelled above right
        ax.annotate(
            f"({n})",
            (w[i], E[i]),
            textcoords="offset points",
            xytext=(-4, -6) if left else (4, 6),
            ha="right" if left else "left",
            va="top" if left else "bottom",
        )
    if s.get("energy_at_omega_1_01"):
        ax.plot([1.01], [s["energy_at_omega_1_01"]], "*", ms=12, color="k", label=r"$\omega_b$ = 1.01")
    ax.set_xlabel(r"$\omega_b$")
    ax.set_yscale("log")  # the acoustic-band part reaches ~10x the gap's energies: both stay readable
    ax.set_ylabel("energy H")
    stop = s["stop_reason"].replace("_", " ")
    ax.set_title(f"frequency continuation, K = {s['K']:g}, M = {s['M']:g}, N = {s['N']} (stopped: {stop})")
    ax.legend(fontsize=8, loc="upper right")
    for k, (n, i) in enumerate(zip(names, labels)):
        a = fig.add_subplot(2, 4, 5 + k)
        prof = points[i].state
        a.plot(np.arange(prof.shape[1]), prof[1] - prof[0], "-", lw=1)
        a.set_title(f"({n}) $\\omega_b$ = {w[i]:.5f}", fontsize=9)
        a.set_xlabel("site j", fontsize=8)
        if k == 0:
            a.set_ylabel(r"$v_j - u_j$ at t = 0", fontsize=8)
        a.tick_params(labelsize=7)
    fig.tight_layout()
    save_figure(fig, out, "continuation_omega_energy")

    _plot_floquet(out, plt, points, s, w, labels, names, gap)


def _plot_floquet(out, plt, points, s, w, labels, names, gap) -> None:
    """largest multiplier along the whole branch, then the gap's stable end (where the bubbles lie) on an axis
    of its own, with the predicted bubbles shaded by their unstable fraction; below, the multipliers at (b)-(e)"""
    fig = plt.figure(figsize=(12, 7.5), layout="constrained")
    grid = fig.add_gridspec(2, 4, height_ratios=[1.05, 1])
    top = grid[0, :].subgridspec(1, 2, width_ratios=[1, 2.2])
    whole, zoom = fig.add_subplot(top[0]), fig.add_subplot(top[1])
    unresolved = s.get("unresolved_bubbles", ())
    # the zoom: from just below the lowest stable point or predicted bubble to the optical band edge
    lowest = [float(w[i]) for i, p in enumerate(points) if p.stable is True]
    lowest += [min(st["start"], st["end"]) for st in unresolved]
    lo = min(lowest) if lowest else s["band_acoustic_top"]
    hi = max(float(w.max()), s["band_optical_bottom"])
    margin = 0.04 * (hi - lo)
    lo, hi = max(lo - margin, s["band_acoustic_top"]), hi + margin
    shade = None
    for ax in (whole, zoom):
        ax.axvspan(s["band_acoustic_top"], s["band_optical_bottom"], **gap)
        shade = stability_strip(ax, points, "omega", unresolved=unresolved, legend=False)
    zoom.axvline(s["band_optical_bottom"], color="tab:blue", lw=0.8, ls="--", label="optical band edge")
    zoom.set_xlim(lo, hi)
    zoom.set_ylabel("")
    zoom.ticklabel_format(axis="x", useOffset=False)
    whole.axvspan(lo, hi, facecolor="none", edgecolor="0.3", ls="--", lw=0.8)
    whole.set_title("(a) the whole branch (dashed: the zoom on the right)", fontsize=9)
    zoom.set_title(
        f"zoom of (a) on the gap's stable end: $\\omega_b$ = {lo:.4f} .. {hi:.4f}, where the stability changes",
        fontsize=9,
    )
    ticks = {}  # where the panels below sit on the branch (a short branch may put two at one point)
    for n, i in zip(names, labels):
        ticks.setdefault(float(w[i]), []).append(n)
    for ax in (whole, zoom):
        top_axis = ax.secondary_xaxis("top")
        top_axis.set_xticks(list(ticks), labels=[f"({','.join(n)})" for n in ticks.values()], fontsize=7)
        top_axis.tick_params(length=3, pad=1)
    if shade is not None:
        bar = fig.colorbar(shade, ax=zoom, pad=0.01, aspect=12)
        bar.set_label("predicted unstable fraction\nof a shaded stretch", fontsize=7)
        bar.ax.tick_params(labelsize=6)
    handles, keys = zoom.get_legend_handles_labels()
    fig.suptitle(
        r"largest nontrivial Floquet multiplier along the branch (kind of the leading instability)", fontsize=11
    )
    fig.legend(handles, keys, loc="outside lower center", ncol=len(keys), fontsize=8, frameon=False)
    th = np.linspace(0, 2 * np.pi, 2000)
    for k, (n, i) in enumerate(zip(names, labels)):
        a = fig.add_subplot(grid[1, k])
        lam = points[i].multipliers
        a.plot(np.cos(th), np.sin(th), "-", color="0.5", lw=0.6)
        a.plot(lam.real, lam.imag, ".", ms=3, color="tab:blue")
        p = points[i]
        if p.instabilities:
            lead = p.instabilities[0]
            root = np.sqrt(lead.mu * lead.mu - 1)
            l0 = lead.mu + root if abs(lead.mu + root) >= 1 else lead.mu - root
            for z in (l0, 1 / l0, np.conj(l0), 1 / np.conj(l0)):
                a.plot(z.real, z.imag, "o", mfc="none", ms=7, color=KIND_COLOURS[lead.kind])
            half = max(4 * (abs(l0) - 1), 2e-4)
            a.set_xlim(l0.real - half, l0.real + half)
            a.set_ylim(abs(l0.imag) - half, abs(l0.imag) + half)
            a.set_title(f"({n}) $\\omega_b$ = {w[i]:.5f}\nzoom on the lead: |$\\lambda$| = {abs(l0):.6f}", fontsize=8)
        else:
            a.set_aspect("equal")
            a.set_title(f"({n}) $\\omega_b$ = {w[i]:.5f}\nall on the unit circle", fontsize=8)
        a.set_xlabel(r"Re $\lambda$", fontsize=7)
        a.set_ylabel(r"Im $\lambda$", fontsize=7)
        a.tick_params(labelsize=6)
        a.locator_params(axis="x", nbins=4)  # long tick labels of a narrow zoom stay apart
    save_figure(fig, out, "continuation_omega_floquet")
