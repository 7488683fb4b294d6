"""Continuation in the coupling K (paper Fig. 6): M = 30, w_b = 1.01, N = 201, from the single-site
anti-continuum seed at K = 0.01 to K = 160, with multipliers and their kinds at every point.

Command: ``python -m scenarios run continuation-k`` (CPU: ~25 s on 2 cores; ``--quick``: N = 101,
coarser steps, under a minute). Options: ``--set KEY=VALUE`` (fields of ``Parameters``), ``--resume``.

Natural-parameter continuation (``continuation.branch.NaturalParameter``) with a secant predictor in
log10 K, landing exactly on K = 5, 20 (profiles I, II) and 160 (III). Steps are bounded by how far
the multipliers move (``continuation.driver``); a step across which the number or kind of unstable
multipliers changes is bisected until the bracket is below ``resolution`` (in log10 K). The branch is
streamed point by point into data.zarr (group ``branch``) through the driver's ``on_point`` hook, and
``--resume`` continues it from there. The NLS energy at K = 160 is the reference line. Where the
site breather gains or loses its localized odd real pair (``continuation.bifurcation``), the first
such point is located by the secant on mu - 1 and marked (dashed), the others by their brackets
(dotted); the ``site-bond`` scene follows the families that branch off there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from continuation import anticontinuum_seed, nls_seed
from continuation import bifurcation as bf
from continuation.branch import NaturalParameter
from warpchain import ChainParams, energy

from continuation.branch_store import load_branch
from ._common import (
    verdicts,
    tight_layout_beside_legends,
    PAPER_K,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    pyplot,
    read_summary,
    save_figure,
)
from ._continuation_common import BRANCH_RULES, BranchParameters, branch_summary, run_branch, stability_strip, step_rule
from ._params import DENSE_MAX_SITES, Rule, anticontinuum_rule, param

RESUMABLE = True


@dataclasses.dataclass(frozen=True)
class Parameters(BranchParameters):
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them); steps in log10 K."""

    N: int = param(PAPER_N, "sites of the chain; the figure draws the 31 central ones", ge=31, le=DENSE_MAX_SITES)
    omega: float = param(PAPER_OMEGA, "breather frequency w_b", gt=0)
    K_start: float = param(0.01, "coupling of the anti-continuum seed, where the branch starts", gt=0)
    K_end: float = param(PAPER_K, "coupling where the branch ends", gt=0)
    profile_K: tuple[float, ...] = param(
        (5.0, 20.0, PAPER_K), "couplings the branch lands on exactly: the profiles I, II, III", gt=0, length=(1, 3)
    )
    ds: float = param(0.15, "first step, in log10 K", gt=0)
    ds_max: float = param(0.3, "largest step, in log10 K", gt=0)
    resolution: float = param(1e-3, "smallest bracket of a stability change, in log10 K: 1e-3 is 0.23 % in K", ge=1e-12)
    locate_first: int = param(
        1, "symmetry-breaking points located by the secant; the rest are given by their brackets", ge=0, le=1_000_000
    )

    RULES = (
        Rule(
            ("K_start", "K_end"),
            "K_start < K_end: the branch goes up from the anti-continuum seed",
            lambda P: P.K_start < P.K_end,
        ),
        Rule(
            ("profile_K", "K_start", "K_end"),
            "every profile_K in (K_start, K_end], where the branch lands on it",
            lambda P: all(P.K_start < k <= P.K_end for k in P.profile_K),
        ),
        anticontinuum_rule("omega"),
        *BRANCH_RULES,
        step_rule("omega", "K_end"),  # the longest step against the limit: at the largest K, the lowest w_b
    )


QUICK = {"N": 101, "ds": 0.5, "ds_max": 1.0, "resolution": 1e-2}


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params = ChainParams(P.M, P.K_start, P.N)
    flow = P.flow(ctx.device)
    settings = P.settings()
    problem = NaturalParameter(params, P.omega, anticontinuum_seed(params, P.omega), P.K_end, flow, targets=P.profile_K)
    attrs = {
        "omega": P.omega,
        "method": P.method,
        "steps_per_period": P.steps_per_period,
        "continuation": "natural parameter, secant predictor in log10 K",
        "coordinate": "log10 K",
        "settings": dataclasses.asdict(settings),
    }
    branch = run_branch(ctx, problem, settings, params, attrs)
    symmetry_breaking = _symmetry_breaking(ctx, P, branch, params, flow)
    nls_energy = float(energy(params.replace(K=P.K_end), nls_seed(params.replace(K=P.K_end), P.omega))[0])
    end = branch.points[-1]
    return {
        "omega": P.omega,
        "M": P.M,
        "N": P.N,
        **branch_summary(branch, "K"),
        "bifurcation_points": symmetry_breaking,
        "nls_energy_at_K_end": nls_energy,
        "end_K": end.K,
        "end_energy": end.energy,
        "end_max_floquet_modulus": end.max_modulus,
        "method": P.method,
        "steps_per_period": P.steps_per_period,
    }


def _symmetry_breaking(ctx, P: Parameters, branch, params, flow) -> list:
    """Where the site breather gains or loses its localized odd real pair (``continuation.bifurcation``):
    the first ``P.locate_first`` located by the secant on mu - 1, the others given by their brackets."""
    out = []
    points = branch.points
    for i, j, vertex in bf.suspect_steps(points, -1):
        a, b = points[i], points[j]
        if len([e for e in out if e["located"]]) < P.locate_first:
            try:
                found = bf.locate_real_pair("site", params, P.omega, a, b, flow, parity=-1, vertex=vertex)
            except bf.NotLocated as exc:  # the mathematics says no; any other error fails the scene
                ctx.log("no symmetry-breaking point located between K = %.8g and %.8g: %s", a.K, b.K, exc)
                found = []
            for bif in found:
                out.append(dict(bif.as_dict(), located=True))
                ctx.log(
                    "symmetry breaking at K = %.10g: the site breather %s a localized odd real pair (%.1f sites)",
                    bif.K,
                    bif.direction,
                    bif.participation,
                )
            if found:
                continue
        out.append(bf.unlocated("site", a, b, vertex, -1))
    return out


def plot(out) -> None:
    _, points, attrs = load_branch(out / "data.zarr", "branch")
    s = read_summary(out)
    K = np.array([p.K for p in points])
    E = np.array([p.energy for p in points])
    stable, unstable, undecided = verdicts(points)
    plt = pyplot()
    fig = plt.figure(figsize=(9.5, 8.5))
    gs = fig.add_gridspec(3, 2, height_ratios=[2.2, 0.9, 1.8])
    ax = fig.add_subplot(gs[0, :])
    ax.semilogx(K, E, "-", color="0.6", lw=1)
    ax.semilogx(K[stable], E[stable], "o", ms=3, color="tab:blue", label="stable")
    ax.semilogx(K[unstable], E[unstable], "o", ms=3, mfc="none", color="tab:red", label="unstable")
    if undecided.any():
        ax.semilogx(K[undecided], E[undecided], "s", ms=3, mfc="none", color="0.5", label="not decided")
    ax.axhline(s["nls_energy_at_K_end"], color="k", ls="--", lw=1, label=f"NLS energy at K = {s['end_K']:g}")
    profile_K = s.get("parameters", {}).get("profile_K", (5.0, 20.0, 160.0))
    for lab, k in zip(("I", "II", "III"), profile_K):
        i = np.argmin(np.abs(K - k))
        if abs(K[i] - k) < 1e-9 * k:
            ax.annotate(lab, (K[i], E[i]), textcoords="offset points", xytext=(-14, 2), ha="right")
    located = [e["K"] for e in s.get("bifurcation_points", []) if e["located"]]
    flagged = [e["K"] for e in s.get("bifurcation_points", []) if not e["located"]]
    for n, k in enumerate(located):
        label = "symmetry breaking (located): K = " + ", ".join(f"{x:.8g}" for x in located) if n == 0 else None
        ax.axvline(k, color="tab:red", ls="--", lw=1, label=label)
    if flagged:  # ticks under the top edge, one legend entry: ~30 full-height lines hid the curve
        ax.plot(
            flagged,
            np.full(len(flagged), 0.97),
            "|",
            ms=8,
            color="tab:red",
            transform=ax.get_xaxis_transform(),
            label=f"{len(flagged)} further changes flagged (not located)",
        )
    ax.set_ylabel("energy H")
    stop = s["stop_reason"].replace("_", " ")
    ax.set_title(f"continuation in K: M = {s['M']:g}, $\\omega_b$ = {s['omega']}, N = {s['N']} (stopped: {stop})")
    ax.margins(y=0.1)  # room for the profile labels at the ends of the branch
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.005, 1.0), borderaxespad=0.0)  # outside, as the strip's
    strip = fig.add_subplot(gs[1, :], sharex=ax)
    shade = stability_strip(strip, points, "K", log=True, unresolved=s.get("unresolved_bubbles", ()))
    aside = []
    if shade is not None:  # the shading's key, under the strip's legend in the right margin
        cax = strip.inset_axes([1.02, 0.1, 0.25, 0.09])
        bar = fig.colorbar(shade, cax=cax, orientation="horizontal")
        bar.set_label("predicted unstable fraction of a shaded stretch", fontsize=7, labelpad=1)
        bar.ax.tick_params(labelsize=6)
        bar.ax.xaxis.set_label_position("top")
        aside.append(cax)
    for col, comp in enumerate(("u", "v")):
        a = fig.add_subplot(gs[2, col])
        for lab, k in zip(("I", "II", "III"), profile_K):
            i = np.argmin(np.abs(K - k))
            if abs(K[i] - k) < 1e-9 * k:
                prof = points[i].state[col]
                c = len(prof) // 2
                sites = np.arange(c - 15, c + 16)
                a.plot(sites, prof[sites], "o-", ms=3, label=f"{lab}: K = {k:g}")
        a.set_xlabel("site j")
        a.set_ylabel(f"${comp}_j$ (t = 0)")
    a.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # one key for both panels
    tight_layout_beside_legends(fig, *aside)
    save_figure(fig, out, "continuation_k")
