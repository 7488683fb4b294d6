"""The GPU throughput tables of docs/performance.md, generated from a throughput summary (no figure typed by hand).

Command: ``python benchmarks/throughput_table.py benchmarks/results/h200-2026-11-22o.json`` (a compact result set:
its ``throughput-summary.json``; a second argument names another of its throughput summaries), or the path of
a scene run's own ``throughput/summary.json``.
"""

from __future__ import annotations

import json
import sys


def rate(results, impl, batch, method="verlet"):
    hit = [r for r in results if r["implementation"] == impl and r["batch"] == batch and r["method"] == method]
    return hit[0]["site_steps_per_second"] if hit else None


def sites_per_thread(results, impl, batch, method="verlet"):
    hit = [r for r in results if r["implementation"] == impl and r["batch"] == batch and r["method"] == method]
    return hit[0].get("sites_per_thread") if hit else None


def fmt(value, spec=".3g", missing="-"):
    return missing if value is None else format(value, spec)


def print_simulate(s):
    sim = (s.get("simulate") or {}).get("rows", [])
    if sim:
        every = s["simulate"]["record_every"]
        print()
        print(
            f"| batch | kernel (`time_steps`) | `simulate()` default | continued (x0 page-locked) | on the device "
            f"| `simulate(save_every={every})` "
            "| frames to host | same into reused `frames_out` | into reused page-locked `frame_buffers` |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")

        def recording(r, name):
            if r.get(f"{name}_seconds") is None:
                return "-"
            return f"{r[f'{name}_rate']:.2e} ({r[f'{name}_over_kernel']:.2f}x), {r[f'{name}_gb_per_second']:.1f} GB/s"

        def continued(r, name="continued"):  # older summaries have no such row (before the leases, the DeviceState)
            if r.get(f"{name}_rate") is None:
                return "-"
            return f"{r[f'{name}_rate']:.2e} ({r[f'{name}_over_kernel']:.2f}x)"

        for r in sim:
            print(
                f"| {r['batch']} | {r['kernel_rate']:.2e} | {r['default_rate']:.2e} ({r['default_over_kernel']:.2f}x) "
                f"| {continued(r)} | {continued(r, 'on_device')} "
                f"| {r['recording_rate']:.2e} ({r['recording_over_kernel']:.2f}x) "
                f"| {r['recording_gb_per_second']:.1f} GB/s | {recording(r, 'recording_reused')} "
                f"| {recording(r, 'recording_pinned')} |"
            )


def load(path, member=None):
    """A throughput summary, from a scene run or from a compact set (benchmarks/results/README.md)."""
    s = json.load(open(path))
    if isinstance(s.get("results"), dict):  # a compact set: its throughput summaries by raw file name
        s = s["results"][member or "throughput-summary.json"]
    if "rows" in s:  # compact rows: lists under row_keys
        s = dict(s, results=[dict(zip(s["row_keys"], row)) for row in s["rows"]])
    return s


def main(path, member=None):
    s = load(path, member)
    results = s["results"]
    batches = sorted({r["batch"] for r in results})
    if s["ratios"]["main_layout"] == "warp-thread":  # a CPU run
        print(
            "| batch | Warp verlet (thread layout) | Warp kahan8 | Warp block layout (CPU fibers) | numpy verlet "
            "| Warp / numpy |"
        )
        print("| --- | --- | --- | --- | --- | --- |")
        for b in batches:
            w, n = rate(results, "warp-thread", b), rate(results, "numpy", b)
            print(
                f"| {b} | {fmt(w, '.2e')} | {fmt(rate(results, 'warp-thread', b, 'kahan8'), '.2e')} "
                f"| {fmt(rate(results, 'warp-block', b), '.2e')} | {fmt(n, '.2e')} "
                f"| {fmt(w / n if w and n else None, '.1f')}{'x' if w and n else ''} |"
            )
        print_simulate(s)
        mono = s.get("monodromy")
        if mono:
            print(
                f"\nmonodromy {mono['monodromy_wall_seconds']:.2f} s wall; Newton iteration "
                f"{1e3 * mono['newton_iteration_seconds']:.0f} ms"
            )
        return
    lines = [
        "| batch | Warp block verlet | Warp block kahan8 | Warp thread verlet | JAX | hand CUDA (CuPy) "
        "| sites per thread (Warp, hand) | Warp block / hand | Warp block / JAX |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for b in batches:
        w, hand, jax = rate(results, "warp-block", b), rate(results, "cupy", b), rate(results, "jax", b)
        sites = [sites_per_thread(results, impl, b) for impl in ("warp-block", "cupy")]
        lines.append(
            f"| {b} | {fmt(w, '.3e')} | {fmt(rate(results, 'warp-block', b, 'kahan8'), '.3e')} "
            f"| {fmt(rate(results, 'warp-thread', b), '.3e')} | {fmt(jax, '.3e')} | {fmt(hand, '.3e')} "
            f"| {fmt(sites[0], 'd')}, {fmt(sites[1], 'd')} "
            f"| {fmt(w / hand if w and hand else None, '.2f')} | {fmt(w / jax if w and jax else None, '.0f')}x |"
        )
    print("\n".join(lines))
    print_simulate(s)
    ratios = s["ratios"]
    print()
    print(f"single lattice: {ratios['single_lattice_ns_per_step']:.0f} ns per Verlet step (Warp block)")
    hand1 = [r for r in results if r["implementation"] == "cupy" and r["batch"] == 1]
    if hand1:
        ns = hand1[0].get("ns_per_step") or 1e9 * s["N"] / hand1[0]["site_steps_per_second"]
        print(f"single lattice, hand CUDA: {ns:.0f} ns per step")
    for b, per in ratios.get("force_eval_cost_over_verlet", {}).items():
        print(f"cost per force evaluation over Verlet at {b}: " + ", ".join(f"{k} {v:.2f}" for k, v in per.items()))
    mono = s.get("monodromy")
    if mono:
        print(
            f"monodromy ({mono['columns']} columns, {mono['period_steps']} steps of {mono['method']}): kernel "
            f"{1e3 * mono['monodromy_kernel_seconds']:.2f} ms"
            + (
                f" (CUDA events; launches host-timed {1e3 * mono['monodromy_launch_seconds']:.2f} ms)"
                if "monodromy_launch_seconds" in mono
                else ""
            )
            + f", wall {1e3 * mono['monodromy_wall_seconds']:.1f} ms"
            + (
                f", through the Flow {1e3 * mono['monodromy_flow_wall_seconds']:.2f} ms wall"
                if "monodromy_flow_wall_seconds" in mono
                else ""
            )
            + "; "
            f"Newton iteration {1e3 * mono['newton_iteration_seconds']:.2f} ms "
            + (
                f"(median {1e3 * mono['newton_iteration_median_seconds']:.2f} ms) "
                if "newton_iteration_median_seconds" in mono
                else ""
            )
            + f"(linear solve {1e3 * mono['newton_linear_solve_seconds']:.2f} ms)"
        )
    for row in s.get("kernel_properties", []):
        print(f"{row['kernel']}: {row['register_count']} registers, occupancy {row['occupancy']:.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:3])
