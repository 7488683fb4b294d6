"""Work queued for one device stays on that device's streams, whatever Warp's current device is (issue #49).

Warp's ``wp.record_event(event)`` (like ``wp.wait_event``, ``wp.get_stream()``, an allocation or a launch without a
device) acts on the current device, which is process-wide: ``cuda:0`` in a Dask worker thread that drives ``cuda:1``.
The guard recorded its events that way, and the breakup sweep over two GPUs died with "Event from device cuda:1
cannot be recorded on stream from device cuda:0". CI has no GPU, and Warp's CPU device has no streams or events, so
no CPU run reaches those calls; the CPU tests here read the engine's sources for calls that lean on the current
device and drive the guard's reader through a stand-in of Warp's stream API as a two-GPU process sees it. The last
test runs on a GPU only (skipped elsewhere): the current device set to another one than the run's."""

import ast
from pathlib import Path

import numpy as np
import pytest

import warpchain
from warpchain.engine.devices import record_on
from warpchain.engine.runner import _GuardReader

SOURCES = sorted(Path(warpchain.__file__).parent.rglob("*.py"))

#: Warp functions that always act on the current device's current stream (no device argument): never in warpchain
CURRENT_ONLY = {"record_event", "wait_event", "wait_stream", "set_device", "ScopedDevice", "ScopedStream"}
#: Warp functions whose first parameter is the device (or stream); without it they take the current device
DEVICE_FIRST = {
    "get_stream",
    "get_device",
    "set_stream",
    "synchronize_device",
    "synchronize_stream",
    "capture_begin",
    "capture_end",
    "ScopedCapture",
    "Event",
    "Stream",
}
#: Warp functions that allocate or launch on the current device unless given ``device=``
DEVICE_KEYWORD = {"empty", "zeros", "ones", "full", "array", "from_numpy", "launch", "launch_tiled"}


def _is_warp(node) -> bool:
    """``wp`` or ``<anything>.wp`` (the runner's ``self.wp``, ``runner.wp``, ``r.wp``)."""
    return (isinstance(node, ast.Name) and node.id == "wp") or (isinstance(node, ast.Attribute) and node.attr == "wp")


def _in_kernel_code(func) -> bool:
    """A ``@wp.func`` / ``@wp.kernel`` (its ``wp.array(...)`` is device code or a type, not an allocation)."""
    for dec in func.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if isinstance(target, ast.Attribute) and _is_warp(target.value) and target.attr.startswith(("func", "kernel")):
            return True
    return False


def _current_device_calls(tree) -> list[tuple[int, str]]:
    """(line, call) of every Warp call in ``tree`` that relies on the current device."""
    found = []

    def visit(node, in_kernel: bool):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            in_kernel = in_kernel or _in_kernel_code(node)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and _is_warp(node.func.value):
            name, keywords = node.func.attr, {k.arg for k in node.keywords}
            if name in CURRENT_ONLY:
                found.append((node.lineno, name))
            elif name in DEVICE_FIRST and not node.args and not keywords & {"device", "stream", "stream_or_device"}:
                found.append((node.lineno, name))
            elif name in DEVICE_KEYWORD and not in_kernel and "device" not in keywords:
                # a bare ``wp.array(dtype=...)`` is a type (an argument annotation), not an allocation
                if name != "array" or node.args or "data" in keywords:
                    found.append((node.lineno, name))
        for child in ast.iter_child_nodes(node):
            visit(child, in_kernel)

    visit(tree, False)
    return found


def test_the_scan_finds_what_the_guard_did_before_the_fix():
    source = """
class _GuardReader:
    def record(self, i):
        self.wp.record_event(self.events[i % 2])

def launches():
    wp.record_event(events[0])
    a = wp.zeros(3, dtype=wp.float64)
    s = wp.get_stream()
    wp.launch(kernel, dim=3, inputs=[a])

def fine(runner, device):
    wp.get_stream(device).record_event(events[0])
    runner.wp.zeros(3, dtype=wp.float64, device=device)
    wp.synchronize_device(device)

Array = wp.array(dtype=wp.float64)
"""
    assert [name for _, name in _current_device_calls(ast.parse(source))] == [
        "record_event",
        "record_event",
        "zeros",
        "get_stream",
        "launch",
    ]


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(Path(warpchain.__file__).parent)))
def test_no_warp_call_in_warpchain_relies_on_the_current_device(path):
    """Every stream, event, capture, allocation and launch names its device: a worker thread driving cuda:1 in a
    process whose current device is cuda:0 queues its work on cuda:1 (issue #49)."""
    calls = _current_device_calls(ast.parse(path.read_text(), filename=str(path)))
    assert not calls, f"{path.name}: Warp calls on the current device, not the work's: {calls}"


class _Event:
    def __init__(self, device, enable_timing=False):
        self.device = device


class _Stream:
    """Warp's ``Stream.record_event``, with its check that the event is of the stream's device."""

    def __init__(self, device):
        self.device, self.recorded = device, []

    def record_event(self, event=None, external=False):
        if event is None:
            event = _Event(self.device)
        elif event.device != self.device:
            raise RuntimeError(
                f"Event from device {event.device} cannot be recorded on stream from device {self.device}"
            )
        self.recorded.append(event)
        return event


class _TwoGpuWarp:
    """The part of Warp's API the guard's reader uses, as a process with two GPUs sees it: ``get_stream()``,
    ``record_event`` (on the current stream) and ``Event`` without a device use the current device, cuda:0.
    Device names of their own, so that nothing here meets the real staging pool's buffers."""

    float64 = np.float64
    current = "stub-cuda:0"

    def __init__(self):
        self.streams = {d: _Stream(d) for d in ("stub-cuda:0", "stub-cuda:1")}

    def get_stream(self, device=None):
        return self.streams[self.current if device is None else device]

    def record_event(self, event=None, external=False):
        return self.get_stream().record_event(event, external)

    def Event(self, device=None, enable_timing=False):  # noqa: N802 (Warp's name)
        return _Event(self.current if device is None else device, enable_timing)

    def empty(self, shape, dtype=float, device=None, pinned=False):
        assert device == "cpu"  # the reader's host buffers
        return np.empty(shape, dtype=dtype)


class _RunnerOn:
    """What the guard's reader takes from a runner: its Warp, device and batch."""

    def __init__(self, wp, device: str, batch: int):
        self.wp, self.device, self.batch = wp, device, batch


def test_the_stand_in_fails_as_warp_did_in_the_sweep():
    wp = _TwoGpuWarp()
    with pytest.raises(RuntimeError, match="Event from device stub-cuda:1 cannot be recorded on stream from device"):
        wp.record_event(wp.Event("stub-cuda:1"))


def test_record_on_uses_the_named_devices_stream():
    wp = _TwoGpuWarp()
    event = wp.Event("stub-cuda:1")
    assert record_on(wp, "stub-cuda:1", event) is event
    assert wp.streams["stub-cuda:1"].recorded == [event] and wp.streams["stub-cuda:0"].recorded == []
    fresh = record_on(wp, "stub-cuda:1")  # no event: a new one of that device
    assert fresh.device == "stub-cuda:1" and wp.streams["stub-cuda:1"].recorded == [event, fresh]


def test_the_guard_reader_records_on_its_runners_device_not_the_current_one():
    """The call that failed in the breakup sweep's cuda:1 worker (``_GuardReader.record``), on a runner of the second
    GPU while the current device is the first."""
    wp = _TwoGpuWarp()
    reader = _GuardReader(_RunnerOn(wp, "stub-cuda:1", batch=3), gpu=True, kept=True)
    for i in range(3):
        reader.record(i)
    assert wp.streams["stub-cuda:0"].recorded == []
    assert wp.streams["stub-cuda:1"].recorded == [reader.events[0], reader.events[1], reader.events[0]]


def _cuda_devices() -> list[str]:
    from warpchain.engine.devices import available_devices

    return [d for d in available_devices() if d.startswith("cuda")]


@pytest.mark.skipif(not _cuda_devices(), reason="needs a GPU (CI has none: the tests above stand in for it)")
def test_runs_on_a_gpu_while_the_current_device_is_another():
    """simulate (plain, recording, sliced, kept on the device), propagate_tangent and a Flow's run and columns (graph
    replays) on the last GPU while Warp's current device is the CPU (with two GPUs: also cuda:0); the results equal
    those of the same runs with the current device untouched."""
    import warp as wp

    from conftest import localized_state
    from warpchain import ChainParams, Placement, Record, propagate_tangent, simulate
    from warpchain.engine import tuning
    from warpchain.flow import Flow

    target = _cuda_devices()[-1]
    p = ChainParams(30.0, 160.0, 41)
    x0 = localized_state(p.N, amplitude=0.8, batch=4, seed=3)
    dx0 = np.eye(4 * p.N)[:6].reshape(6, 4, p.N)

    def runs():
        out = []
        for every in (None, 10):
            record = Record(every=every) if every else None
            run = simulate(p, x0, 2.0, 0.02, method="kahan8", device=target, record=record)
            out += [run.x, run.energy_trace] + ([run.u, run.v] if every else [])
        with tuning.override(sliced_min_values=1, slices=2):
            out.append(simulate(p, x0, 2.0, 0.02, method="kahan8", device=target).x)
        kept = simulate(p, x0, 2.0, 0.02, method="kahan8", device=target, placement=Placement(keep_on_device=True))
        out.append(simulate(p, kept.x, 2.0, 0.02, method="kahan8").x)  # from the DeviceState, on its device
        tangent = propagate_tangent(p, x0[:1], dx0, 50, 0.02, method="verlet", device=target)
        out += [tangent.x, tangent.columns]
        flow = Flow("kahan8", 32, device=target)
        out.append(flow.run(p, x0, 16, 0.02).x_end)
        lin = flow.linearize(p, x0[:1], 16, 0.02)
        out += [lin.columns(dx0) for _ in range(3)]  # the third call replays a captured graph
        return out

    expected = runs()
    for current in ["cpu"] + [d for d in _cuda_devices() if d != target]:
        with wp.ScopedDevice(current):
            got = runs()
        assert len(got) == len(expected)
        for e, g in zip(expected, got):
            assert np.array_equal(e, g), current
