"""Work-precision: final-state error against a tight reference vs wall time, for every Warp method over a
range of steps, the numpy reference and scipy's DOP853 over a range of tolerances - all in one run, on
the current device - for a smooth run and a rough one; and the energy error vs time of the symplectic
methods.

Command: ``python -m scenarios run work-precision`` (about 2 minutes on a 2-core CPU; ``--quick`` ~30 s).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

Cases: ``smooth``, the exact w_b = 1.01 breather over 20 periods; ``contact-loss``, the lowest optical
eigenmode at 2.5 times the exact breather's v_101, which loses contact within the first period, over 5
periods. Reference: DOP853 at rtol 1e-13. Error: max |x - x_ref| / max |x_ref| over the final state.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from continuation import eigenmode_seed
from warpchain import Guard
from warpchain import METHODS, ChainParams, SplittingMethod, reference, simulate, stability_limit
from warpchain.store import read_group, write_table

from ._common import (
    PAPER_K,
    PAPER_M,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    paper_breather,
    pyplot,
    read_summary,
    method_run,
    save_figure,
)
from ._params import Rule, min_steps_per_period, param


def _numpy_steps() -> int:
    """The fewest steps per breather period below every method's linear stability limit: the numpy
    reference runs every method at each of ``numpy_steps_per_period`` (the Warp runs skip unstable steps)."""
    return max(min_steps_per_period(name, PAPER_M, PAPER_K, PAPER_OMEGA) for name in METHODS)


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    smooth_periods: int = param(20, "periods of the exact breather, the smooth case", ge=1, le=10_000)
    contact_loss_periods: int = param(5, "periods of the contact-loss case", ge=1, le=10_000)
    contact_loss_scale: float = param(
        2.5, "that case's eigenmode amplitude, in units of the exact breather's v_101", ge=1, le=100
    )
    steps_per_period: tuple[int, ...] = param(
        (24, 32, 48, 64, 96, 128, 192, 256, 384, 512, 768, 1024),
        "steps per period of the Warp methods; steps above a method's stability limit are skipped",
        ge=1,
        length=(1, None),
        le=65536,
    )
    numpy_steps_per_period: tuple[int, ...] = param(
        (64, 256), "steps per period of the numpy reference, every method at each", ge=1, le=65536
    )
    dop853_rtol: tuple[float, ...] = param(
        (1e-5, 1e-7, 1e-9, 1e-11), "relative tolerances of scipy's DOP853 (float64 takes >= 1e-13)", ge=1e-13, lt=1
    )
    targets: tuple[float, ...] = param(
        (1e-4, 1e-6, 1e-8, 1e-9, 1e-10), "relative errors at which the cheapest implementation is reported", gt=0
    )
    repeats: int = param(2, "best of, for the timings", ge=1, le=100)

    RULES = (
        Rule(
            ("numpy_steps_per_period",),
            lambda P: (
                f"every numpy_steps_per_period >= {_numpy_steps()}: the numpy reference runs every method "
                "there, and needs the step below each one's linear stability limit"
            ),
            lambda P: all(n >= _numpy_steps() for n in P.numpy_steps_per_period),
        ),
    )


QUICK = {"steps_per_period": (24, 64, 192, 512), "numpy_steps_per_period": (), "dop853_rtol": (1e-5, 1e-9)}


def _timed(fn, repeats):
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def _error(x, ref):
    return float(np.max(np.abs(np.asarray(x).reshape(ref.shape) - ref)) / np.max(np.abs(ref)))


def time_to_reach(points, target):
    """Seconds an implementation/method needs for error <= target, interpolated log-log along its
    curve (None if it never gets there)."""
    pts = sorted(points, key=lambda p: p["seconds"])
    for a, b in zip(pts[:-1], pts[1:]):
        if a["error"] > target >= b["error"]:
            la, lb = np.log(a["error"]), np.log(b["error"])
            f = (np.log(target) - la) / (lb - la)
            return float(np.exp(np.log(a["seconds"]) + f * (np.log(b["seconds"]) - np.log(a["seconds"]))))
    reached = [p["seconds"] for p in pts if p["error"] <= target]
    return min(reached) if reached else None


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    case_specs = {
        "smooth": {"periods": P.smooth_periods},
        "contact-loss": {"periods": P.contact_loss_periods, "scale": P.contact_loss_scale},
    }
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    b = paper_breather(ctx.device, log=ctx.log)
    c = params.N // 2
    states = {"smooth": b.state}
    mode = eigenmode_seed(params, abs(b.state[1, c]))
    states["contact-loss"] = case_specs["contact-loss"]["scale"] * mode * np.sign(mode[1, c] * b.state[1, c])
    points, energy_traces = [], {}
    for case, spec in case_specs.items():
        x0 = states[case]
        t_end = spec["periods"] * b.period
        ref, sol = reference.solve_ivp_reference(params, x0, t_end, rtol=1e-13, atol=1e-16)
        ctx.log("%s: reference DOP853 rtol 1e-13 (%d right-hand sides)", case, sol.nfev)
        for name, m in METHODS.items():
            limit = stability_limit(name, params)
            for spp in P.steps_per_period if isinstance(m, SplittingMethod) else ():  # RK4: the numpy rows only
                dt = b.period / spp
                if dt >= limit:
                    continue
                run, sec = _timed(
                    lambda: simulate(
                        params,
                        x0,
                        t_end,
                        dt,
                        method=name,
                        device=ctx.device,
                        guard=Guard(chunks=1, max_energy_error=None),
                    ),
                    P.repeats,
                )
                points.append(
                    {
                        "case": case,
                        "implementation": "warp",
                        "method": name,
                        "dt": dt,
                        "rtol": None,
                        "error": _error(run.x[0], ref),
                        "seconds": sec,
                        "force_evaluations": m.force_evaluations * run.nsteps,
                    }
                )
            for spp in P.numpy_steps_per_period:
                dt = b.period / spp
                nsteps = int(spp) * spec["periods"]
                out, sec = _timed(lambda: reference.integrate(name, params, x0[None], dt, nsteps), P.repeats)
                points.append(
                    {
                        "case": case,
                        "implementation": "numpy",
                        "method": name,
                        "dt": dt,
                        "rtol": None,
                        "error": _error(out["x"][0], ref),
                        "seconds": sec,
                        "force_evaluations": m.force_evaluations * nsteps,
                    }
                )
        for rtol in P.dop853_rtol:
            (end, sol), sec = _timed(
                lambda: reference.solve_ivp_reference(params, x0, t_end, rtol=rtol, atol=rtol * 1e-3), P.repeats
            )
            points.append(
                {
                    "case": case,
                    "implementation": "scipy",
                    "method": "DOP853",
                    "dt": None,
                    "rtol": rtol,
                    "error": _error(end, ref),
                    "seconds": sec,
                    "force_evaluations": int(sol.nfev),
                }
            )
        # energy error vs time for the symplectic methods (128 steps per period), and RK4 for contrast
        for name in METHODS:
            _, t, E = method_run(name, params, x0, t_end, b.period / 128, spec["periods"] * 4, ctx.device)
            energy_traces[(case, name)] = (t, np.abs(E - E[0]) / abs(E[0]))
        ctx.log("%s: %d points", case, sum(p["case"] == case for p in points))

    cheapest, speedups = {}, {}
    for case in case_specs:
        cheapest[case] = {}
        for target in P.targets:
            best = None
            for impl, method in sorted({(p["implementation"], p["method"]) for p in points if p["case"] == case}):
                sec = time_to_reach(
                    [p for p in points if p["case"] == case and p["implementation"] == impl and p["method"] == method],
                    target,
                )
                if sec is not None and (best is None or sec < best["seconds"]):
                    best = {"implementation": impl, "method": method, "seconds": sec}
            cheapest[case][f"{target:g}"] = best
        warp_best = cheapest[case].get("1e-09")
        dop = time_to_reach([p for p in points if p["case"] == case and p["implementation"] == "scipy"], 1e-9)
        warp_times = [
            time_to_reach(
                [p for p in points if p["case"] == case and p["implementation"] == "warp" and p["method"] == m], 1e-9
            )
            for m in METHODS
        ]
        warp_times = [t for t in warp_times if t is not None]  # no Warp method reaching 1e-9: no speedup stated
        if warp_best and dop and warp_times:
            warp_only = min(warp_times)
            speedups[case] = {
                "error": 1e-9,
                "best_warp_seconds": warp_only,
                "dop853_seconds": dop,
                "speedup_vs_dop853": dop / warp_only,
            }
        for target, best in cheapest[case].items():
            if best:
                ctx.log(
                    "%s, error <= %s: cheapest is %s %s (%.3g s)",
                    case,
                    target,
                    best["implementation"],
                    best["method"],
                    best["seconds"],
                )
        if case in speedups:
            ctx.log(
                "%s at error 1e-9: best Warp method %.3g s vs DOP853 %.3g s -> %.1fx",
                case,
                speedups[case]["best_warp_seconds"],
                speedups[case]["dop853_seconds"],
                speedups[case]["speedup_vs_dop853"],
            )

    root = ctx.store(params)
    impls = sorted({p["implementation"] for p in points})
    methods = sorted({p["method"] for p in points})
    cases = list(case_specs)
    write_table(
        root,
        "points",
        {
            "case": [cases.index(p["case"]) for p in points],
            "implementation": [impls.index(p["implementation"]) for p in points],
            "method": [methods.index(p["method"]) for p in points],
            "dt": [np.nan if p["dt"] is None else p["dt"] for p in points],
            "rtol": [np.nan if p["rtol"] is None else p["rtol"] for p in points],
            "error": [p["error"] for p in points],
            "seconds": [p["seconds"] for p in points],
        },
        dim="point",
        attrs={"case_names": cases, "implementation_names": impls, "method_names": methods},
    )
    for (case, name), (t, err) in energy_traces.items():
        write_table(root, f"energy/{case}/{name}", {"t": t, "relative_energy_error": err}, dim="t")
    return {
        "device": ctx.device,
        "cases": {k: {**v, "period": b.period} for k, v in case_specs.items()},
        "points": points,
        "cheapest": cheapest,
        "speedup_at_1e-9": speedups,
        "reference": "scipy DOP853 rtol 1e-13, atol 1e-16",
    }


def plot(out) -> None:
    s = read_summary(out)
    data, attrs = read_group(out / "data.zarr", "points")
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    colors = {
        "verlet": "tab:blue",
        "yoshida4": "tab:orange",
        "yoshida6": "tab:green",
        "kahan6": "tab:purple",
        "kahan8": "tab:brown",
        "rk4": "tab:red",
        "DOP853": "k",
    }
    for k, case in enumerate(attrs["case_names"]):
        ax = axes[k]
        for i_impl, impl in enumerate(attrs["implementation_names"]):
            for i_m, method in enumerate(attrs["method_names"]):
                m = (data["case"] == k) & (data["implementation"] == i_impl) & (data["method"] == i_m)
                if not m.any():
                    continue
                order = np.argsort(data["seconds"][m])
                style = {"warp": "o-", "numpy": "s--", "scipy": "^-"}[impl]
                ax.loglog(
                    data["error"][m][order],
                    data["seconds"][m][order],
                    style,
                    ms=4,
                    color=colors.get(method, "0.5"),
                    label=f"{impl} {method}",
                    mfc="none" if impl == "numpy" else None,
                )
        ax.axvline(1e-9, color="0.7", lw=0.6, ls=":")
        ax.set_xlabel("final-state error (relative)")
        ax.set_ylabel("seconds")
        sp = s["speedup_at_1e-9"].get(case)
        headline = f": best Warp {sp['speedup_vs_dop853']:.1f}x faster than DOP853 at 1e-9" if sp else ""
        ax.set_title(f"{case}{headline}", fontsize=9)
        ax.legend(fontsize=6, ncol=2)
    ax = axes[2]
    for case, ls in zip(attrs["case_names"], ("-", ":")):
        for method in colors:
            if method == "DOP853":
                continue
            d, _ = read_group(out / "data.zarr", f"energy/{case}/{method}")
            ax.semilogy(
                d["t"] / s["cases"][case]["period"],
                np.maximum(d["relative_energy_error"], 1e-17),
                ls,
                color=colors[method],
                label=f"{case} {method}",
            )
    ax.set_xlabel("t / T")
    ax.set_ylabel("|E(t) - E(0)| / E(0)")
    ax.set_title("energy error, 128 steps per period", fontsize=9)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    save_figure(fig, out, "work_precision")
