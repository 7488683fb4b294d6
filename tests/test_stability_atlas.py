"""The stability-atlas scene (issue #36): one frequency branch per K as a task of a Dask sweep, run through the
CLI as a user runs it (``--quick`` on the CPU: a local cluster of one process per core), the store read back
with xarray, and a rerun of the same command that resumes (every task already completed: none runs again)."""

import json
import subprocess
import sys

import numpy as np
import pytest


def _run(*args):
    return subprocess.run([sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_quick_atlas_store_and_resume(tmp_path):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("distributed")
    command = ("run", "stability-atlas", "--quick", "--out", str(tmp_path), "--device", "cpu")
    out = _run(*command)
    assert out.returncode == 0, out.stderr[-3000:]
    folder = tmp_path / "stability-atlas"
    s = json.loads((folder / "summary.json").read_text())
    n_K = s["parameters"]["n_K"]
    assert s["sweep"]["mode"] == "dask" and s["sweep"]["ran"] == n_K and s["sweep"]["skipped"] == 0
    assert len(s["branches"]) == n_K == 6 and s["all_ended_on_physics"]

    ds = xr.open_zarr(folder / "data.zarr", group="atlas")
    assert ds["omega"].dims == ("K", "point") and ds["instabilities"].dims == ("K", "point", "kind")
    assert ds["end_reason"].dims == ("K",) and list(ds["kind"].values) == list(ds["leading_kind"].attrs["kinds"])
    K = ds["K"].values
    assert len(K) == n_K and np.allclose(np.diff(np.log(K)), np.log(K[1] / K[0]))  # log-spaced
    assert K[0] == pytest.approx(1.0) and K[-1] == pytest.approx(160.0)
    assert (ds["completed"].values == 1).all()
    points = ds["points"].values
    assert (points >= 2).all() and (points <= ds.sizes["point"]).all()
    omega, dev, tol = ds["omega"].values, ds["max_modulus_minus_1"].values, ds["tolerance"].values
    stable, counts = ds["stable"].values, ds["instabilities"].values
    for i, n in enumerate(points):
        assert np.isfinite(omega[i, :n]).all() and np.isnan(omega[i, n:]).all()  # padding: NaN
        assert (stable[i, n:] == -1).all() and set(np.unique(stable[i, :n])) <= {0, 1}
        # the stable flag and max |l| - 1 agree. The tolerance t is in mu = (l + 1/l) / 2 (stable: every mu within t
        # of [-1, 1]); a mu at distance d from it has |l| - 1 >= d, and d <= t allows |l| - 1 <= t + sqrt(2 t + t^2)
        s_ok, t = stable[i, :n] == 1, tol[i, :n]
        assert (dev[i, :n][s_ok] <= (t + np.sqrt(2 * t + t * t))[s_ok]).all()
        assert (dev[i, :n][~s_ok] > t[~s_ok]).all()
        assert (counts[i, :n][s_ok] == 0).all() and (counts[i, :n][~s_ok].sum(axis=-1) > 0).all()
        assert omega[i, 0] < 1.0166 and omega[i, n - 1] < omega[i, 0]  # from the optical edge down
    reasons = ds["end_reason"].attrs["reasons"]
    assert {reasons[r] for r in ds["end_reason"].values} <= {"contact_lost", "end_reached"}
    for row, n in zip(s["branches"], points):
        assert row["points"] + row["points_past_contact_loss"] == n and row["omega_range"][1] < 1.0166
        assert row["end"] == "contact_lost" and row["end_omega"] < row["omega_range"][0] + 0.05
    assert (folder / "stability_atlas.png").stat().st_size > 10_000
    assert (folder / "stability_atlas_summary.png").exists()

    before = {name: ds[name].values.copy() for name in ("omega", "seconds", "stable")}
    again = _run(*command)  # the same command: every K is completed, nothing is recomputed
    assert again.returncode == 0, again.stderr[-3000:]
    s2 = json.loads((folder / "summary.json").read_text())
    assert s2["sweep"]["ran"] == 0 and s2["sweep"]["skipped"] == n_K
    assert "all 6 tasks already completed" in again.stderr
    ds2 = xr.open_zarr(folder / "data.zarr", group="atlas")
    for name, values in before.items():  # the task timings too: no task ran again
        np.testing.assert_array_equal(ds2[name].values, values)
    assert s2["branches"] == [{**row} for row in s["branches"]]


def test_parameters_and_grid():
    from scenarios import stability_atlas as atlas
    from scenarios._common import scene_parameters

    P = scene_parameters(atlas, False)
    K = atlas.k_grid(P)
    assert len(K) >= 40 and K[0] == pytest.approx(1.0) and K[-1] == pytest.approx(160.0) and P.N == 201
    assert P.M == 30.0
    assert atlas.start_amplitude(P, 160.0) == pytest.approx(0.03)  # continuation-omega's start at K = 160
    assert atlas.start_amplitude(P, 1.0) < 0.003
    with pytest.raises(ValueError, match="K_min < K_max"):
        scene_parameters(atlas, False, {"K_min": "200"})
    with pytest.raises(ValueError, match="at most one of"):
        scene_parameters(atlas, False, {"workers": "2", "in_process": "true"})
    spec = atlas.sweep_spec(P)
    assert spec.task_dims == ("K",) and spec.shape("omega") == (len(K), P.max_points)
    assert "workers" not in spec.attrs["parameters"]  # how the sweep runs is not what it holds
    plan = atlas.plan(P, "cpu", 41)
    assert plan["gpus"] == 0 and plan["scheduler"] is None
    assert atlas.plan(scene_parameters(atlas, False, {"in_process": "true"}), "cpu", 41)["workers"] == 0
    assert atlas.stable_share(np.array([1.0, 0.9, 0.8]), np.array([True, True, False])) == pytest.approx(0.75)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["stability-atlas", "breakup-statistics"])
def test_the_sweep_scenes_run_on_a_scheduler_started_elsewhere(tmp_path, scene):
    """``--set scheduler=ADDRESS``: both sweep scenes hand their tasks to a running cluster (here two CPU workers
    started by the test, as a user's cluster would be), every task completes there, and the store reads."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40
    ) as cluster:
        args = ("run", scene, "--quick", "--out", str(tmp_path), "--device", "cpu")
        out = _run(*args, "--set", f"scheduler={cluster.scheduler_address}")
    assert out.returncode == 0, out.stderr[-3000:]
    assert f"scheduler {cluster.scheduler_address}" in out.stderr + out.stdout
    s = json.loads((tmp_path / scene / "summary.json").read_text())
    sweep = s["sweep"]
    assert sweep["mode"] == "dask" and sweep["skipped"] == 0 and sweep["ran"] > 0
