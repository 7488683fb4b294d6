"""Direct simulation (paper Fig. 9): four initial conditions at rest, run together as one batched
ensemble for 200 periods (T = 2 pi / 1.01) on 201 sites.

Command: ``python -m scenarios run direct-simulation`` (about 30 s on a 2-core CPU; ``--quick`` 20 periods).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

Cases (the paper's Fig. 9): ``breather-high`` the exact w_b = 1.01 breather computed by the project;
``breather-low`` that profile scaled so v_101 is 1/100 of the exact one; ``eigenmode-low`` the lowest
optical eigenmode with the same v_101 as breather-low; ``eigenmode-high`` the eigenmode with the exact
breather's v_101. Accuracy it needs: the space-time maps (1e-3 of the amplitude is invisible); the
integrator is kahan8 with 32 steps per period (the cheapest at the breather's accuracy,
work-precision scene) - the breather's own discrete map, so the exact
breather is periodic to its Newton tolerance - and a second run at half the step measures how far
each case's trajectory is from converged (the break-up case is chaotic: the difference grows).
Frames are stroboscopic (4 per breather period): the slow beating in the eigenmode-low map is that
sampling aliasing the mode's own frequency (1.01655 against 1.01), not a physical modulation.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from continuation import eigenmode_seed
from warpchain import Guard, Record
from warpchain import ChainParams, simulate
from warpchain.store import FieldWriter, read_group

from ._common import (
    progress_bars,
    BREATHER_STEPS_PER_PERIOD,
    PAPER_K,
    PAPER_M,
    PAPER_N,
    Context,
    paper_breather,
    period_envelope,
    pyplot,
    read_summary,
    save_figure,
)
from ._params import Rule, param

CASES = ("eigenmode-low", "breather-low", "eigenmode-high", "breather-high")  # Fig. 9 (a)-(d)


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    periods: int = param(200, "breather periods T = 2 pi / w_b simulated", ge=1, le=100_000)
    frames_per_period: int = param(
        16,
        f"stored frames per period: a divisor of the breather's {BREATHER_STEPS_PER_PERIOD} steps per period, "
        "enough for the per-period envelope of the maps",
        choices=tuple(n for n in range(1, BREATHER_STEPS_PER_PERIOD + 1) if BREATHER_STEPS_PER_PERIOD % n == 0),
    )

    RULES = (
        Rule(
            ("periods", "frames_per_period"),
            "periods x frames_per_period <= 1e5 frames (held in memory: 2.6 GB of 4 cases at 1e5)",
            lambda P: P.periods * P.frames_per_period <= 10**5,
        ),
    )


QUICK = {"periods": 20}


def initial_conditions(params, breather_state):
    c = params.N // 2
    v_exact = breather_state[1, c]
    mode = eigenmode_seed(params, abs(v_exact))
    if np.sign(mode[1, c]) != np.sign(v_exact):
        mode = -mode
    return {
        "eigenmode-low": mode / 100.0,
        "breather-low": breather_state / 100.0,
        "eigenmode-high": mode,
        "breather-high": breather_state.copy(),
    }


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    start = time.perf_counter()
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    b = paper_breather(ctx.device, log=ctx.log)
    ics = initial_conditions(params, b.state)
    x0 = np.stack([ics[name] for name in CASES])
    periods = P.periods
    steps_per_period = 2 * b.nsteps
    save_every = steps_per_period // P.frames_per_period
    root = ctx.store(params)
    writers = {
        name: FieldWriter(
            root,
            ctx.out / "data.zarr",
            name,
            {"u": (params.N,), "v": (params.N,)},
            ("t", "site"),
            chunk_t=128,
            expected_frames=periods * P.frames_per_period + 1,
            attrs={"case": name, "v101_initial": float(ics[name][1, params.N // 2])},
        )
        for name in CASES
    }

    def stream(t, u, v):
        for k, name in enumerate(CASES):
            writers[name].append(t, u=u[:, k], v=v[:, k])

    run_ = simulate(
        params,
        x0,
        periods * b.period,
        b.dt,
        method=b.method,
        device=ctx.device,
        progress=progress_bars(),
        record=Record(every=save_every, on_chunk=stream),
        guard=Guard(chunks=max(10, periods // 4)),
    )
    for name in CASES:
        writers[name].close(method=run_.method, dt=run_.dt)
    ctx.log("%d periods x %d lattices in %.1f s", periods, len(CASES), run_.wall_seconds)
    # accuracy: the same run at half the step, compared frame by frame
    half = simulate(
        params,
        x0,
        periods * b.period,
        b.dt / 2,
        method=b.method,
        device=ctx.device,
        record=Record(every=2 * save_every),
        guard=Guard(chunks=max(10, periods // 4)),
    )
    cases = {}
    for k, name in enumerate(CASES):
        scale = np.max(np.abs(x0[k, 1]))
        diff = (
            np.maximum(
                np.max(np.abs(run_.u[:, k] - half.u[:, k]), axis=-1),
                np.max(np.abs(run_.v[:, k] - half.v[:, k]), axis=-1),
            )
            / scale
        )
        late = np.flatnonzero(diff > 1e-3)
        cases[name] = {
            "energy_error": float(run_.energy_error[k]),
            "min_contact": float(run_.min_contact[k]),
            "lost_contact": bool(run_.min_contact[k] <= 0),
            "step_halving_difference_final": float(diff[-1]),
            "step_halving_difference_max": float(diff.max()),
            "periods_until_difference_1e-3": None if not late.size else float(run_.t[late[0]] / b.period),
            "v101_initial": float(x0[k, 1, params.N // 2]),
        }
        ctx.log(
            "%-15s energy error %.1e, min contact %.3f%s, step-halving difference %.1e",
            name,
            run_.energy_error[k],
            run_.min_contact[k],
            " (contact lost)" if run_.min_contact[k] <= 0 else "",
            diff.max(),
        )
    return {
        "periods": periods,
        "period": b.period,
        "method": run_.method,
        "dt": run_.dt,
        "steps_per_period": steps_per_period,
        "frames_per_period": P.frames_per_period,
        "wall_seconds": time.perf_counter() - start,
        "simulation_seconds": run_.wall_seconds,
        "cases": cases,
    }


def plot(out) -> None:
    s = read_summary(out)
    plt = pyplot()
    fig, axes = plt.subplots(2, 4, figsize=(14, 8), gridspec_kw={"width_ratios": [4, 1, 4, 1]})
    for k, name in enumerate(CASES):
        data, attrs = read_group(out / "data.zarr", name)
        rel = data["v"] - data["u"]
        ax = axes[k // 2, 2 * (k % 2)]
        side = axes[k // 2, 2 * (k % 2) + 1]
        per = int(s["frames_per_period"])
        envelope = period_envelope(rel, per)  # max over each period of |v_j - u_j| (why: _common)
        n_periods = len(envelope)
        im = ax.imshow(
            envelope.T,
            aspect="auto",
            origin="lower",
            cmap="magma",
            vmin=0.0,
            vmax=float(envelope.max()),
            interpolation="nearest",
            extent=[0, n_periods * data["t"][per] / s["period"], data["site"][0], data["site"][-1]],
        )
        bar = fig.colorbar(im, ax=ax, pad=0.01)
        bar.set_label(r"max over a period of $|v_j - u_j|$", fontsize=8)
        case = s["cases"][name]
        ax.set_title(
            f"({'abcd'[k]}) {name}: E err {case['energy_error']:.0e}"
            + (", contact lost" if case["lost_contact"] else ""),
            fontsize=9,
        )
        ax.set_xlabel("t / T")
        ax.set_ylabel("site j")
        final = rel[-1] / np.max(np.abs(rel[-1]))
        side.plot(final, data["site"], lw=0.8)
        side.set_ylim(data["site"][0], data["site"][-1])
        side.set_yticks([])
        side.set_xlabel(r"$v_j - u_j$ at the end" + "\n(normalised)", fontsize=7)
        side.tick_params(labelsize=6)
    fig.suptitle(
        f"envelope of $v_j - u_j$ over {s['periods']} periods of T = 2$\\pi$/1.01 ({s['method']}, dt = {s['dt']:.4f})"
    )
    fig.tight_layout()
    save_figure(fig, out, "direct_simulation")
