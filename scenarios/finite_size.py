"""Finite size: do the paper breather and the K = 10 site breather exist in the infinite chain, and which of
their instabilities are their own? (issues #36 and #48; beyond the paper)

The paper breather (M = 30, K = 160, w_b = 1.01, from the NLS seed) and the site breather at K = 10 (the
anti-continuum branch continued in K from 0.01 at the smallest N) are solved at N = 201, 401, ..., 12801 sites,
each size seeded with the previous solution padded with zeros at both ends. Newton is matrix-free from
``continuation.shooting.KRYLOV_MIN_SITES`` sites on (``find_breather(solver="auto")``; GMRES with the linear
lattice's preconditioner), dense below. Per size: the energy, the tail amplitude (max |u - v| further than
``tail_distance`` sites from the centre, and over the outer quarter of the chain on each side), and the complete
Floquet verdict with every instability's kind, modulus, participation and parity: dense (4N tangent columns) below
``continuation.floquet.SLICED_MIN_SITES`` sites, and from there every multiplier of the probed sparse Mu, by a dense
eig per parity block (on a GPU with CuPy, or on the host below ``PROBED_HOST_MAX_SITES`` sites) or by shift-invert
slices, certified by a count (``floquet(solver="auto")``, ``continuation.slicing``). Each row says
whether its verdict is complete (it always is unless a count fails to close, which the log and figure show).

The figure's question: the extended instabilities (Krein quadruplets of the breather with the chain's phonons)
against N, with a fitted power law |l| - 1 ~ N^p, beside the breather's own (localized) multipliers converging to
their infinite-chain value.

The K-branch foam: the site family at ``foam_points`` couplings log-spaced over ``foam_K`` (default [2, 4]),
at each N of ``foam_sizes``, each point solved from the previous one and analysed by the complete path
(``floquet(solver="auto")``): the unstable fraction of the grid, its stability changes and moduli against N (a
fixed grid, so that no step control decides which bubbles are seen).

Each family's sizes and each foam size's couplings are solved on a thread of their own (every orbit is seeded by
the previous one), and every Floquet analysis goes to ``workers`` more threads (``scenarios._workers``), all with
one BLAS thread: the summary does not depend on how many run at once. The first failure anywhere fails the scene
at once.

Command: ``python -m scenarios run finite-size`` (one H200 machine with CuPy: 3.5 min, foam included; the 2-core CPU
without the foam, ``--set "foam_sizes=()"``: ~15 min; ``--quick`` N = 101 .. 401, foam at 101 and 201 on 24 points,
~6 s). Options: ``--set KEY=VALUE`` (fields of ``Parameters``).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from continuation import anticontinuum_seed, find_breather, floquet, nls_seed, require
from continuation.branch import NaturalParameter
from continuation.driver import ContinuationSettings, IncompleteVerdict, continuation
from continuation.hostblas import blas_threads
from warpchain import ChainParams, Flow
from warpchain.store import read_group, write_table

from ._common import (
    BREATHER_METHOD,
    BREATHER_STEPS_PER_PERIOD,
    PAPER_K,
    PAPER_M,
    PAPER_OMEGA,
    Context,
    pyplot,
    read_summary,
    save_figure,
)
from ._params import MAX_SITES, Rule, param
from ._workers import Workers


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    sizes: tuple[int, ...] = param(
        (201, 401, 801, 1601, 3201, 6401, 12801),
        "chain lengths N, increasing, odd (a site at the centre)",
        ge=31,
        length=(2, None),
        le=MAX_SITES,
    )
    site_K: float = param(
        10.0, "coupling of the site family's breather (reached by continuation from K = 0.01)", gt=0.01
    )
    solver: str = param(
        "auto",
        "Newton's linear solves at every size: auto (matrix-free from 1025 sites), dense or krylov (GMRES)",
        choices=("auto", "dense", "krylov"),
    )
    floquet_solver: str = param(
        "auto",
        "every multiplier at every size: auto (dense below 1601 sites; from there probed on a GPU with CuPy or below "
        "2000 sites, else sliced, both counted), dense, sliced or probed",
        choices=("auto", "dense", "sliced", "probed"),
    )
    tail_distance: int = param(60, "the tail: sites further than this from the centre", ge=1, le=MAX_SITES)
    foam_sizes: tuple[int, ...] = param(
        (201, 401, 801),
        "chain lengths of the K-branch foam scan (complete Floquet at every point); () skips it",
        ge=31,
        le=MAX_SITES,
    )
    foam_K: tuple[float, ...] = param(
        (2.0, 4.0), "the stretch of the site family's K-branch scanned", gt=0.01, length=(2, 2)
    )
    foam_points: int = param(
        200, "couplings of the scan, log-spaced over foam_K (the same at every N)", ge=2, le=100_000
    )
    workers: int = param(
        0, "host threads for the Floquet analyses (beside one per family and foam size for the solves); 0: one per "
        "2 cores, at most 8", ge=0, le=1024,
    )  # fmt: skip

    RULES = (
        Rule(
            ("sizes",),
            "sizes increasing and odd (a centre site, and a padding of the same width on both sides)",
            lambda P: all(n % 2 == 1 for n in P.sizes) and list(P.sizes) == sorted(set(P.sizes)),
        ),
        Rule(
            ("tail_distance", "sizes"),
            "tail_distance < sizes[0] / 2: the tail lies inside the smallest chain",
            lambda P: 2 * P.tail_distance < P.sizes[0],
        ),
        Rule(("foam_K",), "foam_K[0] < foam_K[1]", lambda P: P.foam_K[0] < P.foam_K[1]),
        Rule(("foam_sizes",), "foam_sizes odd", lambda P: all(n % 2 == 1 for n in P.foam_sizes)),
    )


QUICK = {
    "sizes": (101, 201, 401),
    "tail_distance": 30,
    "foam_sizes": (101, 201),
    "foam_points": 24,
}


FAMILIES = ("paper", "site")


def _pad(state: np.ndarray, N: int) -> np.ndarray:
    """A (4, n) state centred in a chain of N sites (zeros around it)."""
    pad = (N - state.shape[1]) // 2
    return np.pad(state, ((0, 0), (pad, pad)))


def _flow(device: str) -> Flow:
    """A Flow of the scene's integrator (each worker thread makes its own: ``_workers``)."""
    return Flow(BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD, device=device)


def _solve(params: ChainParams, seed, flow: Flow, solver: str = "auto"):
    """The breather at w_b = 1.01 from ``seed`` on ``flow`` (Newton's solves: ``find_breather(solver=...)``)."""
    return require(find_breather(params, PAPER_OMEGA, seed, flow=flow, solver=solver))


def _site_breather(K: float, N: int, flow: Flow, ctx) -> np.ndarray:
    """The site family's breather at coupling K on N sites, continued in K from the anti-continuum limit."""
    p = ChainParams(PAPER_M, 0.01, N)
    problem = NaturalParameter(p, PAPER_OMEGA, anticontinuum_seed(p, PAPER_OMEGA), K_end=K, flow=flow)
    branch = continuation(problem, ContinuationSettings(ds=0.15, ds_max=0.3, floquet=False))
    last = branch.points[-1]
    if abs(last.K - K) > 1e-9 * K:
        raise RuntimeError(f"the site family's continuation stopped at K = {last.K:.6g}: {branch.message}")
    ctx.log("site family: continued to K = %g on N = %d in %d points", K, N, len(branch.points))
    return last.state


def _size_row(flow: Flow, b, P: "Parameters", family: str, ctx) -> dict:
    """One size's row: the solve's energy, tail and Newton record, and its complete Floquet verdict (on a worker)."""
    N = b.params.N
    tail, outer = _tails(b.state, P.tail_distance)
    row = {
        "N": N,
        "energy": b.energy,
        "residual": b.residual,
        "newton_iterations": b.iterations,
        "solver": b.stats["solver"],
        "gmres_products": sum(b.stats.get("krylov_iterations", [])),
        "newton_seconds": b.wall_seconds,
        "tail_amplitude": tail,
        "outer_amplitude": outer,
        "min_contact": b.min_contact,
    }
    fl = floquet(b, solver=P.floquet_solver, flow=flow)
    row.update(
        max_modulus=fl.max_modulus if fl.complete else None,
        stable=fl.stable,
        complete=fl.complete,
        instabilities=[i.as_dict() for i in fl.instabilities],
        floquet_seconds=fl.wall_seconds,
        floquet_path=fl.path,
        floquet_counts=None if fl.coverage is None else fl.coverage["counts"],
        localized_max_modulus=max((i.modulus for i in fl.instabilities if i.localized), default=1.0),
        extended_max_modulus=max((i.modulus for i in fl.instabilities if not i.localized), default=1.0),
    )
    ctx.log(
        "%s N = %5d: E = %.10f (%s Newton, %d its, %.2f s), tail %.3e, outer quarter %.3e, %s, max |l| %.9f, "
        "%d instabilities (%s Floquet, %s, %.2f s)",
        family, N, b.energy, row["solver"], b.iterations, b.wall_seconds, tail, outer, fl.verdict, fl.max_modulus,
        len(row["instabilities"]), row["floquet_path"], "complete" if fl.complete else "INCOMPLETE", fl.wall_seconds,
    )  # fmt: skip
    return row


def _family(flow: Flow, P: "Parameters", family: str, analyses: Workers, ctx) -> tuple:
    """One family's solves at every size, in order (each seeded by the previous one, padded); each size's Floquet
    analysis goes to ``analyses`` as soon as its orbit is solved. Returns the analyses' Futures (rows) and the
    largest chain's state."""
    K = PAPER_K if family == "paper" else P.site_K
    state, rows = None, []
    for N in P.sizes:
        if analyses.stopping.is_set():  # the scene is closing (an error or Ctrl-C elsewhere)
            break
        params = ChainParams(PAPER_M, K, N)
        if state is None:
            seed = nls_seed(params, PAPER_OMEGA) if family == "paper" else _site_breather(P.site_K, N, flow, ctx)
        else:
            seed = _pad(state, N)
        b = _solve(params, seed, flow, P.solver)
        state = b.state
        what = f"the {family} breather's Floquet analysis at N = {N}"
        rows.append(analyses.submit(what, _size_row, b, P, family, ctx))
    return rows, state


def _foam_point(flow: Flow, b, solver: str) -> tuple:
    """One foam point's verdict, reduced to what the foam keeps: (stable, max |l|, extended and localized
    instabilities); ``continuation.driver.IncompleteVerdict`` where the count did not close (never counted as stable
    or unstable: the scene fails, in one line on the command line as a branch's would)."""
    fl = floquet(b, solver=solver, flow=flow)
    if not fl.complete:
        counts = None if fl.coverage is None else fl.coverage.get("counts")
        where = f"foam N = {b.params.N}, K = {b.params.K:.6g}"
        raise IncompleteVerdict(f"{where}: the Floquet count did not close ({counts})")
    extended = sum(not i.localized for i in fl.instabilities)
    return bool(fl.stable), float(fl.max_modulus), extended, len(fl.instabilities) - extended


def _foam_chain(flow: Flow, P: "Parameters", N: int, analyses: Workers, ctx) -> tuple:
    """The site family's K-branch over ``foam_K`` on N sites at ``foam_points`` log-spaced couplings, each solved
    from the previous one; each point's Floquet analysis (the complete path, ``floquet_solver``) goes to
    ``analyses``. A fixed grid, the same at every N, rather than the continuation driver's adaptive steps: the
    unstable fraction is then a sample mean that no step control biases (a step can cross a bubble narrower than
    itself). Returns the grid and the analyses' Futures."""
    grid = np.geomspace(P.foam_K[0], P.foam_K[1], P.foam_points)
    state = _site_breather(float(grid[0]), N, flow, ctx)
    points = []
    for K in grid:
        if analyses.stopping.is_set():  # the scene is closing (an error or Ctrl-C elsewhere)
            break
        b = _solve(ChainParams(PAPER_M, float(K), N), state, flow)
        state = b.state
        what = f"foam N = {N}, K = {K:.6g}: the Floquet analysis"
        points.append(analyses.submit(what, _foam_point, b, P.floquet_solver))
    return grid, points


def _foam(P: "Parameters", N: int, grid: np.ndarray, points: list, ctx) -> tuple:
    """The foam row and columns of N from its points' verdicts: whether each is stable, its largest modulus and
    how many of its instabilities are extended (finite-size) or localized."""
    stable, modulus, extended, localized = [], [], [], []
    for is_stable, largest, n_extended, n_localized in points:
        stable.append(is_stable)
        modulus.append(largest)
        extended.append(n_extended)
        localized.append(n_localized)
    stable = np.array(stable)
    unstable_moduli = np.array(modulus)[~stable] - 1.0
    row = {
        "N": N,
        "unstable_fraction": float(np.mean(~stable)),
        "stability_changes": int(np.count_nonzero(stable[1:] != stable[:-1])),
        "largest_modulus_minus_one": float(max(modulus) - 1.0),
        "median_unstable_modulus_minus_one": float(np.median(unstable_moduli)) if unstable_moduli.size else 0.0,
        "points_with_localized_instabilities": int(np.count_nonzero(localized)),
    }
    ctx.log(
        "foam N = %5d: K in [%g, %g], %d points: unstable fraction %.3f, %d stability changes, largest |l| - 1 %.3e",
        N, P.foam_K[0], P.foam_K[1], len(grid), row["unstable_fraction"], row["stability_changes"],
        row["largest_modulus_minus_one"],
    )  # fmt: skip
    columns = {"K": grid, "stable": stable.astype(np.int8), "max_modulus": np.array(modulus)}
    columns |= {"extended_instabilities": np.array(extended), "localized_instabilities": np.array(localized)}
    return row, columns


def _tails(state: np.ndarray, distance: int) -> tuple[float, float]:
    z = state[0] - state[1]
    N = len(z)
    offset = np.abs(np.arange(N) - N // 2)
    return float(np.max(np.abs(z[offset > distance]))), float(np.max(np.abs(z[offset > N // 4])))


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    make_flow = functools.partial(_flow, ctx.device)
    # The sequential solves (each family's sizes, each foam's couplings: every orbit seeded by the previous one) on
    # one thread per chain; every Floquet analysis, independent of the others, on ``workers`` more. All of them with
    # one BLAS thread (``_workers``), so the results do not depend on how many run at once. A failure anywhere is
    # raised at once and, like Ctrl-C, closes both pools: the solve loops stop at their next orbit, what is queued
    # is cancelled. A chain is not retried (its errors are the mathematics'); an analysis is, once, on a new Flow.
    chains = len(FAMILIES) + len(P.foam_sizes)
    with (
        blas_threads(1),
        Workers(
            P.workers, make_flow, ctx.log, name="finite-size-floquet", most=8, outcomes=(IncompleteVerdict,)
        ) as analyses,
        Workers(chains, make_flow, ctx.log, name="finite-size-chain", retry=False, shared=analyses) as solves,
    ):
        family_jobs = {f: solves.submit(f"the {f} family's solves", _family, P, f, analyses, ctx) for f in FAMILIES}
        foam_jobs = [
            solves.submit(f"the foam's solves at N = {N}", _foam_chain, P, N, analyses, ctx) for N in P.foam_sizes
        ]
        families, profiles = {}, {}
        for family, job in family_jobs.items():  # the first failure anywhere is raised at once (``Workers.result``)
            rows, profiles[family] = solves.result(job)
            families[family] = [analyses.result(row) for row in rows]
        foam = []
        for N, job in zip(P.foam_sizes, foam_jobs):
            grid, points = solves.result(job)
            foam.append(_foam(P, N, grid, [analyses.result(p) for p in points], ctx))

    root = ctx.store(ChainParams(PAPER_M, PAPER_K, P.sizes[-1]))
    for row, columns in foam:
        attrs = {"N": row["N"], "omega": PAPER_OMEGA, "note": "the site family's K-branch on a fixed grid"}
        write_table(root, f"foam_N{row['N']}", columns, dim="point", attrs=attrs)
    for family, rows in families.items():
        write_table(
            root,
            family,
            {
                "N": [r["N"] for r in rows],
                "energy": [r["energy"] for r in rows],
                "tail_amplitude": [r["tail_amplitude"] for r in rows],
                "outer_amplitude": [r["outer_amplitude"] for r in rows],
                "max_modulus": [np.nan if r["max_modulus"] is None else r["max_modulus"] for r in rows],
                "verdict_complete": np.array([r["complete"] for r in rows], dtype=np.int8),
                "extended_max_modulus": [r["extended_max_modulus"] for r in rows],
                "localized_max_modulus": [r["localized_max_modulus"] for r in rows],
                "newton_seconds": [r["newton_seconds"] for r in rows],
            },
            dim="size",
            attrs={"K": PAPER_K if family == "paper" else P.site_K, "omega": PAPER_OMEGA},
        )
        z = profiles[family][0] - profiles[family][1]
        write_table(
            root,
            f"{family}_profile",
            {"site": np.arange(len(z)), "z": z},
            dim="site",
            attrs={"N": len(z), "note": "u - v at t = 0 of the largest chain"},
        )
    summary = {"M": PAPER_M, "omega": PAPER_OMEGA, "sizes": list(P.sizes), "families": families}
    summary["floquet_solver"] = P.floquet_solver
    summary["incomplete_verdicts"] = sum(not r["complete"] for rows in families.values() for r in rows)
    summary["foam"] = {"K": list(P.foam_K), "points": P.foam_points, "sizes": [row for row, _ in foam]}
    if len(foam) >= 2:  # how the foam thins with N: the unstable fraction's and the largest modulus' slopes
        Ns = np.log([row["N"] for row, _ in foam])
        fraction = np.array([row["unstable_fraction"] for row, _ in foam])
        largest = np.array([row["largest_modulus_minus_one"] for row, _ in foam])
        summary["foam"]["unstable_fraction_slope"] = (
            float(np.polyfit(Ns, np.log(fraction), 1)[0]) if np.all(fraction > 0) else None
        )
        summary["foam"]["largest_modulus_slope"] = (
            float(np.polyfit(Ns, np.log(largest), 1)[0]) if np.all(largest > 1e-12) else None
        )
    for family, rows in families.items():
        E = np.array([r["energy"] for r in rows])
        tails = np.array([r["outer_amplitude"] for r in rows])
        Ns = np.array([r["N"] for r in rows], float)
        summary[f"{family}_energy_spread"] = float(E.max() - E.min())
        # the tail's scaling with N (None when it is at round-off: an exponentially localized breather)
        decays = bool(np.all(tails < 1e-12))
        summary[f"{family}_outer_amplitude_slope"] = (
            None if decays else float(np.polyfit(np.log(Ns), np.log(np.maximum(tails, 1e-300)), 1)[0])
        )
        summary[f"{family}_tail_at_round_off"] = decays
        summary[f"{family}_extended_law"] = extended_law(rows)
        localized = [r["localized_max_modulus"] - 1.0 for r in rows if r["complete"]]
        summary[f"{family}_localized_modulus_minus_one"] = localized[-1] if localized else None
        summary[f"{family}_localized_change_last_doubling"] = (
            abs(localized[-1] - localized[-2]) if len(localized) >= 2 else None
        )
    return summary


def extended_law(rows: list) -> dict | None:
    """The power law |l| - 1 = C N^p of the largest extended instability against N, fitted (least squares in
    log-log) over the larger half of the sizes with a complete verdict that have one (at least three: the
    asymptotic law; the small chains' resonances scatter, the paper breather's at N = 401 by a factor 8); None with
    fewer than three such sizes."""
    pts = [(r["N"], r["extended_max_modulus"] - 1.0) for r in rows if r["complete"] and r["extended_max_modulus"] > 1]
    if len(pts) < 3:
        return None
    pts = pts[-max(3, len(pts) // 2 + 1) :]
    N, excess = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    slope, intercept = np.polyfit(N, excess, 1)
    residual = float(np.max(np.abs(excess - (slope * N + intercept))))
    return {"exponent": float(slope), "prefactor": float(np.exp(intercept)), "sizes": [int(p[0]) for p in pts],
            "max_log_residual": residual}  # fmt: skip


def plot(out) -> None:
    s = read_summary(out)
    plt = pyplot()
    foam = s.get("foam", {}).get("sizes", [])
    fig = plt.figure(figsize=(18, 8.4 if foam else 4.2), layout="constrained")
    grid = fig.add_gridspec(2 if foam else 1, 4)
    axes = [fig.add_subplot(grid[0, i]) for i in range(4)]
    if foam:
        _plot_foam(out, s, fig.add_subplot(grid[1, :2]), fig.add_subplot(grid[1, 2]), fig.add_subplot(grid[1, 3]))
    colors = {"paper": "C0", "site": "C3"}
    labels = {"paper": f"paper breather (K = {PAPER_K:g})", "site": "site breather (K = {:g})"}
    for family in FAMILIES:
        t, attrs = read_group(out / "data.zarr", family)
        label = labels[family].format(attrs.get("K", 0.0))
        N, E = t["N"], t["energy"]
        axes[0].loglog(N[:-1], np.abs(E[:-1] - E[-1]), "o-", color=colors[family], label=label)
        floor = 1e-17  # a tail at round-off (0) drawn at the axis' floor
        axes[1].loglog(N, np.maximum(t["tail_amplitude"], floor), "o-", color=colors[family], label=f"{label}: tail")
        axes[1].loglog(
            N, np.maximum(t["outer_amplitude"], floor), "s--", color=colors[family], label=f"{label}: outer quarters"
        )
        _plot_instabilities(axes[2], s, family, colors[family], label)
        prof, _ = read_group(out / "data.zarr", f"{family}_profile")
        z = prof["z"]
        distance = np.abs(np.arange(len(z)) - len(z) // 2)
        right = distance[len(z) // 2 :]
        axes[3].loglog(
            right + 1, np.maximum(np.abs(z[len(z) // 2 :]), 1e-300), color=colors[family], lw=0.7, label=label
        )
    sizes = s["sizes"]
    axes[0].set(
        xlabel="N", ylabel="|E(N) - E(N_max)|", title="energy against the largest chain\n(the site breather's: 0)"
    )
    axes[1].set(xlabel="N", ylabel="max |u - v|", title="the tail: does it decay with N?\n(round-off drawn at 1e-17)")
    axes[2].set(
        xlabel="N",
        ylabel="|l| - 1",
        title="instabilities, every multiplier counted:\no localized (the breather's own), x extended, with the fit",
    )
    axes[2].legend(fontsize=6, loc="lower left")
    axes[3].set(xlabel="sites from the centre + 1", ylabel="|u - v| at t = 0", title=f"profiles at N = {sizes[-1]}")
    axes[3].set_ylim(1e-12, 1.0)
    for ax in axes[:3]:
        ax.set_xticks(sizes, [str(n) for n in sizes], rotation=45, fontsize=7)
        ax.minorticks_off()
    axes[0].legend(fontsize=7, loc="upper left")
    axes[1].legend(fontsize=7, loc="center right")
    axes[3].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"finite size: M = {s['M']:g}, w_b = {s['omega']:g}", fontsize=11)
    save_figure(fig, out, "finite_size")


def _plot_instabilities(ax, s, family, colour, label) -> None:
    """Every instability of each size (o localized, x extended), the fitted law of the largest extended one, and
    rows whose verdict is not complete as grey '?' at the axis' floor (never drawn as stable)."""
    rows = s["families"][family]
    for row in rows:
        if not row.get("complete", True):
            ax.plot(row["N"], 1e-9, marker="$?$", color="0.5", ms=9)
            continue
        for inst in row["instabilities"] or ():
            marker = "o" if inst["localized"] else "x"
            ax.loglog(row["N"], inst["modulus"] - 1.0, marker, color=colour, ms=6 if marker == "o" else 4, mfc="none")
    local = [(r["N"], r["localized_max_modulus"] - 1.0) for r in rows if r.get("complete", True)]
    local = [(n, v) for n, v in local if v > 0]
    if local:
        ax.loglog(*zip(*local), "-", color=colour, lw=0.8, label=f"{label}: localized")
    law = s.get(f"{family}_extended_law")
    if law:
        N = np.array([law["sizes"][0], law["sizes"][-1]], float)
        ax.loglog(N, law["prefactor"] * N ** law["exponent"], "--", color=colour, lw=1,
                  label=f"extended: {law['prefactor']:.2g} N^{law['exponent']:.2f}")  # fmt: skip


def _plot_foam(out, s, strips, fraction, largest) -> None:
    """The K-branch foam: where the grid's points are unstable at each N, and how the unstable fraction and the
    largest modulus scale with N."""
    import matplotlib.ticker

    rows = s["foam"]["sizes"]
    for i, row in enumerate(rows):
        t, _ = read_group(out / "data.zarr", f"foam_N{row['N']}")
        K, unstable = t["K"], t["stable"] == 0
        strips.scatter(K[~unstable], np.full((~unstable).sum(), i), s=4, color="0.75", lw=0)
        strips.scatter(K[unstable], np.full(unstable.sum(), i), s=10, color="C3", lw=0)
    strips.set_yticks(range(len(rows)), [f"N = {row['N']}" for row in rows])
    strips.set_ylim(-0.6, len(rows) - 0.4)
    lo, hi = s["foam"]["K"]
    strips.set(xlabel="K", title=f"site family, K in [{lo:g}, {hi:g}], {s['foam']['points']} points: unstable (red)")
    Ns = [row["N"] for row in rows]
    fraction.loglog(Ns, [max(row["unstable_fraction"], 1e-3) for row in rows], "o-", color="C3")
    fraction.set(xlabel="N", ylabel="unstable fraction of the grid", title="the foam's unstable fraction")
    largest.loglog(Ns, [row["largest_modulus_minus_one"] for row in rows], "o-", color="C3", label="largest")
    largest.loglog(Ns, [row["median_unstable_modulus_minus_one"] or np.nan for row in rows], "s--", color="C1",
                   label="median of the unstable points")  # fmt: skip
    largest.set(xlabel="N", ylabel="|l| - 1", title="the foam's moduli")
    largest.legend(fontsize=7, loc="lower left")
    for ax in (fraction, largest):
        ax.set_xticks(Ns, [str(n) for n in Ns])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
