import numpy as np
import pytest

import continuation as ct
from continuation.branch import (BranchStore, continue_in_coupling, continue_in_frequency, load_branch,
                                 start_from_eigenmode)
from warpchain import ChainParams, lowest_optical_mode


@pytest.fixture(scope="module")
def k_branch(tmp_path_factory):
    path = tmp_path_factory.mktemp("k") / "branch.zarr"
    p = ChainParams(30.0, 0.01, 41)
    store = BranchStore(path, "branch", p, {"omega": 1.01}, max_newton=24)
    branch = continue_in_coupling(p, 1.01, ct.anticontinuum_seed(p, 1.01), 20.0, targets=(5.0,), step=0.5,
                                  max_step=0.8, bisection_steps=1, store=store)
    return path, branch


def test_k_branch_lands_on_targets_with_multipliers_everywhere(k_branch):
    _, branch = k_branch
    K = branch.column("K")
    assert branch.stop_reason == "reached_end"
    assert K[0] == 0.01 and K[-1] == 20.0 and 5.0 in K
    assert np.all(np.diff(K) > 0)
    assert np.all(np.diff(branch.column("energy")) > 0)  # energy grows with the coupling (paper Fig. 6)
    for p in branch.points:
        assert p.multipliers.shape == (4 * 41,) and np.isfinite(p.max_modulus) and p.pairing_error < 1e-8
        assert p.residual_history[-1] <= 1e-10 and p.min_contact > 0


def test_stored_branch_round_trips_and_resumes(k_branch, tmp_path):
    path, branch = k_branch
    params, points, attrs = load_branch(path, "branch")
    assert attrs["complete"] is True and attrs["stop_reason"] == "reached_end"
    assert len(points) == len(branch.points)
    for a, b in zip(points, branch.points):
        assert a.K == b.K and np.array_equal(a.state, b.state) and np.allclose(a.multipliers, b.multipliers)
        assert a.residual_history == pytest.approx(b.residual_history)
    # resume from the points up to K = 5 and finish the branch again: same end point
    upto = [p for p in points if p.K <= 5.0]
    resumed = continue_in_coupling(params.replace(K=upto[-1].K), 1.01, upto[-1].state, 20.0, step=0.5,
                                   max_step=0.8, bisection_steps=0, resume=upto)
    assert resumed.points[-1].K == 20.0
    assert resumed.points[-1].energy == pytest.approx(branch.points[-1].energy, rel=1e-8)


def test_loss_of_contact_stops_the_branch_and_says_so():
    p = ChainParams(30.0, 1.0, 41)
    branch = continue_in_coupling(p, 0.985, ct.nls_seed(p, 0.985), 40.0, max_newton=6, min_step=0.02,
                                  bisection_steps=0)
    assert branch.stop_reason == "contact_lost"
    assert "lost contact" in branch.message and branch.points[-1].min_contact <= 0 < branch.points[-2].min_contact


def test_newton_failure_in_the_acoustic_band_is_the_stop_reason():
    p = ChainParams(30.0, 40.0, 41)
    branch = continue_in_coupling(p, 0.99, ct.nls_seed(p, 0.99), 80.0, max_newton=6)
    assert branch.stop_reason == "start_failed" and "acoustic band" in branch.message and not branch.points


def test_frequency_branch_from_the_eigenmode(tmp_path):
    p = ChainParams(30.0, 160.0, 41)
    start = start_from_eigenmode(p)
    w_lin = lowest_optical_mode(p)[0]
    assert w_lin - 1e-3 < start[1][1] < start[0][1] < w_lin
    store = BranchStore(tmp_path / "w.zarr", "branch", p, {"K": 160.0}, max_newton=40)
    branch = continue_in_frequency(p, start, max_points=7, bisection_steps=0, store=store)
    w = branch.column("omega")
    E = branch.column("energy")
    assert branch.stop_reason == "max_points" and len(branch.points) == 7
    assert np.all(np.diff(w) < 0) and np.all(np.diff(E) > 0)  # into the gap, growing energy
    assert w[-1] < w_lin
    # every point is a breather at its own frequency: fixed-frequency Newton agrees
    last = branch.points[-1]
    check = ct.find_breather(p, last.omega, last.state)
    assert check.success and check.iterations <= 1
    _, stored, attrs = load_branch(tmp_path / "w.zarr", "branch")
    assert len(stored) == 7 and attrs["stop_reason"] == "max_points"
    budget = continue_in_frequency(p, start, max_seconds=0.0, bisection_steps=0)
    assert budget.stop_reason == "time_budget" and "stopped after" in budget.message
