"""The breakup-statistics scene: end to end (quick), reproducible from its seeds, the same store through a
two-worker Dask cluster, and resumable."""

import dataclasses
import json
import os

import numpy as np
import pytest
import zarr

from scenarios._common import run_scene

TINY = {"periods": 24, "final_frames": 4, "checks": False, "fields": False}


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("breakup")
    run_scene("breakup-statistics", out, "cpu", quick=True)
    return out / "breakup-statistics"


def _arrays(path):
    group = zarr.open_group(str(path / "data.zarr"), mode="r")["observables"]
    return {name: group[name][...] for name in sorted(group.array_keys())}


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_quick_scene_end_to_end(quick):
    xr = pytest.importorskip("xarray")
    s = json.loads((quick / "summary.json").read_text())
    assert s["grid"]["lattices"] == 3 * 2 * 2 * 4
    prob = np.array(s["breakup_probability"])
    assert prob.shape == (3, 2, 2) and prob.max() > 0  # the narrow high spots do break up in 80 periods
    checks = s["checks"]
    zero = checks["zero_damping_vs_simulate"]
    assert zero["within_rounding"] and zero["max_abs_difference"] == 0.0  # on the CPU: simulate's engine, bit for bit
    dop = checks["damped_vs_dop853"]["relative_max_difference"]
    assert dop["kahan8/64"] < 1e-8 and dop["kahan8/64"] < dop["kahan8/32"] / 50  # converges to DOP853 at order 8
    assert {"max_probability_change", "within_interval"} <= set(checks["step_check"])
    assert 0 <= s["realisation_halving"]["cells_within_interval"] <= 1
    assert s["sweep"]["ran"] == 6 and s["seeds"]["seed"] == s["parameters"]["seed"]
    ds = xr.open_zarr(quick / "data.zarr", group="observables")
    assert ds["peaks"].dims == ("A", "damping", "W", "realisation", "frame")
    assert ds.sizes["frame"] == s["grid"]["periods"] + 1 and np.isfinite(ds["energy"].values).all()
    lossy = ds["energy"].values[:, 1, ..., -1] < ds["energy"].values[:, 1, ..., 0]
    assert lossy.all()  # contact damping takes energy out of every damped lattice
    for name in s["fields"].values():
        assert xr.open_zarr(quick / "data.zarr", group=name["group"])["u"].dims == ("t", "site")
    for stem in ("breakup_plane", "breakup_distributions", "breakup_time", "breakup_fields"):
        assert (quick / f"{stem}.png").stat().st_size > 10_000


def test_statistics_helpers():
    from scenarios.breakup_statistics import breakup_times, final_counts, wilson_interval

    peaks = np.array([[0, 2, 0, 2, 2, 2, 3, 2], [0, 1, 1, 1, 2, 1, 1, 1]], dtype=float)
    t = np.arange(8.0)
    assert breakup_times(peaks, t)[0] == 1.0  # the first frame with two peaks
    assert breakup_times(peaks, t, persist=3)[0] == 3.0  # the flicker at frame 1 does not count
    assert np.isnan(breakup_times(peaks, t, persist=2)[1])
    np.testing.assert_array_equal(final_counts(peaks, 3), [2.0, 1.0])
    lo, hi = wilson_interval(np.array([0.0, 0.5, 1.0]), 100)
    assert lo[0] == 0.0 and 0.03 < hi[0] < 0.04  # p = 0 out of 100: [0, 0.037]
    np.testing.assert_allclose([lo[1], hi[1]], [0.404, 0.596], atol=1e-3)
    assert hi[2] == pytest.approx(1.0) and 0.96 < lo[2] < 0.97


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_reproducible_from_the_recorded_seeds(quick):
    from scenarios.breakup_statistics import Parameters, _task

    s = json.loads((quick / "summary.json").read_text())
    config = dataclasses.asdict(Parameters(**s["parameters"]))
    again = _task({"A": 2, "damping": 0}, "cpu", config=config)
    stored = _arrays(quick)
    assert np.array_equal(again["peaks"], stored["peaks"][2, 0])
    assert np.array_equal(again["energy"], stored["energy"][2, 0])


@pytest.mark.slow
def test_dask_two_workers_give_the_in_process_store(tmp_path):
    pytest.importorskip("distributed")
    run_scene("breakup-statistics", tmp_path / "local", "cpu", quick=True, overrides=TINY)
    environment = dict(os.environ)
    run_scene("breakup-statistics", tmp_path / "dask", "cpu", quick=True, overrides={**TINY, "workers": 2})
    # the local cluster's nanny wrote its workers' settings (MALLOC_TRIM_THRESHOLD_, one BLAS thread) here too
    assert dict(os.environ) == environment
    local = _arrays(tmp_path / "local" / "breakup-statistics")
    dask = _arrays(tmp_path / "dask" / "breakup-statistics")
    assert local.keys() == dask.keys()
    for name in local:
        assert np.array_equal(local[name], dask[name], equal_nan=True), name
    s = json.loads((tmp_path / "dask" / "breakup-statistics" / "summary.json").read_text())
    assert s["sweep"]["mode"] == "dask" and s["sweep"]["workers"] == 2


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_an_interrupted_sweep_resumes(tmp_path):
    run_scene("breakup-statistics", tmp_path, "cpu", quick=True, overrides=TINY)
    out = tmp_path / "breakup-statistics"
    before = _arrays(out)
    group = zarr.open_group(str(out / "data.zarr"), mode="a")["observables"]
    group["completed"][1, 1] = 0  # as a task killed half way leaves it: region partly written, flag unset
    group["peaks"][1, 1] = np.nan
    run_scene("breakup-statistics", tmp_path, "cpu", quick=True, overrides=TINY)
    s = json.loads((out / "summary.json").read_text())
    assert s["sweep"]["ran"] == 1 and s["sweep"]["skipped"] == 5
    after = _arrays(out)
    for name in before:
        assert np.array_equal(before[name], after[name], equal_nan=True), name
    with pytest.raises(ValueError, match="new output folder"):  # another grid in the same store is refused
        run_scene("breakup-statistics", tmp_path, "cpu", quick=True, overrides={**TINY, "noise": 0.05})
