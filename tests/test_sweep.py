"""The sweep runner (sweep/runner.py): in-process and Dask paths write the same bytes, resume after
a failure or a half-written task, and refuse to mix grids."""

import dataclasses
import functools
import os
import subprocess
import sys

import numpy as np
import pytest
import zarr

from sweep_demo import _demo_spec, _demo_task, _demo_task_dying, _demo_warm_up
from sweep import (
    COMPLETED,
    SweepMismatchError,
    SweepTaskError,
    Variable,
    completed,
    open_sweep,
    run_sweep,
)
from warpchain.store import open_store

GROUP = "observables"


def _arrays(path, group=GROUP) -> dict:
    g = zarr.open_group(str(path), mode="r", use_consolidated=False)[group]
    return {name: np.asarray(arr[...]) for name, arr in g.arrays()}


def assert_same_store(a, b, group=GROUP):
    """Array by array, bitwise (dtype, shape and bytes)."""
    left, right = _arrays(a, group), _arrays(b, group)
    assert sorted(left) == sorted(right)
    for name in left:
        assert left[name].dtype == right[name].dtype, name
        assert left[name].shape == right[name].shape, name
        assert left[name].tobytes() == right[name].tobytes(), name


@pytest.fixture(scope="module")
def clean_store(tmp_path_factory):
    """The reference: the demo grid run in-process."""
    path = tmp_path_factory.mktemp("clean") / "data.zarr"
    report = run_sweep(path, _demo_spec(), _demo_task, progress=False)
    assert report.ran == 6 and report.skipped == 0
    return path


def test_in_process_sweep(tmp_path):
    xr = pytest.importorskip("xarray")
    path = tmp_path / "data.zarr"
    root = open_store(path, params={"N": 31}, provenance_info={"who": "test"})  # a scene's root attrs
    root.require_group("other").attrs["keep"] = 1
    spec = _demo_spec()
    lines = []
    report = run_sweep(path, spec, _demo_task, progress=False, log=lines.append)

    assert (report.tasks, report.skipped, report.ran, report.workers, report.mode) == (6, 0, 6, 0, "in-process")
    assert len(report.task_seconds) == 6 and all(s >= 0 for s in report.task_seconds)
    assert report.task_indices == [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)]
    assert report.wall_seconds >= 0 and report.failed == []
    assert "in-process" in lines[0] and "6 of 6 tasks to run" in lines[0] and "wall" in lines[-1]
    assert completed(path, spec).all() and completed(path, spec).shape == (3, 2)

    root = zarr.open_group(str(path), mode="r", use_consolidated=False)
    assert root.attrs["params"] == {"N": 31} and root.attrs["provenance"] == {"who": "test"}
    assert root["other"].attrs["keep"] == 1
    g = root[GROUP]
    assert g["x"].chunks == (1, 1, 4, 5) and g["n"].chunks == (1, 1, 4) and g[COMPLETED].chunks == (1, 1)
    assert g.attrs["task_dims"] == ["a", "b"] and g.attrs["seed"] == 12345
    assert g["x"].attrs["long_name"] == "demo field"

    ds = xr.open_zarr(path, group=GROUP)
    assert dict(ds.sizes) == {"a": 3, "b": 2, "r": 4, "f": 5, "sweep_variable": 4}
    assert ds["x"].dims == ("a", "b", "r", "f") and ds["y"].dims == ("a", "b") and ds["n"].dims == ("a", "b", "r")
    for dim, values in spec.coords.items():
        np.testing.assert_array_equal(ds[dim].values, values)
    assert ds["n"].dtype == np.int32 and ds[COMPLETED].dtype == np.int8
    assert (ds[COMPLETED].values == 1).all() and (ds["dev"].values == -1).all()
    # every region holds what the task gives for that index, seeded from the index alone
    for a in range(3):
        for b in range(2):
            want = _demo_task({"a": a, "b": b}, "cpu")
            np.testing.assert_array_equal(ds["x"].values[a, b], want["x"])
            np.testing.assert_array_equal(ds["n"].values[a, b], want["n"])
            assert ds["y"].values[a, b] == want["y"]
    assert len({ds["x"].values[a, b].tobytes() for a in range(3) for b in range(2)}) == 6

    again = run_sweep(path, spec, _demo_task, progress=False)  # nothing left to do
    assert (again.skipped, again.ran, again.task_seconds) == (6, 0, [])


@pytest.mark.parametrize("processes", [True, False])
def test_two_workers_equal_in_process(tmp_path, clean_store, processes):
    """Two local workers, as processes or as threads of this process (``processes=False``, the GPU scenes' choice):
    the in-process store, each worker warmed up before its tasks."""
    pytest.importorskip("distributed")
    path = tmp_path / "data.zarr"
    lines = []
    report = run_sweep(
        path,
        _demo_spec(),
        functools.partial(_demo_task, n_f=5),
        workers=2,
        progress=False,
        log=lines.append,
        warm_up=functools.partial(_demo_warm_up, folder=str(tmp_path / "warm")),
        processes=processes,
    )
    assert (report.mode, report.workers, report.ran, report.skipped) == ("dask", 2, 6, 0)
    warmed = sorted(p.read_text() for p in (tmp_path / "warm").iterdir())  # one file per process
    assert warmed == ["cpu 32.0 MiB"] * (2 if processes else 1)
    assert (tmp_path / "warm" / str(os.getpid())).exists() != processes  # threads: warmed in this process
    assert sorted(report.task_indices) == report.task_indices and len(report.task_seconds) == 6
    assert "dask (local cluster, 2 workers on cpu)" in lines[0]
    assert_same_store(clean_store, path)


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=50
    ) as cl:
        yield cl


def test_external_scheduler_gpus_and_failure(tmp_path, cluster, clean_store):
    """scheduler=ADDRESS: devices by worker ordinal; a failing task names its index, the rerun finishes."""
    path = tmp_path / "data.zarr"
    with pytest.raises(SweepTaskError, match=r"a=2, b=0.*demo failure") as err:
        run_sweep(
            path,
            _demo_spec(),
            functools.partial(_demo_task, fail_at=(2, 0)),
            scheduler=cluster.scheduler_address,
            gpus=2,
            progress=False,
        )
    assert err.value.failed == ((2, 0),)
    assert not completed(path, _demo_spec())[2, 0]
    report = run_sweep(path, _demo_spec(), _demo_task, scheduler=cluster.scheduler_address, gpus=2, progress=False)
    assert report.ran + report.skipped == 6 and report.ran >= 1 and (2, 0) in report.task_indices
    dev = _arrays(path)["dev"]
    assert set(np.unique(dev)) <= {0, 1}  # cuda:0 / cuda:1 by worker ordinal
    got, want = _arrays(path), _arrays(clean_store)
    for name in ("x", "n", "y", COMPLETED):
        assert got[name].tobytes() == want[name].tobytes(), name


def test_resume_after_failure(tmp_path, clean_store):
    path = tmp_path / "data.zarr"
    spec = _demo_spec()
    with pytest.raises(SweepTaskError, match=r"task \(a=1, b=1\) failed.*demo failure") as err:
        run_sweep(path, spec, functools.partial(_demo_task, fail_at=(1, 1)), progress=False, tasks_per_worker=1)
    assert err.value.failed == ((1, 1),)
    done = completed(path, spec)
    np.testing.assert_array_equal(done, [[True, True], [True, False], [False, False]])
    stored = _arrays(path)  # tasks not run read as fill values
    assert np.isnan(stored["x"][1, 1]).all() and np.isnan(stored["x"][2]).all() and np.isnan(stored["y"][2]).all()
    assert (stored["n"][1, 1] == -1).all() and (stored["n"][2] == -1).all() and not np.isnan(stored["x"][1, 0]).any()

    # a half-written task (data written, flag not yet set) is redone, not trusted
    g = zarr.open_group(str(path), mode="r+", use_consolidated=False)[GROUP]
    g["x"][2, 0] = np.full((4, 5), 7.0)
    assert not completed(path, spec)[2, 0]

    report = run_sweep(path, spec, _demo_task, progress=False)
    assert (report.skipped, report.ran) == (3, 3)
    assert report.task_indices == [(1, 1), (2, 0), (2, 1)]
    assert completed(path, spec).all()
    assert_same_store(clean_store, path)


def test_keep_going_then_resume(tmp_path, clean_store):
    path = tmp_path / "data.zarr"
    spec = _demo_spec()
    with pytest.raises(SweepTaskError, match=r"1 of 6 tasks failed: \(a=0, b=1\)") as err:
        run_sweep(path, spec, functools.partial(_demo_task, fail_at=(0, 1)), progress=False, fail_fast=False)
    assert err.value.report.ran == 5 and err.value.report.failed == [(0, 1)]
    assert completed(path, spec).sum() == 5
    report = run_sweep(path, spec, _demo_task, progress=False)
    assert (report.skipped, report.ran, report.task_indices) == (5, 1, [(0, 1)])
    assert_same_store(clean_store, path)


def test_mismatched_grid_raises(tmp_path):
    path = tmp_path / "data.zarr"
    spec = _demo_spec()
    run_sweep(path, spec, _demo_task, progress=False)
    before = _arrays(path)

    other_a = dataclasses.replace(spec, coords={**spec.coords, "a": np.linspace(0.1, 0.4, 3)})
    bigger = _demo_spec(n_r=6)
    other_seed = _demo_spec(seed=999)
    new_param = _demo_spec(damping=0.01)
    other_dtype = dataclasses.replace(spec, variables={**spec.variables, "y": Variable(("a", "b"), dtype="float32")})
    other_tasks = dataclasses.replace(
        spec, task_dims=("a",), variables={"x": Variable(("a", "b", "r", "f")), "y": Variable(("a", "b"))}
    )
    for bad in (other_a, bigger, other_seed, new_param, other_dtype, other_tasks):
        with pytest.raises(SweepMismatchError, match="new output folder"):
            run_sweep(path, bad, _demo_task, progress=False)
    with pytest.raises(SweepMismatchError, match=r"coordinate 'a'"):
        open_sweep(path, other_a)
    with pytest.raises(SweepMismatchError, match=r"attribute 'seed'"):
        open_sweep(path, other_seed)

    zarr.open_group(str(path), mode="a").require_group("plain")  # a group not written by run_sweep
    with pytest.raises(SweepMismatchError, match="not written by run_sweep"):
        open_sweep(path, dataclasses.replace(spec, group="plain"))

    after = _arrays(path)  # nothing was touched
    assert all(before[k].tobytes() == after[k].tobytes() for k in before)
    assert run_sweep(path, spec, _demo_task, progress=False).skipped == 6  # the same grid still resumes


def test_bad_task_result_and_spec(tmp_path):
    spec = _demo_spec()

    def wrong_shape(index, device):
        out = _demo_task(index, device)
        out["x"] = out["x"][:, :3]
        return out

    with pytest.raises(SweepTaskError, match=r"a=0, b=0.*'x'.*\(4, 3\)"):  # one in flight: the first task fails first
        run_sweep(tmp_path / "d.zarr", spec, wrong_shape, progress=False, tasks_per_worker=1)
    assert not completed(tmp_path / "d.zarr", spec).any()
    with pytest.raises(ValueError, match="must start with the task dims"):
        dataclasses.replace(spec, variables={"z": Variable(("r", "a", "b"))})
    with pytest.raises(ValueError, match="explicit fill"):
        dataclasses.replace(spec, variables={"z": Variable(("a", "b"), dtype="int16")})
    with pytest.raises(ValueError, match="no coordinate"):
        dataclasses.replace(spec, variables={"z": Variable(("a", "b", "q"))})


def test_dask_is_optional(tmp_path, monkeypatch):
    code = "import sys, sweep; sys.exit(any(m.split('.')[0] in ('dask', 'distributed') for m in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if not installed
    with pytest.raises(ImportError, match=r'pip install -e "\.\[dask\]"'):
        run_sweep(tmp_path / "d.zarr", _demo_spec(), _demo_task, workers=2, progress=False)
    assert not (tmp_path / "d.zarr").exists()
    assert run_sweep(tmp_path / "d.zarr", _demo_spec(), _demo_task, progress=False).ran == 6


def _slow_demo_task(index: dict, device: str, **kwargs) -> dict:
    import time

    time.sleep(0.05 * (1 + sum(index.values()) % 3))  # uneven tasks finish out of grid order
    return _demo_task(index, device, **kwargs)


def test_tasks_in_flight_give_the_same_store(tmp_path, clean_store):
    """Three tasks at once in-process: the same bytes as one at a time; a failure stops handing out
    tasks and run_sweep returns only after the running ones have finished writing."""
    spec = _demo_spec()
    report = run_sweep(tmp_path / "a.zarr", spec, _slow_demo_task, progress=False, tasks_per_worker=3)
    assert report.ran == 6 and sorted(report.task_indices) == report.task_indices
    assert_same_store(clean_store, tmp_path / "a.zarr")

    path = tmp_path / "b.zarr"
    with pytest.raises(SweepTaskError, match=r"task \(a=0, b=1\) failed"):
        run_sweep(path, spec, functools.partial(_slow_demo_task, fail_at=(0, 1)), progress=False, tasks_per_worker=3)
    done = completed(path, spec).copy()
    assert not done[0, 1] and done.sum() <= 3
    import time

    time.sleep(0.4)
    np.testing.assert_array_equal(completed(path, spec), done)  # nothing finished writing after the return
    report = run_sweep(path, spec, _demo_task, progress=False, tasks_per_worker=2)
    assert report.ran == 6 - int(done.sum())
    assert_same_store(clean_store, path)
    with pytest.raises(ValueError, match="tasks_per_worker must be >= 1"):
        run_sweep(path, spec, _demo_task, progress=False, tasks_per_worker=0)


@pytest.mark.parametrize("damage", ["lose n (1, 0)", "lose checksum (0, 1)", "alter y (2, 1)", "swap x (0, 0) (1, 1)"])
def test_a_damaged_completed_task_runs_again(tmp_path, clean_store, damage):
    """A task flagged completed whose data were lost (an int32 chunk reads as its fill value, not zeros),
    altered or swapped with another task's is found by its checksums on resume and run again."""
    import shutil

    path = tmp_path / "data.zarr"
    shutil.copytree(clean_store, path)
    g = path / GROUP
    what, name, *where = damage.replace("(", "").replace(")", "").replace(",", "").split()
    cells = [where[i : i + 2] for i in range(0, len(where), 2)]
    if what == "lose":
        shutil.rmtree(g / name / "c" / cells[0][0] / cells[0][1])
    elif what == "alter":
        zarr.open_array(str(g / name), mode="r+")[int(cells[0][0]), int(cells[0][1])] = 1.5
    else:
        a, b = (g / name / "c" / i / j for i, j in cells)
        a.rename(g / "tmp")
        b.rename(a)
        (g / "tmp").rename(b)
    lines = []
    report = run_sweep(path, _demo_spec(), _demo_task, progress=False, log=lines.append)
    expected = sorted(tuple(int(v) for v in cell) for cell in cells)
    assert sorted(report.task_indices) == expected
    assert sum("flagged completed but" in line for line in lines) == len(cells)
    assert_same_store(clean_store, path)


def test_a_killed_worker_or_client_loses_nothing(tmp_path, clean_store):
    """A worker process that dies in the middle of a task (no cleanup): Dask runs the task again elsewhere and
    the store equals the in-process one. A client killed by SIGKILL mid-sweep: the rerun runs only what is
    missing and the store equals the uninterrupted one."""
    import subprocess
    import sys

    pytest.importorskip("distributed")
    path = tmp_path / "worker.zarr"
    task = functools.partial(_demo_task_dying, marker=str(tmp_path / "died"))
    report = run_sweep(path, _demo_spec(), task, workers=2, progress=False)
    assert (tmp_path / "died").exists() and report.ran == 6
    assert_same_store(clean_store, path)

    path = tmp_path / "client.zarr"
    script = (
        "import functools, sys\n"
        f"sys.path.insert(0, {os.path.dirname(__file__)!r})\n"  # this folder: the demo tasks
        "from sweep_demo import _demo_spec, _demo_task_dying\n"
        "from sweep import run_sweep\n"
        f"task = functools.partial(_demo_task_dying, marker={str(tmp_path / 'client-died')!r}, at=(2, 0))\n"
        f"run_sweep({str(path)!r}, _demo_spec(), task, progress=False, tasks_per_worker=1)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 9, proc.stderr[-2000:]  # the client died at task (2, 0), as SIGKILL would leave it
    done = completed(path, _demo_spec())
    assert done.sum() == 4 and not done[2].any()
    report = run_sweep(path, _demo_spec(), _demo_task, progress=False)
    assert (report.skipped, report.ran) == (4, 2)
    assert_same_store(clean_store, path)


def test_tasks_run_longest_first_with_a_cost_and_the_report_gives_idle_time_per_worker(tmp_path):
    """``cost=`` hands tasks out by descending estimate (here in-process, one at a time: the run order is the
    estimate's); the store is the same bytes as grid order's, and the report has each worker's idle seconds."""
    spec = _demo_spec()
    cost = lambda index: index["a"] + 10 * index["b"]  # noqa: E731 - the last task of the grid is the longest
    ordered = run_sweep(tmp_path / "cost.zarr", spec, _demo_task, progress=False, tasks_per_worker=1, cost=cost)
    plain = run_sweep(tmp_path / "plain.zarr", spec, _demo_task, progress=False, tasks_per_worker=1)
    assert_same_store(tmp_path / "cost.zarr", tmp_path / "plain.zarr")
    assert ordered.task_indices == plain.task_indices == sorted(plain.task_indices)  # reported in grid order
    assert set(ordered.idle_seconds) == {"main"} and ordered.idle_seconds["main"] >= 0.0
    log = []
    run_sweep(tmp_path / "log.zarr", spec, _demo_task, progress=False, tasks_per_worker=1, cost=cost, log=log.append)
    assert "idle per worker: main" in log[-1]
    seen = []

    def recording(index, device):
        seen.append((index["a"], index["b"]))
        return _demo_task(index, device)

    run_sweep(tmp_path / "order.zarr", spec, recording, progress=False, tasks_per_worker=1, cost=cost)
    assert seen == sorted(seen, key=lambda ab: -(ab[0] + 10 * ab[1]))
    from sweep.runner import _idle

    # two overlapping spans and a gap: busy 0..3 and 5..6 of a 0..10 window, idle 6 s
    assert _idle({"w": [(0.0, 2.0), (1.0, 3.0), (5.0, 6.0)]}, 0.0, 10.0) == {"w": 6.0}
