"""The w_b = 1.01, K = 160, M = 30, N = 201 breather: Newton shooting, Floquet multipliers, and a check
by direct simulation over 100 periods; tangent vs finite-difference Jacobians charted.

Command: ``python -m scenarios run breather --device cpu`` (about 40 s on a 2-core CPU; ``--quick`` ~15 s).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``), e.g. ``--set M=30 --set K=10 --set N=101
--set omega=1.012`` for another breather of the family (the frequency in the gap below sqrt((M + 1) / M)).

Steps: the NLS seed -> Newton on the time-reversible half-period map (tangent Jacobian, kahan8,
32 steps per period) -> the full 804 x 804 monodromy and its multipliers -> the general
formulation (full state, x(T) - x0 plus a phase condition) from the same seed as a cross-check
-> 100 periods of direct simulation with the same integrator and an independent scipy DOP853 run.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from continuation import find_breather, floquet, nls_seed, require
from continuation.floquet import VERDICTS
from warpchain import Guard, Record
from warpchain import ChainParams, propagate_tangent, simulate
from warpchain.reference import solve_ivp_reference
from warpchain.store import read_group, write_fields, write_table

from ._common import (
    BREATHER_METHOD,
    BREATHER_STEPS_PER_PERIOD,
    PAPER_K,
    PAPER_M,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    Refused,
    paper_breather,
    pyplot,
    read_summary,
    save_figure,
)
from ._params import Rule, param


#: the longest chain of this scene: its full-monodromy and general-formulation cross-checks factor and diagonalise
#: 4N x 4N dense matrices (6404 x 6404 here, 1.3 GB and tens of minutes at 3201 sites on 2 cores)
CHECKED_MAX_SITES = 1601


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    M: float = param(PAPER_M, "mass ratio m1 / m2", gt=0)
    K: float = param(PAPER_K, "coupling ratio k1 / k2", gt=0)
    N: int = param(
        PAPER_N,
        "sites of the chain (fixed ends); the breather sits at site N // 2; its cross-checks hold the dense 4N x 4N "
        "monodromy (longer chains: continuation.floquet on the sliced path, or finite-size)",
        ge=3,
        le=CHECKED_MAX_SITES,
    )
    omega: float = param(
        PAPER_OMEGA, "breather frequency w_b, in the gap below the optical bottom sqrt((M + 1) / M)", gt=0
    )
    periods: int = param(
        100, "periods of the direct-simulation check with the breather's own integrator", ge=1, le=100_000
    )
    dop853_periods: int = param(100, "periods of the independent scipy DOP853 check", ge=1, le=10_000)
    fd_steps: tuple[float, ...] = param(
        (1e-3, 1e-5, 1e-7, 1e-9),
        "finite-difference steps h of the Jacobian comparison; contact is lost at a displacement of 1",
        gt=0,
        lt=1,
        length=(1, None),
    )
    contact_loss_scale: float = param(3.0, "the breather profile scaled up until resonators lose contact", gt=1)
    general_seed_near_solution: bool = param(
        False, "seed the general formulation next to the solution, not from the NLS profile"
    )

    RULES = (
        Rule(
            ("periods", "N"),
            "periods x N <= 1e8: the direct-simulation check keeps one frame of N sites per period in memory",
            lambda P: P.periods * P.N <= 10**8,
        ),
    )


QUICK = {"dop853_periods": 10, "general_seed_near_solution": True}


def _jacobian_comparison(params, state, n_half, dt, device, label, fd_steps):
    """Half-period Jacobian (2N position columns): tangent vs central finite differences."""
    N = params.N
    directions = np.eye(4 * N)[: 2 * N].reshape(2 * N, 4, N)
    t0 = time.perf_counter()
    tan = propagate_tangent(params, state, directions, n_half, dt, method=BREATHER_METHOD, device=device)
    t_tan = time.perf_counter() - t0
    J = tan.columns.reshape(2 * N, -1)
    rows = [{"case": label, "jacobian": "tangent", "h": None, "seconds": t_tan, "relative_difference": 0.0}]
    for h in fd_steps:
        t0 = time.perf_counter()
        batch = np.concatenate([state[None] + h * directions, state[None] - h * directions])
        run = simulate(
            params,
            batch,
            n_half * dt,
            dt,
            method=BREATHER_METHOD,
            device=device,
            guard=Guard(max_energy_error=None, chunks=1),
        )
        fd = ((run.x[: 2 * N] - run.x[2 * N :]) / (2 * h)).reshape(2 * N, -1)
        rows.append(
            {
                "case": label,
                "jacobian": "finite-difference",
                "h": h,
                "seconds": time.perf_counter() - t0,
                "relative_difference": float(np.max(np.abs(fd - J)) / np.max(np.abs(J))),
            }
        )
    return rows


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    start = time.perf_counter()
    params = ChainParams(P.M, P.K, P.N)
    if not P.omega < params.omega0:
        raise Refused(
            f"--set omega={P.omega:g}: a breather of this family lies below the optical bottom "
            f"sqrt((M + 1) / M) = {params.omega0:.6g} (M = {P.M:g})"
        )
    b = paper_breather(ctx.device, log=ctx.log, params=params, omega=P.omega)
    ctx.log(b.message)
    fl = floquet(b, device=ctx.device)
    ctx.log(
        "Floquet (reduced, 2N = %d): max nontrivial |l| = %.8f, tolerance %.2e in mu (trivial mu off by %.1e, "
        "symplecticity %.1e) -> %s (%.2f s); instabilities: %s",
        2 * params.N,
        fl.max_modulus,
        fl.tolerance,
        fl.accuracy["trivial_deviation"],
        fl.accuracy["symplecticity"],
        fl.verdict if fl.complete else "not decided (a partial analysis)",
        fl.wall_seconds,
        ", ".join(
            f"{i.kind} |l| = {i.modulus:.8f} ({'localized' if i.localized else 'extended'}, "
            f"participation {i.participation:.1f})"
            for i in fl.instabilities
        )
        or "none",
    )
    full = floquet(b, device=ctx.device, reduced=False)
    reduced_vs_full = abs(fl.max_modulus - full.max_modulus)
    ctx.log(
        "Floquet (full 4N monodromy, cross-check): max |l| = %.10f (differs by %.1e), pairing error %.2e (%.2f s)",
        full.max_modulus,
        reduced_vs_full,
        full.pairing_error,
        full.wall_seconds,
    )

    # cross-check: the general formulation from the same seed
    if P.general_seed_near_solution:  # a few cheap iterations
        seed = b.state + 1e-4 * np.exp(-(((np.arange(params.N) - params.N // 2) / 3.0) ** 2))
    else:
        seed = nls_seed(params, P.omega)
    general = require(
        find_breather(
            params,
            P.omega,
            seed,
            formulation="general",
            method=BREATHER_METHOD,
            steps_per_period=BREATHER_STEPS_PER_PERIOD,
            device=ctx.device,
        )
    )
    general_diff = float(np.max(np.abs(general.state - b.state)))
    ctx.log("general formulation: %s; max state difference to the reversible one %.2e", general.message, general_diff)

    # direct simulation over many periods with the same integrator, sampled once per period
    n_period = 2 * b.nsteps
    direct = simulate(
        params,
        b.state,
        P.periods * n_period * b.dt,
        b.dt,
        method=b.method,
        device=ctx.device,
        progress=False,
        record=Record(every=n_period),
    )
    amp = np.max(np.abs(b.state[:2]))
    deviation = (
        np.maximum(
            np.max(np.abs(direct.u[:, 0] - b.state[0]), axis=-1), np.max(np.abs(direct.v[:, 0] - b.state[1]), axis=-1)
        )
        / amp
    )
    ctx.log(
        "direct simulation: %d periods, max relative deviation from the initial profile %.2e, energy error %.1e",
        P.periods,
        deviation.max(),
        direct.energy_error[0],
    )
    t0 = time.perf_counter()
    dop_end, sol = solve_ivp_reference(params, b.state, P.dop853_periods * b.period, rtol=1e-11, atol=1e-13)
    dop_dev = float(np.max(np.abs(dop_end[:2] - b.state[:2])) / amp)
    ctx.log(
        "scipy DOP853 (rtol 1e-11): %d periods in %.1f s, relative deviation %.2e",
        P.dop853_periods,
        time.perf_counter() - t0,
        dop_dev,
    )

    # tangent vs finite-difference Jacobians: smooth orbit and an orbit that loses contact
    rows = _jacobian_comparison(params, b.state, b.nsteps, b.dt, ctx.device, "breather (smooth)", P.fd_steps)
    loss_state = P.contact_loss_scale * b.state
    rows_loss = _jacobian_comparison(params, loss_state, b.nsteps, b.dt, ctx.device, "contact loss", P.fd_steps)
    loss_contact = float(
        simulate(
            params,
            loss_state,
            b.nsteps * b.dt,
            b.dt,
            method=b.method,
            device=ctx.device,
            record=Record(every=1),
            guard=Guard(max_energy_error=None),
        ).min_contact[0]
    )
    ctx.log("contact-loss orbit: min(1 + u - v) = %.3f over the half period", loss_contact)
    rows += rows_loss

    root = ctx.store(params)
    write_table(
        root,
        "breather",
        {
            "site": np.arange(params.N),
            "u": b.state[0],
            "v": b.state[1],
            "u_general": general.state[0],
            "v_general": general.state[1],
        },
        dim="site",
        attrs={"omega": b.omega, "energy": b.energy, "method": b.method, "dt": b.dt},
    )
    write_table(
        root,
        "multipliers",
        {
            "real": fl.multipliers.real,
            "imag": fl.multipliers.imag,
            "trivial": np.isin(np.arange(len(fl.multipliers)), fl.trivial),
        },
        dim="multiplier",
        attrs={"pairing_error": full.pairing_error, "tolerance": fl.tolerance, "path": fl.path},
    )
    write_table(root, "newton", {"residual": np.array(b.residual_history)}, dim="iteration")
    write_fields(
        root,
        ctx.out / "data.zarr",
        "direct",
        direct.t,
        {"u": direct.u[:, 0], "v": direct.v[:, 0]},
        ("t", "site"),
        chunk_t=64,
        attrs={"method": direct.method, "dt": direct.dt, "sampled": "once per period"},
    )
    write_table(
        root, "periodicity", {"period": np.arange(P.periods + 1), "relative_deviation": deviation}, dim="period"
    )
    cases = sorted({r["case"] for r in rows})
    write_table(
        root,
        "jacobian_comparison",
        {
            "case": np.array([cases.index(r["case"]) for r in rows]),
            "finite_difference": np.array([r["jacobian"] == "finite-difference" for r in rows]),
            "h": np.array([np.nan if r["h"] is None else r["h"] for r in rows]),
            "seconds": np.array([r["seconds"] for r in rows]),
            "relative_difference": np.array([r["relative_difference"] for r in rows]),
        },
        dim="row",
        attrs={"case_names": cases, "half_period_columns": 2 * params.N},
    )
    c = params.N // 2
    return {
        "M": params.M,
        "K": params.K,
        "N": params.N,
        "omega": b.omega,
        "energy": b.energy,
        "residual": b.residual,
        "newton_iterations": b.iterations,
        "residual_history": list(b.residual_history),
        "u_center": float(b.state[0, c]),
        "v_center": float(b.state[1, c]),
        "max_floquet_modulus": fl.max_modulus,
        "floquet_pairing_error": full.pairing_error,
        "floquet_tolerance": fl.tolerance,
        "floquet_accuracy": fl.accuracy,
        "stable": fl.stable,
        "verdict_complete": fl.complete,
        "symplecticity_error": fl.symplecticity_error,
        "instabilities": [i.as_dict() for i in fl.instabilities],
        "floquet_full": {
            "max_modulus": full.max_modulus,
            "pairing_error": full.pairing_error,
            "seconds": full.wall_seconds,
            "max_modulus_difference_to_reduced": reduced_vs_full,
        },
        "method": b.method,
        "dt": b.dt,
        "steps_per_period": 2 * b.nsteps,
        "newton_seconds": b.wall_seconds,
        "floquet_seconds": fl.wall_seconds,
        "general_formulation": {
            "iterations": general.iterations,
            "residual": general.residual,
            "max_state_difference": general_diff,
            "seconds": general.wall_seconds,
        },
        "direct_simulation": {
            "periods": P.periods,
            "max_relative_deviation": float(deviation.max()),
            "energy_error": float(direct.energy_error[0]),
            "seconds": direct.wall_seconds,
        },
        "dop853_check": {"periods": P.dop853_periods, "rtol": 1e-11, "relative_deviation": dop_dev},
        "jacobian_comparison": rows,
        "contact_loss_min_contact": loss_contact,
        "wall_seconds": time.perf_counter() - start,
    }


def plot(out) -> None:
    br, battrs = read_group(out / "data.zarr", "breather")
    mult, mattrs = read_group(out / "data.zarr", "multipliers")
    per, _ = read_group(out / "data.zarr", "periodicity")
    jac, jattrs = read_group(out / "data.zarr", "jacobian_comparison")
    s = read_summary(out)
    plt = pyplot()
    # top: the two profiles; bottom: the multipliers on the unit circle, how far each is off it (a panel of its
    # own, not an inset over the circle) and the direct simulation
    fig = plt.figure(figsize=(12, 8))
    gs = fig.add_gridspec(2, 6)
    axes = [fig.add_subplot(gs[0, :3]), fig.add_subplot(gs[0, 3:])]
    c = len(br["site"]) // 2
    sl = slice(max(c - 25, 0), c + 26)
    axes[0].plot(br["site"][sl], br["u"][sl], "o-", ms=3)
    axes[0].set_title(f"$u_j$ at t = 0 ($\\omega_b$ = {s['omega']}, K = {s['K']:g}, M = {s['M']:g})")
    axes[1].plot(br["site"][sl], br["v"][sl], "o-", ms=3, color="tab:orange")
    axes[1].set_title(f"$v_j$ at t = 0 (E = {s['energy']:.6f})")
    for ax in axes:
        ax.set_xlabel("site j")
    lam = mult["real"] + 1j * mult["imag"]
    ax = fig.add_subplot(gs[1, :2])
    th = np.linspace(0, 2 * np.pi, 400)
    ax.plot(np.cos(th), np.sin(th), "k-", lw=0.6)
    ax.plot(lam.real, lam.imag, ".", ms=4, label="multipliers")
    ax.plot(lam[mult["trivial"]].real, lam[mult["trivial"]].imag, "x", color="k", label="trivial pair")
    ax.set_aspect("equal")
    ax.set_title(
        f"Floquet multipliers $\\lambda$: max $|\\lambda|$ = {s['max_floquet_modulus']:.6f} ({VERDICTS[s['stable']]})",
        fontsize=9,
    )
    ax.set_xlabel(r"Re $\lambda$")
    ax.set_ylabel(r"Im $\lambda$")
    ax.legend(fontsize=8, loc="center", frameon=False)  # the inside of the unit circle holds no multiplier
    # how far each multiplier is off the circle, in units of 1e-4, against its angle
    ax = fig.add_subplot(gs[1, 2:4])
    ax.plot(1e4 * (np.abs(lam) - 1), np.angle(lam), ".", ms=4)
    ax.plot(1e4 * (np.abs(lam[mult["trivial"]]) - 1), np.angle(lam[mult["trivial"]]), "x", color="k")
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlim(-4, 4)
    ax.set_xlabel(r"($|\lambda|$ - 1) $\times 10^4$")
    ax.set_ylabel(r"arg $\lambda$")
    ax.set_title(r"distance from the unit circle", fontsize=9)
    ax = fig.add_subplot(gs[1, 4:])
    ax.semilogy(per["period"], np.maximum(per["relative_deviation"], 1e-17), "-")
    ax.set_xlabel("periods")
    ax.set_ylabel(r"max $|x(nT) - x(0)|$ / max $|x(0)|$")
    ax.set_title("direct simulation with the same integrator", fontsize=9)
    fig.tight_layout()
    save_figure(fig, out, "breather")

    fig, ax = plt.subplots(figsize=(6, 4))
    for k, (case, marker) in enumerate(zip(jattrs["case_names"], "os")):
        m = (jac["case"] == k) & jac["finite_difference"]
        t = (jac["case"] == k) & ~jac["finite_difference"]
        timing = f"tangent {jac['seconds'][t][0]:.2f} s, FD {np.mean(jac['seconds'][m]):.2f} s per h"
        ax.loglog(jac["h"][m], jac["relative_difference"][m], marker + "-", label=f"{case}: FD vs tangent ({timing})")
    ax.set_xlabel("finite-difference step h")
    ax.set_ylabel("max |J_FD - J_tangent| / max |J|")
    ax.set_title("half-period Jacobian: finite differences vs tangent", fontsize=10)
    # below the axes: every point, the smooth orbit's best step included, stays in view
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    save_figure(fig, out, "jacobian_comparison")
