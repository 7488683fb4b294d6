"""Dispersion and the parameter fit (paper section "Parameter Fitting", Fig. 2, Appendices A and B).

Command: ``python -m scenarios run dispersion`` (about 5 s on a 2-core CPU; no integration).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

* The discrete chain for M = 30, K = 160: acoustic and optical branches over the Brillouin zone,
  their long-wave limits, the band edges, the N = 201 fixed-end chain's mode frequencies.
* The continuous model (Rayleigh waves on a half-space carrying sphere resonators,
  ``warpchain.physical``) for an assumed material set (1 um silica spheres on soda-lime glass,
  f_0 = 215 MHz as the paper quotes it measured; the source paper's exact values are not in our
  reference), and the fit of M, K to it: K/(M+1) from c_R (the chain's exact long-wave speed), K from
  the upper branch's meeting with the c_T line; also with the paper's K/M slope, for comparison.
* Fig. 2: both models' curves in physical units with the c_T and c_R lines and f_0.
* How sensitive the fitted M and K are to each assumed value (elasticities d ln M / d ln p).
* The order-of-magnitude Appendix A/B estimates for an assumed silica-on-glass set.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from warpchain import ChainParams, band_edges, dispersion, dispersion_long_wave, linear_modes, long_wave_speed
from warpchain import physical
from warpchain.store import write_table

from ._common import PAPER_K, PAPER_M, PAPER_N, Context, pyplot, read_summary, save_figure
from ._params import DENSE_MAX_SITES, param

MATERIALS = physical.SILICA_SPHERES_ON_GLASS
SENSITIVITY_PARAMETERS = (
    "diameter",
    "rho_sphere",
    "rho_substrate",
    "E_substrate",
    "nu_substrate",
    "contact_frequency_hz",
)


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    M: float = param(PAPER_M, "mass ratio m1 / m2", gt=0)
    K: float = param(PAPER_K, "coupling k1 / k2", gt=0)
    N: int = param(PAPER_N, "sites of the fixed-end chain whose mode frequencies are listed", ge=1, le=DENSE_MAX_SITES)
    bloch_points: int = param(801, "Bloch numbers q over [0, pi]", ge=2, le=1_000_000)
    sensitivity_step: float = param(0.05, "relative change of each assumed value, up and down", gt=0, lt=1)
    k_max_over_k_T: float = param(2.0, "Fig. 2 wavenumber range, in units of the c_T crossing", gt=0)
    wavenumber_points: int = param(400, "Fig. 2 wavenumbers", ge=2, le=1_000_000)


QUICK: dict = {}  # the full scene already takes seconds


def _fit_section(ctx, P: Parameters):
    """The continuous model, the fit, its sensitivity; returns (summary dict, curves dict, fit)."""
    mat = MATERIALS
    fit = physical.fit_to_substrate(mat, convention="exact")
    paper = physical.fit_to_substrate(mat, convention="paper")
    ctx.log(
        "fit (exact long-wave speed): M = %.2f, K = %.1f, f0 = %.0f MHz; with the paper's K/M slope: "
        "M = %.2f, K = %.1f",
        fit["M"],
        fit["K"],
        fit["f0_hz"] / 1e6,
        paper["M"],
        paper["K"],
    )
    sensitivity = {}
    for name in SENSITIVITY_PARAMETERS:
        base = getattr(mat, name)
        up = physical.fit_to_substrate(mat.replace(**{name: base * (1 + P.sensitivity_step)}))
        down = physical.fit_to_substrate(mat.replace(**{name: base * (1 - P.sensitivity_step)}))
        span = math.log((1 + P.sensitivity_step) / (1 - P.sensitivity_step))
        sensitivity[name] = {
            "dlnM_dlnp": math.log(up["M"] / down["M"]) / span,
            "dlnK_dlnp": math.log(up["K"] / down["K"]) / span,
        }
        ctx.log(
            "sensitivity to %-20s d ln M / d ln p = %+.2f, d ln K / d ln p = %+.2f",
            name,
            sensitivity[name]["dlnM_dlnp"],
            sensitivity[name]["dlnK_dlnp"],
        )
    model = mat.surface_model()
    k_max = fit["k_T"] * P.k_max_over_k_T
    k = np.linspace(k_max / P.wavenumber_points, k_max, P.wavenumber_points)
    disc_ac, disc_op = dispersion(k * mat.diameter, fit["M"], fit["K"])
    pap_ac, pap_op = dispersion(k * mat.diameter, P.M, P.K)
    curves = {
        "k": k,
        "continuous_lower": model.branch(k, "lower"),
        "continuous_upper": model.branch(k, "upper"),
        "discrete_acoustic": disc_ac * fit["omega0"],
        "discrete_optical": disc_op * fit["omega0"],
        "paper_acoustic": pap_ac * fit["omega0"],
        "paper_optical": pap_op * fit["omega0"],
    }
    hertz_w0 = mat.omega0_hertz
    summary = {
        "fit_M": fit["M"],
        "fit_K": fit["K"],
        "fit_omega0": fit["omega0"],
        "fit_f0_hz": fit["f0_hz"],
        "fit_residual": fit["residual"],
        "fit_lower_branch_misfit": fit["lower_branch_misfit"],
        "fit": fit,
        "fit_paper_slope": paper,
        "paper_slope_difference": {
            "M": paper["M"] / fit["M"] - 1.0,
            "K": paper["K"] / fit["K"] - 1.0,
            "note": "relative change of M, K when the chain's long-wave speed is taken "
            "as D w0 sqrt(K/M) (paper) instead of D w0 sqrt(K/(M+1)) (exact)",
        },
        "material_set": mat.as_dict(),
        "material_note": "assumed handbook values; f0 = 215 MHz is the measured contact resonance the paper quotes",
        "sensitivity": sensitivity,
        "sensitivity_step": P.sensitivity_step,
        "hertz_dmt": {
            "f0_hz": hertz_w0 / (2 * math.pi),
            "work_of_adhesion": mat.work_of_adhesion,
            "work_of_adhesion_for_measured_f0": mat.work_of_adhesion * (fit["omega0"] / hertz_w0) ** 6,
            "note": "w0 from the linearised Hertz-DMT contact scales as w^(1/6)",
        },
    }
    return summary, curves, fit


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    params = ChainParams(P.M, P.K, P.N)
    q = np.linspace(0.0, np.pi, P.bloch_points)
    w_ac, w_op = dispersion(q, P.M, P.K)
    lw_ac, lw_op = dispersion_long_wave(q, P.M, P.K)
    edges = band_edges(P.M, P.K)
    freqs, _ = linear_modes(params)
    ctx.log(
        "band edges: acoustic top %.6f, optical %.6f .. %.6f, gap %.6f",
        edges["acoustic_top"],
        edges["optical_bottom"],
        edges["optical_top"],
        edges["gap_width"],
    )

    mat = physical.SILICA_ON_GLASS
    est_M = physical.estimate_mass_ratio(mat["rho_substrate"], mat["rho_sphere"], mat["wavelength_over_diameter"])
    est_K = physical.estimate_stiffness_ratio(
        mat["diameter"],
        mat["E_substrate"],
        mat["nu_substrate"],
        mat["E_sphere"],
        mat["nu_sphere"],
        mat["work_of_adhesion"],
        mat["wavelength_over_diameter"],
    )
    contact = physical.hertz_contact(
        mat["diameter"],
        mat["E_substrate"],
        mat["nu_substrate"],
        mat["E_sphere"],
        mat["nu_sphere"],
        mat["work_of_adhesion"],
    )
    ctx.log("Appendix estimates for the assumed material set: M ~ %.1f, K ~ %.1f", est_M, est_K)

    fit_summary, physical_curves, fit = _fit_section(ctx, P)

    root = ctx.store(params)
    write_table(
        root,
        "physical_curves",
        physical_curves,
        dim="k",
        attrs={
            "units": "k in 1/m, frequencies in rad/s",
            **{key: fit[key] for key in ("M", "K", "omega0", "c_L", "c_T", "c_R", "k_T", "omega_T")},
            "paper_M": P.M,
            "paper_K": P.K,
        },
    )
    write_table(
        root,
        "curves",
        {"q": q, "acoustic": w_ac, "optical": w_op, "acoustic_long_wave": lw_ac, "optical_long_wave": lw_op},
        dim="q",
        attrs=edges,
    )
    write_table(root, "finite_chain", {"frequency": freqs}, dim="mode", attrs={"N": P.N, "boundary": "fixed"})
    return {
        "M": P.M,
        "K": P.K,
        "N": P.N,
        **edges,
        "lowest_optical_mode": float(freqs[P.N]),
        "long_wave_speed": long_wave_speed(P.M, P.K),
        "verlet_stability_limit": 2.0 / edges["optical_top"],
        "appendix_estimates": {
            "material": mat,
            "M": est_M,
            "K": est_K,
            "hertz": contact,
            "note": "order-of-magnitude estimates (Appendices A, B) for an assumed material set",
        },
        **fit_summary,
    }


def plot(out) -> None:
    from warpchain.store import read_group

    curves, edges = read_group(out / "data.zarr", "curves")
    summary = read_summary(out)
    plt = pyplot()
    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(10, 4.2))
    for a in (ax, zoom):
        a.plot(curves["q"], curves["acoustic"], "r-", lw=1.6, label="discrete, acoustic")
        a.plot(curves["q"], curves["optical"], "r--", lw=1.6, label="discrete, optical")
        a.plot(curves["q"], curves["acoustic_long_wave"], color="0.5", lw=0.9, label="long-wave limit")
        a.plot(curves["q"], curves["optical_long_wave"], color="0.5", lw=0.9)
        a.axhline(1.0, color="k", ls=":", lw=0.8, label=r"$\omega_0^{hs}$ (= 1)")
        a.axhspan(edges["acoustic_top"], edges["optical_bottom"], color="tab:blue", alpha=0.15, label="band gap")
        a.set_xlabel("Bloch number q (rad / cell)")
    ax.set_ylabel(r"$\omega / \omega_0^{hs}$")
    ax.set_ylim(0, 1.05 * edges["optical_top"])
    ax.set_title(f"M = {summary['M']:g}, K = {summary['K']:g}")
    zoom.set_xlim(0, 1.2)
    zoom.set_ylim(0.96, 1.04)
    zoom.axhline(
        summary["lowest_optical_mode"], color="tab:green", lw=0.9, label=f"N = {summary['N']} lowest optical mode"
    )
    zoom.set_title(f"gap: {edges['acoustic_top']:.6f} .. {edges['optical_bottom']:.6f}")
    zoom.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))  # outside: the curves stay in view
    save_figure(fig, out, "dispersion")

    _plot_fig2(out, summary)


def _plot_fig2(out, summary) -> None:
    """Fig. 2: continuous and fitted discrete dispersion curves in physical units."""
    from warpchain.store import read_group

    d, attrs = read_group(out / "data.zarr", "physical_curves")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 5))
    k_um = d["k"] * 1e-6  # 1/um
    mhz = 1.0 / (2 * math.pi * 1e6)
    ax.plot(k_um, d["continuous_lower"] * mhz, "b-", lw=1.8, label="continuous (half-space + resonators)")
    ax.plot(k_um, d["continuous_upper"] * mhz, "b-", lw=1.8)
    ax.plot(
        k_um,
        d["discrete_acoustic"] * mhz,
        "r:",
        lw=2.0,
        label=f"discrete, fitted M = {attrs['M']:.1f}, K = {attrs['K']:.0f}",
    )
    ax.plot(k_um, d["discrete_optical"] * mhz, "r:", lw=2.0)
    ax.plot(
        k_um,
        d["paper_acoustic"] * mhz,
        color="tab:orange",
        ls="--",
        lw=0.9,
        label=f"discrete, paper M = {attrs['paper_M']:g}, K = {attrs['paper_K']:g}",
    )
    ax.plot(k_um, d["paper_optical"] * mhz, color="tab:orange", ls="--", lw=0.9)
    ax.plot(k_um, attrs["c_T"] * d["k"] * mhz, "k-.", lw=0.9, label=r"$c_T$ line")
    ax.plot(k_um, attrs["c_R"] * d["k"] * mhz, "k-.", lw=0.6, alpha=0.6, label=r"$c_R$ line")
    ax.axhline(attrs["omega0"] * mhz, color="k", ls="--", lw=0.9, label=r"$f_0$ (contact resonance)")
    ax.plot([attrs["k_T"] * 1e-6], [attrs["omega_T"] * mhz], "ko", ms=5, mfc="none", label="c_T crossing (fit point)")
    ax.set_xlim(0, k_um[-1])
    ax.set_ylim(0, 1.6 * attrs["omega0"] * mhz)
    ax.set_xlabel(r"wavenumber k (1/$\mu$m)")
    ax.set_ylabel("frequency f (MHz)")
    mat = summary["material_set"]
    ax.set_title(
        f"Fig. 2: {mat['name']}\nc_T = {attrs['c_T']:.0f} m/s, c_R = {attrs['c_R']:.0f} m/s, "
        f"f0 = {attrs['omega0'] * mhz:.0f} MHz",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="lower right")
    save_figure(fig, out, "fig2_fitted")
