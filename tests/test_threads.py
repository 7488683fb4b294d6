"""The engine under threads: several Flows driven from several host threads at once (as site-bond's
workers do) give the bits of the same solves run one after the other, with graphs captured and replayed
(Warp's CPU graphs here; CUDA graphs on a GPU, checked by ``benchmarks/thread_check.py``)."""

import threading

import numpy as np
import pytest

import continuation as ct
from warpchain import ChainParams, simulate
from warpchain.flow import Flow

OMEGAS = (1.01, 1.012, 1.015)


def _solves(flow: Flow, params: ChainParams, omegas) -> list:
    """Newton + Floquet at each frequency; what each solve gives, as arrays."""
    out = []
    for omega in omegas:
        b = ct.require(ct.find_breather(params, omega, ct.nls_seed(params, omega), flow=flow))
        fl = ct.floquet(b, flow=flow)
        out.append((b.state, np.array([b.energy, b.residual]), fl.multipliers))
    return out


@pytest.mark.parametrize("layout", ["thread", "block"])
def test_four_threads_give_the_bits_of_one(layout, monkeypatch):
    from warpchain.engine import tuning

    with tuning.override(graphs_on_cpu=True):  # captures on every thread, as on a GPU
        monkeypatch.setenv("WARPCHAIN_CPU_THREADS", "1")  # one slice per launch, as on a GPU (a CPU graph needs it)
        params = ChainParams(30.0, 160.0, 21)
        sequential = [_solves(Flow("kahan8", 16, device="cpu", layout=layout), params, OMEGAS) for _ in range(4)]
        results, errors = [None] * 4, []
        barrier = threading.Barrier(4)

        def work(i):
            try:
                barrier.wait()  # start together, so that captures and launches interleave
                results[i] = _solves(Flow("kahan8", 16, device="cpu", layout=layout), params, OMEGAS)
            except BaseException as exc:  # surfaced below
                errors.append(exc)

        threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
        for t in threads:
            t.start()
        # a plain simulate() on the main thread meanwhile: its launches must not enter the workers' graphs
        x0 = np.zeros((2, 4, params.N))
        x0[:, 1, params.N // 2] = -0.3
        run = simulate(params, x0, 40 * 0.05, 0.05, method="kahan8", device="cpu")
        for t in threads:
            t.join()
        assert not errors, errors
        alone = simulate(params, x0, 40 * 0.05, 0.05, method="kahan8", device="cpu")
        assert np.array_equal(run.x, alone.x)
        for got, want in zip(results, sequential):
            for a, b in zip(got, want):
                for x, y in zip(a, b):
                    assert np.array_equal(x, y)


def test_a_task_that_raises_is_retried_once_then_fails_the_scene():
    """The scenes' worker tasks (``scenarios._workers``, site-bond's and finite-size's): an engine error is retried
    once on a fresh Flow, a second one is raised (the scene fails); a mathematical outcome (``NotLocated``) is never
    retried; a pool without retries raises the first failure; every failure sets ``stopping``, and so does close."""
    from continuation.bifurcation import NotLocated
    from scenarios import site_bond
    from scenarios._workers import TaskError, Workers

    lines, calls = [], []
    P = site_bond.Parameters(workers=2)
    workers = Workers(P.workers, lambda: P.flow("cpu"), lambda *a: lines.append(a[0] % a[1:]), outcomes=(NotLocated,))
    try:

        def flaky(flow, fails):
            calls.append(flow)
            if len(calls) <= fails:
                raise RuntimeError("Warp copy error: operation failed due to a previous error during capture")
            return "found"

        assert workers.submit("task A", flaky, 1).result() == "found"
        assert len(calls) == 2 and calls[0] is not calls[1]  # the retry ran on a new Flow
        assert any("task A raised RuntimeError" in line and "retrying once" in line for line in lines)
        assert workers.count == 2 and not workers.stopping.is_set() and not workers.errors
        calls.clear()
        with pytest.raises(TaskError, match="task B failed twice: RuntimeError: Warp copy error"):
            workers.submit("task B", flaky, 2).result()
        assert workers.stopping.is_set() and isinstance(workers.errors[0], TaskError)

        def no_crossing(flow):
            calls.append(flow)
            raise NotLocated("no sign change of the test function")

        calls.clear()
        with pytest.raises(NotLocated):
            workers.submit("task C", no_crossing).result()
        assert len(calls) == 1
    finally:
        workers.close()
    assert workers.stopping.is_set()
    once = Workers(1, lambda: P.flow("cpu"), retry=False)
    try:
        calls.clear()
        with pytest.raises(TaskError, match="task D failed: RuntimeError"):
            once.result(once.submit("task D", flaky, 1))
        assert len(calls) == 1
    finally:
        once.close()


def test_the_first_failure_is_raised_while_other_tasks_still_run():
    """``Workers.result`` raises the first failure of either of two shared pools at once, without waiting for the
    task it was asked about (finite-size's family chains wait on their analyses this way); the polling chain then
    sees ``stopping`` and returns early, and closing restores the host BLAS threads."""
    import threading

    from threadpoolctl import threadpool_info

    from scenarios._workers import TaskError, Workers

    before = [p["num_threads"] for p in threadpool_info()]
    release, steps = threading.Event(), []
    analyses = Workers(2, lambda: None, name="test-analyses")
    chains = Workers(1, lambda: None, retry=False, shared=analyses, name="test-chains")
    try:

        def chain(flow):
            while not analyses.stopping.is_set():  # a long loop of solves, polling between them
                steps.append(1)
                release.wait(0.01)
            return "stopped early"

        def bad(flow):
            raise ValueError("the count did not close")

        long = chains.submit("the chain", chain)
        analyses.submit("an analysis", bad)
        with pytest.raises(TaskError, match="an analysis failed twice: ValueError: the count did not close"):
            chains.result(long)  # the chain has not ended: the analysis' failure is raised
        assert long.result(timeout=10) == "stopped early"
    finally:
        chains.close()
        analyses.close()
    assert [p["num_threads"] for p in threadpool_info()] == before


def test_paper_in_order_counts_a_failed_scene_and_runs_the_rest(tmp_path, monkeypatch, capsys):
    import scenarios.__main__ as cli

    ran = []

    def fake_run_scene(name, out, device, quick, command_line=""):
        ran.append(name)
        if name == "nls":
            raise RuntimeError("Graph capture already in progress on this stream")

    monkeypatch.setattr(cli, "run_scene", fake_run_scene)
    assert cli.run_in_order(["dispersion", "nls", "breather"], tmp_path, "cpu", True, "") == 1
    assert ran == ["dispersion", "nls", "breather"]
    assert "error: scene nls failed: RuntimeError: Graph capture already in progress" in capsys.readouterr().err


def test_a_failed_scene_leaves_failed_json_and_no_stale_summary(tmp_path, monkeypatch):
    import json

    from scenarios import _common, nls

    first = _common.run_scene("nls", tmp_path, "cpu", True)
    assert (tmp_path / "nls" / "summary.json").exists() and first

    def broken(ctx):
        raise RuntimeError("Failed to allocate 8 bytes")

    monkeypatch.setattr(nls, "run", broken)
    with pytest.raises(RuntimeError):
        _common.run_scene("nls", tmp_path, "cpu", True)
    assert not (tmp_path / "nls" / "summary.json").exists()  # the earlier run's summary does not stand for this one
    assert "Failed to allocate" in json.loads((tmp_path / "nls" / "failed.json").read_text())["error"]


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs os.fork")
def test_a_forked_child_copies_with_threads_of_its_own():
    """The host copies run on a pool of threads; a child forked after the parent used it (a multiprocessing or
    Dask worker started by fork) has none of them, and its first copy used to wait for them for ever."""
    import os

    from warpchain.engine import hostmem

    src = np.arange(4 << 18, dtype=np.float64)
    dst = np.empty_like(src)
    hostmem._copy(dst, src)  # the pool starts
    assert np.array_equal(dst, src)
    pid = os.fork()
    if pid == 0:  # the child: exit 0 if its copy finishes and is right
        try:
            out = np.empty_like(src)
            hostmem._copy(out, src)
            os._exit(0 if np.array_equal(out, src) else 1)
        except BaseException:
            os._exit(2)
    for _ in range(300):
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        threading.Event().wait(0.1)
    else:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's copy did not finish in 30 s")
    assert os.waitstatus_to_exitcode(status) == 0
