"""Instability bubbles inside a step of a branch, predicted from the multipliers at its two ends.

Where two elliptic multipliers of opposite Krein signature (and the same parity) meet, they generically
leave the unit circle for a short stretch of the branch: a bubble, an instability that is absent at
both ends of a step that spans it. On a long chain the phonon multipliers crowd near +-1 and pass
each other at nearly every step, so solving inside every such step to look for bubbles is
unaffordable (at N = 201 there are ~10 passes per step of the frequency branch). This module predicts
them instead, from what the two analysed end points already hold.

**Model.** Let Mu_a and Mu_b be the reduced matrices (``continuation.floquet``) at the step's ends
(t = 0 and t = 1), restricted to one parity block. Along a smooth branch, Mu(t) = Mu_a + t (Mu_b -
Mu_a) to first order in the step. In the eigenbasis of Mu_a (right vectors R, left L = R^-1), with
D = L (Mu_b - Mu_a) R, two eigenvalues mu_i (signature +1) and mu_j (-1) that come close interact
through the 2 x 2 block (degenerate perturbation theory; the other eigenvalues are further away)

    B(t) = [[mu_i + t D_ii, t D_ij], [t D_ji, mu_j + t D_jj]],

whose eigenvalues are complex (a Krein quadruplet) where

    Delta(t) = (d0 + t d1)^2 + 4 t^2 c < 0,   d0 = mu_i - mu_j,  d1 = D_ii - D_jj,  c = D_ij D_ji.

This needs c < 0 (opposite signatures allow it; equal ones give c > 0 and the pair passes through).
With q = d1^2 + 4c > 0, Delta is smallest at t* = -d0 d1 / q, where Delta* = 4 c d0^2 / q, so

    centre t*,   Im mu at the centre = sqrt(-Delta*) / 2,   width in t = 2 |d0| sqrt(-4c) / q.

A bubble counts when t* lies inside the step and Im mu > max(the end points' Floquet tolerance, FLOOR).

**Why a floor.** The tolerance is measured (10 x the trivial multiplier's deviation, ``continuation.floquet``):
rounding, which differs from machine to machine by factors of a few. A threshold that moves with it decided
bubbles by rounding: on the paper's frequency branch one stretch of predicted bubbles (|l| - 1 = 1.2e-11 over
2e-10 in w_b) was there on one machine and not on another, and two honest runs did not compare equal. FLOOR
is a fixed 1e-10 in mu, ~7 x the paper breather's tolerance (1.5e-11): below it the prediction is
indistinguishable from rounding (the first-order model's own error is larger), and such a bubble grows by a
factor e over > 1e10 periods. A run whose tolerance is above FLOOR (a loose method) keeps its tolerance.

**Measured** on the paper chain's frequency branch (M = 30, K = 160, N = 201, kahan8, 32 steps per
period): in [1.0124, 1.0138] the model predicts every bubble that the exact eigenvalues of the
interpolated Mu(t) show and that a dense 1e-4 scan of direct solves found (at w = 1.0126, 1.0134
and 1.0136, |l| - 1 of 1.9-2.9e-4), to within a few 1e-6 in w. It costs one linear solve and one
product of size N per parity block (~10 ms per step on a 2-core CPU at N = 201), against ~0.3 s for
one branch point. It is a prediction: the driver (``continuation.driver``) solves at the centre of
every predicted bubble wider than ``ContinuationSettings.bubble_width`` and keeps only what the
solves show. On the K-branch's bubble foam near K ~ 3 (N = 201), where one step spans dozens of
passes, the model is not accurate enough to place bubbles of width 1e-5 in log10 K; there it finds
bubbles the steps miss but not all of them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .floquet import outer_modulus

#: predicted bubbles count only above this Im mu (and above the ends' tolerance): see the module docstring
FLOOR = 1e-10


@dataclasses.dataclass(frozen=True)
class Bubble:
    """A predicted instability bubble inside a step.

    Attributes:
        t: centre, as a fraction of the step from its first point (0 < t < 1).
        half_width: half its width, in the same units.
        mu: the predicted (complex) mu at the centre.
        modulus: the predicted outer |l| at the centre.
        parity: the parity block of the two multipliers (+1, -1, or 0 when unresolved).
    """

    t: float
    half_width: float
    mu: complex
    modulus: float
    parity: int


def predict(a, b, sa, sb) -> list:
    """Bubbles predicted between two analysed points.

    Args:
        a, b: the step's ends (BranchPoints, or anything with ``mu``, ``signature`` and ``tolerance``
            from their Floquet analysis).
        sa, sb: their reduced matrices and eigenvectors (``FloquetResult.spectral``), with the same
            parity blocks.

    Returns:
        list of Bubble, sorted by centre (empty when either end has no spectral data).
    """
    if sa is None or sb is None or a.signature is None or not sa.same_blocks(sb):
        return []
    tol = max(float(a.tolerance), float(b.tolerance), FLOOR)
    out = []
    offset = 0
    for k, block in enumerate(sa.blocks):
        parity, R = block.parity, block.vectors
        n = R.shape[1]
        sig = np.asarray(a.signature[offset : offset + n])
        mu = np.asarray(a.mu[offset : offset + n])
        offset += n
        ip, jm = np.flatnonzero(sig == 1), np.flatnonzero(sig == -1)
        if not (len(ip) and len(jm)):
            continue
        change = sb.block_matrix(k) - sa.block_matrix(k)
        try:
            D = np.linalg.solve(R, change @ R)
        except np.linalg.LinAlgError:  # a defective Mu_a (exactly colliding mu): no eigenbasis to expand in
            continue
        diag = np.real(np.diag(D))
        mr = np.real(mu)
        d0 = mr[ip][:, None] - mr[jm][None, :]
        d1 = diag[ip][:, None] - diag[jm][None, :]
        c = np.real(D[np.ix_(ip, jm)] * D[np.ix_(jm, ip)].T)
        q = d1 * d1 + 4.0 * c
        with np.errstate(divide="ignore", invalid="ignore"):
            centre = np.where(q > 0, -d0 * d1 / q, np.nan)
            low = np.where(q > 0, 4.0 * c * d0 * d0 / q, np.inf)
            half = np.where(q > 0, np.abs(d0) * np.sqrt(np.maximum(-4.0 * c, 0.0)) / q, 0.0)
        hit = (c < 0) & (centre > 0) & (centre < 1) & (low < -4.0 * tol * tol)
        for i, j in np.argwhere(hit):
            t = float(centre[i, j])
            m = complex(0.5 * (mr[ip[i]] + mr[jm[j]] + t * (diag[ip[i]] + diag[jm[j]])), 0.5 * np.sqrt(-low[i, j]))
            out.append(Bubble(t, float(half[i, j]), m, float(outer_modulus(np.array([m]))[0]), int(parity)))
    out.sort(key=lambda x: x.t)
    return out


def wide(bubbles, step: float, min_width: float) -> list:
    """The bubbles at least ``min_width`` wide (in the continuation coordinate) in a step of length ``step``."""
    return [x for x in bubbles if 2.0 * x.half_width * step >= min_width]


def covered_fraction(bubbles) -> float:
    """Fraction of the step inside the union of the bubbles' predicted extents [t - w/2, t + w/2]
    (clipped to the step): the share of the step the model predicts unstable."""
    spans = sorted((max(x.t - x.half_width, 0.0), min(x.t + x.half_width, 1.0)) for x in bubbles)
    total, end = 0.0, 0.0
    for lo, hi in spans:
        lo = max(lo, end)
        if hi > lo:
            total += hi - lo
            end = hi
    return float(min(total, 1.0))


def chase_fractions(bubbles, step: float, min_width: float, margin: float = 1.5) -> list:
    """Where to solve for the bubbles at least ``min_width`` wide (in the continuation coordinate) in a
    step of length ``step``: per bubble its centre, and points ``margin`` half-widths out on either
    side (never past the middle to a neighbouring bubble's centre, so that a stable gap between two
    bubbles keeps a point). Predictions of one bubble by several pairs (centres within each other's
    half-width) count once, by the strongest. Returns a list of (centre, (outer_low, outer_high))."""
    kept: list = []
    for x in sorted(wide(bubbles, step, min_width), key=lambda x: x.t):
        if kept and x.t - kept[-1].t < min(x.half_width, kept[-1].half_width):
            if x.modulus > kept[-1].modulus:
                kept[-1] = x
            continue
        kept.append(x)
    out = []
    for k, x in enumerate(kept):
        lo = max(x.t - margin * x.half_width, 0.5 * x.t)
        hi = min(x.t + margin * x.half_width, 0.5 * (1.0 + x.t))
        if k:
            lo = max(lo, 0.5 * (kept[k - 1].t + x.t))
        if k + 1 < len(kept):
            hi = min(hi, 0.5 * (x.t + kept[k + 1].t))
        out.append((x.t, (lo, hi)))
    return out
