"""Worker processes for the host eigensolves (``continuation.workers``): a task's error is one line with the
worker's traceback as its detail and the worker is replaced; a stopped, dead or hung worker fails its task at once
(far below ``TASK_TIMEOUT_SECONDS``, or at it for a hang) and the pool recovers; Ctrl-C during ``map`` returns at
once with the busy workers killed; ``Shared`` arguments travel to each worker once.

Every test uses a private ``Workers(2)`` and closes it. A slow task without editing the package: an argument that
unpickles by calling ``time.sleep`` (``_Sleep``), so the worker sleeps while it reads its task and then runs a
harmless function on what it read."""

import os
import pickle
import signal
import threading
import time

import numpy as np
import pytest
import scipy.sparse as sp

from continuation import slicing, spectrum, workers
from continuation.workers import Shared, WorkerError, Workers


class _Sleep:
    """Unpickles, in the worker, as ``time.sleep(seconds)`` (None)."""

    def __init__(self, seconds: float):
        self.seconds = seconds

    def __reduce__(self):
        return (time.sleep, (self.seconds,))


#: a harmless task on whatever it is given: _state(None) reads /proc/None/stat, fails quietly and returns ""
SLOW = ("_state", (_Sleep(30.0),))
MODULE = "continuation.workers"


@pytest.fixture
def pool():
    p = Workers(2)
    try:
        yield p
    finally:
        for w in list(p.started):  # whatever a test left stopped is woken so that close() can end it
            if w.process.poll() is None:
                try:
                    os.kill(w.process.pid, signal.SIGCONT)
                except OSError:
                    pass
        p.close()
        for w in list(p.started):
            if w.process.poll() is None:
                w.process.kill()
                w.process.wait()


def _processes(p: Workers) -> list:
    return [w.process for w in p.started]


def _wait_until(condition, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def _works(p: Workers) -> None:
    """A quick task on every worker gives the right answer."""
    out = p.map("continuation.slicing", [("_interleaved", (n,)) for n in (4, 6, 8, 10)])
    for n, perm in zip((4, 6, 8, 10), out):
        assert np.array_equal(perm, slicing._interleaved(n))


# ----------------------------------------------------------------------------- a task's error


def test_a_task_error_is_one_line_with_the_traceback_as_detail(pool):
    _works(pool)  # both workers started
    known = {p.pid: p for p in _processes(pool)}
    assert len(known) == 2
    with pytest.raises(WorkerError) as info:
        pool.call("continuation.slicing", "_interleaved", (-3,), what="a bad slice")  # np.empty(-3): ValueError
    message = str(info.value)
    assert "\n" not in message
    assert "ValueError" in message and "negative dimensions" in message and "a bad slice" in message
    (failed,) = [pid for pid in known if f"worker {pid}:" in message]
    assert "Traceback" in info.value.detail and "_interleaved" in info.value.detail
    assert info.value.detail.strip().splitlines()[-1] in message
    assert known[failed].poll() is not None  # that worker is gone (killed, reaped)
    assert failed not in [p.pid for p in _processes(pool)]
    # the next calls work, one of them on a fresh worker
    assert np.array_equal(pool.call("continuation.slicing", "_interleaved", (4,)), [0, 2, 1, 3])
    _works(pool)
    assert len(_processes(pool)) == 2 and failed not in [p.pid for p in _processes(pool)]


def test_an_unknown_function_is_a_worker_error(pool):
    with pytest.raises(WorkerError, match="AttributeError") as info:
        pool.call("continuation.slicing", "no_such_function", ())
    assert "\n" not in str(info.value) and "no_such_function" in info.value.detail
    _works(pool)


def test_a_long_map_says_how_far_it_is(pool, monkeypatch, caplog):
    """A map that takes longer than PROGRESS_SECONDS logs a line per period (a 12801-site verdict on 2 cores was
    silent for minutes); the results are as without."""
    monkeypatch.setattr(workers, "PROGRESS_SECONDS", 0.2)
    tasks = [("_state", (_Sleep(0.7),)), ("_interleaved", (4,))]
    with caplog.at_level("INFO", logger="continuation"):
        out = pool.map(MODULE, tasks[:1], what="trial") + pool.map("continuation.slicing", tasks[1:], what="trial")
    lines = [r.getMessage() for r in caplog.records if "[workers]" in r.getMessage()]
    assert lines and all(line.startswith("[workers] trial: 0 of 1 done (") for line in lines), lines
    assert out[0] == "" and np.array_equal(out[1], slicing._interleaved(4))


def test_map_raises_the_first_error_and_stops_the_other_tasks(pool):
    start = time.monotonic()
    with pytest.raises(WorkerError, match="ValueError"):
        pool.map("continuation.slicing", [("_interleaved", (-1,)), SLOW], what="trial")
    assert time.monotonic() - start < 5.0  # not the sleeper's 30 s
    assert _wait_until(lambda: not _processes(pool), 3.0)  # the sleeper was killed too
    _works(pool)


# ----------------------------------------------------------------------------- stopped, dead, hung


def _in_task(p: Workers, action, delay: float = 0.5) -> threading.Thread:
    """A thread that, once the pool has a worker, waits ``delay`` and applies ``action`` to its process."""
    seen = []

    def run():
        if _wait_until(lambda: bool(p.started), 10.0):
            time.sleep(delay)
            proc = p.started[0].process
            seen.append(proc)
            action(proc)

    t = threading.Thread(target=run, daemon=True)
    t.seen = seen
    t.start()
    return t


def test_a_stopped_worker_fails_its_task_at_once_and_the_pool_recovers(pool):
    assert workers.TASK_TIMEOUT_SECONDS > 60
    stopper = _in_task(pool, lambda proc: os.kill(proc.pid, signal.SIGSTOP))
    start = time.monotonic()
    try:
        with pytest.raises(WorkerError, match="stopped") as info:
            pool.call(MODULE, *SLOW, what="a slice")
        elapsed = time.monotonic() - start
    finally:
        stopper.join(10.0)
        for proc in stopper.seen:  # never leave a stopped process behind
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGCONT)
                proc.kill()
                proc.wait()
    assert elapsed < 5.0, elapsed  # a worker start, 0.5 s to the stop, then one POLL_SECONDS
    assert "SIGSTOP" in str(info.value) and "a slice" in str(info.value) and "\n" not in str(info.value)
    (proc,) = stopper.seen
    assert proc.poll() is not None  # killed and reaped by the pool
    assert proc not in _processes(pool)
    _works(pool)


def test_a_worker_that_dies_mid_task_fails_it_at_once(pool):
    killer = _in_task(pool, lambda proc: proc.kill())
    start = time.monotonic()
    with pytest.raises(WorkerError, match="exited") as info:
        pool.call(MODULE, *SLOW)
    killer.join(10.0)
    assert time.monotonic() - start < 5.0
    assert "\n" not in str(info.value)
    _works(pool)


def test_a_worker_that_died_while_idle_is_replaced(pool):
    _works(pool)
    dead = _processes(pool)[0]
    dead.kill()
    dead.wait()
    _works(pool)  # the dead one is noticed when taken and replaced
    assert dead not in _processes(pool)
    assert all(p.poll() is None for p in _processes(pool))


def test_a_task_past_the_timeout_is_a_hang(pool, monkeypatch):
    monkeypatch.setattr(workers, "TASK_TIMEOUT_SECONDS", 0.5)
    start = time.monotonic()
    with pytest.raises(WorkerError) as info:
        pool.call(MODULE, *SLOW, what="a slice")
    elapsed = time.monotonic() - start
    assert 0.5 <= elapsed < 5.0, elapsed
    message = str(info.value)
    assert "hung" in message and "no answer" in message and "\n" not in message
    assert not _processes(pool)  # the hung worker was killed
    monkeypatch.undo()
    _works(pool)


# ----------------------------------------------------------------------------- Ctrl-C


def test_ctrl_c_during_map_returns_at_once_and_kills_the_busy_workers(pool):
    _works(pool)  # both workers started
    busy = _processes(pool)
    assert len(busy) == 2
    armed = threading.Event()
    armed.set()

    def interrupt():
        if armed.is_set():
            signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    timer = threading.Timer(0.5, interrupt)
    start = time.monotonic()
    try:
        with pytest.raises(KeyboardInterrupt):
            timer.start()
            pool.map(MODULE, [SLOW, SLOW, SLOW])
        elapsed = time.monotonic() - start
    finally:
        armed.clear()
        timer.cancel()
        timer.join()
    assert elapsed < 3.0, elapsed
    assert _wait_until(lambda: all(p.poll() is not None for p in busy), 3.0)  # the busy workers were killed
    assert _wait_until(lambda: not _processes(pool), 3.0)
    _works(pool)  # and the pool works on fresh ones
    assert all(p.pid not in {b.pid for b in busy} for p in _processes(pool))


# ----------------------------------------------------------------------------- shared objects


class _CountingPickle:
    """``pickle`` as ``continuation.workers`` sees it, recording the size of every payload sent to a worker."""

    HIGHEST_PROTOCOL = pickle.HIGHEST_PROTOCOL
    loads = staticmethod(pickle.loads)

    def __init__(self):
        self.sizes = []

    def dumps(self, obj, protocol=None):
        out = pickle.dumps(obj, protocol=protocol)
        self.sizes.append(len(out))
        return out


def test_a_shared_object_is_sent_once_per_worker(pool, monkeypatch):
    rng = np.random.default_rng(0)
    vectors = rng.standard_normal((2000, 50))  # 800 kB
    shared = Shared(vectors)
    counting = _CountingPickle()
    monkeypatch.setattr(workers, "pickle", counting)
    masses = [1.0, 2.0, 3.0, 30.0, 0.5, 7.0, 11.0, 13.0]
    out = pool.map("continuation.spectrum", [("participation", (shared, m)) for m in masses])
    monkeypatch.undo()
    for m, got in zip(masses, out):
        assert np.allclose(got, spectrum.participation(vectors, m), rtol=1e-14, atol=0)
    used = [w for w in pool.started if shared.key in w.held]
    assert 1 <= len(used) <= 2 and len(pool.started) <= 2
    assert all(list(w.held).count(shared.key) == 1 for w in used)
    big = [s for s in counting.sizes if s > vectors.nbytes]
    assert len(counting.sizes) == len(masses)  # one payload per task (replies are unpickled, not counted)
    assert len(big) == len(used)  # the array travelled once to each worker that ran a task, then by key
    assert all(s < 10_000 for s in counting.sizes if s <= vectors.nbytes)
    # reused in a second map: sent no more
    counting = _CountingPickle()
    monkeypatch.setattr(workers, "pickle", counting)
    again = pool.map("continuation.spectrum", [("participation", (shared, m)) for m in masses])
    monkeypatch.undo()
    assert all(np.array_equal(a, b) for a, b in zip(again, out))
    assert sum(s > vectors.nbytes for s in counting.sizes) == sum(1 for w in pool.started if w not in used)


def test_shared_objects_beyond_the_cache_are_sent_again_and_stay_right(pool):
    """More distinct shared objects than CACHE_SIZE, reused in turn: the caller's mirror of each worker's cache
    stays right (a wrong ``_Ref`` would fail with a KeyError in the worker), and every result is right."""
    rng = np.random.default_rng(1)
    mats = [sp.csc_matrix(sp.diags(rng.uniform(-1, 1, 8), 0) + sp.diags(np.ones(7), 1)) for _ in range(11)]
    shares = [Shared(m) for m in mats]
    assert len(shares) > workers.CACHE_SIZE
    order = [i % len(shares) for i in range(3 * len(shares))] + [0, 10, 0, 10, 5]
    tasks = [("_interleaved", (4,))] + [("inertia", (shares[i],)) for i in order]
    out = pool.map("continuation.slicing", tasks)
    for i, got in zip(order, out[1:]):
        want = slicing.inertia(mats[i])
        assert {k: got[k] for k in ("positive", "negative", "zero")} == {
            k: want[k] for k in ("positive", "negative", "zero")
        }
    for w in pool.started:
        assert len(w.held) <= workers.CACHE_SIZE and len(set(w.held)) == len(w.held)


def test_a_shared_operator_in_a_slice_task(pool):
    """The real use: one block's operator and Krein form shared by the slices of two segments, in two workers:
    every eigenvalue of each segment, as in process."""
    rng = np.random.default_rng(2)
    values = rng.uniform(-1.0, 1.0, 120)
    op = sp.csc_matrix(sp.diags(values))
    form = sp.csc_matrix(sp.diags(np.sign(rng.standard_normal(120))))
    shared = (Shared(op), Shared(form), Shared(None))
    cuts = slicing.segments(4)
    tasks = [("slice_task", (*shared, lo, hi, 32, 1.0, float("nan"))) for lo, hi in cuts]
    reports = pool.map("continuation.slicing", tasks)
    mu = np.sort(np.concatenate([r["mu"].real for r in reports]))
    assert np.max(np.abs(mu - np.sort(values))) <= 1e-13
    local = [slicing.slice_task(op, form, None, lo, hi, 32, 1.0, float("nan")) for lo, hi in cuts]
    for r, want in zip(reports, local):
        assert np.allclose(np.sort(r["mu"].real), np.sort(want["mu"].real), atol=1e-14, rtol=0)
        assert r["shifts"] == want["shifts"]
