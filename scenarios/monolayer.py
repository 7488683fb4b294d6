"""The monolayer's breathers: site-centred breathers on square and triangular patches, their energy against the
frequency up to the optical band edge, the energy threshold and the stability change (issue #51, first step;
beyond the paper).

Command: ``python -m scenarios run monolayer --device cpu`` (about 5 min on a 2-core CPU; ``--quick`` about 30 s).
Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

The chain's breathers reach zero energy at the band edge; in two dimensions the envelope obeys a focusing cubic
NLS with critical collapse, so breathers have an energy threshold (Flach, Kladko and MacKay, PRL 78, 1207,
1997): E(w_b) has a positive minimum, and the stability changes where dE/dw_b = 0 (Vakhitov-Kolokolov). The
scene walks w_b from ``omega_start`` towards the optical band's bottom w0 = sqrt((M + 1) / M) in steps of
``omega_step`` (Newton from the previous breather), takes every point's complete Floquet verdict, and stops
``points_after_minimum`` points past the lowest energy (or where Newton loses the breather, or at the edge). The
threshold is the vertex of the parabola through the lowest point and its two neighbours; the stability change is
bisected to ``resolution`` in w_b. Both are stated with their brackets and compared, and set beside the
discrete NLS's threshold on the same patch (``continuation.dnls_threshold``: the small-amplitude limit, which the
measured threshold approaches as K -> 0) and the chain's breathers at the same frequencies (``CHAIN_SITES`` sites),
whose energy has no minimum.

``K_walk`` continues the breather at the threshold's w_b in K (Newton from the previous one, a complete verdict at
every point; ``monolayer-K.png``).

``--set omega=...`` (with one ``lattice``) computes one breather instead of the walk: its ``energy``,
``max_floquet_modulus`` and ``stable`` (the complete verdict) in ``summary.json``, its state and multipliers in the
store. ``n`` and ``boundary`` set the patch.

``family`` picks the breather: site-centred (default), bond-centred (two neighbours in phase) or triangle-centred
(three mutual neighbours, the triangular lattice), or the multi-site ones with the last site out of phase
(``bond-out``, ``triangle-out``: at the other turning point, half a period later); ``check_size`` locates the
threshold again on a larger patch (the refined solves, from the breather embedded in it) and states the relative
difference: the threshold's independence of the patch size.

The linear waves beside them (``_monolayer_waves``): band edges, the dispersion along the Brillouin zone's
high-symmetry path and over the zone, the patch's lowest optical modes, and the chain's coupling with the same
long-wave speed (``monolayer-waves.png``).

How: Newton shooting on the time-reversible half-period map and the reduced Floquet analysis (every multiplier, in
blocks under the patch's 180-degree rotation and a mirror) on the Warp ``Flow`` of ``--device``
(``warpchain.lattice.LatticeParams``: the sites layout reads the patch's neighbour table; on the CPU its bits are the
numpy reference's). Newton is dense up to 31 x 31 and on free or periodic patches, matrix-free beyond (the patch's sine
modes precondition GMRES: ``continuation.krylov``, so free and periodic patches stop at 41 x 41, their ``check_size`` at
61 x 61); the Floquet verdict is ``floquet(solver="auto")``'s: dense below 1601 sites (40 x 40), the probed path beyond
(on a GPU with CuPy; on a host the sliced path past 2000 sites), a verdict where its count closes (else the scene stops
with the counts). One breather and its verdict on one H200 (``benchmarks/breather_scaling.py``, 2026-11-28): 101 x 101
square 30-33 s, triangular 47 s; 201 x 201 square 204-222 s. The default patches are 15 x 15. The walls are fixed by
default (``boundary``). Measured on the square lattice (2026-11-27): 15 x 15 and 21 x 21 give the same energies to the 6
digits logged up to w_b = 1.0161 (past the threshold) and the same threshold and stability change; they part by 4e-6 at
1.0162 and 4e-5 at 1.0163, where the breather spreads over 4 to 8 sites.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

import continuation as ct
import warpchain as wc
from warpchain.lattice import BOUNDARIES, LatticeParams, square, triangular
from continuation.floquet import KINDS
from continuation.seeds import state_from_positions
from warpchain.store import read_group, write_table

from ._monolayer_waves import draw, waves
from ._common import BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, PAPER_M, Context, pyplot, read_summary, save_figure
from ._params import Rule, param

BUILDERS = {"square": square, "triangular": triangular}
#: the breathers' centres (``_seed``): a site, two neighbours or three mutual ones in phase, and "-out": the last of
#: them out of phase
FAMILIES = ("site", "bond", "triangle", "bond-out", "triangle-out")
#: the largest side on free or periodic walls, where Newton is dense (the sine modes precondition fixed walls only)
DENSE_NEWTON_SIDE = 41
#: the largest check_size there: the limit it had on every wall before fixed patches went to 201 (its few refined
#: solves take dense Newton there)
DENSE_CHECK_SIDE = 61
#: solves across the two steps around the lowest energy of the walk, to place the threshold
REFINE = 8


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    M: float = param(PAPER_M, "mass ratio m1 / m2", gt=0)
    K: float = param(1.0, "coupling ratio k1 / k2 (every bond)", gt=0, le=10)
    n: int = param(15, "the patches are n x n sites (odd: a centre site)", ge=5, le=201)
    lattice: str = param("both", "the patches: square, triangular or both", choices=("both", "square", "triangular"))
    boundary: str = param("fixed", "the patches' walls", choices=BOUNDARIES)
    omega: float | None = param(
        None, "one breather at this w_b (with its complete verdict) instead of the walk; one lattice", gt=0
    )
    omega_start: float = param(1.013, "first frequency w_b of the walk, in the gap", gt=0)
    omega_step: float = param(1e-4, "step of w_b towards the band edge", gt=1e-7, lt=1e-2)
    points_after_minimum: int = param(4, "points walked past the lowest energy before the walk stops", ge=2, le=1000)
    resolution: float = param(1e-7, "bracket of w_b the stability change is bisected to", ge=1e-10)
    family: str = param(
        "site",
        "the breather's centre: a site; a bond (two neighbours in phase); a triangle (three, the triangular lattice); "
        "bond-out and triangle-out: the last neighbour out of phase (half a period later)",
        choices=FAMILIES,
    )
    seed: str = param(
        "anticontinuum",
        "Newton's first seed: the anti-continuum orbit(s) of the family, or the discrete NLS soliton (site family: "
        "near the band edge, where the breather is wide)",
        choices=("anticontinuum", "dnls"),
    )
    check_size: int = param(
        0, "a larger patch on which the threshold is located again, its size-independence (0: none)", ge=0, le=201
    )
    K_walk: tuple[float, ...] = param(
        (), "couplings walked in order at the threshold's w_b, from the breather there (); () skips it", gt=0, le=10,
        length=(0, 200),
    )  # fmt: skip

    RULES = (
        Rule(
            ("omega", "lattice"),
            "omega (one breather) with one lattice (lattice=square or triangular)",
            lambda P: P.omega is None or P.lattice != "both",
        ),
        Rule(
            ("omega", "M"),
            "omega below the optical band's bottom sqrt((M + 1) / M)",
            lambda P: P.omega is None or P.omega < math.sqrt((P.M + 1.0) / P.M),
        ),
        Rule(("n",), "n odd (the patch has a centre site, where the site breather sits)", lambda P: P.n % 2 == 1),
        Rule(
            ("check_size", "K_walk", "omega"),
            "check_size and K_walk belong to the walk, not to one breather (omega)",
            lambda P: P.omega is None or (P.check_size == 0 and not P.K_walk),
        ),
        Rule(
            ("seed", "family"),
            "seed=dnls for the site family (the discrete NLS soliton is site-centred)",
            lambda P: P.seed != "dnls" or P.family == "site",
        ),
        Rule(
            ("family", "lattice"),
            "family=triangle or triangle-out on the triangular lattice only (lattice=triangular)",
            lambda P: not P.family.startswith("triangle") or P.lattice == "triangular",
        ),
        Rule(
            ("n", "check_size", "boundary"),
            f"n <= {DENSE_NEWTON_SIDE} and check_size <= {DENSE_CHECK_SIDE} unless boundary=fixed (Newton is "
            "matrix-free on fixed walls only)",
            lambda P: P.boundary == "fixed" or (P.n <= DENSE_NEWTON_SIDE and P.check_size <= DENSE_CHECK_SIDE),
        ),
        Rule(
            ("check_size", "n"),
            "check_size 0, or odd and larger than n",
            lambda P: P.check_size in (0,) or (P.check_size > P.n and P.check_size % 2 == 1),
        ),
        Rule(
            ("omega_start", "M"),
            "omega_start below the optical band's bottom sqrt((M + 1) / M)",
            lambda P: P.omega_start < math.sqrt((P.M + 1.0) / P.M),
        ),
    )


QUICK = {"n": 9, "omega_start": 1.0130, "omega_step": 3e-4, "resolution": 1e-6}


def _breather(params, omega, seed, flow):
    """Newton from ``seed`` (dense below ``KRYLOV_MIN_SITES`` sites, matrix-free from there: ``solver="auto"``): the
    breather, or None where Newton lost it (a residual above 1e-8, or the rest state)."""
    r = ct.find_breather(params, omega, seed, flow=flow, solver="auto")
    return None if r.residual > 1e-8 or r.energy <= 0 else r


def family_label(family: str) -> str:
    """``bond`` -> ``bond-centred``; ``bond-out`` -> ``bond-centred, out of phase`` (logs and titles)."""
    base = family.removesuffix("-out")
    return f"{base}-centred" + (", out of phase" if family.endswith("-out") else "")


def _seed(params, omega: float, family: str, kind: str = "anticontinuum") -> np.ndarray:
    """With ``kind`` "dnls" the discrete NLS soliton (``continuation.dnls_seed``, site-centred); else the anti-continuum
    seed of ``family``: the single-site orbit at the patch's centre, plus the same orbit in phase on its +x neighbour
    (a bond), and on its +y neighbour too (a triangle: the three are mutual neighbours on the triangular lattice);
    "bond-out" and "triangle-out" put the last of them out of phase: at the orbit's other turning point, half a period
    later (the contact law is not symmetric, so that is z_min, not -z_max; ``anticontinuum_seed``'s
    "bond-out-of-phase" on the chain)."""
    if kind == "dnls":
        return ct.dnls_seed(params, omega)
    orbit = ct.anticontinuum_orbit(omega, params.M)
    c, nx = params.lattice.centre, params.lattice.shape[0]
    sites = {"site": [c], "bond": [c, c + 1], "triangle": [c, c + 1, c + nx]}[family.removesuffix("-out")]
    z = np.zeros(params.N)
    z[sites] = orbit.z_max
    if family.endswith("-out"):
        z[sites[-1]] = orbit.z_min
    return state_from_positions(z / (params.M + 1.0), -params.M * z / (params.M + 1.0))


def _embed(state: np.ndarray, small: int, large: int) -> np.ndarray:
    """A small x small patch's state (4, small^2) at the centre of a large x large patch, zero around it."""
    out = np.zeros((4, large, large))
    o = large // 2 - small // 2
    out[:, o : o + small, o : o + small] = state.reshape(4, small, small)
    return out.reshape(4, large * large)


def _vertex(omegas, energies) -> tuple[float, float, int]:
    """The vertex (w_b, E) of the parabola through the lowest of ``energies`` and its two neighbours; a failed solve
    among the three (an infinite energy) is an error, not a NaN threshold."""
    k = int(np.clip(np.argmin(energies), 1, len(omegas) - 2))
    if not np.all(np.isfinite(energies[k - 1 : k + 2])):
        raise RuntimeError(
            f"Newton lost the breather beside the lowest energy (w_b = {omegas[k - 1]:.7f} .. {omegas[k + 1]:.7f}): "
            "no threshold is placed; try a smaller omega_step"
        )
    c2, c1, c0 = np.polyfit(omegas[k - 1 : k + 2] - omegas[k], energies[k - 1 : k + 2], 2)
    return float(omegas[k] - c1 / (2 * c2)), float(c0 - c1 * c1 / (4 * c2)), k


def _one(ctx, name: str, P) -> dict:
    """One breather at w_b = ``omega`` (``--set omega=...``): Newton from the family's anti-continuum seed and its
    complete verdict; the summary's ``energy``, ``max_floquet_modulus`` and ``stable`` are this breather's, and the
    store holds its state (``<lattice>_breather``) and multipliers (``<lattice>_multipliers``)."""
    params = LatticeParams(P.M, P.K, BUILDERS[name](P.n, P.n, P.boundary))
    flow = wc.Flow(BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, device=ctx.device)
    r, fl = _solve(params, P.omega, _seed(params, P.omega, P.family, P.seed), flow)
    if r is None:
        raise RuntimeError(
            f"{name}: Newton found no breather at w_b = {P.omega:g} from the {family_label(P.family)} seed (it "
            "converged to rest or not at all): try a w_b deeper in the gap (--set omega=...), or near the band edge "
            "the discrete NLS's seed (--set seed=dnls)"
        )
    ctx.log(
        "%s %dx%d %s, %s, w_b = %.6f: E = %.10f, %s (max |l| = %.12f, complete %s), residual %.1e",
        name, P.n, P.n, P.boundary, family_label(P.family), P.omega, r.energy, fl.verdict, fl.max_modulus,
        fl.complete, r.residual,
    )  # fmt: skip
    root = ctx.store(None)
    x, y = params.lattice.positions.T
    write_table(
        root, f"{name}_breather", {"site": np.arange(params.N), "x": x, "y": y, "u": r.state[0], "v": r.state[1],
                                   "du": r.state[2], "dv": r.state[3]},
        dim="site", attrs={"omega": float(P.omega)},
    )  # fmt: skip
    mu = np.asarray(fl.multipliers)
    write_table(root, f"{name}_multipliers", {"real": mu.real, "imag": mu.imag}, dim="multiplier")
    return {
        "mode": "one",
        "lattice": name,
        "M": P.M,
        "K": P.K,
        "n": P.n,
        "boundary": P.boundary,
        "family": P.family,
        "omega": float(P.omega),
        "energy": float(r.energy),
        "max_floquet_modulus": float(fl.max_modulus),
        "stable": None if fl.stable is None else bool(fl.stable),
        "floquet_complete": bool(fl.complete),
        "floquet_path": fl.path,
        "verdict": fl.verdict,
        "residual": float(r.residual),
        "breather_participation": _participation(r.state),
    }


def _K_walk(ctx, name: str, params, omega: float, state, flow, P) -> list:
    """The breather at fixed w_b = ``omega`` continued in K through ``P.K_walk`` (Newton from the previous one), with
    its complete verdict at every point; stops where Newton loses it."""
    rows = []
    for K in P.K_walk:
        r, fl = _solve(params.replace(K=float(K)), omega, state, flow)
        if r is None:
            ctx.log("%s: the K walk lost the breather at K = %g (w_b = %.6f)", name, K, omega)
            break
        if not fl.complete:
            raise RuntimeError(f"{name}: the Floquet count did not close at K = {K:g}, w_b = {omega:.6f}")
        state = r.state
        rows.append({"K": float(K), **_row(omega, r, fl)})
        ctx.log(
            "%s at w_b = %.6f: K = %g, E = %.6f, %s (max |l| - 1 = %.2e)",
            name, omega, K, r.energy, fl.verdict, fl.max_modulus - 1,
        )  # fmt: skip
    return rows


def _solve(params, omega, seed, flow):
    r = _breather(params, omega, seed, flow)
    return (None, None) if r is None else (r, ct.floquet(r, solver="auto"))


def _participation(state) -> float:
    """Participation ratio of the breather's z = u - v at t = 0, in sites."""
    z = state[0] - state[1]
    return float(np.sum(z * z) ** 2 / np.sum(z**4))


def _row(omega, r, fl) -> dict:
    return {
        "omega": float(omega),
        "energy": float(r.energy),
        "stable": int(bool(fl.stable)),
        "floquet_complete": int(fl.complete),
        "max_modulus": float(fl.max_modulus),
        "breather_participation": _participation(r.state),
        "centre_amplitude": float(np.abs(r.state[0] - r.state[1]).max()),
        "leading_kind": KINDS.index(fl.instabilities[0].kind) if fl.instabilities else -1,
    }


def _walk(ctx, name: str, P: Parameters) -> dict:
    params = LatticeParams(P.M, P.K, BUILDERS[name](P.n, P.n, P.boundary))
    flow = wc.Flow(BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, device=ctx.device)
    edge = params.omega0
    seed = _seed(params, P.omega_start, P.family, P.seed)
    rows, states, reason, start = [], [], "edge", time.perf_counter()
    omega = P.omega_start
    while omega < edge:
        r, fl = _solve(params, omega, seed, flow)
        if r is None:
            reason = "newton_failed"
            break
        if not fl.complete:
            raise RuntimeError(f"{name}: the Floquet count did not close at w_b = {omega:.6f}")
        rows.append(_row(omega, r, fl))
        states.append(r.state)
        seed = r.state
        low = int(np.argmin([x["energy"] for x in rows]))
        ctx.log(
            "%s %dx%d: w_b = %.5f, E = %.6f, %s (max |l| - 1 = %.2e), participation %.1f sites",
            name, P.n, P.n, omega, r.energy, fl.verdict, fl.max_modulus - 1, rows[-1]["breather_participation"],
        )  # fmt: skip
        if len(rows) - 1 - low >= P.points_after_minimum:
            reason = "past_minimum"
            break
        omega = P.omega_start + len(rows) * P.omega_step
    if not rows:
        raise RuntimeError(
            f"{name}: no breather at w_b = {P.omega_start:g} from the single-site seed (Newton collapsed onto rest): "
            "start lower in the gap (--set omega_start=...)"
        )
    energies = np.array([x["energy"] for x in rows])
    w = np.array([x["omega"] for x in rows])
    low = int(np.argmin(energies))
    threshold = None
    if 0 < low < len(rows) - 1:  # refined: REFINE solves across the two steps around the lowest point, then the
        # vertex of the parabola through the lowest of them and its neighbours
        fine = np.linspace(w[low - 1], w[low + 1], REFINE + 2)
        e_fine = []
        for omega in fine:
            r, _ = _solve(params, omega, states[low], flow)
            e_fine.append(np.inf if r is None else r.energy)
        try:
            omega_star, energy_star, k = _vertex(fine, np.array(e_fine))
            threshold = {
                "omega": omega_star,
                "energy": energy_star,
                "bracket": [float(fine[k - 1]), float(fine[k + 1])],
                "spacing": float(fine[1] - fine[0]),
            }
        except RuntimeError as exc:
            ctx.log("%s: %s", name, exc)
    size_check = None
    if threshold and P.check_size:  # the same refined solves on a larger patch, from the breather embedded in it
        big = LatticeParams(P.M, P.K, BUILDERS[name](P.check_size, P.check_size, P.boundary))
        state, e_big = _embed(states[low], P.n, P.check_size), []
        for omega in fine:
            r = _breather(big, omega, state, flow)
            state = state if r is None else r.state
            e_big.append(np.inf if r is None else r.energy)
        try:
            omega_big, energy_big, _ = _vertex(fine, np.array(e_big))
            size_check = {
                "size": P.check_size,
                "omega": omega_big,
                "energy": energy_big,
                "relative_difference": abs(energy_big - threshold["energy"]) / threshold["energy"],
            }
            ctx.log(
                "%s: on %d x %d the threshold is E* = %.7f at w_b = %.7f (%.1e relative to %d x %d)",
                name, P.check_size, P.check_size, energy_big, omega_big, size_check["relative_difference"], P.n,
                P.n,
            )  # fmt: skip
        except RuntimeError as exc:  # said, stored, and the walk's own results kept
            size_check = {"size": P.check_size, "error": str(exc)}
            ctx.log("%s: on %d x %d: %s", name, P.check_size, P.check_size, exc)
    changes = []  # every change of the verdict along the walk, bisected
    for i in [i for i in range(1, len(rows)) if rows[i]["stable"] != rows[i - 1]["stable"]]:
        lo, hi, s_lo, seed = w[i - 1], w[i], rows[i - 1]["stable"], states[i - 1]
        solves = 0
        while hi - lo > P.resolution:
            mid = 0.5 * (lo + hi)
            r, fl = _solve(params, mid, seed, flow)
            solves += 1
            if r is None:
                break
            if int(bool(fl.stable)) == s_lo:
                lo, seed = mid, r.state
            else:
                hi = mid
        changes.append({"bracket": [float(lo), float(hi)], "from_stable": bool(s_lo), "bisection_solves": solves})
    # the change at the threshold: the one nearest it (others are the patch's finite-size bubbles)
    change = (
        min(changes, key=lambda c: abs(np.mean(c["bracket"]) - threshold["omega"])) if threshold and changes else None
    )
    profile = states[low]
    if threshold and change:
        ctx.log(
            "%s: energy threshold E* = %.6f at w_b = %.6f; stability changes in [%.7f, %.7f] (%s)",
            name, threshold["energy"], threshold["omega"], *change["bracket"],
            "at the minimum, within its spacing" if abs(threshold["omega"] - change["bracket"][0])
            < threshold["spacing"] else "away from it",
        )  # fmt: skip
    dnls = ct.dnls_threshold(params.lattice, P.M, P.K)  # the small-amplitude prediction (continuation.seeds)
    if threshold:
        ctx.log(
            "%s: the discrete NLS predicts E* = %.6f at w_b = %.6f (Townes, the continuum: %.6f); measured / "
            "predicted %.4f",
            name, dnls["energy"], dnls["omega"], dnls["townes_energy"], threshold["energy"] / dnls["energy"],
        )  # fmt: skip
    advice = None
    if threshold is None:  # the walk did not pass a minimum: where the small-amplitude theory puts it
        gap = max(edge - dnls["omega"], 1e-7)
        start, step = dnls["omega"] - 3.0 * gap, max(gap / 10.0, 2e-7)
        whose = "" if P.family == "site" else " (the site breather's threshold: a guide only for this family)"
        advice = (
            f"no energy minimum on the walk ({reason} at w_b = {w[-1]:.6f}); the discrete NLS puts it{whose} at w_b = "
            f"{dnls['omega']:.6f}: try --set omega_start={start:.6f} --set omega_step={step:.2g}"
        )
        ctx.log("%s: %s", name, advice)
    return {
        "advice": advice,
        "lattice": params.lattice.describe(),
        "dnls_threshold": dnls,
        "threshold_over_dnls": threshold["energy"] / dnls["energy"] if threshold else None,
        "size_check": size_check,
        "family": P.family,
        "band_edges": params.lattice.band_edges(P.M, P.K),
        "rows": rows,
        "stop_reason": reason,
        "threshold": threshold,
        "stability_change": change,
        "stability_changes": changes,
        "threshold_minus_change": (threshold["omega"] - 0.5 * sum(change["bracket"]) if threshold and change else None),
        "profile": profile,
        "K_walk": _K_walk(ctx, name, params, threshold["omega"], profile, flow, P) if threshold and P.K_walk else [],
        "positions": params.lattice.positions,
        "seconds": time.perf_counter() - start,
    }


#: sites of the chain whose breathers are drawn beside the patches' (fixed ends; 15 times the NLS width at the
#: walk's last w_b for K <= 1)
CHAIN_SITES = 101


def _chain(ctx, P: Parameters, omegas) -> dict:
    """The chain's site breather at the patches' frequencies (same M and K, ``CHAIN_SITES`` sites, the NLS seed and
    the same flow): its energy falls to zero at the band edge, where the patches' have a minimum."""
    params = wc.ChainParams(P.M, P.K, CHAIN_SITES)
    flow = wc.Flow(BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, device=ctx.device)
    rows = {"omega": [], "energy": [], "breather_participation": []}
    for omega in omegas:
        r = _breather(params, float(omega), ct.nls_seed(params, float(omega)), flow)
        if r is None:
            continue
        rows["omega"].append(float(omega))
        rows["energy"].append(float(r.energy))
        rows["breather_participation"].append(_participation(r.state))
    if rows["omega"]:
        ctx.log(
            "chain (%d sites): E = %.6f at w_b = %.5f down to %.6f at %.5f",
            CHAIN_SITES, rows["energy"][0], rows["omega"][0], rows["energy"][-1], rows["omega"][-1],
        )  # fmt: skip
    return rows


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    names = list(BUILDERS) if P.lattice == "both" else [P.lattice]
    if P.omega is not None:
        return _one(ctx, names[0], P)
    walks = {name: _walk(ctx, name, P) for name in names}
    chain = _chain(ctx, P, sorted({row["omega"] for walk in walks.values() for row in walk["rows"]}))
    root = ctx.store(None)
    write_table(root, "chain", chain, dim="point", attrs={"sites": CHAIN_SITES})
    linear = {}
    for name in names:  # the linear waves of each lattice (``_monolayer_waves``)
        lattice = BUILDERS[name](P.n, P.n, P.boundary)
        linear[name] = waves(root, name, lattice, P.M, P.K)
        ctx.log(
            "%s: acoustic top %.6f, optical band [%.6f, %.6f]; the patch's lowest optical modes %s; K = %g is the "
            "chain's %.4g (the same long-wave speed)", name, linear[name]["band_edges"]["acoustic_top"],
            linear[name]["band_edges"]["optical_bottom"], linear[name]["band_edges"]["optical_top"],
            ", ".join(f"{w:.6f}" for w in linear[name]["lowest_optical_modes"]), P.K,
            linear[name]["chain_equivalent_K"],
        )  # fmt: skip
    for name, walk in walks.items():
        write_table(root, name, {k: [r[k] for r in walk["rows"]] for k in walk["rows"][0]}, dim="point")
        z = walk["profile"][0] - walk["profile"][1]
        x, y = walk["positions"].T
        write_table(
            root,
            f"{name}_profile",
            {"site": np.arange(len(z)), "x": x, "y": y, "z": z},
            dim="site",
            attrs={"omega": walk["rows"][int(np.argmin([r["energy"] for r in walk["rows"]]))]["omega"]},
        )
    summary = {"M": P.M, "K": P.K, "n": P.n, "boundary": P.boundary, "optical_bottom": math.sqrt((P.M + 1.0) / P.M)}
    for name, walk in walks.items():
        summary[name] = {k: v for k, v in walk.items() if k not in ("rows", "profile", "positions", "K_walk")}
        if walk["K_walk"]:
            write_table(root, f"{name}_K", {k: [r[k] for r in walk["K_walk"]] for k in walk["K_walk"][0]}, dim="point")
            summary[name]["K_walk_points"] = len(walk["K_walk"])
        summary[name]["points"] = len(walk["rows"])
        summary[name]["waves"] = linear[name]
    return summary


def plot(out) -> None:
    s = read_summary(out)
    if s.get("mode") == "one":
        return _plot_one(out, s)
    names = [n for n in BUILDERS if n in s]
    plt = pyplot()
    fig, axes = plt.subplots(1, 2 + len(names), figsize=(5 * (2 + len(names)), 4.4), layout="constrained")
    colours = {"square": "tab:blue", "triangular": "tab:green"}
    for name in names:
        d, _ = read_group(out / "data.zarr", name)
        st = d["stable"] == 1
        for ax, y in ((axes[0], d["energy"]), (axes[1], np.maximum(d["max_modulus"] - 1, 1e-16))):
            ax.plot(d["omega"], y, "-", color=colours[name], lw=0.8)
            ax.plot(d["omega"][st], y[st], "o", ms=4, color=colours[name], label=f"{name}: stable")
            ax.plot(d["omega"][~st], y[~st], "o", ms=4, mfc="none", color=colours[name], label=f"{name}: unstable")
            change = s[name]["stability_change"]
            if change:
                ax.axvline(np.mean(change["bracket"]), color=colours[name], ls=":", lw=0.8)
        t = s[name]["threshold"]
        if t:
            axes[0].plot(
                [t["omega"]], [t["energy"]], "*", ms=12, color=colours[name], label=f"{name}: E* = {t['energy']:.5f}"
            )
        d = s[name]["dnls_threshold"]
        site = "" if s[name].get("family", "site") == "site" else " (site)"
        axes[0].plot(
            [d["omega"]], [d["energy"]], "X", ms=8, mfc="none", color=colours[name],
            label=f"{name}: discrete NLS{site}, {d['energy']:.5f}",
        )  # fmt: skip
    c, _ = read_group(out / "data.zarr", "chain")
    axes[0].plot(c["omega"], c["energy"], "-", color="0.35", lw=1.0, label="chain: no threshold")
    for ax in axes[:2]:
        ax.axvline(s["optical_bottom"], color="0.4", ls="--", lw=0.8)
        ax.set_xlabel(r"$\omega_b$")
        ax.ticklabel_format(axis="x", useOffset=False)
    axes[0].set(
        ylabel="energy H",
        title="energy threshold (star; X: the discrete NLS's); dotted: stability change\n"
        f"M = {s['M']:g}, K = {s['K']:g}, {s['n']} x {s['n']} {s['boundary']}, "
        f"{family_label(s[names[0]].get('family', 'site'))}",
    )
    axes[1].set(
        yscale="log", ylabel=r"max $|\lambda|$ - 1", title="complete Floquet verdicts (dashed: optical band bottom)"
    )
    axes[0].set_ylim(bottom=0.0)
    axes[0].legend(fontsize=6, ncols=2, loc="lower left")
    for ax, name in zip(axes[2:], names):
        p, attrs = read_group(out / "data.zarr", f"{name}_profile")
        scale = np.abs(p["z"]).max()
        im = ax.scatter(p["x"], p["y"], c=p["z"], s=40, cmap="RdBu_r", vmin=-scale, vmax=scale)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: z = u - v at t = 0, lowest energy\n($\\omega_b$ = {attrs['omega']:.5f})")
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.8)
    save_figure(fig, out, "monolayer")
    fig, axes = plt.subplots(len(names), 3, figsize=(15, 4.6 * len(names)), layout="constrained", squeeze=False)
    for row, name in zip(axes, names):
        draw(fig, row, out / "data.zarr", name, s[name]["waves"])
    save_figure(fig, out, "monolayer-waves")
    walked = [name for name in names if s[name].get("K_walk_points")]
    if walked:  # the continuation in K at the threshold's frequency
        fig, ax = plt.subplots(figsize=(6, 4.4), layout="constrained")
        for name in walked:
            d, _ = read_group(out / "data.zarr", f"{name}_K")
            st = d["stable"] == 1
            ax.plot(d["K"], d["energy"], "-", color=colours[name], lw=0.8)
            ax.plot(d["K"][st], d["energy"][st], "o", ms=4, color=colours[name], label=f"{name}: stable")
            ax.plot(
                d["K"][~st], d["energy"][~st], "o", ms=4, mfc="none", color=colours[name], label=f"{name}: unstable"
            )
            ax.set_title(f"the breather at the threshold's $\\omega_b$ = {d['omega'][0]:.6f} ({name}), continued in K")
        ax.set(xlabel="K", ylabel="energy H")
        ax.legend(fontsize=7)
        save_figure(fig, out, "monolayer-K")


def _plot_one(out, s) -> None:
    """One breather: z = u - v at t = 0 on the patch, and its multipliers on the unit circle."""
    plt = pyplot()
    b, _ = read_group(out / "data.zarr", f"{s['lattice']}_breather")
    m, _ = read_group(out / "data.zarr", f"{s['lattice']}_multipliers")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.4), layout="constrained")
    z = b["u"] - b["v"]
    scale = np.abs(z).max()
    im = axes[0].scatter(b["x"], b["y"], c=z, s=30, cmap="RdBu_r", vmin=-scale, vmax=scale)
    axes[0].set(aspect="equal", xticks=[], yticks=[])
    axes[0].set_title(
        f"{s['lattice']} {s['n']} x {s['n']} {s['boundary']}, {family_label(s['family'])}, "
        f"$\\omega_b$ = {s['omega']:g}\n"
        f"z = u - v at t = 0; E = {s['energy']:.8f}"
    )
    fig.colorbar(im, ax=axes[0], shrink=0.8)
    t = np.linspace(0, 2 * np.pi, 400)
    axes[1].plot(np.cos(t), np.sin(t), color="0.6", lw=0.8)
    axes[1].plot(m["real"], m["imag"], "o", ms=3)
    axes[1].set(aspect="equal", xlabel="Re", ylabel="Im")
    axes[1].set_title(f"Floquet multipliers: {s['verdict']} (max |l| = {s['max_floquet_modulus']:.10f})")
    save_figure(fig, out, "monolayer")
