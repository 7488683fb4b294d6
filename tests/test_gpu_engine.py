"""The engine around the kernels (run here on the CPU; the same code path drives a GPU): the guard
reduced on the device (energy, finite flag, min contact), frames written into preallocated results,
the chunk count chosen from the work, and the arithmetic shared with the numpy reference (1/M)."""

import numpy as np
import pytest

from conftest import SPLITTING, localized_state
from warpchain import BOUNDARIES, Guard, Placement, Record
from warpchain import ChainParams, IntegrationError, energy, propagate_tangent, reference, simulate
from warpchain.engine import hostmem, tuning
from warpchain.engine.devices import _warp
from warpchain.engine.runner import _GuardReader, _Runner
from warpchain.flow import Flow, ReferenceFlow
from warpchain.integrators import get_method
from warpchain.model import min_contact

LAYOUTS = ["thread", "block", "sites"]


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("method", SPLITTING)
def test_cpu_results_bit_for_bit_with_the_reference(method, layout):
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=3, seed=3)
    M, K = np.array([30.0, 10.0, 50.0]), np.array([160.0, 40.0, 100.0])
    run = simulate(
        p,
        x0,
        200 * 0.02,
        0.02,
        method=method,
        device="cpu",
        M=M,
        K=K,
        record=Record(every=50),
        placement=Placement(layout=layout),
    )
    ref = reference.integrate(method, p, x0, 0.02, 200, M=M, K=K, save_every=50)
    assert np.array_equal(run.x, ref["x"]) and np.array_equal(run.u, ref["u"]) and np.array_equal(run.v, ref["v"])
    # the guard's energies (reduced on the device) agree with model.energy to rounding
    assert np.allclose(run.energy_final, energy(p, run.x, M, K), rtol=1e-13, atol=0)
    assert np.allclose(run.energy_initial, energy(p, x0, M, K), rtol=1e-13, atol=0)
    # min contact over the recorded frames and the chunk ends, as computed on the host before
    expected = np.minimum(np.min(1 + ref["u"] - ref["v"], axis=(0, 2)), min_contact(run.x))
    assert np.array_equal(run.min_contact, expected)


def test_reference_multiplies_by_the_inverse_mass():
    p = ChainParams(3.0, 4.0, 9)
    x = localized_state(p.N, amplitude=0.7, batch=2, seed=1)
    inv = reference.inverse_mass(np.array([3.0, 7.0]))
    acc = reference.accelerations(p, x, inv, np.array([4.0, 5.0]))
    from warpchain.model import accelerations

    divided = accelerations(p, x, np.array([3.0, 7.0]), np.array([4.0, 5.0]))
    assert np.allclose(acc, divided, rtol=1e-15, atol=1e-15) and np.array_equal(acc[:, 1], divided[:, 1])


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_guard_kernel_energy_finite_and_contact(boundary, layout):
    p = ChainParams(3.0, 4.0, 17, boundary)
    x0 = localized_state(p.N, amplitude=1.5, batch=3, centre=2, seed=5)
    x0[0, 1, 3] = 2.0  # lattice 0 has lost contact at site 3
    x0[2, 3, 4] = np.nan
    M, K = np.array([3.0, 2.0, 5.0]), np.array([4.0, 1.0, 6.0])
    runner = _Runner(get_method("verlet"), p, x0, M, K, "cpu", layout=layout)
    out = runner.guard().numpy()
    assert np.allclose(out[:2, 0], energy(p, x0[:2], M[:2], K[:2]), rtol=1e-13, atol=0)
    assert out[:, 1].tolist() == [1.0, 1.0, 0.0]
    assert np.array_equal(out[:2, 2], min_contact(x0[:2])) and out[0, 2] < 0
    # frames enter the running min; a later guard keeps the lowest value seen
    rec = runner.frames(2)
    frames = np.zeros((2, 3, p.N))
    frames[1, 1, 3] = -5.0
    rec[0].assign(frames)
    rec[1].assign(np.zeros((2, 3, p.N)))
    out = runner.guard(rec, 2).numpy()
    assert out[1, 2] == -4.0 and out[0, 2] == min_contact(x0[:1])[0]


def test_chunk_count_comes_from_the_work():
    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.1, batch=2)
    small = simulate(p, x0, 100 * 0.1, 0.1, device="cpu")  # 4200 site-steps, far below a chunk's work
    assert tuning.active().chunk_work > 4200 and small.energy_t.tolist() == [0.0, small.t_final]
    with tuning.override(chunk_work=2 * p.N * 100):  # a chunk: 100 steps of both lattices
        assert simulate(p, x0, 250 * 0.1, 0.1, device="cpu").energy_t.shape == (4,)  # 3 chunks
        assert simulate(p, x0, 100 * 0.1, 0.1, device="cpu", guard=Guard(chunks=5)).energy_t.shape == (6,)  # as asked
        assert simulate(p, x0, 5000 * 0.1, 0.1, device="cpu").energy_t.shape == (11,)  # at most 10


def test_on_chunk_gets_read_only_views_of_the_results(small_chain):
    x0 = localized_state(small_chain.N, batch=2)
    seen = []

    def keep(t, u, v):
        assert not u.flags.writeable and not v.flags.writeable
        seen.append((t.copy(), u.copy(), v.copy()))

    run = simulate(
        small_chain, x0, 3.0, 0.1, device="cpu", record=Record(every=3, on_chunk=keep), guard=Guard(chunks=4)
    )
    assert np.array_equal(np.concatenate([s[1] for s in seen]), run.u)
    assert np.array_equal(np.concatenate([s[2] for s in seen]), run.v)
    assert np.array_equal(np.concatenate([s[0] for s in seen]), run.t)
    assert run.u.flags.writeable  # the result itself is the caller's


def test_blow_up_is_caught_at_the_chunk_where_it_happens():
    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.1, batch=2)
    K = np.array([10.0, 160.0])
    with pytest.warns(RuntimeWarning):
        with pytest.raises(IntegrationError) as info:
            simulate(p, x0, 400.0, 0.5, device="cpu", K=K, guard=Guard(allow_unstable_step=True, chunks=10))
    assert info.value.failed == [1] and info.value.t < 400.0  # before the end: chunks are checked in turn


@pytest.mark.parametrize("layout", LAYOUTS)
def test_flow_min_contact_reduced_on_the_device_matches_the_reference(layout):
    p = ChainParams(3.0, 4.0, 11)
    x0 = localized_state(p.N, amplitude=1.2, batch=2, seed=2)
    flow = Flow("yoshida4", 16, device="cpu", layout=layout)
    ref = ReferenceFlow("yoshida4", 16)
    a, b = flow.run(p, x0, 40, 0.05), ref.run(p, x0, 40, 0.05)
    assert np.array_equal(a.x_end, b.x_end) and np.array_equal(a.min_contact, b.min_contact)
    la, lb = flow.linearize(p, x0[:1], 40, 0.05), ref.linearize(p, x0[:1], 40, 0.05)
    assert la.min_contact == lb.min_contact
    d = np.eye(4 * p.N)[:5].reshape(5, 4, p.N)
    assert np.array_equal(la.columns(d), lb.columns(d))
    # the unit columns (directions made once on the device, buffers reused) against the reference's, and
    # a trial run on the same Flow in between (the history is replayed for the older linearization)
    vel = la.unit_columns("velocities")
    flow.linearize(p, x0[1:], 40, 0.05).unit_columns("positions")
    flow.linearize(p, x0[1:], 40, 0.05)
    pos = la.unit_columns("positions")
    assert np.array_equal(pos, lb.unit_columns("positions")) and np.array_equal(vel, lb.unit_columns("velocities"))
    assert np.array_equal(la.unit_columns("all"), np.hstack([pos, vel])) and la.unit_columns("positions") is pos
    assert la.stats["tangent_columns"] == 5 + 4 * p.N


@pytest.mark.parametrize(
    "method,layout,threads",
    [("kahan8", "block", "1"), ("yoshida4", "thread", "1"), ("verlet", "block", "1"), ("kahan6", "thread", "3")],
)
def test_flow_replayed_as_a_graph_bit_for_bit(method, layout, threads, monkeypatch):
    """The Flow's base runs and unit columns are captured into a graph from their second call with the same
    (step count, dt) and replayed (``_Replay``; a CUDA graph on a GPU, Warp's CPU graph here, on one CPU
    thread as on a GPU's one slice, or on three, whose slices are captured in turn on the capturing thread):
    every replay gives the reference's bits, for new states, new parameters, a new dt and an older
    linearization's history replayed in between."""
    with tuning.override(graphs_on_cpu=True):
        monkeypatch.setenv("WARPCHAIN_CPU_THREADS", threads)
        p, q = ChainParams(30.0, 160.0, 21), ChainParams(20.0, 100.0, 21)
        x0 = localized_state(p.N, amplitude=0.3, batch=2, seed=4)
        flow, ref = Flow(method, 16, device="cpu", layout=layout), ReferenceFlow(method, 16)
        cases = [(p, x0[:1], 0.05), (p, x0[1:], 0.05), (p, x0[:1], 0.04), (q, x0[:1], 0.05), (p, x0[1:], 0.05)] * 2
        older = None
        for params, x, dt in cases:
            a, b = flow.linearize(params, x, 8, dt), ref.linearize(params, x, 8, dt)
            assert np.array_equal(a.x_end, b.x_end) and a.min_contact == b.min_contact
            assert np.array_equal(a.unit_columns("positions"), b.unit_columns("positions"))
            assert np.array_equal(a.unit_columns("all"), b.unit_columns("all"))
            run, run_ref = flow.run(params, x0, 8, dt), ref.run(params, x0, 8, dt)
            assert np.array_equal(run.x_end, run_ref.x_end) and np.array_equal(run.min_contact, run_ref.min_contact)
            if older is not None:  # the older point's buffers went to other runs since: its history is re-run
                assert np.array_equal(older[0].unit_columns("velocities"), older[1].unit_columns("velocities"))
            older = (a, b)
        replays = [r for slot in flow._pool.values() for runner in slot["runners"] for r in runner._replays.values()]
        assert sum(r.graph is not None for r in replays) >= 4  # base runs and columns were replayed as graphs
        assert all(r.issued >= 1 for r in replays)


def test_host_copy_helpers_and_buffer_pool():
    src = np.arange(3 * (1 << 19), dtype=np.float64).reshape(3, -1)  # large enough to be split
    dst = np.empty_like(src)
    hostmem._copy(dst, src)
    assert np.array_equal(dst, src)
    hostmem._fill_zero(dst)
    assert not dst.any()
    wp = _warp()
    with hostmem._STAGING_LOCK:  # earlier tests may have left buffers of other sizes in the pool
        hostmem._STAGING_POOL.pop(("cpu", False), None)
    a = hostmem._take_buffer(wp, "cpu", 1000, False)
    assert a.shape[0] >= 1000
    hostmem._give_buffer("cpu", False, a)
    assert hostmem._take_buffer(wp, "cpu", 500, False) is a  # reused, not allocated again
    t = hostmem._prefault((4, 5))
    t.join()
    assert t.result.shape == (4, 5) and not t.result.any()


@pytest.mark.parametrize("layout", LAYOUTS)
def test_kernels_take_coefficients_from_the_method_type(layout):
    """A splitting not in METHODS runs through the same launch plans: the kernels read the coefficients the
    method owns (bit for bit with the reference on the CPU). A Runge-Kutta tableau runs on the reference only."""
    from warpchain.integrators import RungeKuttaMethod, SplittingMethod, _composition

    p = ChainParams(3.0, 4.0, 13)
    x0 = localized_state(p.N, amplitude=0.6, batch=2, seed=7)
    rk = RungeKuttaMethod(
        "rk-test", 2, False, "a made-up tableau", nodes=(0.25, 0.5, 1.0), weights=(1.0, 3.0, 1.0, 1.0)
    )
    split = SplittingMethod("split-test", 2, True, "two half Verlet steps", *_composition((0.5, 0.5)))
    assert rk.force_evaluations == 4 and split.force_evaluations == 2 and rk.family == "rk4"
    run = simulate(p, x0, 50 * 0.05, 0.05, method=split, device="cpu", placement=Placement(layout=layout))
    assert np.array_equal(run.x, reference.integrate(split, p, x0, 0.05, 50)["x"])
    with pytest.raises(ValueError, match="'rk-test' is not a splitting method"):
        simulate(p, x0, 50 * 0.05, 0.05, method=rk, device="cpu", placement=Placement(layout=layout))
    assert not np.array_equal(
        reference.integrate(rk, p, x0, 0.05, 5)["x"], reference.integrate("rk4", p, x0, 0.05, 5)["x"]
    )


def test_guard_reader_kept_with_the_runner():
    """``simulate`` keeps one guard reader per runner: the same object on the next call, whose ``close``
    keeps its buffers (a pooled GPU runner then makes no events or pinned buffers per call)."""
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=3, seed=2)
    runner = _Runner(get_method("verlet"), p, x0, np.full(3, p.M), np.full(3, p.K), "cpu")
    reader = _GuardReader.of(runner, False)
    reader.close()
    assert _GuardReader.of(runner, False) is reader and reader.kept
    assert not _GuardReader(runner, False).kept


def test_frames_go_straight_into_page_locked_results(small_chain):
    """Frames into arrays that view page-locked Warp memory (``frame_buffers`` on a GPU) are copied off the
    device straight into them, at the views' offsets; emulated on the CPU with a Warp host array marked
    pinned. ``frame_buffers`` gives simulate's frame shape (plain arrays on the CPU)."""
    import warp as wp

    from warpchain import frame_buffers
    from warpchain.engine.hostmem import _FrameSink, _pinned_view

    p = small_chain
    u, v = frame_buffers(p, 3, 40 * 0.05, 0.05, 10, device="cpu")
    assert u.shape == v.shape == (5, 3, p.N) and not np.shares_memory(u, v)
    assert _pinned_view(u) is None
    x0 = localized_state(p.N, amplitude=0.7, batch=3, seed=2)
    runner = _Runner(get_method("verlet"), p, x0, np.full(3, p.M), np.full(3, p.K), "cpu")
    base = [wp.zeros(7 + 5 * 3 * p.N, dtype=wp.float64, device="cpu") for _ in range(2)]
    for b in base:
        b.pinned = True  # what frame_buffers allocates on a GPU
    views = tuple(b.numpy()[7:].reshape(5, 3, p.N) for b in base)
    assert _pinned_view(views[0])[1] == 7
    assert _pinned_view(views[0][:, :, ::2]) is None  # a strided view is not one run of values
    sink = _FrameSink(runner, 5, 2, gpu=True, out=views)
    assert sink.direct is not None and sink.staging == []
    frames = [np.random.default_rng(k).normal(size=(2, 3, p.N)) for k in range(2)]
    for rec, f in zip(sink.rec, frames):
        rec.assign(f)
    sink.enqueue(2, 1, 3)
    sink.take(1, 3, 2)
    assert np.array_equal(views[0][3:5], frames[0]) and np.array_equal(views[1][3:5], frames[1])
    assert np.all(base[0].numpy()[:7] == 0) and np.all(views[0][:3] == 0)


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("sites", [1, 2, 7])
def test_several_sites_per_thread_bit_for_bit(boundary, sites):
    """``block_kernels.site_group_kernels`` (each thread owns a run of sites; the GPU's large-batch path),
    forced on the CPU: identical to the reference with per-lattice M and K, a lattice length that leaves
    idle slots, frames recorded; with losses; and the stiffness history of a tangent base run."""
    from warpchain.losses import Damping

    group = tuning.active().replace(sites_per_thread=sites, group_one_site=True)  # sites = 1: not block_kernels'
    p = ChainParams(3.0, 4.0, 37, boundary)
    x0 = localized_state(p.N, amplitude=0.7, batch=3, seed=9)
    M, K = np.array([3.0, 2.0, 5.0]), np.array([4.0, 1.0, 6.0])
    for method in ("verlet", "yoshida4"):
        with tuning.override(group):
            run = simulate(
                p,
                x0,
                80 * 0.05,
                0.05,
                method=method,
                device="cpu",
                M=M,
                K=K,
                placement=Placement(layout="block"),
                record=Record(every=20),
            )
        ref = reference.integrate(method, p, x0, 0.05, 80, M=M, K=K, save_every=20)
        assert np.array_equal(run.x, ref["x"]) and np.array_equal(run.u, ref["u"]), method
        assert np.array_equal(run.v, ref["v"]), method
    damping = Damping(np.array([0.0, 0.05, 0.02]), 0.01)
    with tuning.override(group):
        run = simulate(
            p, x0, 1.0, 0.05, method="kahan6", device="cpu", damping=damping, placement=Placement(layout="block")
        )
    ref = reference.integrate("kahan6", p, x0, run.dt, run.nsteps, damping=damping)["x"]
    assert np.array_equal(run.x, ref)
    histories = {}
    for forced in (None, sites):
        with tuning.override(sites_per_thread=forced, group_one_site=forced is not None):
            runner = _Runner(get_method("yoshida4"), p, x0, M, K, "cpu", record_stiffness_steps=6, layout="block")
            runner.launch(6, 0.05, record_stiffness=True)
        histories[forced] = (runner.hist.numpy().copy(), runner.x.numpy().copy())
    assert np.array_equal(histories[None][0], histories[sites][0])
    assert np.array_equal(histories[None][1], histories[sites][1])


def test_sites_per_thread_policy():
    from warpchain.engine import site_group_kernels
    from warpchain.engine.plans import site_group_launch, sites_per_thread

    assert sites_per_thread(1, 201, 1, "cpu") == 1  # the CPU default path is the thread layout anyway
    assert sites_per_thread(32768, 201, 1, "cpu") == 1
    assert sites_per_thread(32768, 201, 1, "cuda") == 7 and sites_per_thread(32768, 201, 3, "cuda") == 7
    assert sites_per_thread(805, 201, 1, "cuda") == 1 and sites_per_thread(32768, 201, 15, "cuda") == 1
    assert sites_per_thread(32768, 1001, 1, "cuda") == 8 and sites_per_thread(32768, 41, 1, "cuda") == 2
    assert site_group_launch(1, 1, "cuda") and not site_group_launch(1, 15, "cuda")
    assert not site_group_launch(1, 1, "cpu") and site_group_launch(7, 1, "cpu")
    assert site_group_kernels.group_threads(201, 7) == 32 and site_group_kernels.group_threads(201, 2) == 128
    with pytest.raises(ValueError, match="sites per thread"):
        site_group_kernels.site_group_kernels(32, 9, 0)


def test_frames_out_receives_the_recording(small_chain):
    """Frames recorded into the caller's arrays (allocated once by an ensemble study) equal a plain run's,
    and the result's u and v are those arrays; misuse is refused at the boundary."""
    p = small_chain
    x0 = localized_state(p.N, amplitude=0.7, batch=3, seed=2)
    plain = simulate(p, x0, 40 * 0.05, 0.05, device="cpu", record=Record(every=10))
    u, v = np.full_like(plain.u, np.nan), np.full_like(plain.v, np.nan)
    run = simulate(p, x0, 40 * 0.05, 0.05, device="cpu", record=Record(every=10, into=(u, v)))
    assert run.u is u and run.v is v
    assert np.array_equal(u, plain.u) and np.array_equal(v, plain.v) and np.array_equal(run.x, plain.x)
    with pytest.raises(ValueError, match="give save_every"):
        simulate(p, x0, 1.0, 0.05, device="cpu", frames_out=(u, v))
    with pytest.raises(ValueError, match=r"shape \(5, 3, "):
        simulate(p, x0, 40 * 0.05, 0.05, device="cpu", record=Record(every=10, into=(u[:4], v)))
    with pytest.raises(ValueError, match="share memory"):
        simulate(p, x0, 40 * 0.05, 0.05, device="cpu", record=Record(every=10, into=(u, u)))


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_block_tangent_columns_bit_for_bit(boundary):
    """The block tangent kernel (a block per column, the history loaded one force evaluation ahead): an odd
    column count, columns of two base lattices with their own M and K, a many-stage method (its register-capped
    build) and Verlet; the same bits as the thread layout."""
    p = ChainParams(3.0, 4.0, 37, boundary)
    x0 = localized_state(p.N, amplitude=0.7, batch=2, seed=5)
    eye = np.eye(4 * p.N).reshape(4 * p.N, 4, p.N)
    dx0 = np.concatenate([eye[:25], eye[40:64]])
    base = np.repeat([0, 1], [25, 24])
    M, K = np.array([3.0, 2.0]), np.array([4.0, 6.0])
    for method in ("verlet", "kahan8"):
        cols = {
            layout: propagate_tangent(
                p, x0, dx0, 5, 0.05, method=method, column_base=base, M=M, K=K, device="cpu", layout=layout
            ).columns
            for layout in ("block", "thread")
        }
        assert np.array_equal(cols["block"], cols["thread"]), method


@pytest.mark.parametrize("method", ["verlet", "kahan8"])
def test_kept_launch_commands_match_plain_launches(method):
    """Launch commands kept per argument values (``_Runner.launch_kernel``: always on a GPU, forced here on
    the CPU) give the plain launches' bits; a changed argument (dt, steps, a slot) makes a new command, a
    repeated one reuses its command, and at most ``Tuning.commands_per_runner`` are kept."""
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=5, seed=3)
    M, K = np.full(5, 30.0), np.array([160.0, 40.0, 100.0, 160.0, 80.0])
    kwargs = dict(
        method=method,
        device="cpu",
        M=M,
        K=K,
        guard=Guard(chunks=3),
        placement=Placement(layout="block"),
        record=Record(every=5),
    )
    plain = [simulate(p, x0, 30 * dt, dt, **kwargs) for dt in (0.02, 0.03)]
    with tuning.override(commands_on_cpu=True):
        kept = [simulate(p, x0, 30 * dt, dt, **kwargs) for dt in (0.02, 0.03)]
    for a, b in zip(plain, kept):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u) and np.array_equal(a.min_contact, b.min_contact)
        assert np.array_equal(a.energy_trace, b.energy_trace)

    def sequence(runner):
        runner.launch(10, 0.02)
        runner.launch(10, 0.02)
        runner.launch(10, 0.03)
        runner.guard(slot=1)
        runner.launch(7, 0.02)
        return runner.x.numpy().copy(), runner.guard_out[1].numpy().copy()

    make = lambda: _Runner(get_method(method), p, x0, M, K, "cpu", layout="block")  # noqa: E731
    expected = sequence(make())
    with tuning.override(commands_on_cpu=True):
        runner = make()
        got = sequence(runner)
        assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])
        assert len(runner._commands) == 4  # (10, 0.02) once for two launches, (10, 0.03), the guard, (7, 0.02)
        with tuning.override(commands_per_runner=2):
            runner.launch(11, 0.02)
        assert len(runner._commands) == 2


def test_frames_out_must_not_share_memory_with_x0(small_chain):
    p = small_chain
    x0 = localized_state(p.N, amplitude=0.7, batch=2, seed=1)
    store = np.zeros((2, 3, 2, p.N))
    x0_view = store.reshape(-1)[: x0.size].reshape(x0.shape)
    x0_view[...] = x0
    with pytest.raises(ValueError, match="must not share memory with x0"):
        simulate(p, x0_view, 20 * 0.05, 0.05, device="cpu", record=Record(every=10, into=(store[0], store[1])))


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_run_continued_on_the_device_gives_the_same_bits(layout):
    """``Placement(keep_on_device=True)`` leaves the final state on the device (a ``DeviceState``); passed back as x0 it
    is copied device to device. Chained that way, runs give the bits of the same runs through host arrays,
    recorded frames and energies included; zero steps return x0; misuse is refused with the reason."""
    from warpchain import DeviceState

    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=4, seed=7)
    kwargs = dict(device="cpu", placement=Placement(layout=layout), guard=Guard(chunks=2))
    on_device = dict(kwargs, placement=Placement(layout=layout, keep_on_device=True))
    first = simulate(p, x0, 40 * 0.02, 0.02, **kwargs)
    second = simulate(p, first.x, 40 * 0.02, 0.02, **kwargs, record=Record(every=10))
    kept = simulate(p, x0, 40 * 0.02, 0.02, **on_device)
    assert isinstance(kept.x, DeviceState) and kept.x.shape == x0.shape and kept.x.device == "cpu"
    assert kept.stats["kept_on_device"] and not kept.stats["x0_on_device"]
    assert np.array_equal(kept.x.numpy(), first.x) and np.array_equal(np.asarray(kept.x), first.x)
    again = simulate(p, kept.x, 40 * 0.02, 0.02, **on_device, record=Record(every=10))
    assert again.stats["x0_on_device"] and isinstance(again.x, DeviceState)
    assert np.array_equal(again.x.numpy(), second.x)
    assert np.array_equal(again.u, second.u) and np.array_equal(again.v, second.v)
    assert np.array_equal(again.energy_trace, second.energy_trace)
    assert np.array_equal(again.min_contact, second.min_contact)
    host = simulate(p, kept.x, 40 * 0.02, 0.02, **kwargs)  # from the device back to the host
    assert isinstance(host.x, np.ndarray) and np.array_equal(host.x, second.x)
    assert np.array_equal(kept.x.numpy(), first.x)  # x0 is never written
    still = simulate(p, kept.x, 0.0, 0.02, **on_device)
    assert np.array_equal(still.x.numpy(), first.x)
    with pytest.raises(ValueError, match="does not fit a chain of N = 40"):
        simulate(ChainParams(30.0, 160.0, 40), kept.x, 0.2, 0.02, device="cpu")
    with pytest.raises(ValueError, match="unknown or unavailable device"):
        simulate(p, kept.x, 0.2, 0.02, device="cuda:7")
    bad = x0.copy()
    bad[1, 2, 5] = np.inf
    with pytest.raises(ValueError, match=r"non-finite entries in lattice\(s\) \[1\]"):
        simulate(p, DeviceState.of(bad, device="cpu"), 0.2, 0.02, **kwargs)
    with pytest.raises(ValueError, match="shape"):
        DeviceState.of(np.zeros((3, 5)), device="cpu")
    with pytest.raises(TypeError, match="Warp array"):
        DeviceState(np.zeros((1, 4, 5)))


@pytest.mark.parametrize("layout", LAYOUTS)
def test_sliced_transfers_give_the_same_run(layout):
    """The GPU path for large batches (state moved in lattice slices, the first and last chunks run
    slice by slice), forced here on the CPU: the same results, errors and traces."""
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=6, seed=3)
    M = np.array([30.0, 10.0, 50.0, 30.0, 20.0, 40.0])
    kwargs = dict(method="yoshida4", device="cpu", M=M, placement=Placement(layout=layout))
    plain = simulate(p, x0, 60 * 0.02, 0.02, record=Record(every=10), guard=Guard(chunks=3), **kwargs)
    with tuning.override(slice_on_cpu=True, sliced_min_values=1, slices=4):
        for chunks in (3, 1):
            sliced = simulate(p, x0, 60 * 0.02, 0.02, record=Record(every=10), guard=Guard(chunks=chunks), **kwargs)
            assert sliced.stats["slices"] == 4
            assert np.array_equal(sliced.x, plain.x) and np.array_equal(sliced.u, plain.u)
            assert np.array_equal(sliced.min_contact, plain.min_contact)
            assert np.array_equal(sliced.energy_initial, plain.energy_initial)
        assert np.array_equal(sliced.energy_trace[[0, -1]], plain.energy_trace[[0, -1]])
        bad = x0.copy()
        bad[4, 2, 7] = np.inf
        with pytest.raises(ValueError, match=r"non-finite entries in lattice\(s\) \[4\]"):
            simulate(p, bad, 60 * 0.02, 0.02, guard=Guard(chunks=3), **kwargs)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_short_sliced_runs_default_to_two_chunks(layout):
    """A short run on a large batch (the GPU's sliced path, forced on the CPU) defaults to two chunks, whose
    kernels hide the slices' transfers, in one slice per ``Tuning.slice_lattices`` lattices: the same end
    state as a run in more chunks over the whole batch; a blow-up is still reported at a chunk end with its
    lattice; explicit chunks, progress bars and long runs keep their chunk counts."""
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=7, seed=3)
    M = np.array([30.0, 10.0, 50.0, 30.0, 20.0, 40.0, 25.0])
    kwargs = dict(method="yoshida4", device="cpu", M=M, placement=Placement(layout=layout))
    plain = simulate(p, x0, 60 * 0.02, 0.02, guard=Guard(chunks=4), **kwargs)
    # the work alone would ask for 10 chunks
    with tuning.override(slice_on_cpu=True, sliced_min_values=1, slice_lattices=2, chunk_work=1):
        run = simulate(p, x0, 60 * 0.02, 0.02, **kwargs)
        assert (run.stats["chunks"], run.stats["slices"]) == (2, 3)
        assert np.array_equal(run.x, plain.x) and np.array_equal(run.energy_t, [0.0, 0.6, 1.2])
        assert np.array_equal(run.energy_trace[[0, -1]], plain.energy_trace[[0, -1]])
        assert simulate(p, x0, 60 * 0.02, 0.02, guard=Guard(chunks=4), **kwargs).stats["chunks"] == 4
        assert simulate(p, x0, 60 * 0.02, 0.02, progress=True, **kwargs).stats["chunks"] == 30  # 2 steps each
        with tuning.override(short_run_evaluations=100):
            assert simulate(p, x0, 60 * 0.02, 0.02, **kwargs).stats["chunks"] == 10
        # a bound on the energy error that lattice 5 (last slice) crosses first
        drift = x0[[2, 2, 2, 2, 2, 5, 2]] * np.array([0.5, 0.5, 1, 0.5, 0.5, 1, 0.5])[:, None, None]
        drifting = dict(kwargs, M=np.array([50.0, 50.0, 50.0, 50.0, 50.0, 40.0, 50.0]))
        with pytest.raises(IntegrationError) as error:
            simulate(p, drift, 40 * 0.1, 0.1, guard=Guard(max_energy_error=1.5e-4), **drifting)
        assert error.value.t == 2.0 and error.value.failed == [5]


def test_a_short_run_on_a_large_batch_has_the_same_chunks_on_the_device():
    """A short run on a large batch runs in two chunks whether its state moves in slices (from a plain x0) or
    stays on the device: the same energy trace, the same bits (the sliced path emulated on the CPU)."""
    from warpchain import DeviceState

    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=4, seed=9)
    # the work alone would ask for 10 chunks
    with tuning.override(slice_on_cpu=True, sliced_min_values=1, slices=2, chunk_work=100):
        plain = simulate(p, x0, 40 * 0.02, 0.02, device="cpu")
        on_device = Placement(keep_on_device=True)
        kept = simulate(p, DeviceState.of(x0, device="cpu"), 40 * 0.02, 0.02, device="cpu", placement=on_device)
    assert plain.stats["slices"] == 2 and kept.stats["slices"] == 1
    assert plain.stats["chunks"] == kept.stats["chunks"] == 2
    assert np.array_equal(plain.energy_t, kept.energy_t) and np.array_equal(plain.energy_trace, kept.energy_trace)
    assert np.array_equal(plain.x, kept.x.numpy())


def test_a_dropped_flow_frees_its_runners_without_the_cycle_collector():
    """A runner's replays and plan hold it weakly, so the buffers of a Flow that goes out of scope (2 x 82 MB of
    unit directions and columns at N = 801) are freed at once, not when the cyclic collector runs: a scan that
    solved a breather per point (a new Flow each) grew to 6.7 GB in 40 s before."""
    import gc
    import weakref

    p = ChainParams(30.0, 160.0, 21)
    x0 = localized_state(p.N, amplitude=0.3, batch=1, seed=4)

    def linearize_and_drop():
        flow = Flow("yoshida4", 16, device="cpu")
        lin = flow.linearize(p, x0, 8, 0.05)
        lin.unit_columns("positions")
        lin.columns(np.ones((1, 4, p.N)))
        return [weakref.ref(r) for slot in flow._pool.values() for r in slot["runners"]]

    was = gc.isenabled()
    gc.disable()
    try:
        refs = linearize_and_drop()
        assert refs and all(r() is None for r in refs)
    finally:
        if was:
            gc.enable()
