"""Other implementations of velocity Verlet for the throughput comparison (used when importable):
JAX (vmap over lattices + lax.fori_loop over steps) and a hand-written CUDA kernel through CuPy (one
thread block per lattice, one thread per site, state in registers, neighbours through shared memory,
all steps in one launch). Both float64, fixed ends, same scheme as ``warpchain``'s ``verlet``."""

from __future__ import annotations

import time

import numpy as np


def jax_verlet_runner(M: float, K: float):
    """Returns run(x0, nsteps, dt) -> (x_final, seconds), or None when JAX is not importable."""
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

    def run(x0, nsteps, dt):
        x = jnp.asarray(x0)
        batched(x, nsteps, dt).block_until_ready()  # compile
        t0 = time.perf_counter()
        out = batched(x, nsteps, dt).block_until_ready()
        return np.asarray(out), time.perf_counter() - t0

    return run


_CUDA_SOURCE = r"""
extern "C" __global__ void verlet(double* x, const int n, const int nsteps, const double dt,
                                  const double M, const double K) {
    extern __shared__ double su[];
    const int b = blockIdx.x, j = threadIdx.x;
    double* xb = x + (size_t)b * 4 * n;
    double u = 0, v = 0, du = 0, dv = 0, au = 0, av = 0;
    if (j < n) { u = xb[j]; v = xb[n + j]; du = xb[2 * n + j]; dv = xb[3 * n + j]; su[j] = u; }
    __syncthreads();
    #define ACC() { double l = j > 0 ? su[j - 1] : 0.0, r = j < n - 1 ? su[j + 1] : 0.0; \
        double s = fmax(1.0 + u - v, 0.0); double f = (2.0 / 3.0) * (s * sqrt(s) - 1.0); \
        au = -(K * ((u - l) + (u - r)) + f) / M; av = f; }
    if (j < n) ACC();
    for (int step = 0; step < nsteps; ++step) {
        __syncthreads();
        if (j < n) { du += 0.5 * dt * au; dv += 0.5 * dt * av; u += dt * du; v += dt * dv; su[j] = u; }
        __syncthreads();
        if (j < n) { ACC(); du += 0.5 * dt * au; dv += 0.5 * dt * av; }
    }
    if (j < n) { xb[j] = u; xb[n + j] = v; xb[2 * n + j] = du; xb[3 * n + j] = dv; }
}
"""


def cupy_verlet_runner(M: float, K: float):
    """Returns run(x0, nsteps, dt) -> (x_final, seconds) with the hand-written kernel, or None."""
    try:
        import cupy as cp

        cp.cuda.runtime.getDeviceCount()
    except Exception:
        return None
    kernel = cp.RawKernel(_CUDA_SOURCE, "verlet")

    def run(x0, nsteps, dt):
        batch, _, n = x0.shape
        threads = ((n + 31) // 32) * 32
        x = cp.asarray(x0)
        args = (x, np.int32(n), np.int32(nsteps), np.float64(dt), np.float64(M), np.float64(K))
        kernel((batch,), (threads,), args, shared_mem=8 * n)  # warm-up
        x = cp.asarray(x0)
        args = (x, *args[1:])
        cp.cuda.Device().synchronize()
        t0 = time.perf_counter()
        kernel((batch,), (threads,), args, shared_mem=8 * n)
        cp.cuda.Device().synchronize()
        return cp.asnumpy(x), time.perf_counter() - t0

    return run
