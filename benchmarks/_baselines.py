"""Other implementations of velocity Verlet for the throughput comparison (used when importable):
JAX (vmap over lattices + lax.fori_loop over steps) and a hand-written CUDA kernel through CuPy (one
thread block per lattice, one thread per site, state in registers, neighbours through shared memory,
all steps in one launch). Both float64, fixed ends, same scheme as ``warpchain``'s ``verlet``."""

from __future__ import annotations

import time

import numpy as np


def jax_verlet_runner(M: float, K: float):
    """Returns run(x0, nsteps, dt, repeats=1) -> (x_final, seconds), or None when JAX is not importable."""
    try:
        import jax
        import jax.numpy as jnp
    except Exception:
        return None
    jax.config.update("jax_enable_x64", True)

    def acc(u, v):
        lap = 2 * u - jnp.pad(u, (1, 0))[:-1] - jnp.pad(u, (0, 1))[1:]
        s = jnp.maximum(1.0 + u - v, 0.0)
        f = (2.0 / 3.0) * (s * jnp.sqrt(s) - 1.0)
        return -(K * lap + f) / M, f

    def run_one(x, nsteps, dt):
        def body(_, carry):
            u, v, du, dv, au, av = carry
            du = du + 0.5 * dt * au
            dv = dv + 0.5 * dt * av
            u = u + dt * du
            v = v + dt * dv
            au, av = acc(u, v)
            return u, v, du + 0.5 * dt * au, dv + 0.5 * dt * av, au, av

        au, av = acc(x[0], x[1])
        u, v, du, dv, _, _ = jax.lax.fori_loop(0, nsteps, body, (x[0], x[1], x[2], x[3], au, av))
        return jnp.stack([u, v, du, dv])

    batched = jax.jit(jax.vmap(run_one, in_axes=(0, None, None)), static_argnums=(1,))

    def run(x0, nsteps, dt, repeats: int = 1):
        """(state after nsteps, best seconds of ``repeats`` runs of nsteps, each continuing from the last)."""
        x = jnp.asarray(x0)
        batched(x, nsteps, dt).block_until_ready()  # compile
        first, best = None, np.inf
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            x = batched(x, nsteps, dt).block_until_ready()
            best = min(best, time.perf_counter() - t0)
            first = x if first is None else first
        return np.asarray(first), best

    return run


_CUDA_SOURCE = r"""
// Velocity Verlet, float64, fixed ends, one thread block per WC_LPB lattices, one thread per site.
// Compile-time: WC_N (sites), WC_T (threads per lattice, a whole number of warps >= WC_N), WC_LPB (lattices per
// block), WC_MINB (__launch_bounds__ minimum blocks per SM, 0: none).
// Tricks: 1/M precomputed on the host and multiplied (no division anywhere), WC_N and the block shape
// known to the compiler, state in registers for the whole launch, fixed walls as two zero entries
// padding each shared row (no boundary branch in the loop), idle threads write a dummy slot chosen
// by a select (no branch), ping-pong shared rows so one barrier per step suffices, the kick and drift
// factors (dt/2, dt) hoisted out of the loop, 2/3 as a constant.
#define WC_ROW (WC_T + 3)
#if WC_MINB > 0
#define BOUNDS __launch_bounds__(WC_T * WC_LPB, WC_MINB)
#else
#define BOUNDS __launch_bounds__(WC_T * WC_LPB)
#endif
extern "C" __global__ void BOUNDS verlet(double* __restrict__ x, const int batch, const int nsteps,
                                         const double dt, const double inv_m, const double K) {
    __shared__ double su[2][WC_LPB][WC_ROW];
    const int lane = threadIdx.x % WC_T, sub = threadIdx.x / WC_T;
    const int b = blockIdx.x * WC_LPB + sub;
    const bool active = lane < WC_N && b < batch;
    double* xb = x + (size_t)(b < batch ? b : 0) * 4 * WC_N;
    double u = 0.0, v = 0.0, du = 0.0, dv = 0.0;
    if (active) { u = xb[lane]; v = xb[WC_N + lane]; du = xb[2 * WC_N + lane]; dv = xb[3 * WC_N + lane]; }
#if WC_IDLE_ZERO
    const double live = lane < WC_N ? 1.0 : 0.0;  // idle threads keep u = 0 (their acceleration is masked)
#endif
    const int w = lane < WC_N ? lane + 1 : WC_N + 2;  // idle threads write past the right wall
    for (int p = 0; p < 2; ++p)
        for (int i = threadIdx.x; i < WC_LPB * WC_ROW; i += WC_T * WC_LPB) su[p][i / WC_ROW][i % WC_ROW] = 0.0;
    __syncthreads();
    const double hdt = 0.5 * dt, c23 = 2.0 / 3.0;
    su[0][sub][w] = u;
    __syncthreads();
    double s = fmax(1.0 + u - v, 0.0);
    double av = c23 * (s * sqrt(s) - 1.0);
    double au = -(K * ((u - su[0][sub][lane]) + (u - su[0][sub][lane + 2])) + av) * inv_m;
    int p = 1;
    for (int step = 0; step < nsteps; ++step) {
        du += hdt * au; dv += hdt * av;
        u += dt * du; v += dt * dv;
        su[p][sub][w] = u;
        __syncthreads();
        const double l = su[p][sub][lane], r = su[p][sub][lane + 2];
        s = fmax(1.0 + u - v, 0.0);
        av = c23 * (s * sqrt(s) - 1.0);
        au = -(K * ((u - l) + (u - r)) + av) * inv_m;
#if WC_IDLE_ZERO
        au *= live; av *= live;
#endif
        du += hdt * au; dv += hdt * av;
        p ^= 1;
    }
    if (active) { xb[lane] = u; xb[WC_N + lane] = v; xb[2 * WC_N + lane] = du; xb[3 * WC_N + lane] = dv; }
}
"""

_CUDA_SITES_SOURCE = r"""
// Velocity Verlet, float64, fixed ends, one thread block per lattice, WC_S consecutive sites per thread
// (WC_T threads, a whole number of warps, WC_T * WC_S >= WC_N). Each thread keeps its run of sites in
// registers and takes interior neighbours from them; only its first and last u cross threads, as one
// double2 per thread in a shared row with zero wall entries at both ends (ping-pong: one barrier per step).
// Slots past the lattice's end get 1/M = 0, so they stay at rest without a branch. Tricks as ``verlet``.
extern "C" __global__ void __launch_bounds__(WC_T) verlet_sites(double* __restrict__ x, const int batch,
                                                                const int nsteps, const double dt,
                                                                const double inv_m, const double K) {
    __shared__ double2 se[2][WC_T + 2];
    const int t = threadIdx.x, b = blockIdx.x;
    double* xb = x + (size_t)b * 4 * WC_N;
    double u[WC_S], v[WC_S], du[WC_S], dv[WC_S], m[WC_S], au[WC_S], av[WC_S];
#pragma unroll
    for (int s = 0; s < WC_S; ++s) {
        const int j = t * WC_S + s;
        const bool a = j < WC_N;
        u[s] = a ? xb[j] : 0.0; v[s] = a ? xb[WC_N + j] : 0.0;
        du[s] = a ? xb[2 * WC_N + j] : 0.0; dv[s] = a ? xb[3 * WC_N + j] : 0.0;
        m[s] = a ? inv_m : 0.0;
    }
    if (t < 2) { se[t][0] = make_double2(0.0, 0.0); se[t][WC_T + 1] = make_double2(0.0, 0.0); }
    const double hdt = 0.5 * dt, c23 = 2.0 / 3.0;
    se[0][t + 1] = make_double2(u[0], u[WC_S - 1]);
    __syncthreads();
    double L = se[0][t].y, R = se[0][t + 2].x;
#pragma unroll
    for (int s = 0; s < WC_S; ++s) {
        const double l = s == 0 ? L : u[s > 0 ? s - 1 : 0], r = s == WC_S - 1 ? R : u[s < WC_S - 1 ? s + 1 : 0];
        const double q = fmax(1.0 + u[s] - v[s], 0.0);
        av[s] = c23 * (q * sqrt(q) - 1.0);
        au[s] = -(K * ((u[s] - l) + (u[s] - r)) + av[s]) * m[s];
    }
    int p = 1;
    for (int step = 0; step < nsteps; ++step) {
#pragma unroll
        for (int s = 0; s < WC_S; ++s) {
            du[s] += hdt * au[s]; dv[s] += hdt * av[s];
            u[s] += dt * du[s]; v[s] += dt * dv[s];
        }
        se[p][t + 1] = make_double2(u[0], u[WC_S - 1]);
        __syncthreads();
        L = se[p][t].y; R = se[p][t + 2].x;
#pragma unroll
        for (int s = 0; s < WC_S; ++s) {
            const double l = s == 0 ? L : u[s > 0 ? s - 1 : 0], r = s == WC_S - 1 ? R : u[s < WC_S - 1 ? s + 1 : 0];
            const double q = fmax(1.0 + u[s] - v[s], 0.0);
            av[s] = c23 * (q * sqrt(q) - 1.0);
            au[s] = -(K * ((u[s] - l) + (u[s] - r)) + av[s]) * m[s];
            du[s] += hdt * au[s]; dv[s] += hdt * av[s];
        }
        p ^= 1;
    }
#pragma unroll
    for (int s = 0; s < WC_S; ++s) {
        const int j = t * WC_S + s;
        if (j < WC_N) { xb[j] = u[s]; xb[WC_N + j] = v[s]; xb[2 * WC_N + j] = du[s]; xb[3 * WC_N + j] = dv[s]; }
    }
}
"""

#: the variant the throughput scene runs (``benchmarks/hand_cuda_variants.py`` measured them on the H200)
#: "lattices_per_block": "auto" takes 2 lattices per block from AUTO_TWO_PER_BLOCK lattices on, else 1 (the
#: variants study on the H200: 2 per block is ~4 % faster at 4096 and 32768 lattices, 7 % slower at 805)
#: "sites": "auto" runs ``verlet_sites`` with ceil(N / 32) sites per thread (a warp per lattice) from
#: AUTO_SITES_BATCH lattices on, else ``verlet`` (``benchmarks/sites_per_thread.py`` on the H200: 3.99e11 against
#: 3.78e11 site-steps/s at 4096 lattices, 4.31e11 against 3.91e11 at 32768; at 2400 one site per thread is faster)
DEFAULT_VARIANT = {"lattices_per_block": "auto", "min_blocks": 0, "threads": None, "idle_zero": False, "sites": "auto"}
AUTO_TWO_PER_BLOCK = 4096
AUTO_SITES_BATCH = 4096


def cupy_variant() -> dict:
    """What the throughput scene's hand-written kernel is (recorded in its summary)."""
    return {
        **DEFAULT_VARIANT,
        "tricks": "1/M precomputed and multiplied (no division), N and block shape compile-time constants, "
        "state in registers, fixed walls as zero padding of the shared row (no boundary branch), idle threads "
        "write a dummy slot by a select, ping-pong shared rows: one barrier per step; from 4096 lattices a warp "
        "per lattice (ceil(N / 32) consecutive sites per thread, neighbours from registers, only the ends of "
        "each thread's run through shared memory, idle slots held by 1/M = 0)",
    }


def cupy_verlet_runner(
    M: float,
    K: float,
    lattices_per_block: int | None = None,
    min_blocks: int | None = None,
    threads: int | None = None,
    idle_zero: bool | None = None,
    sites: int | str | None = None,
):
    """Returns run(x0, nsteps, dt, repeats=1) -> (x_final, seconds) with the hand-written kernel, or None.

    The kernel is compiled per lattice length (``N``, threads per lattice rounded up to whole warps);
    ``lattices_per_block`` (an int or "auto"), ``min_blocks``, ``threads`` and ``idle_zero`` pick the
    variant (defaults: ``DEFAULT_VARIANT``); ``sites`` > 1 runs ``verlet_sites`` instead (that many consecutive
    sites per thread, one lattice per block)."""
    try:
        import cupy as cp

        cp.cuda.runtime.getDeviceCount()
    except Exception:
        return None
    lpb_choice = DEFAULT_VARIANT["lattices_per_block"] if lattices_per_block is None else lattices_per_block
    minb = DEFAULT_VARIANT["min_blocks"] if min_blocks is None else int(min_blocks)
    fixed_threads = DEFAULT_VARIANT.get("threads") if threads is None else threads
    zero = int(DEFAULT_VARIANT.get("idle_zero", False) if idle_zero is None else idle_zero)
    sites_choice = DEFAULT_VARIANT["sites"] if sites is None else sites
    kernels = {}

    def kernel_for(n, lpb, sites):
        if sites > 1:  # several sites per thread: one lattice per block
            if (n, "sites", sites) not in kernels:
                threads = ((-(-n // sites)) + 31) // 32 * 32
                options = (f"-DWC_N={n}", f"-DWC_T={threads}", f"-DWC_S={int(sites)}")
                kernel = cp.RawKernel(_CUDA_SITES_SOURCE, "verlet_sites", options=options)
                kernels[n, "sites", sites] = (kernel, threads)
            return kernels[n, "sites", sites]
        if (n, lpb) not in kernels:
            threads = max(int(fixed_threads or 0), ((n + 31) // 32) * 32)
            options = (f"-DWC_N={n}", f"-DWC_T={threads}", f"-DWC_LPB={lpb}", f"-DWC_MINB={minb}")
            options += (f"-DWC_IDLE_ZERO={zero}",)
            kernels[n, lpb] = (cp.RawKernel(_CUDA_SOURCE, "verlet", options=options), threads)
        return kernels[n, lpb]

    def run(x0, nsteps, dt, repeats: int = 1):
        """(state after nsteps, best seconds of ``repeats`` launches of nsteps), timed as ``time_steps`` times
        Warp's kernel: an untimed launch (compile, load; here on a copy of the state), then ``repeats``
        launches one after the other, each continuing from the state the previous one left, each timed by
        CUDA events with no host transfer in between. Returns the state after the first timed launch (x0
        advanced by nsteps). ``run.wall_seconds``: the best launch timed on the host, as ``time_steps`` does.

        (Before 2026-11-22k the untimed launch ran nsteps on the state itself and one launch was timed from
        there: the hand kernel was timed on steps nsteps..2 nsteps while Warp's best of three covered steps
        1..3 nsteps + 1. The hand kernel's per-step cost moves over a long run: one lattice, segments of 2e6
        steps, 124.9, 130.7 and 149.7 ns from steps 0, 2e6 and 4e6, Warp's 117.8 ns throughout
        (``benchmarks/results/h200-2026-11-22k.json``, ``state-dependence.txt``). So both are now timed on the same
        segments.)"""
        batch, _, n = x0.shape
        if sites_choice == "auto":
            per_thread = min(8, -(-n // 32)) if batch >= AUTO_SITES_BATCH else 1
        else:
            per_thread = int(sites_choice)
        run.sites = per_thread
        if per_thread > 1:
            lpb = 1
        elif lpb_choice == "auto":
            lpb = 2 if batch >= AUTO_TWO_PER_BLOCK else 1
        else:
            lpb = int(lpb_choice)
        run.lattices_per_block = lpb
        kernel, threads = kernel_for(n, lpb, per_thread)
        grid = (-(-batch // lpb),)

        def args(steps):
            return (np.int32(batch), np.int32(steps), np.float64(dt), np.float64(1.0 / M), np.float64(K))

        x = cp.asarray(x0)
        kernel(grid, (threads * lpb,), (x.copy(), *args(1)))  # compile, load, warm up (on a copy)
        result, best, wall = None, np.inf, np.inf
        start, end = cp.cuda.Event(), cp.cuda.Event()
        for _ in range(max(1, int(repeats))):
            cp.cuda.Device().synchronize()
            t0 = time.perf_counter()
            start.record()
            kernel(grid, (threads * lpb,), (x, *args(nsteps)))
            end.record()
            end.synchronize()
            wall = min(wall, time.perf_counter() - t0)
            best = min(best, cp.cuda.get_elapsed_time(start, end) / 1e3)
            if result is None:
                result = x.copy()
        run.wall_seconds = wall
        return cp.asnumpy(result), best

    return run
