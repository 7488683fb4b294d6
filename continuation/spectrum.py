"""Floquet multipliers as data: what every path of the analysis returns (``FloquetResult``, ``Instability``), how a
path's reduced eigenvalues mu become multipliers, kinds and a verdict (``assemble``), and the measures of their
vectors (participation, central weight). The derivations are in ``continuation.floquet``'s module docstring; the paths
(dense, sliced, window) and the parity split import from here, and ``floquet`` re-exports it all.
"""

from __future__ import annotations

import dataclasses

import numpy as np


#: sites on each side of the orbit's energy centre counted in an instability's ``central_weight``
CENTRAL_SITES = 2


def _site_weights(vectors: np.ndarray, M: float) -> np.ndarray:
    """Each column's site weight M|a_u|^2 + |a_v|^2 (columns of length 2N: u then v), (N, columns)."""
    vectors = np.asarray(vectors)
    n = vectors.shape[0] // 2
    return M * np.abs(vectors[:n]) ** 2 + np.abs(vectors[n:]) ** 2


def site_measures(vectors: np.ndarray, M: float, centre: float, windows=()) -> tuple:
    """(participation, central weight, *the weight's share on each mask of ``windows``) of each column, from one site
    weight (``participation`` and ``central_weight``, the same bits; the central weight NaN where ``centre`` is not
    finite): the Floquet paths' measures of their vectors."""
    w = _site_weights(vectors, M)
    total = np.sum(w, axis=0)
    pr = total**2 / np.maximum(np.sum(w * w, axis=0), 1e-300)

    def share(near):
        return np.sum(w[near], axis=0) / np.maximum(total, 1e-300)

    central = share(central_sites(w.shape[0], centre)) if np.isfinite(centre) else np.full(w.shape[1], np.nan)
    return (pr, central, *(share(near) for near in windows))


def participation(vectors: np.ndarray, M: float) -> np.ndarray:
    """Participation ratio in sites of each column (2N: u then v), site weight M|a_u|^2 + |a_v|^2."""
    w = _site_weights(vectors, M)
    return np.sum(w, axis=0) ** 2 / np.maximum(np.sum(w * w, axis=0), 1e-300)


def central_sites(n: int, centre: float, sites: int = CENTRAL_SITES) -> np.ndarray:
    """The sites (a boolean mask of n) whose index lies within ``sites`` of ``centre``: ``central_weight``'s window."""
    return np.abs(np.arange(n) - centre) <= sites + 0.5


def central_weight(vectors: np.ndarray, M: float, centre: float, sites: int = CENTRAL_SITES) -> np.ndarray:
    """Fraction of each column's site weight (M|a_u|^2 + |a_v|^2; columns of length 2N) on the sites
    within ``sites`` of ``centre``."""
    w = _site_weights(vectors, M)
    return np.sum(w[central_sites(w.shape[0], centre, sites)], axis=0) / np.maximum(np.sum(w, axis=0), 1e-300)


def energy_centre(state) -> float:
    """Centre of a profile, sum j z_j^2 / sum z_j^2 with z = u - v at t = 0 (0-based sites): the centre
    site c for a site-centred breather, c + 1/2 for a bond-centred one on (c, c + 1)."""
    z = np.asarray(state)[0] - np.asarray(state)[1]
    w = z * z
    return float(np.sum(np.arange(len(z)) * w) / max(float(np.sum(w)), 1e-300))


KINDS = ("real_pair", "period_doubling", "complex_quadruplet")


#: a mode counts as localized when the participation ratio of its Floquet vector (in sites, with
#: site weight M |a_u|^2 + |a_v|^2) is below this fraction of N
LOCALIZED_FRACTION = 0.1


@dataclasses.dataclass(frozen=True)
class Instability:
    """One unstable multiplier pair (or quadruplet).

    Attributes:
        kind: ``real_pair``, ``period_doubling`` or ``complex_quadruplet``.
        mu: (l + 1/l) / 2 (complex).
        modulus: |l| >= 1 of the outer multiplier.
        participation: participation ratio of its Floquet vector in sites (NaN on the full path).
        localized: participation < LOCALIZED_FRACTION * N.
        parity: +1 even, -1 odd, 0 unknown.
        central_weight: fraction of the Floquet vector's site weight on the CENTRAL_SITES sites on
            either side of the orbit's energy centre (NaN on the full path or without the orbit).
    """

    kind: str
    mu: complex
    modulus: float
    participation: float
    localized: bool
    parity: int
    central_weight: float = float("nan")

    def as_dict(self) -> dict:
        return {
            "kind": self.kind,
            "mu_real": float(self.mu.real),
            "mu_imag": float(self.mu.imag),
            "modulus": self.modulus,
            "participation": self.participation,
            "localized": self.localized,
            "parity": self.parity,
            "central_weight": self.central_weight,
        }


@dataclasses.dataclass(frozen=True)
class FloquetResult:
    """Multipliers of a periodic orbit, their kinds and the stability verdict.

    Attributes:
        multipliers: all 4N multipliers, complex, shape (4N,).
        trivial: indices (into ``multipliers``) of the trivial pair at +1.
        max_modulus: largest |l| excluding the trivial pair; NaN when ``complete`` is False (what was found:
            ``partial_max_modulus``).
        tolerance: the verdict's tolerance (in mu on the reduced paths, in |l| - 1 on the full path).
        stable: the verdict, only where every multiplier was accounted for (``complete``): True when no
            nontrivial multiplier is off the unit circle by more than the tolerance, False otherwise; None (not
            decided) on a partial analysis, whatever it found (``partial_stable``).
        instabilities: the unstable pairs/quadruplets, largest modulus first.
        mu: (l + 1/l)/2 of each pair, shape (2N,) (reduced path; None on the full path).
        mu_trivial: index of the trivial mu.
        signature: Krein signature of each mu (+1/-1 for elliptic ones, 0 otherwise), shape (2N,).
        parity: parity of each mu's Floquet vector (+1, -1, 0), shape (2N,).
        participation: participation ratio (sites) of each mu's Floquet vector, shape (2N,).
        central_weight: fraction of each mu's Floquet vector on the orbit's central sites, shape (2N,).
        vectors: the position part of each mu's Floquet vector (eigenvectors of Mu), shape (2N, 2N)
            (reduced path; None on the full path).
        spectral: Mu and its eigenvectors per parity block (reduced path), for predicting what happens
            between two analysed orbits (``continuation.bubbles``).
        accuracy: the measured gauges (``trivial_deviation``, ``symplecticity`` or ``pairing_error``; the
            probe's ``probe_halfwidth`` on the sliced and window paths).
        path: ``"reduced"`` (dense), ``"full"``, ``"sliced"`` (every multiplier from the probed Mu by slices,
            counted: ``continuation.slicing``), ``"probed"`` (the probed Mu by a dense eig per block, counted) or
            ``"window"`` (the multipliers near +1 and -1 only: every array above then
            holds that subset).
        coverage: what the sliced and window paths searched: the segments or mu intervals swept, the half-height
            of the strip around the real axis they cover, the shifts, and on the sliced path the count per
            parity block (``counts``: P's inertia against what was found) and whether it closed; None on the dense
            paths.
        complete: every multiplier accounted for (dense paths; the sliced and probed paths when their count
            closed).
        partial_stable: on a partial analysis (``complete`` False), whether the multipliers it found hold no
            instability (a window: "none near +-1"); None on a complete one.
        partial_max_modulus: on a partial analysis, the largest |l| among those found; NaN on a complete one.
        pairing_error, symplecticity_error: kept for the full path's reports (0 / gauge on the reduced).
        monodromy: V (4N x 4N) when kept (full path).
        wall_seconds: time for the tangent columns and the eigenvalues.
        stats: counters (``tangent_columns``).
    """

    multipliers: np.ndarray
    trivial: np.ndarray
    max_modulus: float
    tolerance: float
    stable: bool | None
    instabilities: tuple
    mu: np.ndarray | None
    mu_trivial: int | None
    signature: np.ndarray | None
    parity: np.ndarray | None
    participation: np.ndarray | None
    accuracy: dict
    path: str
    pairing_error: float
    symplecticity_error: float
    monodromy: np.ndarray | None
    wall_seconds: float
    stats: dict = dataclasses.field(default_factory=dict)
    central_weight: np.ndarray | None = None
    vectors: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    spectral: "SpectralData | None" = dataclasses.field(default=None, repr=False, compare=False)
    coverage: dict | None = None
    complete: bool = True
    partial_stable: bool | None = None
    partial_max_modulus: float = float("nan")

    @property
    def verdict(self) -> str:
        """``"stable"``, ``"unstable"`` or ``"not decided"`` (a partial analysis), for log lines and summaries."""
        return VERDICTS[self.stable]

    @property
    def nontrivial(self) -> np.ndarray:
        mask = np.ones(len(self.multipliers), bool)
        mask[self.trivial] = False
        return self.multipliers[mask]

    @property
    def unstable_counts(self) -> dict:
        """Number of unstable pairs of each kind (quadruplets counted once)."""
        return {k: sum(1 for i in self.instabilities if i.kind == k) for k in KINDS}

    @property
    def kinds(self) -> tuple:
        return tuple(k for k in KINDS if self.unstable_counts[k])


@dataclasses.dataclass(frozen=True)
class SpectralData:
    """The reduced matrix of an orbit and its eigenvectors, per parity block.

    Attributes:
        blocks: ``ParityBlock``s in the order of the result's ``mu``: the even (+1) and the odd (-1) block
            of a mirror-symmetric orbit (on a patch that keeps a mirror too, two of each: ``parity_blocks``),
            or a single block of parity 0 and basis None (the whole Mu) when the orbit is not mirror-symmetric.
    """

    blocks: tuple = dataclasses.field(repr=False)

    @property
    def parities(self) -> tuple:
        return tuple(b.parity for b in self.blocks)

    def same_blocks(self, other: "SpectralData") -> bool:
        """Whether ``other`` has the same blocks in the same bases (a patch's four blocks of two different mirrors
        have the same parities)."""
        if self.parities != other.parities:
            return False
        for a, b in zip(self.blocks, other.blocks):
            if (a.basis is None) != (b.basis is None):
                return False
            if a.basis is not None and not all(np.array_equal(x, y) for x, y in zip(a.basis, b.basis)):
                return False
        return True

    def block_matrix(self, k: int) -> np.ndarray:
        """Block k of Mu in block k's basis."""
        return self.blocks[k].Mu


def pairing_error(multipliers: np.ndarray) -> float:
    """max_i min_j |l_i - 1/l_j| of a spectrum (0 for an exactly symplectic one)."""
    lam = np.asarray(multipliers)
    inv = 1.0 / lam
    return float(np.max(np.min(np.abs(lam[:, None] - inv[None, :]), axis=1)))


def _masses(M: float, N: int) -> np.ndarray:
    return np.concatenate([np.full(N, float(M)), np.ones(N)])


def symplecticity_error(V: np.ndarray, M: float) -> float:
    """max |W^T J W - J| / max(max|W|^2, 1) of a map V (4N x 4N, on (q, q')) in (q, p) coordinates."""
    n2 = V.shape[0] // 2
    scale = np.concatenate([np.ones(n2), _masses(M, n2 // 2)])
    W = scale[:, None] * V / scale[None, :]
    Jmat = np.block([[np.zeros((n2, n2)), np.eye(n2)], [-np.eye(n2), np.zeros((n2, n2))]])
    return float(np.max(np.abs(W.T @ Jmat @ W - Jmat)) / max(np.max(np.abs(W)) ** 2, 1.0))


def half_map_symplecticity(A: np.ndarray, M: float) -> float:
    """max |W^T J W - J| (absolute) of the half-period map A in (q, p) coordinates."""
    n2 = A.shape[0] // 2
    m = _masses(M, n2 // 2)
    W11, W12, W21, W22 = (
        A[:n2, :n2],
        A[:n2, n2:] / m[None, :],
        m[:, None] * A[n2:, :n2],
        m[:, None] * A[n2:, n2:] / m[None, :],
    )
    # W^T J W - J with J = [[0, I], [-I, 0]]: blocks S11 = W11^T W21 - W21^T W11, S12 = W11^T W22 - W21^T W12 - I,
    # S22 = W12^T W22 - W22^T W12
    S11 = W11.T @ W21 - W21.T @ W11
    S12 = W11.T @ W22 - W21.T @ W12 - np.eye(n2)
    S22 = W12.T @ W22 - W22.T @ W12
    return float(max(np.max(np.abs(S11)), np.max(np.abs(S12)), np.max(np.abs(S22))))


def reduced_matrix(A: np.ndarray, M: float) -> np.ndarray:
    """Mu = Mm^-1 (A22^T Mm A11 + A12^T Mm A21) from the half-period map A (4N x 4N, on (q, q'))."""
    n2 = A.shape[0] // 2
    m = _masses(M, n2 // 2)
    A11, A12, A21, A22 = A[:n2, :n2], A[:n2, n2:], A[n2:, :n2], A[n2:, n2:]
    return ((A22.T * m) @ A11 + (A12.T * m) @ A21) / m[:, None]


def reduced_products(A: np.ndarray, M: float) -> tuple:
    """Mu, the symplecticity gauge and P = A11^T Mm A21 from four products of size 2N instead of ten.

    In (q, p) coordinates W11 = A11, W12 = A12 Mm^-1, W21 = Mm A21, W22 = Mm A22 Mm^-1, so with
    X = W22^T W11 and Y = W12^T W21: Mu = X + Y, and the blocks of W^T J W - J are
    S12 = (X - Y)^T - I, S11 = P - P^T with P = W11^T W21, S22 = Q - Q^T with Q = W12^T W22. P also
    gives the Krein signature: (A11 a)^T Mm (A21 a) = a^T P a. Same values as ``reduced_matrix`` and
    ``half_map_symplecticity`` (up to round-off in the order of the sums).

    Returns:
        (Mu (2N, 2N), symplecticity (float), P (2N, 2N)).
    """
    n2 = A.shape[0] // 2
    return _products(A[:n2, :n2], A[:n2, n2:], A[n2:, :n2], A[n2:, n2:], _masses(M, n2 // 2))


def _products(A11, A12, A21, A22, m) -> tuple:
    """``reduced_products`` on the four blocks of A (n x n each) with the diagonal mass matrix m (n,)."""
    n = A11.shape[0]
    C = A12.T * m
    X = (A22.T * m) @ A11  # Mm X
    Y = C @ A21  # Mm Y
    P = (A11.T * m) @ A21
    Z = C @ A22  # Mm Q Mm
    Mu = (X + Y) / m[:, None]
    S12 = (X - Y) / m[:, None]
    S12[np.diag_indices(n)] -= 1.0
    S22 = (Z - Z.T) / m[:, None] / m[None, :]
    sympl = max(float(np.max(np.abs(S12))), float(np.max(np.abs(P - P.T))), float(np.max(np.abs(S22))))
    return Mu, sympl, P


def multipliers_from_mu(mu: np.ndarray) -> np.ndarray:
    """The pair (l, 1/l) of each mu, |l| >= 1 first: shape (2 * len(mu),)."""
    mu = np.asarray(mu, dtype=complex)
    root = np.sqrt(mu * mu - 1.0)
    lam = mu + root
    lam = np.where(np.abs(lam) < 1.0, mu - root, lam)
    return np.concatenate([lam, 1.0 / lam])


def outer_modulus(mu) -> np.ndarray:
    """|l| >= 1 of the outer multiplier of each mu."""
    mu = np.asarray(mu, dtype=complex)
    root = np.sqrt(mu * mu - 1.0)
    return np.maximum(np.abs(mu + root), np.abs(mu - root))


def mu_kind(mu: np.ndarray, tol: float) -> np.ndarray:
    """Kind of each mu: ``elliptic`` within tol of [-1, 1], else the instability kind."""
    mu = np.asarray(mu, dtype=complex)
    out = np.full(mu.shape, "elliptic", dtype=object)
    out[mu.real > 1.0 + tol] = "real_pair"
    out[mu.real < -1.0 - tol] = "period_doubling"
    out[np.abs(mu.imag) > tol] = "complex_quadruplet"
    return out


def assemble(
    mu,
    parity,
    act,
    pr,
    weight,
    N,
    accuracy,
    tolerance,
    *,
    path,
    vectors=None,
    spectral=None,
    coverage=None,
    complete=True,
    wall_seconds,
    stats,
) -> FloquetResult:
    """The reduced paths' result from the mu of Mu with their parities, Krein forms a^T P a, participations and
    central weights (and, where kept, their eigenvectors: position parts, columns): the trivial mu, the tolerance,
    kinds, signatures and the instabilities, and the verdict where ``complete``. ``mu`` may be a subset of the 2N
    (a window: ``coverage`` says which)."""
    sympl = accuracy["symplecticity"]
    trivial = int(np.argmin(np.abs(mu - 1.0)))
    accuracy = {"trivial_deviation": float(abs(mu[trivial] - 1.0)), **accuracy}
    tol = 10.0 * max(accuracy["trivial_deviation"], sympl, 1e-13) if tolerance is None else float(tolerance)
    if tol < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance!r}")
    kinds = mu_kind(mu, tol)
    # Krein signature of elliptic mu: -sign((A11 a)^T Mm (A21 a)) = -sign(a^T P a) (real eigenvectors for real mu)
    signature = np.where(kinds == "elliptic", -np.sign(act), 0).astype(int)
    signature[trivial] = 0
    modulus = outer_modulus(mu)
    mask = np.ones(len(mu), bool)
    mask[trivial] = False
    instabilities = []
    for i in np.flatnonzero(mask & (kinds != "elliptic")):
        if kinds[i] == "complex_quadruplet" and mu[i].imag < 0:
            continue  # the conjugate mu belongs to the same quadruplet
        instabilities.append(
            Instability(
                kind=str(kinds[i]),
                mu=complex(mu[i]),
                modulus=float(modulus[i]),
                participation=float(pr[i]),
                localized=bool(pr[i] < LOCALIZED_FRACTION * N),
                parity=int(parity[i]),
                central_weight=float(weight[i]),
            )
        )
    instabilities.sort(key=lambda s: -s.modulus)
    lam = multipliers_from_mu(mu)
    largest = float(np.max(modulus[mask])) if mask.any() else 1.0
    return FloquetResult(
        multipliers=lam,
        trivial=np.array([trivial, trivial + len(mu)]),
        max_modulus=largest if complete else float("nan"),
        tolerance=tol,
        stable=not instabilities if complete else None,
        instabilities=tuple(instabilities),
        mu=mu,
        mu_trivial=trivial,
        signature=signature,
        parity=parity,
        participation=pr,
        central_weight=weight,
        vectors=vectors,
        spectral=spectral,
        coverage=coverage,
        complete=bool(complete),
        partial_stable=None if complete else not instabilities,
        partial_max_modulus=float("nan") if complete else largest,
        accuracy=accuracy,
        path=path,
        pairing_error=0.0,
        symplecticity_error=sympl,
        monodromy=None,
        wall_seconds=wall_seconds,
        stats=dict(stats or {}),
    )


#: a verdict in words (None: not decided, a partial analysis or none), for log lines, summaries and figures
VERDICTS = {True: "stable", False: "unstable", None: "not decided"}
