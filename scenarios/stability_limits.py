"""Where methods fail: measured vs linear stability limits, observed orders on a smooth run and a run
with contact loss, where fixed-frequency Newton stops converging as w_b enters the acoustic band, and
float32 against float64.

Command: ``python -m scenarios run stability-limits`` (about 1-2 minutes on a 2-core CPU; ``--quick`` ~30 s).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

* Measured limit: the largest step at which a small-amplitude eigenmode state (plus 1e-6 noise on every
  site, to seed the highest modes) survives 3000 steps, found by bisection around the linear limit
  (from the top of the optical band); also for the exact breather, whose compressed contacts are stiffer.
* Orders: slope of log error vs log dt against DOP853 (rtol 1e-13), on the breather over 5 periods
  (smooth) and on the eigenmode at 2.5 times the breather's v_101 over 2 periods (contact lost: the
  contact force is not smooth there, so the high-order methods are expected to lose order).
* Newton: natural continuation in w_b downwards from the 1.01 breather with fixed-frequency Newton.
* float32: the numpy reference run in single precision (same schemes): error reached on the smooth run,
  and Newton (tangent Jacobian, float32) on the breather problem - the residual it can reach.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from continuation import eigenmode_seed, find_breather
from continuation.shooting import _solve
from warpchain import Guard, Record
from warpchain.model import _signed_energy_change
from warpchain import (
    METHODS,
    ChainParams,
    IntegrationError,
    SplittingMethod,
    band_edges,
    reference,
    simulate,
    stability_limit,
)

from ._common import (
    BREATHER_METHOD,
    BREATHER_STEPS_PER_PERIOD,
    PAPER_K,
    PAPER_M,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    paper_breather,
    method_run,
    reference_run,
    pyplot,
    read_summary,
    save_figure,
)
from ._params import Rule, number, param

#: steps per period of the observed-order fits, per method (not a ``Parameters`` field: one tuple per method)
ORDER_STEPS_PER_PERIOD = {
    "verlet": (256, 512, 1024),
    "yoshida4": (64, 128, 256),
    "yoshida6": (32, 64, 128),
    "kahan6": (32, 48, 64),
    "kahan8": (16, 24, 32),
    "rk4": (64, 128, 256),
}


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    limit_steps: int = param(3000, "steps a run must survive at a measured stability limit", ge=1, le=1_000_000)
    bisections: int = param(12, "bisection steps of each measured limit", ge=1, le=60)
    smooth_periods: int = param(5, "periods of the exact breather for the observed orders and float32", ge=1, le=10_000)
    rough_periods: int = param(
        2, "periods of the large eigenmode for the observed orders with contact loss", ge=1, le=10_000
    )
    rough_scale: float = param(2.5, "that eigenmode's amplitude, in units of the exact breather's v_101", gt=0)
    newton_step: float = param(0.002, "fixed-frequency Newton: decrement of w_b from the breather's 1.01", gt=0)
    newton_floor: float = param(0.95, "fixed-frequency Newton: the lowest w_b tried", gt=0)
    float32_newton_iterations: int = param(6, "Newton iterations in float32", ge=1, le=100)

    RULES = (
        Rule(
            ("newton_floor", "newton_step"),
            f"newton_floor <= {number(PAPER_OMEGA)} - newton_step: Newton goes down from the breather's w_b and "
            "tries one frequency at least",
            lambda P: P.newton_floor <= PAPER_OMEGA - P.newton_step,
        ),
        Rule(
            ("newton_step", "newton_floor"),
            "(1.01 - newton_floor) / newton_step <= 10000 frequencies tried",
            lambda P: (PAPER_OMEGA - P.newton_floor) / P.newton_step <= 10_000,
        ),
    )


QUICK = {"bisections": 6, "newton_floor": 0.99, "float32_newton_iterations": 3}


def _survives(params, x0, dt, method, device, limit_steps):
    if not isinstance(METHODS[method], SplittingMethod):  # RK4 runs on the numpy reference: simulate's guard
        _, _, E = reference_run(method, params, x0, limit_steps * dt, dt, chunks=10)
        return bool(np.all(np.isfinite(E)) and np.max(np.abs(_signed_energy_change(E, E[0], params.N))) <= 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            simulate(
                params,
                x0,
                limit_steps * dt,
                dt,
                method=method,
                device=device,
                guard=Guard(allow_unstable_step=True, max_energy_error=0.5, chunks=10),
            )
            return True
        except IntegrationError:
            return False


def measured_limit(params, x0, method, device, bisections, limit_steps):
    linear = stability_limit(method, params)
    lo, hi = 0.5 * linear, 1.5 * linear
    if not _survives(params, x0, lo, method, device, limit_steps):
        return None
    while _survives(params, x0, hi, method, device, limit_steps):
        hi *= 1.5
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _survives(params, x0, mid, method, device, limit_steps) else (lo, mid)
    return lo


def observed_order(params, x0, periods, period, method, device, ref):
    dts = np.array([period / spp for spp in ORDER_STEPS_PER_PERIOD[method]])
    errs = np.array(
        [np.max(np.abs(method_run(method, params, x0, periods * period, dt, 1, device)[0] - ref)) for dt in dts]
    )
    return float(np.polyfit(np.log(dts), np.log(errs), 1)[0]), errs.tolist(), dts.tolist()


def float32_newton(params, state, omega, method, steps_per_period, iterations=6):
    """Newton on the reversible half-period map, everything in float32 (numpy reference with its tangent)."""
    N = params.N
    n_half = steps_per_period // 2
    dt = np.pi / omega / n_half
    q = state[:2].ravel().astype(np.float32)
    cols = np.eye(4 * N, dtype=np.float32)[: 2 * N].reshape(1, 2 * N, 4, N)
    history = []
    for _ in range(iterations):
        x0 = np.zeros((1, 4, N), np.float32)
        x0[0, :2] = q.reshape(2, N)
        out = reference.integrate(method, params, x0, dt, n_half, dx0=cols, dtype=np.float32)
        r = out["x"][0, 2:].ravel()
        history.append(float(np.linalg.norm(r.astype(np.float64))))
        J = out["dx"][0][:, 2:].reshape(2 * N, 2 * N).T
        step, _ = _solve(J.astype(np.float32), r)
        q = (q - step.astype(np.float32)).astype(np.float32)
    return history


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    b = paper_breather(ctx.device, log=ctx.log)
    c = params.N // 2
    mode = eigenmode_seed(params, 0.01)
    noisy = mode + 1e-6 * np.random.default_rng(0).standard_normal(mode.shape) * np.array([1, 1, 0, 0])[:, None]
    mode_big = P.rough_scale * eigenmode_seed(params, abs(b.state[1, c]))
    mode_big *= np.sign(mode_big[1, c] * b.state[1, c])
    ref_smooth, _ = reference.solve_ivp_reference(params, b.state, P.smooth_periods * b.period, rtol=1e-13, atol=1e-16)
    ref_rough, _ = reference.solve_ivp_reference(params, mode_big, P.rough_periods * b.period, rtol=1e-13, atol=1e-16)
    rough_contact = float(
        simulate(
            params,
            mode_big,
            P.rough_periods * b.period,
            b.period / 256,
            method="yoshida6",
            device=ctx.device,
            record=Record(every=1),
            guard=Guard(max_energy_error=None),
        ).min_contact[0]
    )
    methods = {}
    for name in METHODS:
        linear = stability_limit(name, params)
        lin_measured = measured_limit(params, noisy, name, ctx.device, P.bisections, P.limit_steps)
        breather_measured = measured_limit(params, b.state, name, ctx.device, P.bisections, P.limit_steps)
        o_s, e_s, d_s = observed_order(params, b.state, P.smooth_periods, b.period, name, ctx.device, ref_smooth)
        o_r, e_r, d_r = observed_order(params, mode_big, P.rough_periods, b.period, name, ctx.device, ref_rough)
        methods[name] = {
            "order": METHODS[name].order,
            "linear_limit": linear,
            "measured_limit": lin_measured,
            "measured_limit_breather": breather_measured,
            "order_smooth": o_s,
            "order_contact_loss": o_r,
            "errors_smooth": e_s,
            "errors_contact_loss": e_r,
            "dts_smooth": d_s,
            "dts_contact_loss": d_r,
        }
        if not METHODS[name].symplectic:
            methods[name]["note"] = (
                "not symplectic: |R(i w dt)| < 1 damps the motion, so the run fails the 50 % "
                "energy criterion (numerical damping) before its linear stability bound"
            )
        ctx.log(
            "%-8s linear limit %.4f, measured %.4f (breather %.4f); order smooth %.2f, with contact loss %.2f",
            name,
            linear,
            lin_measured or float("nan"),
            breather_measured or float("nan"),
            o_s,
            o_r,
        )

    # fixed-frequency Newton going down in frequency
    edges = band_edges(PAPER_M, PAPER_K)
    omega, state, last_ok, failure, trail = b.omega, b.state, b.omega, None, []
    while omega - P.newton_step >= P.newton_floor:
        omega -= P.newton_step
        res = find_breather(
            params,
            omega,
            state,
            method=BREATHER_METHOD,
            steps_per_period=BREATHER_STEPS_PER_PERIOD,
            max_iterations=15,
            device=ctx.device,
        )
        trail.append({"omega": omega, "converged": res.success, "iterations": res.iterations, "residual": res.residual})
        if not res.success:
            failure = {"omega": omega, "message": res.message}
            break
        state, last_ok = res.state, omega
    ctx.log(
        "fixed-frequency Newton: last converged at w_b = %.4f%s",
        last_ok,
        f", failed at {failure['omega']:.4f}" if failure else " (no failure above the floor)",
    )

    # float32 vs float64
    f32 = {}
    for name in ("verlet", "kahan8"):
        dt = b.period / (256 if name == "verlet" else 32)
        n = int(round(P.smooth_periods * b.period / dt))
        x32 = reference.integrate(name, params, b.state[None], dt, n, dtype=np.float32)["x"][0].astype(np.float64)
        x64 = simulate(params, b.state, n * dt, dt, method=name, device=ctx.device, guard=Guard(chunks=1)).x[0]
        scale = np.max(np.abs(ref_smooth))
        f32[name] = {
            "dt": dt,
            "error_float32": float(np.max(np.abs(x32 - ref_smooth)) / scale),
            "error_float64": float(np.max(np.abs(x64 - ref_smooth)) / scale),
        }
    newton32 = float32_newton(
        params,
        b.state + 1e-4 * (b.state != 0),
        b.omega,
        BREATHER_METHOD,
        BREATHER_STEPS_PER_PERIOD,
        iterations=P.float32_newton_iterations,
    )
    f32["newton_residual_history"] = newton32
    f32["newton_best_residual"] = min(newton32)
    f32["newton_reaches_1e-10"] = bool(min(newton32) <= 1e-10)
    f32["finding"] = (
        "float32 is enough where truncation error dominates (Verlet at 256 steps per period: the same "
        "error in both precisions), not for breather accuracy: kahan8 floors at the float32 roundoff "
        "level, and float32 Newton stalls near 1e-6, far from the 1e-10 tolerance"
    )
    ctx.log(
        "float32: smooth-run error %s; Newton residuals %s",
        {k: f"{v['error_float32']:.1e}" for k, v in f32.items() if isinstance(v, dict)},
        ", ".join(f"{r:.1e}" for r in newton32),
    )
    return {
        "methods": methods,
        "linear_limit_basis": f"bound / optical band top {edges['optical_top']:.6f}",
        "rough_case_min_contact": rough_contact,
        "newton_fails_below_omega": failure["omega"] if failure else None,
        "newton_last_converged_omega": last_ok,
        "newton_failure": failure,
        "newton_trail": trail,
        "acoustic_top": edges["acoustic_top"],
        "float32": f32,
    }


def plot(out) -> None:
    s = read_summary(out)
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    names = list(s["methods"])
    x = np.arange(len(names))
    ax = axes[0]
    ax.bar(x - 0.25, [s["methods"][n]["linear_limit"] for n in names], 0.25, label="linear (optical band top)")
    ax.bar(x, [s["methods"][n]["measured_limit"] or 0 for n in names], 0.25, label="measured, small amplitude")
    ax.bar(
        x + 0.25,
        [s["methods"][n]["measured_limit_breather"] or 0 for n in names],
        0.25,
        label="measured, exact breather",
    )
    ax.set_xticks(x, names, fontsize=8)
    ax.set_ylabel("largest stable dt")
    ax.legend(fontsize=7)
    ax = axes[1]
    for n in names:
        m = s["methods"][n]
        (line,) = ax.loglog(m["dts_smooth"], m["errors_smooth"], "o-", ms=3, label=f"{n} ({m['order_smooth']:.1f})")
        ax.loglog(
            m["dts_contact_loss"],
            m["errors_contact_loss"],
            "s--",
            ms=3,
            color=line.get_color(),
            label=f"{n}, contact loss ({m['order_contact_loss']:.1f})",
        )
    ax.set_xlabel("dt")
    ax.set_ylabel("final-state error")
    ax.set_title("observed orders (slope): smooth solid, contact loss dashed", fontsize=9)
    ax.legend(fontsize=5, ncol=2)
    ax = axes[2]
    trail = s["newton_trail"]
    ax.semilogy([t["omega"] for t in trail], [max(t["residual"], 1e-16) for t in trail], "o-")
    ax.axvline(s["acoustic_top"], color="k", ls=":", label="acoustic band top")
    ax.axhline(1e-10, color="0.6", lw=0.8)
    ax.set_xlabel(r"$\omega_b$")
    ax.set_ylabel("final Newton residual")
    ax.set_title("fixed-frequency Newton going down in frequency", fontsize=9)
    ax.invert_xaxis()
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, out, "stability_limits")
