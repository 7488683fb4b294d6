"""The site-bond scene's figures (``scenarios.site_bond``): ``site_bond`` (the families' energies, the first
exchange of stability, the Peierls-Nabarro barrier, the unstable Floquet vectors' participation, the profiles and
null vectors at the branch points) and ``site_bond_floquet`` (the unstable Floquet vectors per K and N of the
finite-size check). Drawing only: the scene's ``plot`` reads the summary and the store and hands them here.
"""

from __future__ import annotations

import numpy as np

from continuation.floquet import KINDS

from ._common import pyplot, save_figure, tight_layout_beside_legends, verdicts
from ._continuation_common import KIND_COLOURS, KIND_LABELS

#: the families as the figures name them (their code names are the store's groups)
FAMILY_WORDS = {
    "site": "site-centred",
    "bond-in-phase": "bond-centred, in phase",
    "bond-out-of-phase": "bond-centred, out of phase",
    "asymmetric": "asymmetric",
}


def draw_figures(out, s: dict, fam: dict, root) -> None:
    """Both figures into ``out``: ``s`` is the summary, ``fam`` the families' branch points by family (the
    asymmetric one may be missing), ``root`` the store's zarr group."""
    bif = root["bifurcations"]
    bif_attrs = dict(bif.attrs)
    plt = pyplot()
    colours = {"site": "tab:blue", "bond-in-phase": "tab:green", "bond-out-of-phase": "tab:purple", "asymmetric": "k"}

    fig = plt.figure(figsize=(13, 10))
    gs = fig.add_gridspec(3, 2, height_ratios=[1.6, 1.3, 1.2])
    ax = fig.add_subplot(gs[0, 0])
    for family, points in fam.items():
        K = np.array([p.K for p in points])
        E = np.array([p.energy for p in points])
        st, unst, _ = verdicts(points)
        ax.plot(K, E, "-", color=colours[family], lw=1, label=FAMILY_WORDS.get(family, family))
        ax.plot(K[st], E[st], "o", ms=3, color=colours[family])
        ax.plot(K[unst], E[unst], "o", ms=3, mfc="none", color=colours[family])
    for k, family in zip(bif["K"][:], bif_attrs["family"]):
        ax.axvline(k, color=colours[family], ls=":", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("K")
    ax.set_ylabel("energy H")
    ax.set_title(f"families at $\\omega_b$ = {s['omega']}, N = {s['N']} (filled: stable, open: unstable)", fontsize=10)
    ax.legend(fontsize=8)

    # zoom: the first exchange of stability, energies relative to the site family at the same K
    az = fig.add_subplot(gs[0, 1])
    site = fam["site"]
    if "exchange" in root.group_keys() and "asymmetric" in fam:
        ex = root["exchange"]
        K_s = float(ex.attrs["site_pitchfork_K"])
        K_b = float(ex.attrs["bond_branch_point_K"])
        Kx, Esx, Ebx = ex["K"][:], ex["site_energy"][:], ex["bond_energy"][:]
        az.plot(Kx - K_s, np.zeros_like(Kx), "-", color=colours["site"], label="site")
        az.plot(Kx - K_s, Ebx - Esx, "-", color=colours["bond-in-phase"], label="bond in phase")
        asym = fam["asymmetric"]
        Ka = np.array([p.K for p in asym])
        Ea = np.array([p.energy for p in asym]) - np.interp(Ka, Kx, Esx)  # site energy is linear on this scale
        st = verdicts(asym)[0]
        az.plot(Ka - K_s, Ea, "o-", ms=4, color=colours["asymmetric"], mfc="none", label="asymmetric")
        if st.any():
            az.plot(Ka[st] - K_s, Ea[st], "o", ms=4, color=colours["asymmetric"])
        az.plot([0.0], [0.0], "*", ms=12, color=colours["site"], label=f"site pitchfork K* = {K_s:.10g}")
        az.plot(
            [K_b - K_s],
            [np.interp(K_b, Kx, Ebx - Esx)],
            "*",
            ms=12,
            color=colours["bond-in-phase"],
            label=f"bond branch point, K* + {K_b - K_s:.2e}",
        )
        az.set_xlabel("K - K*")
        az.legend(fontsize=7)
    az.set_ylabel("E - E(site) at the same K")
    az.set_title("the first exchange of stability: the asymmetric family joins site and bond", fontsize=10)

    # PN barrier along K (the bond orbit solved at every site point's K)
    ap = fig.add_subplot(gs[1, 0])
    if "pn_barrier" in root.group_keys():
        pn = root["pn_barrier"]
        Kp, dE = pn["K"][:], pn["barrier"][:]
        ap.loglog(Kp[dE > 0], dE[dE > 0], "o", ms=3, color="tab:red", label="E(bond) > E(site)")
        ap.loglog(Kp[dE < 0], -dE[dE < 0], "o", ms=3, mfc="none", color="tab:blue", label="E(bond) < E(site)")
        floor = 1e-13 * float(np.max(np.abs(pn["site_energy"][:])))
        ap.axhline(floor, color="0.6", ls=":", lw=0.8, label="energy resolution")
    for row in s["pn_barrier"]:
        if row["barrier"] is not None:
            y = max(abs(row["barrier"]), 1e-16)
            ap.plot([row["K"]], [y], "k*", ms=9)
            last = row["K"] >= max(r["K"] for r in s["pn_barrier"])  # labelled to its left, inside the axes
            ap.annotate(
                f"{row['barrier']:.2e}",
                (row["K"], y),
                fontsize=7,
                xytext=(-4 if last else 4, 8),
                textcoords="offset points",
                ha="right" if last else "left",
            )
    for k, family in zip(bif["K"][:], bif_attrs["family"]):
        if family == "site":
            ap.axvline(k, color=colours["site"], ls=":", lw=0.8)
    ap.set_ylim(top=30 * ap.get_ylim()[1])  # headroom for the stars' labels
    ap.set_xlabel("K (dotted: the site family's pitchforks)")
    ap.set_ylabel("|E(bond in phase) - E(site)|")
    ap.set_title("Peierls-Nabarro barrier (stars: the summary's K values)", fontsize=10)
    ap.legend(fontsize=8)

    # participation of the unstable Floquet vectors along the site family
    aq = fig.add_subplot(gs[1, 1])
    for kind in KINDS:
        x = [p.K for p in site for i in p.instabilities if i.kind == kind]
        y = [i.participation for p in site for i in p.instabilities if i.kind == kind]
        if x:
            aq.loglog(x, y, "o", ms=3, color=KIND_COLOURS[kind], label=KIND_LABELS[kind])
    aq.axhline(0.1 * s["N"], color="0.5", ls="--", lw=0.8, label="localized below")
    aq.set_xlabel("K")
    aq.set_ylabel("participation (sites)")
    aq.set_title("unstable Floquet vectors of the site family", fontsize=10)
    aq.legend(fontsize=7)

    # profiles and null vectors at the first exchange (site pitchfork, bond branch point), with the
    # asymmetric orbit halfway between them
    families = list(bif_attrs["family"])
    first = [families.index(f) for f in ("site", "bond-in-phase") if f in families]
    N = s["N"]
    c = N // 2
    sites = np.arange(c - 8, c + 10)
    for col, name in enumerate(("state", "null_vector")):
        a = fig.add_subplot(gs[2, col])
        data = bif[name][:]
        for k in first:
            lab = f"{FAMILY_WORDS.get(families[k], families[k])} at its branch point, K = {bif['K'][k]:.10g}"
            if name == "state":
                y = data[k, 0] - data[k, 1]
            else:  # signed site amplitude sqrt(M a_u^2 + a_v^2)
                half = data.shape[1] // 2
                au, av = data[k, :half], data[k, half:]
                y = np.sqrt(s["M"] * au**2 + av**2) * np.sign(av + 1e-300)
            a.plot(sites, y[sites], "o-", ms=3, color=colours[families[k]], label=lab)
        if name == "state" and "asymmetric" in fam:
            mid = fam["asymmetric"][len(fam["asymmetric"]) // 2]
            z = mid.state[0] - mid.state[1]
            a.plot(sites, z[sites], "s--", ms=3, color=colours["asymmetric"], label=f"asymmetric, K = {mid.K:.10g}")
        a.set_xlabel("site j")
        a.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
        a.set_title(
            "profiles z = u - v at the first exchange" if name == "state" else "null vectors (signed site amplitude)",
            fontsize=10,
        )
        a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False)  # below: off the profiles
    fig.tight_layout()
    save_figure(fig, out, "site_bond")

    # the unstable Floquet vectors per K and N
    groups = sorted(k for k in root.group_keys() if k.startswith("finite_size_"))
    if groups:
        Ks_fs = sorted({float(root[g].attrs["K"]) for g in groups})
        # each panel's key in a row of its own under it: the extended vectors fill the whole chain
        lines = [max(root[g]["weight"].shape[0] for g in groups if float(root[g].attrs["K"]) == K) for K in Ks_fs]
        key_heights = [0.15 + 0.14 * ((n + 1) // 2) for n in lines]  # two columns of 6 pt lines
        fig = plt.figure(figsize=(13, 3.6 * len(Ks_fs) + sum(key_heights)))
        grid = fig.add_gridspec(2 * len(Ks_fs), 2, height_ratios=[h for k in key_heights for h in (3.6, k)])
        for r, K in enumerate(Ks_fs):
            for cidx, g in enumerate(
                sorted((g for g in groups if float(root[g].attrs["K"]) == K), key=lambda g: root[g].attrs["N"])
            ):
                a = fig.add_subplot(grid[2 * r, cidx])
                t = root[g]
                n = int(t.attrs["N"])
                weight = t["weight"][:]
                n_ext = 0
                for k in range(weight.shape[0]):
                    kind = KINDS[int(t["kind"][k])]
                    localized = bool(t["localized"][k])
                    name = kind.replace("complex_", "").replace("_", " ")
                    lab = f"{name}, $|\\lambda|$ - 1 = {t['modulus'][k] - 1:.2e}, {t['participation'][k]:.0f} sites"
                    if localized:
                        style = dict(lw=2.0, color=KIND_COLOURS[kind], zorder=3)
                    else:
                        style = dict(lw=0.8, color=plt.cm.Oranges(0.35 + 0.5 * (n_ext % 4) / 3), zorder=2)
                        n_ext += 1
                    a.semilogy(np.arange(n) - n // 2, np.maximum(weight[k], 1e-12), "-", label=lab, **style)
                a.set_ylim(1e-8, 3)
                rows = s.get("finite_size", {}).get(f"{K:g}", {}).get("classification", [])
                verdict = "; ".join(
                    f"{r['kind'].replace('_', ' ')} {r['modulus'] - 1:.1e}: {r['class']}" for r in rows[:3]
                )
                first = cidx == 0 and verdict
                a.set_title(
                    f"K = {K:g}, N = {n}" + (f"\n{verdict}" if first else " (re-solved, profile padded)"), fontsize=9
                )
                a.set_xlabel("site - centre")
                a.set_ylabel("site weight of the Floquet vector")
                key = fig.add_subplot(grid[2 * r + 1, cidx])
                key.axis("off")
                key.legend(*a.get_legend_handles_labels(), fontsize=6, loc="upper center", ncol=2, frameon=False)
        tight_layout_beside_legends(fig)  # the keys keep to their rows; the panels keep their width
        save_figure(fig, out, "site_bond_floquet")
