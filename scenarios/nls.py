"""NLS approximation vs the numerical breather (paper Fig. 5b) at M = 30, K = 160, w_b = 1.01.

Command: ``python -m scenarios run nls`` (about 30 s on a 2-core CPU; ``--quick`` about 10 s).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

The NLS profile (coefficients derived again in ``continuation.seeds``) is compared with the
breather Newton finds from it; a sweep of w_b towards the band edge shows the difference shrinking,
which is what an asymptotic approximation must do.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from continuation import find_breather, nls_breather, nls_seed, require
from warpchain import ChainParams, band_edges, energy
from warpchain.store import read_group, write_table

from ._common import (
    BREATHER_METHOD,
    BREATHER_STEPS_PER_PERIOD,
    PAPER_K,
    PAPER_M,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    paper_breather,
    pyplot,
    read_summary,
    save_figure,
)
from ._params import param


#: the paper chain's band gap: a breather's frequency lies in it, the NLS one below the optical band bottom w0
GAP = band_edges(PAPER_M, PAPER_K)


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    sweep: tuple[float, ...] = param(
        (1.016, 1.015, 1.0125, 1.01, 1.0075, 1.005),
        "frequencies w_b of the NLS comparison, towards the optical band edge w0 = 1.01653: in the gap",
        gt=GAP["acoustic_top"],
        lt=GAP["optical_bottom"],
        length=(1, None),
    )


QUICK = {"sweep": (1.014, 1.01)}


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)
    numerical = paper_breather(ctx.device, log=lambda m: ctx.log(m))
    nls_state = nls_seed(params, PAPER_OMEGA)
    nls_first = nls_seed(params, PAPER_OMEGA, order=1)
    diff = float(np.max(np.abs(nls_state[:2] - numerical.state[:2])))
    nls_energy = float(energy(params, nls_state)[0])
    ctx.log(
        "w_b = %.4f: NLS energy %.6f, numerical %.6f, max profile difference %.3e",
        PAPER_OMEGA,
        nls_energy,
        numerical.energy,
        diff,
    )

    sweep = []
    for omega in P.sweep:
        if omega == PAPER_OMEGA:
            b = numerical
        else:
            b = require(
                find_breather(
                    params,
                    omega,
                    nls_seed(params, omega),
                    method=BREATHER_METHOD,
                    steps_per_period=BREATHER_STEPS_PER_PERIOD,
                    device=ctx.device,
                )
            )
        approx = nls_seed(params, omega)
        peak = float(np.max(np.abs(b.state[1])))
        rel = float(np.max(np.abs(approx[:2] - b.state[:2])) / peak)
        delta = nls_breather(PAPER_M, PAPER_K, omega).delta
        sweep.append(
            {
                "omega": omega,
                "delta": delta,
                "relative_profile_difference": rel,
                "nls_energy": float(energy(params, approx)[0]),
                "numerical_energy": b.energy,
            }
        )
        ctx.log("w_b = %.4f (w0 - w_b = %.4f): relative profile difference %.3e", omega, delta, rel)

    deltas = np.array([s["delta"] for s in sweep])
    rels = np.array([s["relative_profile_difference"] for s in sweep])
    slope = float(np.polyfit(np.log(deltas), np.log(rels), 1)[0]) if len(sweep) > 1 else None

    root = ctx.store(params)
    write_table(
        root,
        "profiles",
        {
            "site": np.arange(params.N),
            "u_numerical": numerical.state[0],
            "v_numerical": numerical.state[1],
            "u_nls": nls_state[0],
            "v_nls": nls_state[1],
            "u_nls_first_order": nls_first[0],
            "v_nls_first_order": nls_first[1],
        },
        dim="site",
        attrs={"omega": PAPER_OMEGA},
    )
    write_table(root, "sweep", {k: [s[k] for s in sweep] for k in sweep[0]}, dim="point")
    b = nls_breather(PAPER_M, PAPER_K, PAPER_OMEGA)
    return {
        "M": PAPER_M,
        "K": PAPER_K,
        "N": PAPER_N,
        "omega": PAPER_OMEGA,
        "nls_energy": nls_energy,
        "numerical_energy": numerical.energy,
        "profile_max_difference": diff,
        "nls_first_order_profile_max_difference": float(np.max(np.abs(nls_first[:2] - numerical.state[:2]))),
        "nls_coefficients": {
            "dispersion_D": b.dispersion,
            "nonlinearity_G": b.nonlinearity,
            "z_amplitude": b.amplitude,
            "kappa": b.kappa,
        },
        "sweep": sweep,
        "relative_difference_vs_delta_slope": slope,
    }


def plot(out) -> None:
    prof, _ = read_group(out / "data.zarr", "profiles")
    sweep, _ = read_group(out / "data.zarr", "sweep")
    s = read_summary(out)
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4), layout="constrained")
    c = len(prof["site"]) // 2
    sl = slice(c - 25, c + 26)
    for ax, comp in zip(axes[:2], ("u", "v")):
        ax.plot(prof["site"][sl], prof[f"{comp}_nls"][sl], "k-", label="NLS (2nd order)")
        ax.plot(prof["site"][sl], prof[f"{comp}_nls_first_order"][sl], "k:", lw=0.8, label="NLS (1st order)")
        ax.plot(
            prof["site"][sl],
            prof[f"{comp}_numerical"][sl],
            "o",
            mfc="none",
            color="tab:red",
            ms=4,
            label="numerical breather",
        )
        ax.set_xlabel("site j")
        ax.set_ylabel(f"${comp}_j$ at t = 0")
        ax.set_title(f"${comp}_j$, $\\omega_b$ = {s['omega']}, K = {s['K']:g}")
        ax.legend(fontsize=8, loc="upper right" if comp == "u" else "lower right")
    axes[2].loglog(sweep["delta"], sweep["relative_profile_difference"], "o-")
    axes[2].set_xlabel(r"$\omega_0 - \omega_b$")
    axes[2].set_ylabel(r"max $|v_{NLS} - v|$ / max $|v|$")
    slope = s.get("relative_difference_vs_delta_slope")
    axes[2].set_title("NLS error towards the band edge" + (f"\n(log-log slope {slope:.2f})" if slope else ""))
    save_figure(fig, out, "nls")
