"""Anti-continuum limit (paper Fig. 5a): the single-site orbit at w_b = 1.01 and the frequency-amplitude curve.

Command: ``python -m scenarios run anticontinuum`` (about 5 s on a 2-core CPU).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

At K = 0 each site is the oscillator z'' = -w0^2 f(z), w0^2 = (M + 1)/M; it softens, so the orbit of
frequency w_b < w0 is found by root finding on its period (a one-degree-of-freedom problem). The
seed puts it on the centre site with M u + v = 0 and the rest of the chain at rest.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from continuation import anticontinuum_orbit, anticontinuum_seed, oscillator_frequency
from warpchain import ChainParams
from warpchain.store import read_group, write_table

from ._common import PAPER_M, PAPER_N, PAPER_OMEGA, Context, pyplot, read_summary, save_figure
from ._params import MAX_SITES, Rule, anticontinuum_rule, param


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    M: float = param(PAPER_M, "mass ratio m1 / m2", gt=0)
    N: int = param(PAPER_N, "sites of the chain the seed is stored on", ge=1, le=MAX_SITES)
    omega: float = param(PAPER_OMEGA, "frequency w_b of the single-site orbit", gt=0)
    K_seed: float = param(0.01, "coupling stored with the seed; the K = 0 orbit does not depend on it", ge=0)
    amplitude_min: float = param(
        1e-3,
        "frequency-amplitude curve: the smallest upper turning point z_max, log-spaced to amplitude_max; below "
        "0.05, where the Lindstedt expansion is checked (>= 1e-5: the frequency shift z_max^2 / 24 must stay above "
        "float64's resolution)",
        ge=1e-5,
        lt=0.05,
    )
    amplitude_max: float = param(
        3.0, "the largest z_max; the period solver follows a half period up to t = 100 / w0, z_max ~ 35.9", gt=0, le=35
    )
    amplitude_points: int = param(60, "points of that grid", ge=2, le=2000)
    amplitude_stride: int = param(1, "use every n-th point of that grid", ge=1, le=2000)

    RULES = (
        anticontinuum_rule("omega"),
        Rule(
            ("amplitude_max", "amplitude_min"),
            "amplitude_min < amplitude_max",
            lambda P: P.amplitude_min < P.amplitude_max,
        ),
    )


QUICK = {"amplitude_stride": 4}


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params = ChainParams(P.M, P.K_seed, P.N)
    orbit = anticontinuum_orbit(P.omega, P.M)
    ctx.log("orbit at w_b = %.4f: z in [%.6f, %.6f], period %.6f", P.omega, orbit.z_min, orbit.z_max, orbit.period)
    amplitudes = np.geomspace(P.amplitude_min, P.amplitude_max, P.amplitude_points)[:: P.amplitude_stride]
    freqs = np.array([oscillator_frequency(a, P.M) for a in amplitudes])
    seed = anticontinuum_seed(params, P.omega)
    omega0 = params.omega0
    small = amplitudes < 0.05
    # Lindstedt: w = w0 (1 - a^2 / 24) for z = a cos(w t) + O(a^2); the largest relative deviation
    # among the small amplitudes checks the expansion (it should shrink like a^4)
    lindstedt = omega0 * (1 - amplitudes**2 / 24)
    root = ctx.store(params)
    write_table(
        root,
        "orbit",
        {"t": orbit.t, "z": orbit.z},
        dim="t",
        attrs={"omega": P.omega, "z_max": orbit.z_max, "z_min": orbit.z_min},
    )
    write_table(
        root,
        "frequency_amplitude",
        {"z_max": amplitudes, "omega": freqs, "lindstedt": lindstedt},
        dim="point",
        attrs={"omega0": omega0},
    )
    write_table(root, "seed", {"u": seed[0], "v": seed[1], "site": np.arange(P.N)}, dim="site")
    return {
        "M": P.M,
        "omega": P.omega,
        "omega0": omega0,
        "z_max": orbit.z_max,
        "z_min": orbit.z_min,
        "period": orbit.period,
        "seed_u_center": seed[0, P.N // 2],
        "seed_v_center": seed[1, P.N // 2],
        "lindstedt_max_relative_deviation_small_amplitude": float(np.max(np.abs(freqs[small] / lindstedt[small] - 1))),
    }


def plot(out) -> None:
    orbit, oattrs = read_group(out / "data.zarr", "orbit")
    curve, cattrs = read_group(out / "data.zarr", "frequency_amplitude")
    seed, _ = read_group(out / "data.zarr", "seed")
    s = read_summary(out)
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), layout="constrained")
    c = len(seed["site"]) // 2
    sl = slice(c - 10, c + 11)
    axes[0].plot(seed["site"][sl], seed["u"][sl], "o-", label="$u_j$")
    axes[0].plot(seed["site"][sl], seed["v"][sl], "s-", label="$v_j$")
    axes[0].set_ylabel("displacement at t = 0")
    axes[0].set_title(f"single-site seed, $\\omega_b$ = {s['omega']}")
    axes[0].set_xlabel("site j")
    axes[0].xaxis.get_major_locator().set_params(integer=True)
    axes[0].legend()
    axes[1].plot(orbit["t"], orbit["z"])
    axes[1].axhline(-1, color="r", ls=":", label="contact lost (1 + z = 0)")
    axes[1].set_xlabel("t")
    axes[1].set_ylabel("$z = u - v$ at the seed site")
    axes[1].set_title("the site's orbit over one period")
    axes[1].legend(fontsize=8)
    w0 = cattrs["omega0"]
    for a in (axes[2], axes[2].inset_axes([0.14, 0.08, 0.46, 0.5])):
        a.semilogx(curve["z_max"], curve["omega"], label="oscillator (computed)")
        a.semilogx(curve["z_max"], curve["lindstedt"], "--", label=r"Lindstedt $\omega_0(1 - a^2/24)$")
        a.axhline(w0, color="k", ls=":", lw=0.8, label=rf"$\omega_0 = \sqrt{{(M+1)/M}}$ = {w0:.4f}")
        a.axhline(s["omega"], color="tab:red", lw=0.8, label=rf"$\omega_b$ = {s['omega']}")
    axes[2].set_ylim(0.5, 1.1)
    axes[2].set_xlabel(r"upper turning point $z_{\max}$")
    axes[2].set_ylabel(r"frequency $\omega$")
    axes[2].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    # zoom on the two lines 0.0065 apart (2 px on the full axis), placed in the empty lower left: the oscillator
    # leaves w_0 and crosses w_b at the seed's amplitude
    zoom = axes[2].child_axes[0]
    zoom.set_xlim(curve["z_max"].min(), 0.8)
    gap = w0 - s["omega"]
    zoom.set_ylim(s["omega"] - 0.6 * gap, w0 + 0.4 * gap)
    zoom.tick_params(labelsize=6)
    zoom.set_title("zoom", fontsize=7, pad=2)
    for y, name, colour in ((w0, r"$\omega_0$", "k"), (s["omega"], r"$\omega_b$", "tab:red")):
        zoom.annotate(
            name,
            (0.02, y),
            xycoords=("axes fraction", "data"),
            xytext=(0, 2),
            textcoords="offset points",
            fontsize=8,
            color=colour,
            va="bottom",
        )
    (x0, x1), (y0, y1) = zoom.get_xlim(), zoom.get_ylim()
    axes[2].indicate_inset((x0, y0, x1 - x0, y1 - y0), edgecolor="0.5")  # the zoomed box, no connectors over data
    save_figure(fig, out, "anticontinuum")
