"""A frequency branch never steps over a stable window between two unstable points: on two small chains where
the walk's steps join strongly unstable points (max |l| - 1 of 4e-3 to 5e-2) across a stable window, the
branch finds every stability change that a dense fixed-frequency scan (Newton + Floquet on a grid) finds.

* M = 30, K = 200, N = 17: one complex quadruplet at both ends of the step; inside, it closes onto the unit
  circle and opens again (a window 1.7e-4 wide in w_b, just above the acoustic band), the same unstable set at
  both ends (``events.near_critical``).
* M = 30, K = 60, N = 27: a real pair and a quadruplet at one end, more at the other; inside, the
  quadruplet closes before the real pair opens (a window 1.1e-5 wide; ``events.changed``'s unstable set).

Both were stepped over by the rule that examined only verdict changes and weakly unstable ends."""

import numpy as np
import pytest

import continuation as ct
from continuation.branch import PseudoArclength
from continuation.driver import ContinuationSettings, continuation
from warpchain import ChainParams, Flow

SCENE = ContinuationSettings(ds=0.05, ds_max=0.6, grow=1.3, resolution=1e-3)  # continuation-omega's settings


def _scan_changes(params, flow, branch, hi, lo, step):
    """Where the verdict changes on a grid from hi down to lo, each solve seeded by the one before (the first
    by the branch point nearest hi): the grid intervals (w_low, w_high)."""
    omega = branch.column("omega")
    seed = branch.points[int(np.argmin(np.abs(omega - hi)))].state
    grid = np.arange(hi, lo - 1e-12, -step)
    stable = []
    for w in grid:
        b = ct.require(ct.find_breather(params, float(w), seed, flow=flow))
        seed = b.state
        stable.append(ct.floquet(b).stable)
    return [(grid[i + 1], grid[i]) for i in range(len(grid) - 1) if stable[i] != stable[i + 1]]


@pytest.mark.parametrize(
    "K,N,hi,lo,step",
    [(200.0, 17, 0.9999, 0.9993, 5e-6), (60.0, 27, 0.99880, 0.99856, 5e-7)],
    ids=["closes-and-reopens", "one-leaves-one-arrives"],
)
@pytest.mark.slow  # a few seconds: the fast set stays under 90 s on 2 cores
@pytest.mark.parametrize("settings", [SCENE, ContinuationSettings()], ids=["scene", "default"])
def test_the_branch_finds_every_window_of_a_dense_scan(K, N, hi, lo, step, settings):
    params, flow = ChainParams(30.0, K, N), Flow("kahan8", 32, device="cpu")
    branch = continuation(PseudoArclength(params, flow, None, omega_min=0.8), settings)
    scan = _scan_changes(params, flow, branch, hi, lo, step)
    assert len(scan) >= 2  # a window: lost and regained inside the interval
    found = [sorted(c["bracket"]) for c in branch.stability_changes() if lo < min(c["bracket"]) < hi]
    assert len(found) == len(scan), (found, scan)
    for (w_low, w_high), (b_low, b_high) in zip(sorted(scan), sorted(found)):
        assert b_low <= w_high + step and w_low - step <= b_high  # the same change, within the scan's grid
