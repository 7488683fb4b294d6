"""A resumed branch keeps what the stored walk found (its events: stability changes, Krein passes, foam), and a
resume with settings other than the stored branch's is refused with one line that names them."""

import json

import numpy as np
import pytest

from scenarios.__main__ import main


def _summary(out):
    return json.loads((out / "continuation-omega" / "summary.json").read_text())


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_resume_keeps_the_events_and_refuses_other_settings(tmp_path, capsys):
    args = ["run", "continuation-omega", "--quick", "--device", "cpu", "--out", str(tmp_path)]
    assert main(args) == 0
    first = _summary(tmp_path)
    assert first["stability_changes"] and first["krein_crossings_recorded"] > 0
    assert main(args + ["--resume"]) == 0  # a finished branch: nothing to add, nothing lost
    again = _summary(tmp_path)
    for key in ("stability_changes", "unstable_intervals", "events", "krein_crossings_recorded", "unresolved_bubbles"):
        assert again[key] == first[key], key
    capsys.readouterr()
    assert main(args + ["--resume", "--set", "K=100", "--set", "steps_per_period=64"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "K = 160.0 (stored) vs 100.0" in err and "steps_per_period = 32" in err
    assert _summary(tmp_path)["points"] == first["points"]  # the refused resume wrote nothing


def test_a_scene_folder_in_use_is_refused_and_a_left_lock_file_taken_over(tmp_path, capsys):
    import fcntl
    import os
    import socket

    folder = tmp_path / "nls"
    folder.mkdir()
    lock = folder / ".lock"
    lock.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": 0}))
    args = ["run", "nls", "--quick", "--device", "cpu", "--out", str(tmp_path)]
    with open(lock) as held:  # a live holder: the OS lock, not the file, says so
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and f"in use by process {os.getpid()} on {socket.gethostname()}" in err
        lock.write_text("\x00garbage")  # a holder whose file cannot be read is still a holder
        assert main(args) == 2
        assert "in use by another process" in capsys.readouterr().err
    assert not (folder / "summary.json").exists() and lock.exists()
    assert main(args) == 0  # a lock file with no holder (its process gone, or garbage): taken over
    assert (folder / "summary.json").exists() and not lock.exists()


def test_two_processes_never_both_take_the_scene_lock(tmp_path):
    """Racing takers (the old existence lock let 7 of 80 pairs both in): exactly one holds it at any time."""
    import subprocess
    import sys

    code = (
        "import sys, time, pathlib\n"
        "from scenarios._common import scene_lock, Refused\n"
        "out = pathlib.Path(sys.argv[1]); held = 0\n"
        "for _ in range(40):\n"
        "    try:\n"
        "        with scene_lock(out):\n"
        "            flag = out / 'inside'\n"
        "            assert not flag.exists(), 'two holders'\n"
        "            flag.touch(); time.sleep(0.002); flag.unlink(); held += 1\n"
        "    except Refused:\n"
        "        pass\n"
        "print(held)\n"
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        for _ in range(3)
    ]
    results = [p.communicate(timeout=120) for p in procs]
    for p, (out, err) in zip(procs, results):
        assert p.returncode == 0, err[-2000:]
    assert sum(int(out) for out, _ in results) > 0


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_sigterm_marks_the_store_interrupted_like_ctrl_c(tmp_path):
    import signal

    import zarr

    code, err = _signal_the_walk(["--out", str(tmp_path)], 5, signal.SIGTERM)
    assert code == 143, err[-2000:]
    store = tmp_path / "continuation-omega" / "data.zarr"
    assert "terminated (SIGTERM): what was stored so far is complete" in err
    attrs = zarr.open_group(str(store), mode="r")["branch"].attrs
    # marked interrupted, or (the signal came after the branch was finished, while the scene drew) complete
    assert attrs["stop_reason"] == "interrupted" or attrs["complete"] is True, dict(attrs)
    assert attrs["stop_reason"] is not None and attrs["n_points"] >= 3
    assert not (tmp_path / "continuation-omega" / ".lock").exists()


def _signal_the_walk(args: list, after: int, sig) -> tuple[int, str]:
    """Runs ``python -m scenarios run continuation-omega --quick --device cpu ARGS``, sends ``sig`` once the
    walk has logged ``after`` points (while it goes on: points not yet written included) and returns (exit
    status, stderr). The child gets SIGINT's default back: a shell's background job (a CI runner's) ignores
    SIGINT, and a Python started so keeps ignoring it."""
    import signal
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "scenarios", "run", "continuation-omega", "--quick", "--device", "cpu", *args]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    seen, lines = 0, []
    while seen < after:  # the walk logs a line per point it steps from ("w = ...: E = ...")
        line = proc.stderr.readline()
        assert line, "".join(lines[-20:])
        lines.append(line)
        seen += "[continuation-omega] w = " in line
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, "".join(lines) + err


def _arrays_and_attrs(store):
    import zarr

    g = zarr.open_group(str(store), mode="r", use_consolidated=False)["branch"]
    return {name: g[name][...] for name in g.array_keys()}, dict(g.attrs)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole")
    assert main(["run", "continuation-omega", "--quick", "--device", "cpu", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize("how, after", [("SIGKILL", 6), ("SIGINT", 9), ("max_points", 20)])
def test_a_resume_equals_the_uninterrupted_branch(uninterrupted, tmp_path, how, after):
    """Killed (SIGKILL: the writer's queue is lost, the lock left behind), interrupted (SIGINT) or cut by a
    point count, then resumed: every array, the events and the counters equal the uninterrupted run's."""
    import signal
    import subprocess
    import sys

    import numpy as np

    cmd = [sys.executable, "-m", "scenarios", "run", "continuation-omega", "--quick", "--device", "cpu"]
    cmd += ["--out", str(tmp_path)]
    store = tmp_path / "continuation-omega" / "data.zarr"
    if how == "max_points":
        assert subprocess.run(cmd + ["--set", f"max_points={after}"], capture_output=True).returncode == 0
    else:
        code, err = _signal_the_walk(["--out", str(tmp_path)], after, getattr(signal, how))
        assert code in (-9, 130), err[-2000:]
    cut = _arrays_and_attrs(store)[1]
    expected = {"max_points": ("max_points", True), "SIGINT": ("interrupted", False), "SIGKILL": (None, False)}[how]
    assert (cut["stop_reason"], cut["complete"]) == expected
    assert cut["n_points"] >= (after if how == "SIGINT" else 0)  # SIGINT flushes; SIGKILL may lose the queue
    # no consolidated metadata while the branch grew (a kill leaves none, never a stale one); marked runs have it
    meta = json.loads((store / "zarr.json").read_text())
    assert ("consolidated_metadata" in meta) == (how != "SIGKILL")
    assert main(["run", "continuation-omega", "--quick", "--device", "cpu", "--resume", "--out", str(tmp_path)]) == 0
    whole, whole_attrs = _arrays_and_attrs(uninterrupted / "continuation-omega" / "data.zarr")
    resumed, resumed_attrs = _arrays_and_attrs(store)
    assert sorted(whole) == sorted(resumed)
    for name in whole:
        assert np.array_equal(whole[name], resumed[name], equal_nan=True), name
    import xarray as xr

    assert xr.open_zarr(store, group="branch").sizes["point"] == whole_attrs["n_points"]  # consolidated again
    for key in ("events", "stop_reason", "walk_state", "n_points", "complete"):
        assert whole_attrs[key] == resumed_attrs[key], key
    assert {k: v for k, v in whole_attrs["stats"].items() if "seconds" not in k} == {
        k: v for k, v in resumed_attrs["stats"].items() if "seconds" not in k
    }


@pytest.mark.slow
def test_a_point_count_that_cuts_a_step_resumes_into_the_same_branch(tmp_path):
    """max_points = 40 stops inside a bisected step (the last completed step ends at point 19 here): the
    resumed walk redoes that step, and its 80 points, events and counters equal one walk of 80."""
    import continuation as ct
    import warpchain as wc
    from continuation.branch import NaturalParameter
    from continuation.driver import ContinuationSettings, WalkState, continuation
    from continuation.branch_store import BranchStore, load_branch

    p = wc.ChainParams(30.0, 0.01, 101)

    def problem():
        return NaturalParameter(p, 1.01, ct.anticontinuum_seed(p, 1.01), K_end=20.0, flow=wc.Flow("kahan8", 32))

    settings = ContinuationSettings(ds=0.15, ds_max=0.3, resolution=1e-3, max_points=40)
    store = BranchStore(tmp_path / "cut.zarr", "branch", p, {})
    store.finish(continuation(problem(), settings, on_point=store.append, on_step=store.step))
    _, points, attrs = load_branch(tmp_path / "cut.zarr", "branch")
    state = WalkState.from_dict(attrs["walk_state"], attrs["events"])
    assert state.points < 40 and len(state.events) < len(attrs["events"])  # the cut step's events follow
    store = BranchStore(tmp_path / "cut.zarr", "branch", p, {}, resume=True, keep=state.points)
    more = continuation(
        problem(),
        settings.replace(max_points=80),
        resume=points,
        resume_state=state,
        on_point=store.append,
        on_step=store.step,
    )
    store.finish(more)
    one = continuation(problem(), settings.replace(max_points=80))
    assert len(more.points) == len(one.points) == 80
    for a, b in zip(more.points, one.points):
        assert a.K == b.K and np.array_equal(a.state, b.state) and np.array_equal(a.mu, b.mu)
    assert more.events == one.events
    assert {k: v for k, v in more.stats.items() if "seconds" not in k} == {
        k: v for k, v in one.stats.items() if "seconds" not in k
    }


@pytest.mark.slow
def test_resuming_from_any_completed_step_gives_the_same_branch():
    """Every on_step state of the quick frequency branch (steps with many bisection points among them, after
    which the corrector no longer holds the walk point's Jacobian: WalkState.chord) resumes into the same
    points, bit for bit, the same events and the same counters."""
    from continuation.branch import PseudoArclength
    from continuation.driver import continuation
    from scenarios import continuation_omega as co
    from scenarios._common import scene_parameters
    from warpchain import ChainParams

    P = scene_parameters(co, True)
    params = ChainParams(P.M, P.K, P.N)

    def problem():
        return PseudoArclength(params, P.flow("cpu"), None, omega_min=P.omega_min)

    states = []
    whole = continuation(problem(), P.settings(), on_step=states.append)
    assert any(s.chord is None for s in states) and any(s.chord for s in states)  # the case that needs the flag occurs
    for state in states[1::2]:
        again = continuation(problem(), P.settings(), resume=list(whole.points[: state.points]), resume_state=state)
        assert len(again.points) == len(whole.points), state.points
        for a, b in zip(again.points, whole.points):
            assert np.array_equal(a.state, b.state) and np.array_equal(a.mu, b.mu, equal_nan=True), state.points
        assert again.events == whole.events and again.stats["solves"] == whole.stats["solves"]
