"""The spot experiment on a surface: an impulsive Gaussian spot on a monolayer patch, does it break up into
breathers, and how does that compare with the chain and with the monolayer's energy threshold? (issue #51; beyond
the paper)

Command: ``python -m scenarios run monolayer-spot --device cpu`` (81 x 81 triangular patch, 9 spots, 100 periods:
about 2 min on a 2-core CPU; ``--quick`` about 25 s, drawings included). On a GPU: ``--device cuda --set n=201
--set periods=200`` (or ``n=512``). Options: ``--set KEY=VALUE`` (fields of ``Parameters``).

The paper closes by proposing to see breathers by "impulsively exciting a large spot on the substrate surface";
``breakup-statistics`` ran that on the chain. Here the spot is two-dimensional: every lattice starts at rest in
place with the substrate velocity u'_s = A exp(-d_s^2 / (2 W^2)) (1 + ``noise`` xi_s) (d_s: the distance of site
s from the patch's centre, in lattice spacings; xi_s standard normal, one draw for all spots, as the chain's study
seeds its modulational instability; the spheres at rest), for every amplitude A and width W of the sweep, all
lattices in one launch. The same spots run on the chain (``n`` sites, the same M, losses and observables: the
chain is the lattice ``warpchain.lattice.chain``). ``K`` is the chain's; the patch takes K / kappa, which keeps the
chain's long-wave speed (``warpchain.physical.monolayer_coupling``: both fitted to the same surface wave; the
triangular patch of the paper's K = 160 has K = 106.7). Losses are the breakup study's (``warpchain.losses``): contact
damping gamma_c on z and substrate damping gamma_s on u'.

Why it differs from the chain: near the optical bottom a wide packet obeys the focusing cubic NLS, critical in
two dimensions: a spot whose NLS norm is below the Townes value spreads out, one above it collapses; and the
monolayer's breathers have an energy threshold E* (the ``monolayer`` scene; the discrete NLS's prediction
``continuation.dnls_threshold``, within 2-72 % of the measured E* for K <= 2, is the reference here). On the chain
breathers exist at every energy. The impulse puts most of its energy E0 into acoustic waves (the substrate and
the spheres moving together), which run away at the speed of sound; what can make a breather is the optical part,
the spheres' motion relative to the substrate, with energy E_opt = sum (1/2) (M / (M + 1)) u'_s^2 = E0 / (M + 1) at
t = 0 (the reduced mass). Each spot's E_opt is stated against E*_DNLS.

Observables, once per period: the envelope e_s = max |v_s - u_s| over every step of the period and the energy are
reduced on the device (``simulate(..., observe=...)``, ``warpchain.observe``), and only the envelope and the end state
come to the host, where ``observables`` finds the rest: *peaks*, sites whose envelope
is above ``threshold``, the largest within ``radius`` lattice spacings, and falls to ``contrast`` of it at that
distance; the energy within ``radius`` of a peak (the breathers' share); the r.m.s. distance from the centre
weighted by the envelope squared (the spread of the resonators' motion: the acoustic waves the impulse also
launches carry most of the energy away at the speed of sound); the energy. Every spot runs beside its *linear
control*, the same spot times ``LINEAR`` (peaks counted above ``threshold`` times ``LINEAR``): what the control does
is dispersion alone. A spot is *self-localized* when its spread at the end is below ``LOCALIZED`` of its control's;
it has *formed breathers* when the median peak count over the last ``final_frames``
periods is >= 1 and its control's is 0; that median is its number of breathers. The envelope of one lattice
(``movie``) is stored every period: the snapshots and the animation (``monolayer-spot.gif``) are drawn from it.

Integration: Kahan-Li order 6 (kahan6) at 32 steps per period of T = 2 pi / 1.01, as the breakup study (its
accuracy check there: kahan6/32, kahan8/32 and kahan8/64 gave the same breakup probabilities); the Warp kernels of
``--device`` (the patch's neighbour table in the sites layout).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import numpy as np

import continuation as ct
from warpchain import Guard, Observation, simulate
from warpchain.lattice import BOUNDARIES, LatticeParams, chain, square, triangular
from warpchain.losses import Damping
from warpchain.physical import monolayer_coupling
from warpchain.model import contact_potential
from warpchain.store import read_group, write_fields, write_table

from ._common import PAPER_K, PAPER_M, Context, pyplot, read_summary, save_figure
from ._params import Rule, param

BUILDERS = {"square": square, "triangular": triangular}
#: the frequency that sets the period, as the chain's Fig. 9 and breakup study
OMEGA_PERIOD = 1.01
#: the side of the patch on which the discrete NLS's threshold is computed
DNLS_SITES = 41
#: the observables per period and lattice, in the store's ``series`` group
SERIES = ("peaks", "energy", "breather_energy", "spread", "max_envelope")


@dataclasses.dataclass(frozen=True)
class Parameters:
    """The scene's parameters (``--set KEY=VALUE`` overrides any of them)."""

    lattice: str = param("triangular", "the monolayer's lattice", choices=tuple(BUILDERS))
    n: int = param(81, "the patch is n x n sites (the chain: n sites)", ge=11, le=1025)
    boundary: str = param("fixed", "walls of the patch and the chain", choices=BOUNDARIES)
    M: float = param(PAPER_M, "mass ratio m1 / m2", gt=0)
    K: float = param(
        PAPER_K, "the chain's coupling k1 / k2; the patch's is K / kappa (the same long-wave speed)", gt=0, le=1000
    )
    amplitudes: tuple[float, ...] = param(
        (0.05, 0.15, 0.4), "peak substrate velocities A of the spots", gt=0, le=2, length=(1, 64)
    )
    widths: tuple[float, ...] = param((3.0, 6.0, 10.0), "Gaussian widths W of the spots, lattice spacings", gt=0)
    periods: int = param(100, "periods of T = 2 pi / 1.01 simulated", ge=2, le=5000)
    contact_damping: float = param(0.0, "gamma_c: contact damping on z (Q = w0 / gamma_c)", ge=0, le=1)
    substrate_damping: float = param(0.0, "gamma_s: substrate damping on u' (radiation into the bulk)", ge=0, le=1)
    threshold: float = param(0.1, "envelope |v - u| above which a peak counts as a breather", gt=0)
    radius: float = param(10.0, "a peak is the largest envelope within this many lattice spacings", ge=1, le=50)
    contrast: float = param(0.5, "localized: the envelope at the radius falls to this fraction of the peak", gt=0, le=1)
    final_frames: int = param(10, "periods over which the final count is a median", ge=1, le=5000)
    noise: float = param(0.02, "relative per-site perturbation of the impulse (seeds the modulational instability)",
                         ge=0, le=1)  # fmt: skip
    seed: int = param(20261128, "seed of the noise (numpy's default_rng)", ge=0, le=2**63 - 1)
    movie: int = param(
        -1, "the spot (index in amplitude-major order; -1 the last) whose envelope is stored", ge=-4096, lt=4096
    )

    RULES = (
        Rule(("widths", "n"), "widths below n / 4 (the spot fits the patch)", lambda P: max(P.widths) < P.n / 4),
        Rule(("final_frames", "periods"), "final_frames <= periods", lambda P: P.final_frames <= P.periods),
        Rule(
            ("K", "lattice", "M"),
            "K small enough for kahan6 at 32 steps per period on the patch (the step below its stability limit)",
            lambda P: _step_is_stable(P),
        ),
        Rule(
            ("movie", "amplitudes", "widths"),
            "movie an index of the sweep (-len .. len - 1, amplitude-major)",
            lambda P: -len(P.amplitudes) * len(P.widths) <= P.movie < len(P.amplitudes) * len(P.widths),
        ),
        Rule(
            ("n", "amplitudes", "widths", "periods"),
            "n^2 x spots x periods <= 2e9 site-periods (a day on a GPU)",
            lambda P: P.n**2 * len(P.amplitudes) * len(P.widths) * P.periods <= 2e9,
        ),
    )


#: the quick run: K = 16 (breathers ~4 sites wide) so that a 41 x 41 patch holds spots that do and do not localize
QUICK = {
    "n": 41,
    "K": 16.0,
    "amplitudes": (0.05, 0.4),
    "widths": (3.0,),
    "periods": 60,
    "final_frames": 5,
    "radius": 4.0,
}


def _step_is_stable(P) -> bool:
    """Whether T / 32 is below kahan6's stability limit on the patch and on the chain (the optical tops)."""
    from warpchain.integrators import stability_limit

    lattice = BUILDERS[P.lattice](3, 3)
    limit = min(
        stability_limit("kahan6", LatticeParams(P.M, monolayer_coupling(P.K, lattice), lattice)),
        stability_limit("kahan6", LatticeParams(P.M, P.K, chain(3))),
    )
    return 2.0 * math.pi / OMEGA_PERIOD / 32 < limit


def spots(lattice, P: Parameters) -> np.ndarray:
    """The initial states (spots, 4, sites): u' = A exp(-d^2 / (2 W^2)) (1 + noise xi) about the centre, xi standard
    normal (one draw for every spot), amplitude-major."""
    d = lattice.distances(lattice.centre)
    xi = np.random.default_rng(P.seed).standard_normal(lattice.n_sites)
    x0 = np.zeros((len(P.amplitudes) * len(P.widths), 4, lattice.n_sites))
    for k, (A, W) in enumerate((A, W) for A in P.amplitudes for W in P.widths):
        x0[k, 2] = A * np.exp(-0.5 * (d / W) ** 2) * (1.0 + P.noise * xi)
    return x0


def _footprints(lattice, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The disc d <= radius and its rim radius - 1 < d <= radius on the lattice's axial grid (a small patch of the
    same geometry: a new lattice needs nothing here); made once per geometry and radius (read-only)."""
    return _footprints_of(lattice.name, float(radius))


@functools.lru_cache(maxsize=8)
def _footprints_of(name: str, radius: float) -> tuple[np.ndarray, np.ndarray]:
    side = 4 * math.ceil(radius) + 1  # axial reach of a disc: 2 R / sqrt(3) on the triangular lattice, so 2 R is ample
    small = chain(side) if name == "chain" else BUILDERS[name](side, side)
    d = small.distances(small.centre).reshape(small.shape[::-1])
    disc = d <= radius + 1e-9
    # cropped to the disc's extent about the centre on each axis (odd sides, still centred)
    centre = np.array(d.shape) // 2
    reach = [int(np.max(np.abs(np.nonzero(disc.any(axis=tuple(a for a in range(disc.ndim) if a != k)))[0] - centre[k])))
             for k in range(disc.ndim)]  # fmt: skip
    crop = tuple(slice(c - h, c + h + 1) for c, h in zip(centre, reach))
    out = disc[crop], ((d > radius - 1.0 + 1e-9) & disc)[crop]
    for a in out:
        a.setflags(write=False)
    return out


@functools.lru_cache(maxsize=4)
def _centre_distance2(lattice) -> np.ndarray:
    """Squared distances from the patch's centre (the nearest image on a periodic patch), made once per lattice."""
    r2 = lattice.distances(lattice.centre) ** 2
    r2.setflags(write=False)
    return r2


def site_energies(params: LatticeParams, x: np.ndarray, sites=None) -> np.ndarray:
    """The Hamiltonian's density (batch, sites): kinetic, contact, and the bonds shared out
    (``Lattice.site_bond_energy``); it sums to ``model.energy``. ``sites``: at those sites only."""
    at = slice(None) if sites is None else np.asarray(sites, dtype=np.intp)
    u, v, pu, pv = x[:, 0, at], x[:, 1, at], x[:, 2, at], x[:, 3, at]
    return (
        0.5 * params.M * pu * pu
        + 0.5 * pv * pv
        + contact_potential(u - v)
        + params.K * params.lattice.site_bond_energy(x[:, 0], sites)
    )


def _window(field: np.ndarray, centres: np.ndarray, footprint: np.ndarray, wrap: bool):
    """The values of ``field`` (grid) over ``footprint`` (centred, odd sides) around each of ``centres`` (k, ndim):
    (k, footprint sites) values (0 outside the patch unless ``wrap``) and their flat indices (-1 outside)."""
    grid = np.array(field.shape)
    offsets = np.argwhere(footprint) - np.array(footprint.shape) // 2
    pos = centres[:, None, :] + offsets[None]
    if wrap:
        pos %= grid
        inside = np.ones(pos.shape[:2], bool)
    else:
        inside = np.all((pos >= 0) & (pos < grid), axis=-1)
        pos = np.where(inside[..., None], pos, 0)
    flat = np.ravel_multi_index(tuple(np.moveaxis(pos, -1, 0)), field.shape)
    return np.where(inside, field.ravel()[flat], 0.0), np.where(inside, flat, -1)


def _peaks(e: np.ndarray, floor: float, disc, rim, contrast: float, wrap: bool):
    """One envelope field's peaks (see the module docstring) and the sites within their discs, flat boolean masks.
    Candidates are the maxima over the largest box inside the disc above ``floor`` (a separable filter); each is then
    checked over its disc and rim (a full-disc filter over the patch cost a second per period at 201 x 201)."""
    from scipy import ndimage

    # the largest axial box inside the disc: a peak is the largest over it too (a separable filter, cheap whatever
    # the radius), which leaves few candidates even where noise puts local maxima everywhere above a low floor
    c, h = np.array(disc.shape) // 2, 0
    while h < c.min() and disc[tuple(slice(k - h - 1, k + h + 2) for k in c)].all():
        h += 1
    local = ndimage.maximum_filter(e, size=2 * h + 1, mode="wrap" if wrap else "constant", cval=0.0)
    centres = np.argwhere((e > floor) & (e >= local))
    peaks = np.zeros(e.size, bool)
    covered = np.zeros(e.size, bool)
    if len(centres):
        height = e[tuple(centres.T)]
        inside, _ = _window(e, centres, disc, wrap)
        edge, _ = _window(e, centres, rim, wrap)
        keep = (inside.max(axis=1) <= height) & (edge.max(axis=1) <= contrast * height)
        peaks[np.ravel_multi_index(tuple(centres[keep].T), e.shape)] = True
        _, flat = _window(e, centres[keep], disc, wrap)
        covered[flat[flat >= 0]] = True
    return peaks, covered


def observables(
    params: LatticeParams, envelope: np.ndarray, x: np.ndarray, energy: np.ndarray, P: Parameters, scale
) -> dict:
    """One period's observables of each lattice (see the module docstring), from its envelope (batch, sites), end
    state (batch, 4, sites) and energy (batch,: the device's); a lattice's peaks count above ``threshold`` times its
    ``scale`` (batch,). The site energies are summed only over the breathers' discs, on the lattices that have any."""
    lat = params.lattice
    grid = lat.shape[::-1]  # (ny, nx): site i + nx j
    disc, rim = _footprints(lat, P.radius)
    wrap = lat.boundary == "periodic"
    found = [
        _peaks(f.reshape(grid), P.threshold * float(c), disc, rim, P.contrast, wrap) for f, c in zip(envelope, scale)
    ]
    peaks = np.array([f[0] for f in found])
    covered = np.array([f[1] for f in found])
    breather = np.zeros(len(x))
    for b in np.flatnonzero(covered.any(axis=1)):
        breather[b] = site_energies(params, x[b : b + 1], np.flatnonzero(covered[b])).sum()
    r2 = _centre_distance2(lat)
    weight = envelope * envelope  # the resonators' (optical) part: the acoustic waves carry most of the energy away
    return {
        "peaks": peaks.sum(axis=1),
        "energy": np.asarray(energy, dtype=float),
        "breather_energy": breather,
        "spread": np.sqrt(weight @ r2 / np.maximum(weight.sum(axis=1), 1e-300)),
        "max_envelope": envelope.max(axis=1),
    }


#: a spot is *self-localized* when its spread at the end is below this fraction of its linear control's
LOCALIZED = 0.8

#: the linear control: every spot again at this fraction of its amplitude (its nonlinearity 1e-6 of the spot's)
LINEAR = 1e-3


def _run_spots(ctx: Context, params: LatticeParams, P: Parameters, label: str, movie: int | None):
    """Every spot on one lattice, and its linear control (the same spot times ``LINEAR``, peaks counted above the
    threshold times ``LINEAR``), in one batch for ``periods`` periods, a period per ``simulate`` call whose
    observation (every step's |z| reduced on the device) gives the period's envelope and energy. Returns the series
    of the spots and of the controls (name -> (periods + 1, spots)), the movie spot's envelope per period and the
    seconds spent stepping and on the host's observables."""
    x = spots(params.lattice, P)
    n_spots = len(x)
    x = np.concatenate([x, LINEAR * x])
    scale = np.repeat([1.0, LINEAR], n_spots)
    damping = None
    if P.contact_damping or P.substrate_damping:
        damping = Damping(contact=P.contact_damping, substrate=P.substrate_damping)
    period = 2.0 * math.pi / OMEGA_PERIOD
    # the device's own observables (its peak rule, participation, the spot's energy) are not the scene's; its envelope
    # and energy are: one frame per period, its peak rule at its smallest ball (a ball of 10 bonds about each of 512^2
    # sites, made on the host, took 11 s)
    watch = Observation(frame_every=32, threshold=P.threshold, radius=1, contrast=P.contrast)
    series = {k: [] for k in SERIES}
    frames = []
    start, last_log = time.perf_counter(), time.perf_counter()
    seconds = {"simulate": 0.0, "observables": 0.0}
    for p in range(P.periods):
        t0 = time.perf_counter()
        x0 = x
        run = simulate(
            params, x0, period, period / 32, method="kahan6", device=ctx.device, damping=damping, observe=watch,
            guard=Guard(chunks=1),
        )  # fmt: skip
        x, seen = run.x, run.observed
        t1 = time.perf_counter()
        if p == 0:  # frame 0: the initial state (its envelope |z|, its energy from the same reduction)
            first = observables(params, np.abs(x0[:, 1] - x0[:, 0]), x0, seen["energy"][0], P, scale)
            for k in SERIES:
                series[k].append(first[k])
            if movie is not None:
                frames.append(np.abs(x0[movie, 1] - x0[movie, 0]))
        obs = observables(params, seen.envelope, x, seen["energy"][-1], P, scale)
        seconds["simulate"] += t1 - t0
        seconds["observables"] += time.perf_counter() - t1
        for k in SERIES:
            series[k].append(obs[k])
        if movie is not None:
            frames.append(seen.envelope[movie])
        if time.perf_counter() - last_log > 20 or p == P.periods - 1:
            last_log = time.perf_counter()
            ctx.log(
                "%s: period %d / %d, peaks %s, linear controls %s (%.0f s)", label, p + 1, P.periods,
                series["peaks"][-1][:n_spots].tolist(), series["peaks"][-1][n_spots:].tolist(), last_log - start,
            )  # fmt: skip
    out = {k: np.array(v) for k, v in series.items()}
    spots_, controls = ({k: v[:, sl] for k, v in out.items()} for sl in (slice(0, n_spots), slice(n_spots, None)))
    return spots_, controls, (np.array(frames) if movie is not None else None), seconds


def _finals(series, controls, P: Parameters) -> dict:
    """Per spot at the end: breathers (the median peak count over the last ``final_frames`` periods), whether they
    formed (>= 1, and none in the linear control: a packet that only disperses slowly is not a breather), the
    energy fractions within the breathers (the spot's and its control's), the spread against the control's."""
    count = np.median(series["peaks"][-P.final_frames :], axis=0)
    linear = np.median(controls["peaks"][-P.final_frames :], axis=0)
    e, c = series["energy"], controls["energy"]
    return {
        "breathers": count,
        "linear_peaks": linear,
        "formed": ((count >= 1) & (linear == 0)).astype(np.int8),
        "breather_energy_fraction": series["breather_energy"][-1] / np.maximum(e[-1], 1e-300),
        "linear_energy_fraction": controls["breather_energy"][-1] / np.maximum(c[-1], 1e-300),
        "energy_initial": e[0],
        "optical_energy": e[0] / (P.M + 1.0),  # the spheres' relative motion: the reduced mass M / (M + 1)
        "energy_final": e[-1],
        "spread_final": series["spread"][-1],
        "spread_over_linear": series["spread"][-1] / np.maximum(controls["spread"][-1], 1e-300),
        "self_localized": (series["spread"][-1] < LOCALIZED * controls["spread"][-1]).astype(np.int8),
    }


def run(ctx: Context) -> dict:
    P: Parameters = ctx.params
    lattice = BUILDERS[P.lattice](P.n, P.n, P.boundary)
    K_patch = monolayer_coupling(P.K, lattice)  # the chain's long-wave speed (warpchain.physical)
    patch = LatticeParams(P.M, K_patch, lattice)
    line = LatticeParams(P.M, P.K, chain(P.n, P.boundary))
    n_spots = len(P.amplitudes) * len(P.widths)
    movie = P.movie % n_spots
    A = np.repeat(np.array(P.amplitudes, dtype=float), len(P.widths))
    W = np.tile(np.array(P.widths, dtype=float), len(P.amplitudes))
    # the discrete NLS's threshold on a patch of DNLS_SITES^2 of the same geometry: the minimal-norm soliton spans
    # ~2 sites (15 x 15 and 41 x 41 agree to 1e-5), and its sparse Newton on a 201 x 201 patch took minutes
    dnls = ct.dnls_threshold(BUILDERS[P.lattice](min(P.n, DNLS_SITES), min(P.n, DNLS_SITES), P.boundary), P.M, K_patch)
    ctx.log(
        "%s, M = %g, K = %.6g (the chain's %g over kappa = %g): %d spots (A x W) and their linear controls, "
        "%d periods; the discrete NLS puts the breathers' energy threshold at E* = %.4g", lattice.describe(), P.M,
        K_patch, P.K, lattice.long_wave_curvature, n_spots, P.periods, dnls["energy"],
    )  # fmt: skip
    t0 = time.perf_counter()
    flat, flat_linear, movie_frames, patch_seconds = _run_spots(ctx, patch, P, P.lattice, movie)
    t_patch = time.perf_counter() - t0
    t0 = time.perf_counter()
    line_series, line_linear, _, chain_seconds = _run_spots(ctx, line, P, "chain", None)
    t_chain = time.perf_counter() - t0
    results = {"monolayer": _finals(flat, flat_linear, P), "chain": _finals(line_series, line_linear, P)}
    root = ctx.store(None)
    times = np.arange(P.periods + 1) * 2 * math.pi / OMEGA_PERIOD
    for name, series, controls in (("monolayer", flat, flat_linear), ("chain", line_series, line_linear)):
        write_table(root, f"{name}_spots", {"A": A, "W": W, **results[name]}, dim="spot")
        fields = {**{k: series[k] for k in SERIES}, **{f"linear_{k}": controls[k] for k in SERIES}}
        write_fields(root, ctx.out / "data.zarr", f"{name}_series", times, fields, dims=("t", "spot"))
    i, j = lattice._coords.T
    write_fields(
        root, ctx.out / "data.zarr", "movie", times, {"envelope": movie_frames}, dims=("t", "site"),
        coords={"x": (("site",), lattice.positions[:, 0]), "y": (("site",), lattice.positions[:, 1]),
                "i": (("site",), i), "j": (("site",), j)},
        attrs={"A": float(A[movie]), "W": float(W[movie]), "spot": int(movie)},
    )  # fmt: skip
    m, c = results["monolayer"], results["chain"]
    for k in range(n_spots):
        ctx.log(
            "A = %g, W = %g: E_opt = %.4g (%.3g E*); %s: %g breathers (%.0f %% of the energy, linear control %.0f %%), "
            "spread / linear %.2f; chain: %g (%.0f %%, linear %.0f %%), spread / linear %.2f",
            A[k], W[k], m["optical_energy"][k], m["optical_energy"][k] / dnls["energy"], P.lattice,
            m["breathers"][k], 100 * m["breather_energy_fraction"][k], 100 * m["linear_energy_fraction"][k],
            m["spread_over_linear"][k], c["breathers"][k], 100 * c["breather_energy_fraction"][k],
            100 * c["linear_energy_fraction"][k], c["spread_over_linear"][k],
        )  # fmt: skip
    below = m["optical_energy"] < dnls["energy"]
    summary = {
        "lattice": lattice.describe(),
        "M": P.M,
        "K": P.K,
        "K_patch": K_patch,
        "dnls_threshold": dnls,
        "spots": n_spots,
        "sites": lattice.n_sites,
        "site_steps": float(2 * n_spots * lattice.n_sites * 32 * P.periods),
        "seconds": {
            "monolayer": t_patch,
            "chain": t_chain,
            "monolayer_parts": patch_seconds,
            "chain_parts": chain_seconds,
        },  # fmt: skip
        "formed": {name: int(r["formed"].sum()) for name, r in results.items()},
        "self_localized": {name: int(r["self_localized"].sum()) for name, r in results.items()},
        "below_threshold": {"spots": int(below.sum()), "formed_breathers": int(m["formed"][below].sum())},
        "movie": {"A": float(A[movie]), "W": float(W[movie])},
        "per_spot": {
            "A": A.tolist(),
            "W": W.tolist(),
            "optical_energy_over_threshold": (m["optical_energy"] / dnls["energy"]).tolist(),
            **{
                f"{name}_{key}": results[name][key].tolist()
                for name in results
                for key in ("breathers", "spread_over_linear", "self_localized", "formed")
            },
        },
    }
    ctx.log(
        "%d of %d spots formed breathers on the %s patch (%d self-localized), %d on the chain (%d); %d spots with "
        "E_opt below E*_DNLS, of which %d formed breathers (the patch with its controls: %.1f s, %.3g site-steps/s)",
        summary["formed"]["monolayer"], n_spots, P.lattice, summary["self_localized"]["monolayer"],
        summary["formed"]["chain"], summary["self_localized"]["chain"], below.sum(),
        summary["below_threshold"]["formed_breathers"], t_patch, summary["site_steps"] / t_patch,
    )  # fmt: skip
    return summary


def plot(out) -> None:
    from matplotlib.ticker import FuncFormatter

    s = read_summary(out)
    store = out / "data.zarr"
    plt = pyplot()
    E_star = s["dnls_threshold"]["energy"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), layout="constrained")
    for name, marker in (("monolayer", "o"), ("chain", "s")):
        d, _ = read_group(store, f"{name}_spots")
        widths = np.unique(d["W"])
        for w in widths:
            k = d["W"] == w
            colour = plt.cm.viridis(float(np.searchsorted(widths, w)) / max(len(widths) - 1, 1))
            face = colour if name == "monolayer" else "none"
            label = f"{'patch' if name == 'monolayer' else 'chain'}, W = {w:g}"
            x = d["optical_energy"][k] / E_star
            axes[0].plot(x, d["breathers"][k], marker, mfc=face, color=colour, label=label)
            unformed = k & (d["linear_peaks"] > 0) & (d["breathers"] > 0)  # the linear control had peaks too
            axes[0].plot(d["optical_energy"][unformed] / E_star, d["breathers"][unformed], "x", color="k", ms=9)
            axes[1].plot(x, d["spread_over_linear"][k], marker, mfc=face, color=colour, label=label)
    series, _ = read_group(store, "monolayer_series")
    spots, _ = read_group(store, "monolayer_spots")
    for k in range(len(spots["A"])):
        (line,) = axes[2].plot(series["t"], series["spread"][:, k], lw=0.9, label=f"A = {spots['A'][k]:g}, "
                               f"W = {spots['W'][k]:g}")  # fmt: skip
        axes[2].plot(series["t"], series["linear_spread"][:, k], lw=0.7, ls=":", color=line.get_color())
    for ax in axes[:2]:
        ax.axvline(1.0, color="0.4", ls="--", lw=0.8)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))  # plain text: no mathtext
        ax.set_xlabel("optical energy E_opt / E*_DNLS (dashed: the patch's threshold)")
    axes[0].set(
        ylabel="breathers at the end (median peak count)",
        title=f"{s['lattice']}, M = {s['M']:g}, K = {s['K_patch']:.4g} (chain: {s['K']:g})\n"
        "filled: the patch, open: the chain; x: the linear control has peaks too",
    )
    axes[1].axhline(1.0, color="0.4", lw=0.8)
    axes[1].set(ylabel="r.m.s. spread at the end / the linear control's", title="below 1: self-localized")
    axes[2].set(xlabel="t", ylabel="r.m.s. distance from the centre (weight: envelope²)",
                title="the patch's spread (dotted: linear controls)")  # fmt: skip
    axes[0].legend(fontsize=6, ncols=2)
    axes[2].legend(fontsize=6, ncols=2)
    save_figure(fig, out, "monolayer-spot")
    _snapshots(out, s)


#: the drawings show the sites whose envelope ever passes this fraction of the colour scale (and their surroundings)
VISIBLE = 0.05


def _movie(out):
    """The stored movie as images on the patch's grid: ``images`` (periods + 1, ny, nx), the affine map from grid
    indices (i, j) to positions (fitted to the stored x, y: exact for a Bravais patch), and ``view``, the half-side
    in sites of the square about the centre that the drawings show: the whole patch, or 1.5 times the reach of the
    sites whose envelope ever passes ``VISIBLE`` of the colour scale where that is smaller (a localized spot on a
    large patch), and ``shown``, which the titles say where it is smaller; ``scale``, the colour scale (the
    envelope's largest value after t = 0)."""
    frames, attrs = read_group(out / "data.zarr", "movie")
    i, j = frames["i"].astype(int), frames["j"].astype(int)
    nx, ny = int(i.max()) + 1, int(j.max()) + 1
    images = np.full((len(frames["t"]), ny, nx), np.nan)
    images[:, j, i] = frames["envelope"]
    grid = np.column_stack([i, j, np.ones(len(i))])
    coef = np.linalg.lstsq(grid, np.column_stack([frames["x"], frames["y"]]), rcond=None)[0]
    matrix = np.vstack([coef.T, [0.0, 0.0, 1.0]])
    env = frames["envelope"]
    scale = float(env[1:].max()) if len(env) > 1 else float(env.max())
    seen = (env > VISIBLE * scale).any(axis=0)
    reach = np.max(np.maximum(np.abs(i - (nx - 1) / 2), np.abs(j - (ny - 1) / 2))[seen], initial=0.0)
    view = min(max(nx, ny) // 2, max(int(math.ceil(1.5 * reach)), 10))
    shown = "" if 2 * view >= max(nx, ny) - 1 else f"the centre +- {view} sites shown"
    return {"t": frames["t"], "images": images, "matrix": matrix, "view": view, "scale": scale, "shown": shown}, attrs


def _draw(ax, movie, k):
    """Envelope k of the movie on the true geometry: the grid's image under the affine map (a triangular patch's
    pixels are rhombi), limited to the view about the centre."""
    from matplotlib.transforms import Affine2D

    ny, nx = movie["images"].shape[1:]
    im = ax.imshow(
        movie["images"][k], origin="lower", extent=(-0.5, nx - 0.5, -0.5, ny - 0.5), interpolation="nearest",
        transform=Affine2D(movie["matrix"]) + ax.transData, cmap="magma", vmin=0, vmax=movie["scale"],
    )  # fmt: skip
    h, c = movie["view"] + 0.5, ((nx - 1) / 2, (ny - 1) / 2)
    corners = np.array([[c[0] + a, c[1] + b, 1.0] for a in (-h, h) for b in (-h, h)]) @ movie["matrix"].T
    ax.set_xlim(corners[:, 0].min(), corners[:, 0].max())
    ax.set_ylim(corners[:, 1].min(), corners[:, 1].max())
    ax.set_aspect("equal")
    ax.set(xticks=[], yticks=[])
    return im


def _snapshots(out, s) -> None:
    movie, attrs = _movie(out)
    plt = pyplot()
    n = len(movie["t"])
    picks = sorted({0, n // 4, n // 2, (3 * n) // 4, n - 1})
    fig, axes = plt.subplots(1, len(picks), figsize=(3.6 * len(picks), 3.6), layout="constrained")
    for ax, k in zip(axes, picks):
        im = _draw(ax, movie, k)
        ax.set_title(f"t = {movie['t'][k]:.0f} ({k} periods)")
    fig.colorbar(im, ax=axes, shrink=0.8, label="envelope max |v - u| over the period")
    shown = f" ({movie['shown']})" if movie["shown"] else ""
    fig.suptitle(f"{s['lattice']}: the spot A = {attrs['A']:g}, W = {attrs['W']:g}{shown}")
    save_figure(fig, out, "monolayer-spot-snapshots")
    _animation(out, movie, attrs)


#: frames of the animation at most (the stored periods subsampled evenly)
ANIMATION_FRAMES = 100


def _animation(out, movie, attrs) -> None:
    """``monolayer-spot.gif``: the movie's envelope, period by period. The figure is drawn once; each frame restores
    its background and draws the image and the label alone (blitting: the colour bar's and axes' text is not laid
    out again), and Pillow writes the frames whole."""
    from PIL import Image

    plt = pyplot()
    n = len(movie["t"])
    picks = np.unique(np.linspace(0, n - 1, min(n, ANIMATION_FRAMES)).round().astype(int))
    fig, ax = plt.subplots(figsize=(5, 4.4), layout="constrained", dpi=80)
    im = _draw(ax, movie, 0)
    fig.colorbar(im, ax=ax, shrink=0.8, label="max |v - u| over the period")
    shown = f"\n{movie['shown']}" if movie["shown"] else ""
    # the label is the figure's, above the equal-aspect axes (an axes title moves when it is hidden for the background)
    label = fig.text(0.5, 0.98, "", ha="center", va="top")
    im.set_visible(False)
    fig.canvas.draw()
    background = fig.canvas.copy_from_bbox(fig.bbox)
    im.set_visible(True)
    frames = []
    for k in picks:
        im.set_data(movie["images"][k])
        label.set_text(f"A = {attrs['A']:g}, W = {attrs['W']:g}, t = {movie['t'][k]:.0f}{shown}")
        fig.canvas.restore_region(background)
        ax.draw_artist(im)
        fig.draw_artist(label)
        frames.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()))
    plt.close(fig)
    tmp = out / "monolayer-spot.part.gif"
    frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=100, loop=0)
    tmp.replace(out / "monolayer-spot.gif")
