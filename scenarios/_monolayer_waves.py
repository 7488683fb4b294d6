"""Linear waves of the monolayer (issue #51 item 2), for the ``monolayer`` scene: band edges, the dispersion along
the Brillouin zone's high-symmetry path and over the zone, and the lowest optical modes of the finite patch, from
``warpchain.lattice`` (the symbol lam(q) and the patch's linear modes). Computed in ``waves``, drawn from the store in
``draw``.

Wave vectors are cartesian (lattice spacing 1); the axial Bloch numbers of ``Lattice.lam`` are q_i = k . a_i. The
path: Gamma (0, 0), X (pi, 0), M (pi, pi) on the square lattice; Gamma, M (0, 2 pi / sqrt 3), K (2 pi / 3,
2 pi / sqrt 3) on the triangular one (lam = 8 at M, its maximum 9 at K). The coupling: a patch at K has the
long-wave speed of the chain at K kappa (``Lattice.long_wave_curvature``; ``warpchain.physical.monolayer_coupling``
goes the other way), stated beside each lattice.
"""

from __future__ import annotations

import math

import numpy as np

from warpchain.store import read_group, write_table

#: high-symmetry points (cartesian k) of each lattice's path, in order
CORNERS = {
    "square": (("Gamma", (0.0, 0.0)), ("X", (math.pi, 0.0)), ("M", (math.pi, math.pi)), ("Gamma", (0.0, 0.0))),
    "triangular": (
        ("Gamma", (0.0, 0.0)),
        ("M", (0.0, 2 * math.pi / math.sqrt(3))),
        ("K", (2 * math.pi / 3, 2 * math.pi / math.sqrt(3))),
        ("Gamma", (0.0, 0.0)),
    ),
}
#: points per unit length of the path, and of the zone's grid per axis
PATH_DENSITY, GRID = 40, 161
#: optical modes of the patch drawn
MODES = 3


def _branches(lattice, k: np.ndarray, M: float, K: float):
    """(acoustic, optical) at cartesian wave vectors k (..., 2)."""
    q = np.moveaxis(k @ lattice.basis.T, -1, 0)  # q_i = k . a_i
    return lattice.dispersion(q, M, K)


def waves(root, name: str, lattice, M: float, K: float) -> dict:
    """Store the path (``<name>_path``), the optical surface (``<name>_zone``) and the lowest optical modes of the
    patch (``<name>_modes``); return the band edges, the modes' frequencies and the coupling's chain equivalent."""
    corners = CORNERS[name]
    points, s, labels = [], [], []
    length = 0.0
    for (a, ka), (_, kb) in zip(corners, corners[1:]):
        ka, kb = np.array(ka), np.array(kb)
        steps = max(2, int(PATH_DENSITY * np.linalg.norm(kb - ka)))
        t = np.linspace(0.0, 1.0, steps, endpoint=False)
        points.append(ka + t[:, None] * (kb - ka))
        s.append(length + t * np.linalg.norm(kb - ka))
        labels.append((a, length))
        length += float(np.linalg.norm(kb - ka))
    points.append(np.array([corners[-1][1]]))
    s.append(np.array([length]))
    labels.append((corners[-1][0], length))
    k, s = np.concatenate(points), np.concatenate(s)
    acoustic, optical = _branches(lattice, k, M, K)
    write_table(
        root, f"{name}_path", {"s": s, "kx": k[:, 0], "ky": k[:, 1], "acoustic": acoustic, "optical": optical},
        dim="point", attrs={"corners": [[a, x] for a, x in labels]},
    )  # fmt: skip
    reach = 1.05 * max(np.linalg.norm(c) for _, c in corners)
    axis = np.linspace(-reach, reach, GRID)
    grid = np.stack(np.meshgrid(axis, axis, indexing="xy"), axis=-1)
    _, surface = _branches(lattice, grid, M, K)
    write_table(root, f"{name}_zone", {"k": axis, "optical": surface}, dim="k")
    freqs, shapes = lattice.linear_modes(M, K)
    n = lattice.n_sites
    picks = np.arange(n, n + MODES)  # the optical modes follow the n acoustic ones
    z = shapes[picks, 1] - shapes[picks, 0]  # the spheres' motion relative to the substrate
    x, y = lattice.positions.T
    write_table(root, f"{name}_modes", {"site": np.arange(n), "x": x, "y": y, "z": z.T}, dim="site",
                attrs={"frequencies": freqs[picks].tolist()})  # fmt: skip
    return {
        "band_edges": lattice.band_edges(M, K),
        "lowest_optical_modes": freqs[picks].tolist(),
        "long_wave_curvature": lattice.long_wave_curvature,
        "chain_equivalent_K": K * lattice.long_wave_curvature,
    }


def draw(fig, axes, store, name: str, info: dict) -> None:
    """One row of the waves figure: the optical surface over the zone, the branches along the path, the patch's
    lowest optical mode."""
    zone, _ = read_group(store, f"{name}_zone")
    path, attrs = read_group(store, f"{name}_path")
    modes, mode_attrs = read_group(store, f"{name}_modes")
    edges = info["band_edges"]
    im = axes[0].pcolormesh(zone["k"], zone["k"], zone["optical"], cmap="viridis", shading="nearest")
    corners = np.array([[path["kx"][np.argmin(np.abs(path["s"] - x))], path["ky"][np.argmin(np.abs(path["s"] - x))]]
                        for _, x in attrs["corners"]])  # fmt: skip
    axes[0].plot(corners[:, 0], corners[:, 1], "w-", lw=0.8)
    for label, (kx, ky) in zip([a for a, _ in attrs["corners"]], corners):
        axes[0].annotate(label, (kx, ky), color="w", fontsize=8)
    axes[0].set(aspect="equal", xlabel="$k_x$", ylabel="$k_y$", title=f"{name}: optical branch $\\omega(k)$")
    fig.colorbar(im, ax=axes[0], shrink=0.8)
    for branch in ("acoustic", "optical"):
        axes[1].plot(path["s"], path[branch], lw=1.0, label=branch)
    for key in ("acoustic_top", "optical_bottom", "optical_top"):
        axes[1].axhline(edges[key], color="0.5", ls=":", lw=0.7)
    axes[1].set_xticks([x for _, x in attrs["corners"]], [a.replace("Gamma", r"$\Gamma$") for a, _ in attrs["corners"]])
    axes[1].set(
        ylabel=r"$\omega$",
        title=f"gap [{edges['acoustic_top']:.4f}, {edges['optical_bottom']:.4f}]; chain-equivalent K = "
        f"{info['chain_equivalent_K']:.4g}",
    )
    axes[1].legend(fontsize=7, loc="center left")
    inset = axes[1].inset_axes([0.52, 0.12, 0.45, 0.4])  # the optical band, narrow at small K, magnified
    inset.plot(path["s"], path["optical"], color="tab:orange", lw=1.0)
    inset.set_xticks([x for _, x in attrs["corners"]], [a.replace("Gamma", r"$\Gamma$") for a, _ in attrs["corners"]])
    inset.tick_params(labelsize=6)
    inset.ticklabel_format(axis="y", useOffset=False)
    inset.set_title("optical band", fontsize=7)
    z = modes["z"][:, 0]
    scale = np.abs(z).max()
    axes[2].scatter(modes["x"], modes["y"], c=z, s=30, cmap="RdBu_r", vmin=-scale, vmax=scale)
    axes[2].set(aspect="equal", xticks=[], yticks=[])
    axes[2].set_title(
        f"lowest optical mode of the patch, v - u\n$\\omega$ = {mode_attrs['frequencies'][0]:.6f} "
        f"(band bottom {edges['optical_bottom']:.6f})"
    )
