"""Dispersion of the discrete chain (paper Fig. 2, discrete curves) and Appendix A/B estimates.

Command: ``python -m scenarios run dispersion`` (about 5 s on a 2-core CPU; no integration).

Computes the acoustic and optical branches of the infinite chain for M = 30, K = 160 over the
Brillouin zone, their long-wave limits, the band edges (closed forms), the N = 201 fixed-end
chain's linear mode frequencies, and the order-of-magnitude estimates of M and K from material
properties (Appendices A and B) for an assumed silica-on-glass material set.
"""

from __future__ import annotations

import numpy as np

from warpchain import ChainParams, band_edges, dispersion, dispersion_long_wave, linear_modes, long_wave_speed
from warpchain import physical
from warpchain.store import open_store, provenance, write_table

from ._common import Context, pyplot, read_summary, save_figure

# parameters
M, K, N = 30.0, 160.0, 201
N_Q = 801


def run(ctx: Context) -> dict:
    params = ChainParams(M, K, N)
    q = np.linspace(0.0, np.pi, N_Q)
    w_ac, w_op = dispersion(q, M, K)
    lw_ac, lw_op = dispersion_long_wave(q, M, K)
    edges = band_edges(M, K)
    freqs, _ = linear_modes(params)
    ctx.log("band edges: acoustic top %.6f, optical %.6f .. %.6f, gap %.6f", edges["acoustic_top"],
            edges["optical_bottom"], edges["optical_top"], edges["gap_width"])

    mat = physical.SILICA_ON_GLASS
    est_M = physical.estimate_mass_ratio(mat["rho_substrate"], mat["rho_sphere"], mat["wavelength_over_diameter"])
    est_K = physical.estimate_stiffness_ratio(mat["diameter"], mat["E_substrate"], mat["nu_substrate"],
                                              mat["E_sphere"], mat["nu_sphere"], mat["work_of_adhesion"],
                                              mat["wavelength_over_diameter"])
    contact = physical.hertz_contact(mat["diameter"], mat["E_substrate"], mat["nu_substrate"], mat["E_sphere"],
                                     mat["nu_sphere"], mat["work_of_adhesion"])
    ctx.log("Appendix estimates for the assumed material set: M ~ %.1f, K ~ %.1f", est_M, est_K)

    root = open_store(ctx.out / "data.zarr", params=params.as_dict(), provenance_info=provenance(ctx.device))
    write_table(root, "curves", {"q": q, "acoustic": w_ac, "optical": w_op, "acoustic_long_wave": lw_ac,
                                 "optical_long_wave": lw_op}, dim="q", attrs=edges)
    write_table(root, "finite_chain", {"frequency": freqs}, dim="mode", attrs={"N": N, "boundary": "fixed"})
    return {
        "M": M, "K": K, "N": N,
        **edges,
        "lowest_optical_mode": float(freqs[N]),
        "long_wave_speed": long_wave_speed(M, K),
        "verlet_stability_limit": 2.0 / edges["optical_top"],
        "appendix_estimates": {"material": mat, "M": est_M, "K": est_K, "hertz": contact,
                               "note": "order-of-magnitude estimates (Appendices A, B) for an assumed material set"},
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
    zoom.axhline(summary["lowest_optical_mode"], color="tab:green", lw=0.9,
                 label=f"N = {summary['N']} lowest optical mode")
    zoom.set_title(f"gap: {edges['acoustic_top']:.6f} .. {edges['optical_bottom']:.6f}")
    zoom.legend(fontsize=7, loc="lower right")
    save_figure(fig, out, "dispersion")
