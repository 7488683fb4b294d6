"""Deterministic demo tasks and their grid for the sweep tests (``test_sweep.py``): importable by the Dask workers
the tests start (their processes inherit this folder on ``sys.path``) and by the client the tests kill."""

import os

import numpy as np

from sweep import SweepSpec, Variable, runner


def _demo_task(index: dict, device: str, *, n_r: int = 4, n_f: int = 5, seed: int = 12345, fail_at=None) -> dict:
    """A deterministic numpy task for tests and examples (variables x (r, f), n (r,), y (), dev ()):
    seeded from ``seed`` and the task index; raises at ``fail_at`` (an index tuple) to test resume."""
    key = tuple(int(i) for i in index.values())
    if fail_at is not None and key == tuple(fail_at):
        raise RuntimeError(f"demo failure at {key}")
    rng = np.random.default_rng((seed, *key))
    x = rng.standard_normal((n_r, n_f))
    return {
        "x": x,
        "n": rng.integers(0, 1000, size=n_r, dtype=np.int32),
        "y": np.float64(x.sum()),
        "dev": np.int8(-1 if device == "cpu" else int(device.split(":")[1])),
    }


def _demo_warm_up(device: str, *, folder: str) -> None:
    """A warm-up for tests: writes ``folder/<pid>`` with the device it was given and the mmap threshold
    that :func:`host_allocator` set in this process."""
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, str(os.getpid())), "w") as fh:
        fh.write(f"{device} {runner._ALLOCATOR.get('mmap_threshold', 0) / 2**20:.1f} MiB")


def _demo_task_dying(index: dict, device: str, *, marker: str, at=(1, 0), **kwargs) -> dict:
    """``_demo_task``, except that at index ``at`` the first call kills its process (as SIGKILL would: no
    cleanup, no exception) after leaving ``marker``; the next call there runs normally."""
    key = tuple(int(i) for i in index.values())
    if key == tuple(at) and not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(9)
    return _demo_task(index, device, **kwargs)


def _demo_spec(
    group: str = "observables", n_a: int = 3, n_b: int = 2, n_r: int = 4, n_f: int = 5, **attrs
) -> SweepSpec:
    """The grid matching :func:`_demo_task`: task dims (a, b), per task (r, f)."""
    coords = {
        "a": np.linspace(0.1, 0.3, n_a),
        "b": np.arange(n_b, dtype=np.int64) * 10,
        "r": np.arange(n_r),
        "f": np.linspace(0.0, 1.0, n_f),
    }
    variables = {
        "x": Variable(("a", "b", "r", "f"), attrs={"long_name": "demo field"}),
        "n": Variable(("a", "b", "r"), dtype="int32", fill=-1),
        "y": Variable(("a", "b")),
        "dev": Variable(("a", "b"), dtype="int8", fill=-2),
    }
    return SweepSpec(group, coords, ("a", "b"), variables, attrs={"seed": 12345, **attrs})
