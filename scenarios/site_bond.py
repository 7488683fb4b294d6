"""Site- and bond-centred breathers, the asymmetric family that joins them, and which instabilities
are the breather's own (the paper's abstract: breathers "localized around one or two lattice sites").

Command: ``python -m scenarios run site-bond`` (CPU: ~30 s on 2 cores; ``--quick``: N = 101, under
a minute). Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

1. **Families** at w_b = 1.01, from the anti-continuum seeds at K = 0.01 to K = 160: site-centred
   (natural parameter in log10 K, kept mirror symmetric) and bond-centred in phase (natural
   parameter: a pseudo-arclength corrector stalls at its branch points, where the bordered Jacobian
   is singular), bond-centred out of phase (pseudo-arclength in log10 K, ``branch.CouplingAxis``,
   which follows it through its fold), multipliers and their kinds at every point.
2. **Branch points** (``continuation.bifurcation``): where the number of localized real pairs changes
   (per parity on the symmetric family), located by the secant on mu - 1 to ``locate_atol`` in log10 K.
3. **Switching** at the site family's symmetry-breaking pitchfork onto the asymmetric family, followed
   until its energy centre reaches the bond centre (it joins the bond-centred family) or it leaves the
   K range. The square-root law is measured with ``sqrt_amplitudes``; its first points are checked for
   periodicity with scipy's DOP853.
4. **Peierls-Nabarro barrier**: E(bond in phase) - E(site) at ``pn_K`` and at the site family's
   points from ``pn_from_K`` on (the bond orbit solved at each of those K, unless the bond family
   has a point there).
5. **Finite-size check** at ``finite_size_K``: the site breather re-solved on 2N - 1 sites; unstable
   multipliers that keep their modulus and are localized are intrinsic, the others finite-size.
6. Period doubling and localized Krein collisions on the families are reported (not followed).

Everything is stored in ``data.zarr`` (groups ``site``, ``bond_in_phase``, ``bond_out_of_phase``,
``asymmetric``, ``bifurcations``, ``sqrt_law``, ``finite_size_K<K>_N<N>``); the figures read it
(drawn by ``_site_bond_figures``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from continuation import anticontinuum_seed, find_breather
from continuation import bifurcation as bf
from continuation.branch import CouplingAxis, NaturalParameter, PseudoArclength
from continuation.driver import KREIN_MODES
from continuation.floquet import KINDS, energy_centre
from warpchain import ChainParams
from warpchain.reference import solve_ivp_reference
from warpchain.store import StoreError, open_store, write_table

from continuation.branch_store import load_branch
from ._common import (
    PAPER_K,
    PAPER_N,
    PAPER_OMEGA,
    Context,
    read_summary,
)
from ._continuation_common import (
    BRANCH_RULES,
    BranchParameters,
    branch_summary,
    run_branch,
    step_rule,
)
from ._params import DENSE_MAX_SITES, Rule, anticontinuum_rule, param
from ._site_bond_figures import draw_figures
from ._workers import Workers

FAMILIES = ("site", "bond-in-phase", "bond-out-of-phase", "asymmetric")
BIFURCATION_KINDS = ("symmetry_breaking_pitchfork", "branch_point", "period_doubling", "krein_collision")


@dataclasses.dataclass(frozen=True)
class Parameters(BranchParameters):
    """The scene's parameters (``--set KEY=VALUE``); steps and resolution in log10 K."""

    N: int = param(
        PAPER_N,
        "sites of the chain; the figure draws sites c - 8 .. c + 9 around the centre c",
        ge=19,
        le=DENSE_MAX_SITES,
    )
    omega: float = param(PAPER_OMEGA, "breather frequency w_b", gt=0)
    K_start: float = param(0.01, "coupling of the anti-continuum seeds, where the families start", gt=0)
    K_end: float = param(PAPER_K, "coupling where the families end", gt=0)
    ds: float = param(0.15, "first step, in log10 K", gt=0)
    ds_max: float = param(0.3, "largest step, in log10 K", gt=0)
    fine_from_K: float = param(5.0, "from this K to fine_to_K, steps of at most ds_fine", gt=0)
    fine_to_K: float = param(30.0, "end of the fine steps; the exchanges located by default lie below it", gt=0)
    ds_fine: float = param(
        0.05, "largest step in the fine window, in log10 K: the site/bond exchanges come every ~0.07-0.12", gt=0
    )
    resolution: float = param(
        0.3,
        "smallest bracket of a stability change, in log10 K: no bisection, Brent's method locates instead",
        ge=1e-12,
    )
    bisect_krein: str = param(
        "none",
        "passes of opposite Krein signature bisected: the phonon foam is the continuation scenes'",
        choices=KREIN_MODES,
    )
    multiplier_floor: float = param(0.1, "floor of the spectral step bound, continuation.driver", gt=0)
    out_of_phase_ds_max: float = param(
        0.3, "largest arclength step of the bond-out-of-phase family, followed only to its fold", gt=0
    )
    locate_atol: float = param(
        1e-8,
        "tolerance of a located branch point, in log10 K: 2.3e-8 relative in K; the noise of mu limits it more",
        gt=0,
    )
    pn_from_K: float = param(1.0, "the barrier is solved at the site family's points from this K on, and at pn_K", gt=0)
    locate_K_max: float = param(30.0, "branch points above this K are reported with their bracket, not located", gt=0)
    pn_K: tuple[float, ...] = param(
        (5.0, 20.0, PAPER_K), "couplings where the Peierls-Nabarro barrier is reported", gt=0
    )
    switch_amplitude: float = param(
        0.02,
        "step onto the asymmetric family along the unit null vector of positions; contact is lost at 1",
        gt=0,
        lt=1,
    )
    sqrt_amplitudes: tuple[float, ...] = param(
        (0.005, 0.01, 0.02, 0.04),
        "amplitudes along the null vector that measure the square-root law by a fit: two or more, distinct",
        gt=0,
        lt=1,
        length=(2, None),
    )
    asymmetric_ds: float = param(
        0.02, "arclength steps of the asymmetric family: at most 4 x this, at least its ds_min 1e-6", ge=1e-6, le=1.0
    )
    asymmetric_max_points: int = param(60, "points of the asymmetric family at most", ge=1, le=1_000_000)
    finite_size_K: tuple[float, ...] = param(
        (10.0, PAPER_K), "couplings of the finite-size check: the site orbit re-solved on 2N - 1 sites", gt=0
    )
    dop853_rtol: float = param(1e-11, "relative tolerance of the DOP853 check of the asymmetric family", ge=1e-13, lt=1)
    workers: int = param(
        0, "host threads for the branch-point and finite-size solves; 0: one per 2 cores, at most 4", ge=0, le=1024
    )

    RULES = (
        Rule(
            ("K_start", "K_end"),
            "K_start < K_end: the families go up from the anti-continuum seeds",
            lambda P: P.K_start < P.K_end,
        ),
        Rule(("fine_from_K", "fine_to_K"), "fine_from_K < fine_to_K", lambda P: P.fine_from_K < P.fine_to_K),
        *(
            Rule(
                (name, "K_start", "K_end"),
                f"every {name} in (K_start, K_end], where the families land on it",
                lambda P, name=name: all(P.K_start < k <= P.K_end for k in getattr(P, name)),
            )
            for name in ("pn_K", "finite_size_K")
        ),
        Rule(
            ("sqrt_amplitudes",),
            "distinct sqrt_amplitudes: a line is fitted through them",
            lambda P: len(set(P.sqrt_amplitudes)) == len(P.sqrt_amplitudes),
        ),
        anticontinuum_rule("omega"),
        *BRANCH_RULES,
        Rule(
            ("ds", "ds_min", "out_of_phase_ds_max"),
            "ds_min <= ds <= out_of_phase_ds_max, that family's largest step",
            lambda P: P.ds_min <= P.ds <= P.out_of_phase_ds_max,
        ),
        step_rule("omega", "K_end"),
    )

    def settings(self):
        return super().settings().replace(multiplier_floor=self.multiplier_floor)


QUICK = {
    "N": 61,
    "K_end": 25.0,
    "ds": 0.3,
    "ds_max": 0.5,
    "ds_fine": 0.1,
    "resolution": 0.5,
    "locate_K_max": 12.0,
    "finite_size_K": (10.0,),
    "pn_K": (5.0, 20.0),
}


def _group(family: str) -> str:
    return family.replace("-", "_")


class _FinerIn:
    """A continuation problem whose steps are capped at ``ds`` while K_lo <= K < K_hi (every other
    attribute is the wrapped problem's)."""

    def __init__(self, problem, K_lo: float, K_hi: float, ds: float):
        self._problem, self._K_lo, self._K_hi, self._ds = problem, K_lo, K_hi, ds

    def __getattr__(self, name):
        return getattr(self._problem, name)

    def clip_step(self, last, h: float) -> float:
        h = self._problem.clip_step(last, h)
        return min(h, self._ds) if self._K_lo <= last.K < self._K_hi else h


def _arclength_in_K(params, omega, flow, starts, K_range, until=None) -> PseudoArclength:
    """Pseudo-arclength in (positions, log10 K) from two start points, without symmetry projection."""
    axis = CouplingAxis(params, omega)
    return PseudoArclength(params, flow, starts, axis=axis, symmetric=False, K_range=K_range, until=until)


def _family_sites(P: Parameters, family: str) -> int:
    """Sites of a family's chain: N, except N + 1 for the in-phase bond family when N is odd, so that
    the chain is mirror symmetric about the bond (its profile is then projected onto that symmetry,
    which removes its singular odd direction at its own branch points; boundary effects on energies
    are ~exp(-kappa N / 2), far below 1e-13)."""
    return P.N + 1 if family == "bond-in-phase" and P.N % 2 else P.N


def _family_branch(ctx: Context, P: Parameters, flow, family: str):
    """Continue one family from its anti-continuum seed at K_start to K_end."""
    params = ChainParams(P.M, P.K_start, _family_sites(P, family))
    settings = P.settings()
    if family == "bond-out-of-phase":
        settings = settings.replace(ds_max=P.out_of_phase_ds_max, resolution=P.out_of_phase_ds_max)
    attrs = {"family": family, "omega": P.omega, "method": P.method, "steps_per_period": P.steps_per_period}
    seed = anticontinuum_seed(params, P.omega, family, centre=params.N // 2 - (params.N % 2 == 0))
    if family != "bond-out-of-phase":  # monotonic in K; the natural parameter steps over the branch points
        problem = NaturalParameter(params, P.omega, seed, P.K_end, flow, targets=tuple(P.pn_K) + tuple(P.finite_size_K))
        kept = f" (mirror symmetric, N = {params.N})"
        attrs.update(continuation=f"natural parameter in log10 K{kept}", coordinate="log10 K")
    else:
        first = find_breather(params, P.omega, seed, flow=flow, symmetric=False)
        if not first.success:
            raise RuntimeError(f"the {family} seed did not converge at K = {P.K_start}: {first.message}")
        p2 = params.replace(K=P.K_start * 10 ** (0.5 * P.ds))
        second = find_breather(p2, P.omega, first.state, flow=flow, symmetric=False)
        if not second.success:
            raise RuntimeError(f"the {family} family's second point did not converge: {second.message}")
        starts = [
            (r.state, math.log10(r.params.K), r.iterations, r.residual_history, r.linearization())
            for r in (first, second)
        ]
        problem = _arclength_in_K(params, P.omega, flow, starts, (0.5 * P.K_start, P.K_end))
        attrs.update(continuation="pseudo-arclength in (positions, log10 K)", coordinate="arclength")
    attrs["settings"] = dataclasses.asdict(settings)
    if family != "bond-out-of-phase":
        problem = _FinerIn(problem, P.fine_from_K, P.fine_to_K, P.ds_fine)
        attrs["fine_steps"] = {"from_K": P.fine_from_K, "to_K": P.fine_to_K, "ds": P.ds_fine}
    new = family == "site"
    return run_branch(ctx, problem, settings, params, attrs, group=_group(family), new_store=new)


def _solve_near(points, K: float, P: Parameters, flow, symmetric=None):
    """The family's orbit at exactly K, by Newton from its nearest stored point (None when K lies
    outside the family's range or Newton fails)."""
    Ks = np.array([p.K for p in points])
    if not (Ks.min() <= K <= Ks.max()):
        return None
    near = points[int(np.argmin(np.abs(np.log(Ks) - math.log(K))))]
    N = near.state.shape[1]
    res = find_breather(ChainParams(P.M, K, N), P.omega, near.state, flow=flow, symmetric=symmetric)
    return res if res.success else None


def _finite_size(flow, P: Parameters, K: float, site_points):
    """``bifurcation.finite_size_check`` of the site orbit at K (None when K is outside the family)."""
    site = _solve_near(site_points, K, P, flow, symmetric=True)
    return None if site is None else bf.finite_size_check(ChainParams(P.M, K, P.N), P.omega, site.state, flow)


def _folds(family: str, points) -> list:
    """Turning points in K of an arclength family: K maxima or minima of three consecutive points,
    placed at the vertex of the parabola through them in (arclength, log10 K)."""
    out = []
    for index, (a, b, c) in enumerate(zip(points, points[1:], points[2:]), start=1):
        ka, kb, kc = (math.log10(p.K) for p in (a, b, c))
        if (kb - ka) * (kc - kb) < 0:
            s = np.array([a.s, b.s, c.s])
            coeff = np.polyfit(s - b.s, [ka, kb, kc], 2)
            vertex = kb if coeff[0] == 0 else float(np.polyval(coeff, -coeff[1] / (2 * coeff[0])))
            out.append(
                {
                    "K": 10.0**vertex,
                    "kind": "fold",
                    "family": family,
                    "bracket": [min(a.K, c.K), max(b.K, 10.0**vertex)],
                    "located": False,
                    "index": index,
                }
            )
    return out


def _padded(arrays, shape) -> np.ndarray:
    """Stack (rows, n_i) arrays into (len, *shape), NaN to the right of each one's n_i columns."""
    out = np.full((len(arrays), *shape), np.nan)
    for k, a in enumerate(arrays):
        out[k, :, : a.shape[1]] = a
    return out


def _other_events(family: str, points) -> list:
    """Where a localized period-doubling pair or a localized Krein quadruplet appears or disappears
    along a family (reported, not followed); extended ones (finite-size resonances) are only counted
    in the families' summaries."""
    out = []
    for kind, name in (("period_doubling", "period_doubling"), ("complex_quadruplet", "krein_collision")):
        has = [any(i.kind == kind and i.localized for i in p.instabilities) for p in points]
        for a, b, ha, hb in zip(points, points[1:], has, has[1:]):
            if ha != hb:
                out.append(
                    {
                        "K": math.sqrt(a.K * b.K),
                        "kind": name,
                        "family": family,
                        "bracket": sorted([a.K, b.K]),
                        "direction": "gained" if hb else "lost",
                        "located": False,
                    }
                )
    return out


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    # branch points and finite-size checks on host threads (``_workers``); an error or Ctrl-C closes the pool,
    # cancelling the queued solves rather than running them first
    with Workers(P.workers, lambda: P.flow(ctx.device), ctx.log, name="site-bond", outcomes=(bf.NotLocated,)) as w:
        return _run(ctx, w)


def _run(ctx: Context, workers: Workers) -> dict:
    P: Parameters = ctx.params
    flow = P.flow(ctx.device)
    branches, bifurcations, folds, unlocated = {}, [], [], []

    # 1. the three families from the anti-continuum limit
    for family in FAMILIES[:3]:
        branches[family] = _family_branch(ctx, P, flow, family)

    # 2. branch points: localized real pairs through +1, located on worker threads (each solve is
    # independent; the log lines follow in the families' order)
    tasks = []
    for family in FAMILIES[:3]:
        points = branches[family].points
        parity = -1 if family != "bond-out-of-phase" else None
        family_folds = _folds(family, points)
        folds.extend(family_folds)
        for i, j, vertex in bf.suspect_steps(points, parity):
            if any(abs(i - f["index"]) <= 2 or abs(j - f["index"]) <= 2 for f in family_folds):
                continue  # a real pair through +1 at a fold in K is the fold itself (J singular there)
            if points[i].K > P.locate_K_max:
                unlocated.append(bf.unlocated(family, points[i], points[j], vertex, parity))
                continue
            tasks.append((family, points[i], points[j], vertex, parity))

    def locate(flow, family, a, b, vertex, parity):
        try:
            chain = ChainParams(P.M, P.K_start, a.state.shape[1])
            return bf.locate_real_pair(
                family, chain, P.omega, a, b, flow, parity=parity, vertex=vertex, atol=P.locate_atol
            )
        except bf.NotLocated as exc:  # the mathematics says no: reported; any other error fails the scene
            return exc

    located = [
        workers.submit(f"{t[0]}: locating the branch point between K = {t[1].K:.8g} and {t[2].K:.8g}", locate, *t)
        for t in tasks
    ]
    # the finite-size checks (step 5) only need the site family: they run beside the rest
    finite_jobs = {
        K: workers.submit(f"the finite-size check at K = {K:g}", _finite_size, P, K, branches["site"].points)
        for K in P.finite_size_K
    }
    for (family, a, b, _, _), job in zip(tasks, located):
        found = job.result()
        if isinstance(found, bf.NotLocated):
            ctx.log("%s: the branch point between K = %.8g and %.8g was not located: %s", family, a.K, b.K, found)
            continue
        for bif in found:
            ctx.log(
                "%s: %s at K = %.10g +- %.1e (%s the localized real pair; null vector: %.1f sites, %.0f %% on the "
                "centre; mu - 1 = %.1e; %d solves)",
                family,
                bif.kind,
                bif.K,
                bif.K_error,
                bif.direction,
                bif.participation,
                100 * bif.central_weight,
                bif.test,
                bif.evaluations,
            )
            bifurcations.append(bif)
    if unlocated:
        ctx.log(
            "%d more exchanges of the localized real pair above K = %g (brackets in summary.json; "
            "--set locate_K_max=... locates them)",
            len(unlocated),
            P.locate_K_max,
        )
    others = unlocated + folds + [e for family in FAMILIES[:3] for e in _other_events(family, branches[family].points)]
    for e in folds:
        ctx.log("%s: fold at K = %.6g (the family turns back towards smaller K)", e["family"], e["K"])

    # 3. switch onto the asymmetric family at the site family's pitchfork
    pitchforks = [b for b in bifurcations if b.kind == "symmetry_breaking_pitchfork"]
    asym, sqrt_rows, dop, reached_bond_centre = None, [], [], []
    if pitchforks:
        pf = pitchforks[0]
        params_pf = ChainParams(P.M, pf.K, P.N)
        site_points = branches["site"].points
        for a in P.sqrt_amplitudes:  # the square-root law: distance from the symmetric family vs K - K*
            (s1, c1, *_), _ = bf.switch_to_asymmetric(pf, params_pf, flow, a, tol=1e-12)
            K1 = 10.0**c1
            sym = _solve_near(site_points, K1, P, flow, symmetric=True)
            dist = float(np.linalg.norm(s1[:2] - sym.state[:2])) if sym is not None else float("nan")
            sqrt_rows.append((a, K1, K1 - pf.K, dist, energy_centre(s1) - energy_centre(pf.state)))
        # K(a) = K0 + c a^2 from the new points alone: K0 cross-checks the located K*, and the exponent
        # of distance vs |K - K0| does not depend on K*'s last digits (the offsets are ~1e-8 .. 1e-6)
        amps, Ks_new = np.array([r[0] for r in sqrt_rows]), np.array([r[1] for r in sqrt_rows])
        curvature, K0 = np.polyfit(amps**2, Ks_new, 1)
        fit = np.polyfit(np.log(np.abs(Ks_new - K0)), np.log([r[3] for r in sqrt_rows]), 1)
        ctx.log(
            "square-root law: K = K0 + %.3g a^2 with K0 - K* = %.1e; distance ~ |K - K0|^%.4f (expected 1/2)",
            curvature,
            K0 - pf.K,
            fit[0],
        )
        starts = bf.switch_to_asymmetric(pf, params_pf, flow, P.switch_amplitude)
        for state, c, *_ in starts:  # the new orbits are breathers of the ODE, not only of the map
            Kc = 10.0**c
            end, _ = solve_ivp_reference(
                ChainParams(P.M, Kc, P.N), state, 2 * math.pi / P.omega, rtol=P.dop853_rtol, atol=1e-3 * P.dop853_rtol
            )
            dop.append(float(np.max(np.abs(end - state)) / np.max(np.abs(state[:2]))))
        ctx.log(
            "asymmetric family's first points: DOP853 returns after one period to %s",
            ", ".join(f"{d:.1e}" for d in dop),
        )
        bond_centre = energy_centre(pf.state) + 0.5

        def until(prev, point):
            a, b = energy_centre(prev.state) - bond_centre, energy_centre(point.state) - bond_centre
            if a * b <= 0:
                reached_bond_centre.append((prev.K, point.K))
                return f"its energy centre reached the bond centre between K = {prev.K:.10g} and {point.K:.10g}"
            return None

        problem = _arclength_in_K(params_pf, P.omega, flow, starts, (P.K_start, P.K_end), until)
        settings = P.settings().replace(
            ds=P.asymmetric_ds, ds_max=4 * P.asymmetric_ds, max_points=P.asymmetric_max_points, ds_min=1e-6
        )
        attrs = {"family": "asymmetric", "omega": P.omega, "born_at_K": pf.K, "settings": dataclasses.asdict(settings)}
        asym = run_branch(ctx, problem, settings, params_pf, attrs, group="asymmetric", new_store=False)
        branches["asymmetric"] = asym
    end_join = _asymmetric_end(asym, bifurcations, bool(reached_bond_centre))
    if end_join:
        ctx.log("asymmetric family: %s", end_join["message"])

    # 4. the Peierls-Nabarro barrier: the bond-in-phase orbit solved at every site point's K
    barrier = []
    site_points, bond_points = branches["site"].points, branches["bond-in-phase"].points
    bond_K = np.array([p.K for p in bond_points])
    pn_rows = []
    for p in site_points:
        if not bond_K.min() <= p.K <= bond_K.max() or (p.K < P.pn_from_K and p.K not in P.pn_K):
            continue
        same = [b for b in bond_points if abs(b.K - p.K) <= 1e-12 * p.K]  # the bond family landed on it
        bond = same[0] if same else _solve_near(bond_points, p.K, P, flow)
        if bond is not None:
            pn_rows.append((p.K, p.energy, bond.energy))
    for K in P.pn_K:
        row = next((r for r in pn_rows if abs(r[0] - K) <= 1e-12 * K), None)
        if row is None:
            barrier.append({"K": K, "site_energy": None, "bond_energy": None, "barrier": None})
            continue
        barrier.append({"K": K, "site_energy": row[1], "bond_energy": row[2], "barrier": row[2] - row[1]})
        ctx.log("PN barrier at K = %g: E_bond - E_site = %.3e (E_site = %.10f)", K, row[2] - row[1], row[1])

    # the exchange window of the first pitchfork: site and bond solved on a grid, the asymmetric points
    exchange = None
    if asym is not None and end_join and end_join.get("bond_branch_point_K"):
        K_s, K_b = pitchforks[0].K, end_join["bond_branch_point_K"]
        width = abs(K_b - K_s)
        bond_start = min((b for b in bifurcations if b.family == "bond-in-phase"), key=lambda b: abs(b.K - K_b)).state
        bond_start = bond_start[:, : P.N]  # the bond family's chain has one more (empty) site at the end
        grid = np.linspace(min(K_s, K_b) - 0.5 * width, max(K_s, K_b) + 0.5 * width, 11)
        rows = []
        for K in grid:
            site = find_breather(ChainParams(P.M, K, P.N), P.omega, pitchforks[0].state, flow=flow, tol=1e-12)
            bond = find_breather(ChainParams(P.M, K, P.N), P.omega, bond_start, flow=flow, tol=1e-12)
            if site.success and bond.success:
                rows.append((K, site.energy, bond.energy))
        exchange = np.array(rows, float)

    # 5. finite-size check on the site family
    root = open_store(ctx.out / "data.zarr", mode="a")
    tables = {}
    for K, job in finite_jobs.items():
        check = job.result()
        if check is None:
            continue
        tables[f"{K:g}"] = check
        for row in check["classification"]:
            ctx.log(
                "K = %g, N = %d: %s |l| = %.7f (%.1f sites, %.0f %% central) -> N = %d: %s: %s",
                K,
                check["N"],
                row["kind"],
                row["modulus"],
                row["participation"],
                100 * row["central_weight"],
                check["N_new"],
                "%.7f" % row["modulus_new"] if row["modulus_new"] else "gone",
                row["class"],
            )
        for n, rows in check["tables"].items():
            write_table(
                root,
                f"finite_size_K{K:g}_N{n}",
                {
                    "modulus": np.array([r["modulus"] for r in rows], float),
                    "kind": np.array([KINDS.index(r["kind"]) for r in rows], np.int8),
                    "participation": np.array([r["participation"] for r in rows], float),
                    "central_weight": np.array([r["central_weight"] for r in rows], float),
                    "localized": np.array([r["localized"] for r in rows], np.int8),
                    "parity": np.array([r["parity"] for r in rows], np.int8),
                    "weight": check["weights"][n],
                },
                dim="instability",
                attrs={"K": K, "N": n, "kinds": list(KINDS)},
            )

    # the bifurcation table, the square-root law, the barrier and the exchange window
    n_max = max([P.N] + [b.state.shape[1] for b in bifurcations])
    if pn_rows:
        rows = np.array(pn_rows, float)
        write_table(
            root,
            "pn_barrier",
            {"K": rows[:, 0], "site_energy": rows[:, 1], "bond_energy": rows[:, 2], "barrier": rows[:, 2] - rows[:, 1]},
            dim="K",
        )
    if exchange is not None and len(exchange):
        write_table(
            root,
            "exchange",
            {"K": exchange[:, 0], "site_energy": exchange[:, 1], "bond_energy": exchange[:, 2]},
            dim="K",
            attrs={"site_pitchfork_K": pitchforks[0].K, "bond_branch_point_K": end_join["bond_branch_point_K"]},
        )
    write_table(
        root,
        "bifurcations",
        {
            "K": np.array([b.K for b in bifurcations], float),
            "energy": np.array([b.energy for b in bifurcations], float),
            "participation": np.array([b.participation for b in bifurcations], float),
            "central_weight": np.array([b.central_weight for b in bifurcations], float),
            "state": _padded([b.state for b in bifurcations], (4, n_max)),
            "null_vector": _padded([b.null_vector.reshape(2, -1) for b in bifurcations], (2, n_max)).reshape(
                -1, 2 * n_max
            ),
            "sites": np.array([b.state.shape[1] for b in bifurcations], np.int32),
        },
        dim="bifurcation",
        attrs={
            "padding": "families on N + 1 sites are stored as they are, shorter ones padded with NaN on the right",
            "family": [b.family for b in bifurcations],
            "kind": [b.kind for b in bifurcations],
            "direction": [b.direction for b in bifurcations],
        },
    )
    if sqrt_rows:
        rows = np.array(sqrt_rows, float)
        write_table(
            root,
            "sqrt_law",
            {"amplitude": rows[:, 0], "K": rows[:, 1], "K_offset": rows[:, 2], "distance": rows[:, 3]},
            dim="amplitude",
            attrs={"K_star": pitchforks[0].K, "exponent": float(fit[0])},
        )
    oop = branches["bond-out-of-phase"].points
    z_end = oop[-1].state[0] - oop[-1].state[1]
    out_of_phase_end = {
        "K": oop[-1].K,
        "energy": oop[-1].energy,
        "excited_sites": int(np.sum(np.abs(z_end) > 0.3 * np.max(np.abs(z_end)))),
        "message": branches["bond-out-of-phase"].message,
    }
    summary = {
        "omega": P.omega,
        "M": P.M,
        "N": P.N,
        "bifurcation_points": [b.as_dict() for b in bifurcations] + others,
        "pn_barrier": barrier,
        "bond_out_of_phase_end": out_of_phase_end,
        "asymmetric": None
        if asym is None
        else {
            "born_at_K": pitchforks[0].K,
            "points": len(asym.points),
            "K_range": [min(p.K for p in asym.points), max(p.K for p in asym.points)],
            "stop_reason": asym.stop_reason.value,
            "message": asym.message,
            "joins": end_join,
            "sqrt_law_exponent": float(fit[0]),
            "sqrt_law_K0": float(K0),
            "sqrt_law_curvature": float(curvature),
            "sqrt_law": [dict(zip(("amplitude", "K", "K_offset", "distance", "centre_shift"), r)) for r in sqrt_rows],
            "dop853_periodicity": dop,
        },
        "finite_size": {
            K: {
                "N": c["N"],
                "N_new": c["N_new"],
                "tables": {str(n): rows for n, rows in c["tables"].items()},
                "classification": c["classification"],
                "energy": {str(n): e for n, e in c["energy"].items()},
            }
            for K, c in tables.items()
        },
        "families": {f: branch_summary(b, "K") for f, b in branches.items()},
    }
    for f in summary["families"].values():
        f.pop("points", None)  # in the store
    return summary


def _asymmetric_end(asym, bifurcations, joined: bool) -> dict | None:
    """Where the asymmetric family ended, and how close that is to a branch point of the bond family."""
    if asym is None or not asym.points:
        return None
    last = asym.points[-1]
    bond = [b for b in bifurcations if b.family == "bond-in-phase"]
    out = {"message": asym.message, "K_end": last.K, "joins_bond_family": joined}
    if bond:
        nearest = min(bond, key=lambda b: abs(b.K - last.K))
        out.update(bond_branch_point_K=nearest.K, relative_distance=abs(last.K - nearest.K) / nearest.K)
        out["message"] += f"; the bond-in-phase family's branch point is at K = {nearest.K:.10g}"
    return out


# ----------------------------------------------------------------------------- figures


def plot(out) -> None:
    """The figures: the summary and the store's groups read here, drawn by ``_site_bond_figures``."""
    s = read_summary(out)
    path = out / "data.zarr"
    fam = {}
    for family in FAMILIES:
        try:
            fam[family] = load_branch(path, _group(family))[1]
        except StoreError:
            if family != "asymmetric":
                raise
    import zarr

    root = zarr.open_group(str(path), mode="r", zarr_format=3, use_consolidated=False)
    draw_figures(out, s, fam, root)
