"""Plain numpy reference of every scheme in ``METHODS``, step for step, on batches.

This is the oracle the Warp kernels are tested against: the same stages, the same coefficients,
vectorised over lattices and sites instead of looped. It also propagates tangent vectors (the
exact derivative of the discrete map), used to check the Warp tangent kernels, and runs the observables of
``warpchain.observe`` frame by frame (``observe``: the peak rule ``peak_mask`` and ``frame_observables``, which the
host's peak tracking reads too).

Shapes: a batch state ``x`` is (batch, 4, N) ordered (u, v, u', v'); tangent columns ``dx`` are
(batch, ncols, 4, N), each column attached to its lattice. ``dtype=np.float32`` runs the same
schemes in single precision (the stability-limits scene's float32 comparison).
"""

from __future__ import annotations

import numpy as np

from . import losses, model
from .integrators import Method, SplittingMethod, get_method
from .model import (
    ChainParams,
    contact_force,
    contact_stiffness,
    lattice_laplacian,
    per_lattice_parameters,
    site_energies,
)


def inverse_mass(M, dtype=np.float64):
    """1/M, rounded once: every scheme multiplies by it instead of dividing by M (the Warp kernels
    receive this same array), so u'' = -(K lap(u) + f(u - v)) * (1/M)."""
    M = np.asarray(M, dtype=dtype)
    return dtype(1.0) / M


def accelerations(params: ChainParams, x, inv_M, K):
    """(u'', v'') of a batch, shape (batch, 2, N), from the positions in x[:, :2] and per-lattice
    1/M and K (shape (batch,)); the arithmetic of the kernels (multiplied by 1/M)."""
    u, v = x[:, 0], x[:, 1]
    force = contact_force(u - v)
    acc = np.empty((x.shape[0], 2, x.shape[-1]), dtype=x.dtype)
    acc[:, 0] = -(K[:, None] * lattice_laplacian(params, u) + force) * inv_M[:, None]
    acc[:, 1] = force
    return acc


def _linear_accelerations(params: ChainParams, q, dq, inv_M, K):
    """Tangent of the accelerations at positions q (batch, 2, N) along dq (batch, ncols, 2, N)."""
    stiff = contact_stiffness(q[:, 0] - q[:, 1])[:, None, :]  # (batch, 1, N)
    dz = dq[:, :, 0] - dq[:, :, 1]
    out = np.empty_like(dq)
    lap = lattice_laplacian(params, dq[:, :, 0])
    out[:, :, 0] = -(K[:, None, None] * lap + stiff * dz) * inv_M[:, None, None]
    out[:, :, 1] = stiff * dz
    return out


def damped_kick(x, acc, coefficients) -> None:
    """In place, the exact damped kick w <- E w + F a of every lattice (``losses``), in the kernels'
    operation order; ``coefficients`` (batch, 12) holds E00, E01, E10, E11, F00, F01, F10, F11 (then H, unused here)."""
    e = [coefficients[:, i, None] for i in range(8)]
    pu, pv, au, av = x[:, 2].copy(), x[:, 3].copy(), acc[:, 0], acc[:, 1]
    x[:, 2] = e[0] * pu + e[1] * pv + (e[4] * au + e[5] * av)
    x[:, 3] = e[2] * pu + e[3] * pv + (e[6] * au + e[7] * av)


def step(
    method: Method | str,
    params: ChainParams,
    x,
    dt: float,
    M=None,
    K=None,
    dx=None,
    dtype=np.float64,
    damping=None,
    dissipated: np.ndarray | None = None,
):
    """Advance a batch (and optionally its tangent columns) by one step of ``method``.

    Args:
        x: state, shape (batch, 4, N); not modified.
        dt: step size.
        M, K: per-lattice parameters, shape (batch,), or None for ``params``' values.
        dx: tangent columns, shape (batch, ncols, 4, N), or None.
        dtype: float64 (default) or float32; coefficients and the step are rounded to it.
        damping: ``losses.Damping`` (or a (contact, substrate) pair), splitting methods only: each
            kick becomes the exact damped kick; lattices without losses keep the plain kick, so zero
            damping is today's scheme bit for bit.
        dissipated: with ``damping``, an array (batch,) to which each damped kick adds the energy it
            dissipates, exactly (``losses.kick_dissipation``; ``observe``'s kernels do the same per site).

    Returns:
        the new state, or (state, tangent columns) when ``dx`` is given.
    """
    method = get_method(method)
    x = np.array(x, dtype=dtype, copy=True)
    batch = x.shape[0]
    M_b = np.broadcast_to(np.asarray(params.M if M is None else M, dtype=dtype), (batch,))
    inv_M = inverse_mass(M_b, dtype)
    K = np.broadcast_to(np.asarray(params.K if K is None else K, dtype=dtype), (batch,))
    dx = None if dx is None else np.array(dx, dtype=dtype, copy=True)
    dt = dtype(dt)
    damping = losses.as_damping(damping)
    if damping is not None:
        losses.require_splitting(method)
        if dx is not None:
            raise ValueError("tangent runs are for conservative orbits: run them without damping")
    if isinstance(method, SplittingMethod):
        kicks, drifts = [dtype(k) for k in method.kicks], [dtype(c) for c in method.drifts]
        plain = damped = None
        if damping is not None:
            coefficients = losses.kick_matrices(method.kicks, float(dt), M_b, damping, batch)
            no_loss = losses.lossless(coefficients)
            plain, damped = np.flatnonzero(no_loss), np.flatnonzero(~no_loss)
            coefficients = coefficients[damped]

        def kick(i, acc):
            if damped is None:
                x[:, 2:] += kicks[i] * dt * acc
                return
            x[plain, 2:] += kicks[i] * dt * acc[plain]  # lattices without losses: the plain kick
            sub = x[damped]
            if dissipated is not None:
                dissipated[damped] += losses.kick_dissipation(sub[:, 2:], acc[damped], coefficients[:, i], M_b[damped])
            damped_kick(sub, acc[damped], coefficients[:, i])
            x[damped] = sub

        acc = accelerations(params, x, inv_M, K)
        dacc = None if dx is None else _linear_accelerations(params, x[:, :2], dx[:, :, :2], inv_M, K)
        kick(0, acc)
        if dx is not None:
            dx[:, :, 2:] += kicks[0] * dt * dacc
        for i, (c, d) in enumerate(zip(drifts, kicks[1:])):
            x[:, :2] += c * dt * x[:, 2:]
            acc = accelerations(params, x, inv_M, K)
            kick(i + 1, acc)
            if dx is not None:
                dx[:, :, :2] += c * dt * dx[:, :, 2:]
                dacc = _linear_accelerations(params, x[:, :2], dx[:, :, :2], inv_M, K)
                dx[:, :, 2:] += d * dt * dacc
        return x if dx is None else (x, dx)

    # classical RK4 on y' = F(y) = (y', a(y))
    def rhs(y):
        out = np.empty_like(y)
        out[:, :2] = y[:, 2:]
        out[:, 2:] = accelerations(params, y, inv_M, K)
        return out

    def tangent_rhs(y, dy):
        out = np.empty_like(dy)
        out[:, :, :2] = dy[:, :, 2:]
        out[:, :, 2:] = _linear_accelerations(params, y[:, :2], dy[:, :, :2], inv_M, K)
        return out

    # the Runge-Kutta method's own tableau (classical RK4: nodes 1/2, 1/2, 1; weights 1, 2, 2, 1; / 6)
    stage_coefficients = tuple(dtype(a) for a in method.nodes)
    weights = tuple(dtype(w) for w in method.weights)
    k = rhs(x)
    dk = None if dx is None else tangent_rhs(x, dx)
    total = weights[0] * k
    dtotal = None if dx is None else weights[0] * dk
    for a, w in zip(stage_coefficients, weights[1:]):
        y = x + a * dt * k
        if dx is not None:
            dk = tangent_rhs(y, dx + a * dt * dk)
            dtotal = dtotal + w * dk
        k = rhs(y)
        total = total + w * k
    x_new = x + (dt / dtype(method.divisor)) * total
    if dx is None:
        return x_new
    return x_new, dx + (dt / dtype(method.divisor)) * dtotal


def integrate(
    method: Method | str,
    params: ChainParams,
    x0,
    dt: float,
    nsteps: int,
    M=None,
    K=None,
    dx0=None,
    save_every: int | None = None,
    dtype=np.float64,
    damping=None,
):
    """Integrate ``nsteps`` steps with the numpy reference (``damping``: as in ``step``).

    Args:
        x0: state, shape (batch, 4, N).
        dx0: optional tangent columns, shape (batch, ncols, 4, N).
        save_every: record (u, v) every this many steps (and at t = 0).

    Returns:
        dict with ``x`` (final state), ``dx`` (final tangent columns or None) and, when
        ``save_every`` is given, ``u`` and ``v`` of shape (n_saved, batch, N).
    """
    x = np.array(x0, dtype=dtype, copy=True)
    dx = None if dx0 is None else np.array(dx0, dtype=dtype, copy=True)
    us, vs = ([x[:, 0].copy()], [x[:, 1].copy()]) if save_every else (None, None)
    for n in range(nsteps):
        if dx is None:
            x = step(method, params, x, dt, M, K, dtype=dtype, damping=damping)
        else:
            x, dx = step(method, params, x, dt, M, K, dx, dtype=dtype)
        if save_every and (n + 1) % save_every == 0:
            us.append(x[:, 0].copy())
            vs.append(x[:, 1].copy())
    out = {"x": x, "dx": dx}
    if save_every:
        out["u"] = np.stack(us)
        out["v"] = np.stack(vs)
    return out


def rhs_flat(params: ChainParams, M=None, K=None):
    """Right-hand side f(t, y) of one lattice with y the flattened (4, N) state, for scipy."""
    N = params.N

    def f(t, y):
        x = y.reshape(1, 4, N)
        out = np.empty((4, N))
        out[:2] = x[0, 2:]
        out[2:] = model.accelerations(params, x, M, K)[0]
        return out.ravel()

    return f


def solve_ivp_reference(
    params: ChainParams,
    x0,
    t_final: float,
    rtol: float = 1e-13,
    atol: float = 1e-15,
    method: str = "DOP853",
    M=None,
    K=None,
):
    """Integrate one lattice with scipy's ``solve_ivp`` (DOP853 by default); returns the (4, N) state."""
    from scipy.integrate import solve_ivp

    x0 = np.asarray(x0, dtype=np.float64).reshape(4, params.N)
    sol = solve_ivp(rhs_flat(params, M, K), (0.0, t_final), x0.ravel(), method=method, rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"scipy {method} failed: {sol.message}")
    return sol.y[:, -1].reshape(4, params.N), sol


# ----------------------------------------------------------------------------- the observables' oracle

#: what ``warpchain.observe`` reduces per frame and lattice, in this order (the kernels' ``site.store_observables``)
OBSERVABLES = ("peaks", "participation", "spot_energy", "max_envelope", "min_contact", "energy", "dissipated")
N_OBSERVABLES = len(OBSERVABLES)
#: the tracked extremes of z start from these (any real displacement replaces them)
_FAR = 1.0e300


def peak_mask(env: np.ndarray, threshold: float, radius: int, contrast: float = 1.0) -> np.ndarray:
    """Localized peaks of envelope profiles env (..., N): the rule of the kernels (module docstring).
    Running extremes over ``radius`` sites on each side, in place (past the chain's ends: -inf for the
    largest-value test, 0 for the localization test)."""
    env = np.asarray(env, dtype=np.float64)
    n = env.shape[-1]
    r = min(int(radius), n)
    j = np.arange(n)
    left_max = np.full_like(env, -np.inf)
    right_max = np.full_like(env, -np.inf)
    left_min = np.broadcast_to(np.where(j < r, 0.0, np.inf), env.shape).copy()  # a window past an end holds 0
    right_min = np.broadcast_to(np.where(j >= n - r, 0.0, np.inf), env.shape).copy()
    for i in range(1, r + 1):
        if i >= n:
            break
        np.maximum(left_max[..., i:], env[..., :-i], out=left_max[..., i:])
        np.maximum(right_max[..., :-i], env[..., i:], out=right_max[..., :-i])
        np.minimum(left_min[..., i:], env[..., :-i], out=left_min[..., i:])
        np.minimum(right_min[..., :-i], env[..., i:], out=right_min[..., :-i])
    mask = (env > threshold) & (env > left_max) & (env >= right_max)
    return mask & (left_min <= contrast * env) & (right_min <= contrast * env)


def table_peak_mask(lattice, env: np.ndarray, threshold: float, radius: int, contrast: float = 1.0) -> np.ndarray:
    """Localized peaks of envelope profiles env (..., sites) on a lattice given as a table (``warpchain.lattice``):
    the chain's rule (``peak_mask``) with the table's neighbourhoods. A site is a peak when its envelope is above
    ``threshold``, larger than every site's within ``radius`` bonds of a lower index and at least every higher one's
    (the ball of ``lattice.balls_of``), and falls to ``contrast`` times its value along each bonded slot direction
    within ``radius`` steps (a step past a wall or a free edge reads 0; a weightless slot tests nothing). On a
    chain's table with fixed or free ends this is ``peak_mask``; on a ring the table's windows wrap."""
    from .colouring import balls_of

    env = np.asarray(env, dtype=np.float64)
    n, r = lattice.n_sites, int(radius)
    ball, _ = balls_of(lattice, r)
    rows = np.repeat(np.arange(n), np.diff(ball.indptr))
    cols = ball.indices
    er, ec = env[..., rows], env[..., cols]
    fails = ((cols < rows) & ~(er > ec)) | ((cols > rows) & ~(er >= ec))
    count = np.zeros(env.shape)
    np.add.at(count.reshape(-1, n), (slice(None), rows), fails.reshape(-1, rows.size).astype(float))
    mask = (env > threshold) & (count == 0)
    nb, w = lattice.neighbours, lattice.weights
    for d in range(nb.shape[1]):
        low = np.full(env.shape, np.inf)
        t = np.arange(n)
        for _ in range(r):
            t = np.where(t >= 0, nb[np.maximum(t, 0), d], t)  # a negative slot (wall, edge) stays: the ray left
            low = np.minimum(low, np.where(t >= 0, env[..., np.maximum(t, 0)], 0.0))
        mask &= (w[:, d] == 0) | (low <= contrast * env)
    return mask


def frame_observables(params, x, z_low, z_high, M, K, observation, dissipated=0.0) -> tuple[np.ndarray, np.ndarray]:
    """The observables of one frame from the state x (batch, 4, N), the interval's z extremes (batch, N) and the
    energy dissipated so far (batch,), for ``observation`` (a ``warpchain.Observation``). Returns (values (batch,
    len(OBSERVABLES)), envelope (batch, N))."""
    env = np.maximum(z_high, -z_low)
    e = site_energies(params, x, M, K)
    n = x.shape[-1]
    spot = np.broadcast_to(np.asarray(observation.spot, dtype=np.float64), (x.shape[0],))
    rule = (observation.threshold, observation.radius, observation.contrast)
    if isinstance(params, ChainParams):
        inside = np.abs(np.arange(n)[None, :] - n // 2) <= spot[:, None]
        peaks = peak_mask(env, *rule)
    else:  # a lattice: the spot is a disc about the centre site, peaks are the table's (``table_peak_mask``)
        lattice = params.lattice
        inside = lattice.distances(lattice.centre)[None, :] <= spot[:, None]
        peaks = table_peak_mask(lattice, env, *rule)
    total = e.sum(axis=-1)
    squares = (e * e).sum(axis=-1)
    out = np.empty((x.shape[0], N_OBSERVABLES))
    out[:, 0] = peaks.sum(axis=-1)
    out[:, 1] = np.where(squares > 0, total * total / np.where(squares > 0, squares, 1.0), 0.0)
    out[:, 2] = np.where(inside, e, 0.0).sum(axis=-1)
    out[:, 3] = env.max(axis=-1)
    out[:, 4] = (1.0 + z_low).min(axis=-1)
    out[:, 5] = total
    out[:, 6] = dissipated
    return out, env


def observe(method, params: ChainParams, x0, dt: float, nsteps: int, observation, M=None, K=None, damping=None):
    """``warpchain.observe``'s numpy oracle: the same scheme (``step``) and the same tracking.

    Returns:
        (values (n_frames, batch, len(OBSERVABLES)), envelope of the last frame (batch, N), final state).
    """
    x = np.array(x0, dtype=np.float64)
    batch = x.shape[0]
    Mb, Kb = per_lattice_parameters(params, batch, M, K)
    lost = np.zeros(batch)
    z = x[:, 0] - x[:, 1]
    first, env = frame_observables(params, x, z, z, Mb, Kb, observation)
    frames = [first]
    low = np.full_like(z, _FAR)
    high = np.full_like(z, -_FAR)
    for n in range(nsteps):
        x = step(method, params, x, dt, Mb, Kb, damping=damping, dissipated=lost)
        z = x[:, 0] - x[:, 1]
        low, high = np.minimum(low, z), np.maximum(high, z)
        if (n + 1) % observation.frame_every == 0:
            values, env = frame_observables(params, x, low, high, Mb, Kb, observation, lost.copy())
            frames.append(values)
            low = np.full_like(z, _FAR)
            high = np.full_like(z, -_FAR)
    return np.stack(frames), env, x
