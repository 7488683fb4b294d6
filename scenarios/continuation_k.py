"""Continuation in the coupling K (paper Fig. 6): M = 30, w_b = 1.01, N = 201, from the single-site
anti-continuum seed at K = 0.01 to K = 160, energy and Floquet multipliers at every point.

Command: ``python -m scenarios run continuation-k`` (a few minutes on a 2-core CPU; ``--quick``, N = 101
and coarser steps, under a minute).

Natural-parameter continuation with a secant predictor in log10 K, adaptive steps, landing exactly on
K = 5, 20 (profiles I, II) and 160 (III); stability changes are located by bisection with the
multipliers recomputed at every trial point. The branch is stored point by point in data.zarr
(group ``branch``) and can be resumed from it. The NLS energy at K = 160 is the reference line.
"""

from __future__ import annotations

import numpy as np

from continuation import anticontinuum_seed, nls_seed
from continuation.branch import BranchStore, continue_in_coupling, load_branch
from warpchain import ChainParams, energy

from ._common import (BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, PAPER_K, PAPER_M, PAPER_N, PAPER_OMEGA, Context,
                      pyplot, read_summary, save_figure)

# parameters
K_START, K_END, PROFILE_K = 0.01, PAPER_K, (5.0, 20.0, PAPER_K)
STEP, MAX_STEP = 0.15, 0.3          # in log10 K
QUICK = {"N": 101, "STEP": 0.5, "MAX_STEP": 1.0, "BISECTION": 1}


def run(ctx: Context) -> dict:
    N = QUICK["N"] if ctx.quick else PAPER_N
    params = ChainParams(PAPER_M, K_START, N)
    store = BranchStore(ctx.out / "data.zarr", "branch", params,
                        {"omega": PAPER_OMEGA, "method": BREATHER_METHOD, "steps_per_period": BREATHER_STEPS_PER_PERIOD,
                         "continuation": "natural, secant predictor in log10 K"}, max_newton=24, device=ctx.device)
    branch = continue_in_coupling(
        params, PAPER_OMEGA, anticontinuum_seed(params, PAPER_OMEGA), K_END, targets=PROFILE_K,
        step=QUICK["STEP"] if ctx.quick else STEP, max_step=QUICK["MAX_STEP"] if ctx.quick else MAX_STEP,
        bisection_steps=QUICK["BISECTION"] if ctx.quick else 3, method=BREATHER_METHOD,
        steps_per_period=BREATHER_STEPS_PER_PERIOD, device=ctx.device, store=store, progress=True, log=ctx.log)
    ctx.log("stop: %s (%d points, %.0f s)", branch.message, len(branch.points), branch.wall_seconds)
    nls_energy = float(energy(params.replace(K=PAPER_K), nls_seed(params.replace(K=PAPER_K), PAPER_OMEGA))[0])
    end = branch.points[-1]
    return {
        "omega": PAPER_OMEGA, "M": PAPER_M, "N": N,
        "points": [{"K": p.K, "energy": p.energy, "max_floquet_modulus": p.max_modulus, "stable": p.stable,
                    "min_contact": p.min_contact, "newton_iterations": p.iterations} for p in branch.points],
        "nls_energy_at_K160": nls_energy, "stop_reason": branch.stop_reason, "message": branch.message,
        "end_K": end.K, "end_energy": end.energy, "end_max_floquet_modulus": end.max_modulus,
        "unstable_K_intervals": [e["located"] for e in branch.events if e["type"] == "stability_change"],
        "events": branch.events, "method": BREATHER_METHOD, "steps_per_period": BREATHER_STEPS_PER_PERIOD,
        "branch_seconds": branch.wall_seconds,
    }


def plot(out) -> None:
    _, points, attrs = load_branch(out / "data.zarr", "branch")
    s = read_summary(out)
    K = np.array([p.K for p in points])
    E = np.array([p.energy for p in points])
    stable = np.array([p.stable for p in points])
    plt = pyplot()
    fig = plt.figure(figsize=(11, 7))
    ax = fig.add_subplot(2, 1, 1)
    ax.semilogx(K, E, "-", color="0.6", lw=1)
    ax.semilogx(K[stable], E[stable], "o", ms=4, color="tab:blue", label="stable")
    ax.semilogx(K[~stable], E[~stable], "o", ms=4, mfc="none", color="tab:red", label="unstable (|l| > 1 + tol)")
    ax.axhline(s["nls_energy_at_K160"], color="k", ls="--", lw=1, label="NLS energy at K = 160")
    for lab, k in zip(("I", "II", "III"), (5.0, 20.0, 160.0)):
        i = np.argmin(np.abs(K - k))
        if abs(K[i] - k) < 1e-9 * k:
            ax.annotate(lab, (K[i], E[i]), textcoords="offset points", xytext=(-4, 8))
    ax.set_xlabel("K")
    ax.set_ylabel("energy H")
    ax.set_title(f"continuation in K: M = {s['M']:g}, $\\omega_b$ = {s['omega']}, N = {s['N']} ({s['stop_reason']})")
    ax.legend(fontsize=8)
    for col, comp in enumerate(("u", "v")):
        a = fig.add_subplot(2, 2, 3 + col)
        for lab, k in zip(("I", "II", "III"), (5.0, 20.0, 160.0)):
            i = np.argmin(np.abs(K - k))
            if abs(K[i] - k) < 1e-9 * k:
                prof = points[i].state[col]
                c = len(prof) // 2
                sites = np.arange(c - 15, c + 16)
                a.plot(sites + 1, prof[sites], "o-", ms=3, label=f"{lab}: K = {k:g}")
        a.set_xlabel("site j")
        a.set_ylabel(f"{comp}_j (t = 0)")
        a.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out, "continuation_k")
