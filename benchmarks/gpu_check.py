"""Agreement of the Warp kernels on a GPU with the numpy reference (the CPU tests' checks, on CUDA).

Every method, both kernel layouts: 1000 steps of a localized large-amplitude state with per-lattice
(M, K), and 40 steps of tangent columns (full Jacobians of two base states); the Flow replayed as CUDA graphs
against its launches issued one by one; a run continued on the device (``keep_on_device``, a ``DeviceState``
x0) against the same runs through host arrays, plain and lent. Prints and writes the largest relative
differences as JSON.

Command: ``python benchmarks/gpu_check.py [--device cuda] [--out check.json]`` (about 30 s).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


from warpchain import Placement
from warpchain import METHODS, ChainParams, propagate_tangent, reference, simulate
from warpchain.engine import tuning
from warpchain.integrators import SplittingMethod

#: the methods the Warp engine steps (RK4 runs on the numpy reference only)
ENGINE_METHODS = sorted(name for name, m in METHODS.items() if isinstance(m, SplittingMethod))


def localized(n, amplitude, batch, seed):
    rng = np.random.default_rng(seed)
    x = np.zeros((batch, 4, n))
    sites = np.arange(n)
    for b in range(batch):
        shape = np.exp(-0.5 * ((sites - n // 2) / 2.0) ** 2)
        x[b, 0] = amplitude * shape * (1 + 0.1 * rng.standard_normal(n))
        x[b, 1] = -amplitude * shape
        x[b, 2] = 0.1 * amplitude * rng.standard_normal(n) * shape
    return x


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    out = {"device": args.device, "ensemble": {}, "tangent": {}}
    p = ChainParams(30.0, 160.0, 201)
    x0 = localized(p.N, 0.8, 3, 3)
    M, K, dt = np.array([30.0, 10.0, 50.0]), np.array([160.0, 40.0, 100.0]), 0.02
    for method in ENGINE_METHODS:
        ref = reference.integrate(method, p, x0, dt, 1000, M=M, K=K)["x"]
        for layout in ("block", "thread", "sites"):
            run = simulate(
                p, x0, 1000 * dt, dt, method=method, device=args.device, M=M, K=K, placement=Placement(layout=layout)
            )
            err = float(np.max(np.abs(run.x - ref)) / np.max(np.abs(ref)))
            out["ensemble"][f"{method}/{layout}"] = err
            print(f"ensemble {method:9s} {layout:6s} rel diff {err:.2e}", flush=True)
        with tuning.override(sites_per_thread=7):  # also a warp per lattice (7 sites per thread)
            run = simulate(
                p, x0, 1000 * dt, dt, method=method, device=args.device, M=M, K=K, placement=Placement(layout="block")
            )
        err = float(np.max(np.abs(run.x - ref)) / np.max(np.abs(ref)))
        out["ensemble"][f"{method}/block-7-sites"] = err
        print(f"ensemble {method:9s} 7 sites/thread rel diff {err:.2e}", flush=True)
    q = ChainParams(3.0, 4.0, 9)
    xt = localized(q.N, 0.7, 2, 5)
    n = 4 * q.N
    eye = np.eye(n).reshape(n, 4, q.N)
    dx0 = np.concatenate([eye, eye])
    base = np.repeat([0, 1], n)
    for method in ENGINE_METHODS:
        ref = reference.integrate(method, q, xt, 0.05, 40, dx0=dx0.reshape(2, n, 4, q.N))["dx"].reshape(2 * n, 4, q.N)
        for layout in ("block", "thread", "sites"):
            tan = propagate_tangent(
                q, xt, dx0, 40, 0.05, method=method, column_base=base, device=args.device, layout=layout
            )
            err = float(np.max(np.abs(tan.columns - ref)) / np.max(np.abs(ref)))
            out["tangent"][f"{method}/{layout}"] = err
            print(f"tangent  {method:9s} {layout:6s} rel diff {err:.2e}", flush=True)
    out["flow_replay"] = flow_replay(q, xt, args.device)
    out["on_device"] = on_device(p, x0, M, K, dt, args.device)
    out["observe"] = observed(p, x0, M, K, dt, args.device)
    worst = max(max(out[key].values()) for key in ("ensemble", "tangent", "flow_replay", "on_device", "observe"))
    out["worst"] = worst
    print(f"worst relative difference {worst:.2e}")
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    return 0 if worst <= 1e-12 else 1


def on_device(p, x0, M, K, dt, device):
    """Two 500-step runs chained on the device (a ``DeviceState`` in between) against the same two runs through
    host arrays (the second call of a shape gets lent page-locked results): the same bits (a difference is
    reported as 1.0), and the relative difference to 1000 steps of the numpy reference."""
    from warpchain import DeviceState

    ref = reference.integrate("verlet", p, x0, dt, 1000, M=M, K=K)["x"]
    out = {}
    for layout in ("block", "thread", "sites"):
        kw = dict(device=device, M=M, K=K, placement=Placement(layout=layout))
        on_device = dict(kw, placement=Placement(layout=layout, keep_on_device=True))
        ends = []
        for _ in range(2):  # plain results, then lent ones
            ends.append(simulate(p, simulate(p, x0, 500 * dt, dt, **kw).x, 500 * dt, dt, **kw).x)
        kept = simulate(p, x0, 500 * dt, dt, **on_device).x
        ends.append(simulate(p, kept, 500 * dt, dt, **on_device).x.numpy())
        ends.append(simulate(p, DeviceState.of(x0, device=device), 1000 * dt, dt, **kw).x)
        same = all(np.array_equal(e, ends[0]) for e in ends[1:])
        err = float(np.max(np.abs(ends[0] - ref)) / np.max(np.abs(ref)))
        out[f"verlet/{layout}"] = err if same else 1.0
        print(f"on device  {layout:6s} same bits as through the host: {same}, rel diff {err:.2e}", flush=True)
    return out


def observed(p, x0, M, K, dt, device):
    """``observe`` (the observed splitting kernels, with losses on two of three lattices) against its numpy
    oracle ``reference.observe``: the largest relative difference of the final state, of the observables and
    of the last envelope (a peak count that differs is reported as 1.0)."""
    from warpchain.observe import Observation, observe

    obs = Observation(frame_every=50, threshold=0.05, radius=5, contrast=0.7, spot=np.array([3.0, 5.0, 8.0]))
    damping = (np.array([0.0, 0.02, 0.05]), np.array([0.0, 0.01, 0.0]))
    out = {}
    for method in ("verlet", "kahan8"):
        values, env, x = reference.observe(method, p, x0, dt, 1000, obs, M=M, K=K, damping=damping)
        for layout in ("block", "thread"):
            run = observe(p, x0, 1000 * dt, dt, observation=obs, method=method, damping=damping, M=M, K=K,
                          device=device, layout=layout)  # fmt: skip
            same_peaks = np.array_equal(run["peaks"], values[..., 0])
            pairs = ((run.x, x), (run.values, values), (run.envelope, env))
            err = max(float(np.max(np.abs(a - b)) / np.max(np.abs(b))) for a, b in pairs)
            out[f"{method}/{layout}"] = err if same_peaks else 1.0
            print(f"observe {method:9s} {layout:6s} same peaks: {same_peaks}, rel diff {err:.2e}", flush=True)
    return out


def flow_replay(q, xt, device):
    """The Flow's base runs and unit columns replayed as CUDA graphs (from the second call with the same step
    count and dt) against the same calls issued one by one: the same bits (a difference is reported as
    1.0), and the relative difference to the numpy reference."""
    from warpchain.flow import Flow, ReferenceFlow

    out = {}
    cases = [(xt[:1], 0.05), (xt[1:], 0.05), (xt[:1], 0.04), (xt[1:], 0.05), (xt[:1], 0.05)]
    for method, layout in (
        ("kahan8", "block"),
        ("verlet", "block"),
        ("kahan8", "thread"),
        ("kahan8", "sites"),
    ):
        results = {}
        for after in (1, None):
            with tuning.override(graph_after=after):
                flow = Flow(method, 16, device=device, layout=layout)
                results[after] = []
                for x, dt in cases:
                    lin = flow.linearize(q, x, 8, dt)
                    results[after].append((lin.x_end, lin.unit_columns("positions"), lin.unit_columns("all")))
        same = all(np.array_equal(a, b) for r, e in zip(results[1], results[None]) for a, b in zip(r, e))
        ref = ReferenceFlow(method, 16)
        err = 0.0
        for (x, dt), got in zip(cases, results[1]):
            lin = ref.linearize(q, x, 8, dt)
            exact = (lin.x_end, lin.unit_columns("positions"), lin.unit_columns("all"))
            err = max(err, max(float(np.max(np.abs(a - b)) / np.max(np.abs(b))) for a, b in zip(got, exact)))
        out[f"{method}/{layout}"] = err if same else 1.0
        print(f"flow replay {method:9s} {layout:6s} same bits as eager: {same}, rel diff {err:.2e}", flush=True)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
