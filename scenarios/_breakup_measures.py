"""What the breakup-statistics scene (``scenarios.breakup_statistics``) measures from its observables.

A lattice's number of breathers (the median of its peak count over the last frames), its time to breakup (the
first frame of a run of frames with two peaks or more), the 95 % Wilson score interval of a breakup probability,
the modulational-instability comparison (Gamma = w_0 a^2 / 24 against the time to breakup) and the distributions
the summary reports. Functions of arrays, no I/O: the scene's run, its checks and its figures share them.
"""

from __future__ import annotations

import numpy as np

from ._common import PAPER_M


def final_counts(peaks: np.ndarray, final_frames: int) -> np.ndarray:
    """Median peak count over the last frames: peaks (..., frame) -> (...)."""
    return np.median(peaks[..., -final_frames:], axis=-1)


def breakup_times(peaks: np.ndarray, t: np.ndarray, persist: int = 1) -> np.ndarray:
    """Time of the first frame that starts ``persist`` frames in a row with >= 2 peaks (NaN if none):
    peaks (..., frame) -> (...)."""
    broken = peaks >= 2
    run = broken.copy()
    for k in range(1, persist):
        run[..., :-k] &= broken[..., k:]
        run[..., -k:] = False
    first = np.argmax(run, axis=-1)
    return np.where(run.any(axis=-1), t[first], np.nan)


def wilson_interval(p: np.ndarray, n: int, z: float = 1.96) -> tuple[np.ndarray, np.ndarray]:
    """95 % Wilson score interval (lo, hi) of a binomial proportion p out of n trials."""
    p = np.asarray(p, dtype=float)
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return np.clip(centre - half, 0.0, 1.0), np.clip(centre + half, 0.0, 1.0)


def omega0() -> float:
    return float(np.sqrt((PAPER_M + 1.0) / PAPER_M))


def distribution(values: np.ndarray) -> dict:
    v = values[np.isfinite(values)]
    if not v.size:
        return {"count": 0}
    return {
        "count": int(v.size),
        "median": float(np.median(v)),
        "p10": float(np.percentile(v, 10)),
        "p90": float(np.percentile(v, 90)),
        "max": float(v.max()),
    }


def mi_summary(A, W, product, t_break, a_initial) -> dict:
    """Gamma * t_breakup of the lossless, wide-spot lattices that broke up, per A and overall, and the
    power law t_breakup ~ a^p fitted to them (MI: p = -2, up to the slowly varying log factor)."""
    finite = np.isfinite(product)
    if finite.sum() >= 3:
        slope = np.polyfit(np.log(a_initial[finite]), np.log(t_break[finite]), 1)[0]
    else:
        slope = None
    by_A = [float(np.median(product[i][finite[i]])) if finite[i].any() else None for i in range(len(A))]
    t_by_A = [float(np.median(t_break[i][np.isfinite(t_break[i])])) if finite[i].any() else None for i in range(len(A))]
    all_ = product[finite]
    return {
        "gamma_rule": "Gamma = w0 a^2 / 24, a = the first period's max |z| envelope",
        "gamma_t_by_A": by_A,
        "t_breakup_median_by_A": t_by_A,
        "a_initial_by_A": [float(np.median(a_initial[i])) for i in range(len(A))],
        "gamma_t_median": float(np.median(all_)) if all_.size else None,
        "gamma_t_iqr": float(np.subtract(*np.percentile(all_, [75, 25]))) if all_.size else None,
        "broken_lattices": int(all_.size),
        "t_breakup_exponent": None if slope is None else float(slope),
    }
