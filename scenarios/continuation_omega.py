"""Continuation in frequency (paper Figs. 7 and 8): M = 30, K = 160, N = 201, pseudo-arclength in
(state, w_b) from the small-amplitude lowest optical eigenmode, through the gap and into the acoustic
band, until a resonator loses contact; Floquet multipliers at every point.

Command: ``python -m scenarios run continuation-omega`` (a few minutes on a 2-core CPU; ``--quick``,
N = 101 and a shorter branch, under a minute).

Figures: energy vs frequency with the gap edges and four labelled points (profiles), the largest
|multiplier| along the branch with an inset on the gap, and the multipliers of the labelled points in
the complex plane. The breather at exactly w_b = 1.01 is solved from the nearest branch point so the
branch can be compared with the K-continuation's end point and the ``breather`` scene.
"""

from __future__ import annotations

import numpy as np

from continuation import find_breather, require
from continuation.branch import BranchStore, continue_in_frequency, load_branch, start_from_eigenmode
from warpchain import ChainParams, band_edges

from ._common import (BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, PAPER_K, PAPER_M, PAPER_N, PAPER_OMEGA, Context,
                      pyplot, read_summary, save_figure)

# parameters
OMEGA_MIN = 0.80            # a floor; the branch is expected to stop at contact loss first
DS, MAX_DS = 0.05, 0.6      # arclength steps in the weighted norm (theta = 1 / gap width)
MAX_SECONDS = 210           # budget for the branch (the 5-minute target of the whole scene)
QUICK = {"N": 101, "OMEGA_MIN": 1.005, "MAX_DS": 0.6, "BISECTION": 0, "MAX_SECONDS": 40}


def run(ctx: Context) -> dict:
    N = QUICK["N"] if ctx.quick else PAPER_N
    params = ChainParams(PAPER_M, PAPER_K, N)
    start = start_from_eigenmode(params, method=BREATHER_METHOD, steps_per_period=BREATHER_STEPS_PER_PERIOD,
                                 device=ctx.device, log=ctx.log)
    store = BranchStore(ctx.out / "data.zarr", "branch", params,
                        {"K": PAPER_K, "method": BREATHER_METHOD, "steps_per_period": BREATHER_STEPS_PER_PERIOD,
                         "continuation": "pseudo-arclength in (positions, omega)"}, max_newton=40, device=ctx.device)
    branch = continue_in_frequency(
        params, start, method=BREATHER_METHOD, steps_per_period=BREATHER_STEPS_PER_PERIOD, omega_min=QUICK["OMEGA_MIN"] if ctx.quick else OMEGA_MIN, ds=DS,
        max_ds=QUICK["MAX_DS"] if ctx.quick else MAX_DS, bisection_steps=QUICK["BISECTION"] if ctx.quick else 2,
        device=ctx.device, store=store, progress=True, log=ctx.log,
        max_seconds=QUICK["MAX_SECONDS"] if ctx.quick else MAX_SECONDS)
    ctx.log("stop: %s (%d points, %.0f s)", branch.message, len(branch.points), branch.wall_seconds)

    omegas = branch.column("omega")
    energies = branch.column("energy")
    edges = band_edges(PAPER_M, PAPER_K)
    # energy-frequency dependence, computed along the branch (it is parametrised by arclength, so w
    # may turn back): monotonic where every step has dE dw < 0; folds are where dw changes sign
    dw, dE = np.diff(omegas), np.diff(energies)
    in_gap = (omegas[:-1] > edges["acoustic_top"]) & (omegas[1:] > edges["acoustic_top"])
    monotonic_gap = bool(np.all(dE[in_gap] * dw[in_gap] < 0))
    folds = [float(omegas[i + 1]) for i in range(len(dw) - 1) if dw[i] * dw[i + 1] < 0]
    monotonic_all = bool(np.all(dE * dw < 0) and not folds)
    ctx.log("energy vs frequency: monotonic in the gap: %s; along the whole branch: %s (%d folds in w_b)",
            monotonic_gap, monotonic_all, len(folds))
    at_101 = None
    if omegas.min() <= PAPER_OMEGA <= omegas.max():
        nearest = branch.points[int(np.argmin(np.abs(omegas - PAPER_OMEGA)))]
        at_101 = require(find_breather(params, PAPER_OMEGA, nearest.state, method=BREATHER_METHOD,
                                       steps_per_period=BREATHER_STEPS_PER_PERIOD, device=ctx.device))
        ctx.log("w_b = 1.01 on this branch: E = %.12f", at_101.energy)
    in_band = [p.omega for p in branch.points if p.omega <= edges["acoustic_top"]]
    return {
        "K": PAPER_K, "M": PAPER_M, "N": N,
        "points": [{"omega": p.omega, "energy": p.energy, "max_floquet_modulus": p.max_modulus,
                    "min_contact": p.min_contact, "stable": p.stable, "newton_iterations": p.iterations}
                   for p in branch.points],
        "stop_reason": branch.stop_reason, "message": branch.message,
        "energy_monotonic_in_frequency_in_gap": monotonic_gap,
        "energy_monotonic_in_frequency_whole_branch": monotonic_all, "frequency_folds_at": folds,
        "energy_at_omega_1_01": None if at_101 is None else at_101.energy,
        "omega_range": [float(omegas.min()), float(omegas.max())],
        "entered_acoustic_band": bool(in_band), "lowest_omega": float(omegas.min()),
        "events": branch.events, **{f"band_{k}": v for k, v in edges.items()},
        "method": BREATHER_METHOD, "steps_per_period": BREATHER_STEPS_PER_PERIOD, "branch_seconds": branch.wall_seconds,
    }


def _labelled(points):
    """Four points across the branch: near the band edge, w_b ~ 1.01, deep in the gap, lowest."""
    omegas = np.array([p.omega for p in points])
    wanted = [omegas.max() - 0.15 * (omegas.max() - 1.01), 1.01, 1.0005, omegas.min()]
    idx = []
    for w in wanted:
        i = int(np.argmin(np.abs(omegas - w)))
        if i not in idx:
            idx.append(i)
    return idx


def plot(out) -> None:
    _, points, attrs = load_branch(out / "data.zarr", "branch")
    s = read_summary(out)
    w = np.array([p.omega for p in points])
    E = np.array([p.energy for p in points])
    lmax = np.array([p.max_modulus for p in points])
    labels = _labelled(points)
    names = "bcde"
    plt = pyplot()
    fig = plt.figure(figsize=(12, 7))
    ax = fig.add_subplot(2, 1, 1)
    ax.axvspan(s["band_acoustic_top"], s["band_optical_bottom"], color="tab:blue", alpha=0.12, label="band gap")
    ax.plot(w, E, ".-", color="k", ms=4)
    for n, i in zip(names, labels):
        ax.annotate(f"({n})", (w[i], E[i]), textcoords="offset points", xytext=(4, 6))
    if s.get("energy_at_omega_1_01"):
        ax.plot([1.01], [s["energy_at_omega_1_01"]], "*", ms=12, color="tab:red", label=r"$\omega_b$ = 1.01")
    ax.set_xlabel(r"$\omega_b$")
    ax.set_ylabel("energy H")
    ax.set_title(f"frequency continuation, K = {s['K']:g}, M = {s['M']:g}, N = {s['N']}: {s['stop_reason']}")
    ax.legend(fontsize=8)
    for k, (n, i) in enumerate(zip(names, labels)):
        a = fig.add_subplot(2, 4, 5 + k)
        prof = points[i].state
        a.plot(np.arange(prof.shape[1]) + 1, prof[1] - prof[0], "-", lw=1)
        a.set_title(f"({n}) $\\omega_b$ = {w[i]:.5f}", fontsize=9)
        a.set_xlabel("site j", fontsize=8)
        if k == 0:
            a.set_ylabel("v_j - u_j at t = 0", fontsize=8)
        a.tick_params(labelsize=7)
    fig.tight_layout()
    save_figure(fig, out, "continuation_omega_energy")

    fig = plt.figure(figsize=(12, 6.5))
    ax = fig.add_subplot(2, 1, 1)
    ax.axvspan(s["band_acoustic_top"], s["band_optical_bottom"], color="tab:blue", alpha=0.12, label="band gap")
    ax.semilogy(w, np.maximum(lmax - 1, 1e-16), ".-", ms=4)
    ax.set_xlabel(r"$\omega_b$")
    ax.set_ylabel("max |l| - 1 (nontrivial)")
    ax.set_title("largest Floquet multiplier along the branch")
    gap = (w >= s["band_acoustic_top"]) & (w <= s["band_optical_bottom"])
    if gap.sum() > 1:
        inset = ax.inset_axes([0.62, 0.12, 0.35, 0.5])
        inset.plot(w[gap], lmax[gap], ".-", ms=3)
        inset.set_title("inside the gap: max |l|", fontsize=7)
        inset.tick_params(labelsize=6)
    th = np.linspace(0, 2 * np.pi, 300)
    for k, (n, i) in enumerate(zip(names, labels)):
        a = fig.add_subplot(2, 4, 5 + k)
        lam = points[i].multipliers
        a.plot(np.cos(th), np.sin(th), "k-", lw=0.5)
        a.plot(lam.real, lam.imag, ".", ms=3)
        a.set_aspect("equal")
        a.set_title(f"({n}) max |l| = {lmax[i]:.6f}", fontsize=8)
        a.tick_params(labelsize=6)
    fig.tight_layout()
    save_figure(fig, out, "continuation_omega_floquet")
