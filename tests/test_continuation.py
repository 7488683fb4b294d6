import json
import shutil

import numpy as np
import pytest

import continuation as ct
from continuation.branch import continue_in_coupling, continue_in_frequency, start_from_eigenmode
from continuation.driver import ContinuationSettings
from continuation.events import StopReason
from continuation.branch_store import CHUNK, BranchStore, StoreError, load_branch
from warpchain import ChainParams, Flow, ReferenceFlow, lowest_optical_mode

K_SETTINGS = ContinuationSettings(ds=0.5, ds_min=1e-3, ds_max=0.8, resolution=1e-2)


@pytest.fixture(scope="module")
def k_branch(tmp_path_factory):
    path = tmp_path_factory.mktemp("k") / "branch.zarr"
    p = ChainParams(30.0, 0.01, 41)
    store = BranchStore(path, "branch", p, {"omega": 1.01})
    branch = continue_in_coupling(
        p, 1.01, ct.anticontinuum_seed(p, 1.01), 20.0, targets=(5.0,), settings=K_SETTINGS, on_point=store.append
    )
    store.finish(branch)
    return path, branch


def test_k_branch_lands_on_targets_with_multipliers_everywhere(k_branch):
    _, branch = k_branch
    K = branch.column("K")
    assert branch.stop_reason is StopReason.END_REACHED and branch.stop_reason.physical
    assert K[0] == 0.01 and K[-1] == 20.0 and 5.0 in K
    assert np.all(np.diff(K) > 0)
    assert np.all(np.diff(branch.column("energy")) > 0)  # energy grows with the coupling (paper Fig. 6)
    for p in branch.points:
        assert p.multipliers.shape == (4 * 41,) and p.mu.shape == (2 * 41,) and np.isfinite(p.max_modulus)
        assert p.residual_history[-1] <= 1e-10 and p.min_contact > 0
    assert branch.stats["points"] == len(branch.points) and branch.stats["seconds_per_point"] > 0


def test_stability_changes_are_bracketed_to_the_resolution_and_confirmed_directly(k_branch):
    _, branch = k_branch
    changes = [e for e in branch.events if e["type"] == "stability_change"]
    assert changes, "the N = 41 K-branch to K = 20 has stability changes"
    for e in changes:
        a, b = e["bracket"]
        assert abs(np.log10(b) - np.log10(a)) <= K_SETTINGS.resolution * 1.0001
        # both ends are branch points whose verdicts differ, and a direct solve agrees with each
        pa = next(p for p in branch.points if p.K == a)
        pb = next(p for p in branch.points if p.K == b)
        if e["from_stable"] != e["to_stable"]:
            assert pa.stable != pb.stable
        for p in (pa, pb):
            direct = ct.floquet(ct.require(ct.find_breather(ChainParams(30.0, p.K, 41), 1.01, p.state)))
            assert direct.stable == p.stable
    intervals = branch.unstable_intervals()
    assert all(
        iv["start"] <= iv["end"] and set(iv["kinds"]) <= set(ct.floquet.__globals__["KINDS"]) for iv in intervals
    )


def test_stored_branch_round_trips_and_resumes(k_branch):
    path, branch = k_branch
    params, points, attrs = load_branch(path, "branch")
    assert attrs["complete"] is True and attrs["stop_reason"] == "end_reached" and attrs["n_points"] == len(points)
    assert len(points) == len(branch.points)
    for a, b in zip(points, branch.points):
        assert a.K == b.K and np.array_equal(a.state, b.state) and np.allclose(a.mu, b.mu)
        assert a.stable == b.stable and [i.kind for i in a.instabilities] == [i.kind for i in b.instabilities]
    import zarr

    counts = zarr.open_group(str(path), mode="r", use_consolidated=False)["branch"]["instability_count"][...]
    assert counts.tolist() == [len(p.instabilities) for p in branch.points]  # all, not only the stored 16
    upto = [p for p in points if p.K <= 5.0]
    resumed = continue_in_coupling(
        params.replace(K=upto[-1].K), 1.01, upto[-1].state, 20.0, settings=K_SETTINGS, resume=upto
    )
    assert resumed.points[-1].K == 20.0
    assert resumed.points[-1].energy == pytest.approx(branch.points[-1].energy, rel=1e-8)


def _copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_a_missing_chunk_is_an_error_not_zeros(k_branch, tmp_path):
    path, _ = k_branch
    bad = _copy(path, tmp_path / "bad.zarr")
    chunk = next((bad / "branch" / "energy" / "c").iterdir())  # the first point's chunk
    chunk.unlink()
    with pytest.raises(StoreError, match=r"energy.*point \d+.*checksum \(reads as its fill value: a lost chunk"):
        load_branch(bad, "branch")


@pytest.mark.parametrize(
    "damage, match",
    [
        ("lose instability_kind unstable", r"'instability_kind', point \d+\): .*lost chunk"),
        ("lose signature 1", rf"'signature', point {CHUNK}\): .*lost chunk"),
        ("lose stable 0", r"'stable', point 0\): .*lost chunk"),
        ("lose checksum 2", rf"'checksum', point {2 * CHUNK}\): reads as its fill value"),
        ("alter s 4", r"'s', point 4\): .*altered or misplaced"),
        ("swap energy 0 1", r"'energy', point 0\): .*altered or misplaced"),
        ("swap all 1 2", rf"point {CHUNK}\): .*altered or misplaced"),
        ("edit instability_count 0", r"'instability_count', point 0\): .*altered or misplaced"),
        ("lower n_points 2", r"'checksum'\): \d+ rows but the group says \d+ points"),
        ("empty events x", r"group 'branch'\): its attributes do not match their checksum"),
        ("edit params.K x", r"\(root\): its attributes do not match their checksum"),
    ],
)
def test_every_array_is_checked_against_its_point(k_branch, tmp_path, damage, match):
    """Lost chunks of integer arrays, altered values, chunks swapped between points (of one array, or a
    whole point moved) and an edited point count are refused, naming array and point."""
    import zarr

    path, branch = k_branch
    bad = _copy(path, tmp_path / "bad.zarr")
    what, *args = damage.rsplit(" ", 2) if damage.startswith("swap") else damage.rsplit(" ", 1)
    g = bad / "branch"
    if args == ["unstable"]:
        args = [str(next(i for i, p in enumerate(branch.points) if p.instabilities) // CHUNK)]
    if what.startswith("lose"):
        chunk = g / what.split()[1] / "c" / args[0]  # chunk k: points CHUNK k .. (a folder for arrays of more dims)
        shutil.rmtree(chunk) if chunk.is_dir() else chunk.unlink()
    elif what == "alter s":
        zarr.open_array(str(g / "s"), mode="r+")[int(args[0])] = 123.0
    elif what == "edit instability_count":
        zarr.open_array(str(g / "instability_count"), mode="r+")[int(args[0])] = 99
    elif what.startswith("swap"):
        names = [n.name for n in g.iterdir() if n.is_dir()] if what == "swap all" else [what.split()[1]]
        i, j = args
        for name in names:  # chunks equal to the fill value are not written: move what exists
            a, b, tmp = g / name / "c" / i, g / name / "c" / j, g / name / "c" / "tmp"
            if a.exists():
                a.rename(tmp)
            if b.exists():
                b.rename(a)
            if tmp.exists():
                tmp.rename(b)
    elif what == "empty events":  # the foam's record gone (an audit case): the signature is not
        meta = json.loads((g / "zarr.json").read_text())
        meta["attributes"]["events"] = []
        (g / "zarr.json").write_text(json.dumps(meta))
    elif what == "edit params.K":  # the chain's parameters at the root, edited to match another --set
        meta = json.loads((bad / "zarr.json").read_text())
        meta["attributes"]["params"]["K"] = 100.0
        (bad / "zarr.json").write_text(json.dumps(meta))
    else:
        from warpchain.store import SIGNATURE, attributes_checksum

        meta = json.loads((g / "zarr.json").read_text())
        meta["attributes"]["n_points"] -= int(args[0])
        meta["attributes"][SIGNATURE] = attributes_checksum(meta["attributes"])  # signed again: the count is checked
        (g / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError, match=match):
        load_branch(bad, "branch")


def test_a_corrupt_metadata_file_names_the_store(k_branch, tmp_path):
    path, _ = k_branch
    bad = _copy(path, tmp_path / "bad2.zarr")
    (bad / "branch" / "state" / "zarr.json").write_text("{not json")
    with pytest.raises(StoreError, match="bad2.zarr"):
        load_branch(bad, "branch")
    meta = json.loads((bad / "branch" / "zarr.json").read_text())
    meta["attributes"]["n_points"] = 10**6
    (bad / "branch" / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError):
        load_branch(bad, "branch")


def test_loss_of_contact_stops_the_branch_and_says_so():
    p = ChainParams(30.0, 1.0, 41)
    branch = continue_in_coupling(
        p,
        0.985,
        ct.nls_seed(p, 0.985),
        40.0,
        settings=ContinuationSettings(ds=0.15, ds_min=0.02, ds_max=0.3, max_newton=6, floquet=False),
    )
    assert branch.stop_reason is StopReason.CONTACT_LOST
    assert "lost contact" in branch.message and branch.points[-1].min_contact <= 0 < branch.points[-2].min_contact


def test_newton_failure_at_the_start_is_the_stop_reason():
    p = ChainParams(30.0, 40.0, 41)
    branch = continue_in_coupling(
        p, 0.99, ct.nls_seed(p, 0.99), 80.0, settings=ContinuationSettings(ds=0.15, ds_max=0.3, max_newton=6)
    )
    assert branch.stop_reason is StopReason.NEWTON_FAILED and "acoustic band" in branch.message and not branch.points


def test_frequency_branch_from_the_eigenmode(tmp_path):
    p = ChainParams(30.0, 160.0, 41)
    start = start_from_eigenmode(p)
    w_lin = lowest_optical_mode(p)[0]
    assert w_lin - 1e-3 < start[1][1] < start[0][1] < w_lin
    store = BranchStore(tmp_path / "w.zarr", "branch", p, {"K": 160.0})
    settings = ContinuationSettings(ds=0.05, ds_max=0.6, max_points=7, resolution=1e-2)
    branch = continue_in_frequency(p, start, settings=settings, on_point=store.append)
    store.finish(branch)
    w, E = branch.column("omega"), branch.column("energy")
    assert branch.stop_reason is StopReason.MAX_POINTS and len(branch.points) == 7  # exact, bisections included
    assert np.all(np.diff(w) < 0) and np.all(np.diff(E) > 0)  # into the gap, growing energy
    last = branch.points[-1]
    check = ct.find_breather(p, last.omega, last.state)
    assert check.success and check.iterations <= 1  # every point is a breather at its own frequency
    _, stored, attrs = load_branch(tmp_path / "w.zarr", "branch")
    assert len(stored) == len(branch.points) and attrs["stop_reason"] == "max_points"
    budget = continue_in_frequency(p, start, settings=settings.replace(max_seconds=0.0, max_points=None))
    assert budget.stop_reason is StopReason.TIME_BUDGET


def test_newton_integrates_each_point_once():
    p = ChainParams(30.0, 160.0, 41)
    res = ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01))
    assert res.success
    # one trajectory per Newton point (trial points included), a Jacobian per iteration, none extra
    assert res.stats["jacobians"] == res.iterations
    assert res.stats["evaluations"] == res.iterations + 1  # no damping was needed here


def test_continuation_runs_on_the_numpy_reference_flow():
    p = ChainParams(30.0, 0.5, 11)
    settings = ContinuationSettings(ds=0.3, ds_max=0.3, resolution=0.05)
    ref = continue_in_coupling(
        p, 1.01, ct.anticontinuum_seed(p, 1.01), 2.0, settings=settings, flow=ReferenceFlow("kahan8", 32)
    )
    warp = continue_in_coupling(
        p, 1.01, ct.anticontinuum_seed(p, 1.01), 2.0, settings=settings, flow=Flow("kahan8", 32, "cpu")
    )
    assert ref.stop_reason is StopReason.END_REACHED and len(ref.points) == len(warp.points)
    for a, b in zip(ref.points, warp.points):
        assert a.K == b.K and np.max(np.abs(a.state - b.state)) < 1e-13 and a.stable == b.stable


def test_settings_are_validated():
    with pytest.raises(ValueError, match="ds"):
        ContinuationSettings(ds=-1.0)
    with pytest.raises(ValueError, match="max_points"):
        ContinuationSettings(max_points=0)
    with pytest.raises(ValueError, match="bisect_krein"):
        ContinuationSettings(bisect_krein="some")
    with pytest.raises(ValueError, match="blas_threads"):
        ContinuationSettings(blas_threads=0)


def test_the_walk_runs_on_one_blas_thread_and_restores_the_setting():
    from threadpoolctl import threadpool_info

    from continuation.hostblas import blas_threads, threads_for

    def counts():
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    before = counts()
    seen = []
    p = ChainParams(30.0, 100.0, 21)
    settings = ContinuationSettings(ds=0.1, ds_max=0.1, max_points=2, floquet=False)
    continue_in_coupling(
        p,
        1.01,
        ct.nls_seed(p, 1.01),
        160.0,
        settings=settings,
        device="cpu",
        on_point=lambda point: seen.append(counts()),
    )
    assert seen and all(c == [1] * len(c) for c in seen)  # "auto" on the CPU device: one thread
    assert counts() == before
    assert threads_for("cpu") == 1 and threads_for("numpy") == 1 and threads_for("cuda:0") is None
    with blas_threads(None):
        assert counts() == before
    with pytest.raises(ValueError, match="BLAS threads"):
        with blas_threads(0):
            pass


def test_blas_limits_of_blocks_open_at_once_come_back_when_the_last_ends():
    """Two blocks open at once that do not end in the order they began (two Floquet analyses on two threads): the
    smallest limit holds while both are open and while the one that asked for it is, and the limits from before
    come back when the last ends (the first to end used to restore them under the other); a block on another
    thread than the first to set them takes effect."""
    import threading

    from threadpoolctl import threadpool_info

    from continuation.hostblas import blas_threads

    def counts():
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    before = counts()
    with blas_threads(1):  # the main thread sets the limits first: threadpoolctl then ignored other threads
        pass
    seen = {}

    def on_a_thread():
        with blas_threads(1):
            seen["thread"] = counts()

    with blas_threads(2):
        worker = threading.Thread(target=on_a_thread)
        worker.start()
        worker.join()
        seen["main"] = counts()
    assert seen == {"thread": [1] * len(before), "main": [2] * len(before)} and counts() == before
    first, second = blas_threads(2), blas_threads(1)
    first.__enter__()
    second.__enter__()
    both = counts()
    first.__exit__(None, None, None)
    after_first = counts()
    second.__exit__(None, None, None)
    assert both == [1] * len(before) and after_first == [1] * len(before)
    assert counts() == before


def test_a_branch_without_floquet_is_stored_and_read_back(tmp_path):
    p = ChainParams(30.0, 0.01, 21)
    store = BranchStore(tmp_path / "nf.zarr", "branch", p, {"omega": 1.01})
    branch = continue_in_coupling(
        p,
        1.01,
        ct.anticontinuum_seed(p, 1.01),
        0.1,
        settings=ContinuationSettings(ds=0.3, ds_max=0.5, floquet=False),
        on_point=store.append,
    )
    store.finish(branch)
    _, points, _ = load_branch(tmp_path / "nf.zarr", "branch")
    assert len(points) == len(branch.points) and all(q.mu is None and not q.stable for q in points)


def test_a_store_written_in_the_background_equals_one_written_inline(k_branch, tmp_path):
    _, branch = k_branch
    points = branch.points[:12]
    p = ChainParams(30.0, points[0].K, 41)
    inline = BranchStore(tmp_path / "a.zarr", "branch", p, {"omega": 1.01})
    behind = BranchStore(tmp_path / "b.zarr", "branch", p, {"omega": 1.01}).background()
    for q in points:
        inline.append(q)
        behind.append(q)
    inline.finish(branch)
    behind.finish(branch)  # waits for the queue
    _, a, _ = load_branch(tmp_path / "a.zarr", "branch")
    _, b, _ = load_branch(tmp_path / "b.zarr", "branch")
    assert len(a) == len(b) == 12
    for x, y in zip(a, b):
        assert np.array_equal(x.state, y.state) and x.K == y.K and np.array_equal(x.mu, y.mu, equal_nan=True)


def test_a_branch_whose_start_fails_has_the_walked_branch_stats_and_the_scene_says_what_to_try(tmp_path):
    """A failed start returns a branch with no points and the same stats keys as a walked one (the scenes' stop
    line read ``seconds_per_point`` and raised KeyError); the scene then fails with a line naming the cure."""
    from continuation.branch import PseudoArclength
    from continuation.driver import ContinuationSettings, StopReason, continuation
    from warpchain import ChainParams, Flow

    p = ChainParams(30.0, 160.0, 31)
    problem = PseudoArclength(p, Flow("verlet", 32, device="cpu"), None, omega_min=0.99, eigenmode_amplitude=3.0)
    b = continuation(problem, ContinuationSettings(floquet=False))
    assert b.stop_reason == StopReason.NEWTON_FAILED and not b.points
    assert b.stats["points"] == 0 and b.stats["seconds_per_point"] == 0.0 and b.wall_seconds > 0
    import subprocess
    import sys

    args = ["run", "continuation-omega", "--quick", "--device", "cpu", "--set", "eigenmode_amplitude=3"]
    out = subprocess.run(
        [sys.executable, "-m", "scenarios", *args, "--out", str(tmp_path)], capture_output=True, text=True
    )
    assert out.returncode != 0 and "eigenmode_amplitude" in out.stderr and "KeyError" not in out.stderr


@pytest.mark.slow  # 20 s on 2 cores: worker processes for every point
def test_a_branch_on_the_sliced_path_is_the_dense_one_stored_and_read_back(tmp_path):
    """``floquet_solver="sliced"``: every point's 2N mu from the probed Mu, counted (complete verdicts), the same
    points, mu and verdicts as the dense path; the store keeps each point's completeness flag and reads it back; a
    resume from the store continues the branch; the window, which gives no verdict, is refused."""
    p = ChainParams(30.0, 0.01, 41)
    settings = K_SETTINGS.replace(floquet_solver="sliced")
    store = BranchStore(tmp_path / "w.zarr", "branch", p, {"omega": 1.01})
    seed = ct.anticontinuum_seed(p, 1.01)
    branch = continue_in_coupling(p, 1.01, seed, 20.0, settings=settings, on_point=store.append)
    store.finish(branch)
    dense = continue_in_coupling(p, 1.01, seed, 20.0, settings=K_SETTINGS.replace(floquet_solver="dense"))
    assert branch.stop_reason is StopReason.END_REACHED
    assert [q.K for q in branch.points] == pytest.approx([q.K for q in dense.points], rel=1e-9)
    for a, b in zip(branch.points, dense.points):
        assert a.complete and len(a.mu) == 2 * 41 and a.stable == b.stable
        assert max(np.min(np.abs(b.mu - m)) for m in a.mu) <= 1e-11
    params, points, _ = load_branch(tmp_path / "w.zarr", "branch")
    assert len(points) == len(branch.points)
    for a, b in zip(points, branch.points):
        assert np.array_equal(a.mu, b.mu) and np.array_equal(a.signature, b.signature)
        assert (
            a.stable == b.stable
            and a.complete
            and [i.kind for i in a.instabilities] == [i.kind for i in b.instabilities]
        )
    upto = [q for q in points if q.K <= 5.0]
    resumed = continue_in_coupling(
        params.replace(K=upto[-1].K), 1.01, upto[-1].state, 20.0, settings=settings, resume=upto
    )
    assert resumed.points[-1].K == 20.0
    for solver in ("window", "krylov"):
        with pytest.raises(ValueError, match="floquet_solver|now 'window'"):
            ContinuationSettings(floquet_solver=solver)
    with pytest.raises(ValueError, match="floquet_solver"):
        ContinuationSettings(floquet_solver="arnoldi")


def test_read_store_checks_the_branch_and_gives_a_dataset_indexed_by_K(k_branch, tmp_path):
    """``warpchain.read_store``: the branch as a Dataset along K (s and omega coordinates), a bool ``stable`` that
    is True only at decided stable points, kinds with their CF flag meanings; a damaged copy is refused."""
    import warpchain as wc

    path, branch = k_branch
    ds = wc.read_store(path, "branch")
    assert ds.energy.dims == ("K",) and np.array_equal(ds.K.values, branch.column("K"))
    assert {"s", "omega", "point"} <= set(ds.coords) and "checksum" not in ds and "walk_state" not in ds.attrs
    assert ds.stable.dtype == bool and list(ds.stable.values) == [p.stable is True for p in branch.points]
    assert ds.instability_kind.attrs["flag_meanings"] == "real_pair period_doubling complex_quadruplet"
    for name, var in ds.variables.items():
        assert var.attrs.get("long_name") and "units" in var.attrs, name
    tree = wc.read_store(path)
    assert list(tree.children) == ["branch"] and tree.attrs["params"]["N"] == 41
    import zarr

    bad = _copy(path, tmp_path / "bad.zarr")
    zarr.open_array(str(bad / "branch" / "energy"), mode="r+")[3] = 1.0
    with pytest.raises(wc.StoreError, match=r"'energy', point 3"):
        wc.read_store(bad)


def test_ctrl_c_while_the_writer_drains_loses_no_point(k_branch, tmp_path, monkeypatch):
    """An interrupt that lands in ``flush`` waits for the writer to finish before it is raised (an interrupted
    Thread.join marked the writer as ended while it still wrote, and reported points were lost: issue #49)."""
    import os
    import signal
    import threading
    import time

    from continuation.branch_store import BranchStore, load_branch

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # a CI runner's background job ignores it

    _, branch = k_branch
    write = BranchStore._write_points

    def slow(self, points, state=None):
        time.sleep(0.3)
        write(self, points, state)

    monkeypatch.setattr(BranchStore, "_write_points", slow)
    path = tmp_path / "b.zarr"
    store = BranchStore(path, "branch", ChainParams(30.0, 0.01, 41), {"omega": 1.01}).background()
    for point in branch.points[:3]:
        store.append(point)
    threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()  # a real signal: it interrupts a wait
    try:
        with pytest.raises(KeyboardInterrupt):
            store.flush()
    finally:
        signal.signal(signal.SIGINT, previous)
    assert store.n_points == 3  # raised once every queued point was written, not while the writer still wrote
    store.interrupted("interrupted in a test")
    assert store.n_points == 3 and len(load_branch(path, "branch")[1]) == 3
