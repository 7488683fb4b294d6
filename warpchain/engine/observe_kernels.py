"""The kernels of ``warpchain.observe``: a splitting step loop per layout (``thread_kernel``: a thread per
lattice; ``block_kernel``: a thread block per lattice) that tracks each site's z extremes every step and
reduces the observables at every frame (``warpchain.observe``'s module docstring says what they are), with
the exact energy of every damped kick. Built on first use."""

import functools

import warp as wp


@functools.lru_cache(maxsize=None)
def thread_kernel():

    from .thread_kernels import (
        NO_CONTACT,
        ONE,
        ZERO,
        any_kick,
        compute_accelerations,
        drift,
        kick_loss,
        site_energy,
    )

    @wp.func
    def frame(
        x: wp.array3d(dtype=wp.float64),
        b: int,
        n: int,
        boundary: int,
        mass: wp.float64,
        coupling: wp.float64,
        half_width: wp.float64,
        threshold: wp.float64,
        radius: int,
        contrast: wp.float64,
        z_low: wp.array2d(dtype=wp.float64),
        z_high: wp.array2d(dtype=wp.float64),
        envelope: wp.array2d(dtype=wp.float64),
        obs: wp.array3d(dtype=wp.float64),
        r: int,
        dissipated: wp.float64,
    ):
        """Frame r of lattice b: obs[r, b] from the state and the interval's z extremes, which it resets."""
        centre = n / 2
        for j in range(n):
            envelope[b, j] = wp.max(z_high[b, j], -z_low[b, j])
        total = ZERO
        squares = ZERO
        inside = ZERO
        top = ZERO
        low = NO_CONTACT
        peaks = int(0)
        for j in range(n):
            e = site_energy(
                x[b, 0, j], x[b, 1, j], x[b, 2, j], x[b, 3, j], x[b, 0, (j + 1) % n], j, n, boundary, mass, coupling
            )
            total = total + e
            squares = squares + e * e
            if wp.abs(wp.float64(j - centre)) <= half_width:
                inside = inside + e
            env = envelope[b, j]
            top = wp.max(top, env)
            low = wp.min(low, ONE + z_low[b, j])
            if env > threshold:
                peak = int(1)
                left_low = env
                right_low = env
                for i in range(1, radius + 1):
                    left = ZERO  # past the chain's end
                    right = ZERO
                    if j - i >= 0:
                        left = envelope[b, j - i]
                        if left >= env:
                            peak = 0
                    if j + i < n:
                        right = envelope[b, j + i]
                        if right > env:
                            peak = 0
                    left_low = wp.min(left_low, left)
                    right_low = wp.min(right_low, right)
                if left_low > contrast * env or right_low > contrast * env:
                    peak = 0
                peaks = peaks + peak
        for j in range(n):
            z_low[b, j] = NO_CONTACT
            z_high[b, j] = -NO_CONTACT
        obs[r, b, 0] = wp.float64(peaks)
        pr = ZERO
        if squares > ZERO:
            pr = total * total / squares
        obs[r, b, 1] = pr
        obs[r, b, 2] = inside
        obs[r, b, 3] = top
        obs[r, b, 4] = low
        obs[r, b, 5] = total
        obs[r, b, 6] = dissipated

    @wp.func
    def lossy_kick(
        x: wp.array3d(dtype=wp.float64),
        acc: wp.array3d(dtype=wp.float64),
        b: int,
        n: int,
        h: wp.float64,
        loss: int,
        damp: wp.array3d(dtype=wp.float64),
        i: int,
        mass: wp.float64,
    ) -> wp.float64:
        """Kick i (``kernels.any_kick``); returns the energy it dissipates (``kernels.kick_loss``, exact)."""
        spent = ZERO
        if loss != 0:
            for j in range(n):
                spent = spent + kick_loss(x[b, 2, j], x[b, 3, j], acc[b, 0, j], acc[b, 1, j], damp, b, i, mass)
        any_kick(x, acc, b, n, h, loss, damp, i)
        return spent

    @wp.kernel(enable_backward=False)
    def observed_splitting(
        x: wp.array3d(dtype=wp.float64),
        acc: wp.array3d(dtype=wp.float64),
        inv_mass: wp.array(dtype=wp.float64),
        mass: wp.array(dtype=wp.float64),
        coupling: wp.array(dtype=wp.float64),
        drifts: wp.array(dtype=wp.float64),
        kicks: wp.array(dtype=wp.float64),
        boundary: int,
        dt: wp.float64,
        nsteps: int,
        lossy: wp.array(dtype=wp.int32),
        damp: wp.array3d(dtype=wp.float64),
        first_step: int,
        frame_every: int,
        threshold: wp.float64,
        radius: int,
        contrast: wp.float64,
        spot: wp.array(dtype=wp.float64),
        z_low: wp.array2d(dtype=wp.float64),
        z_high: wp.array2d(dtype=wp.float64),
        lost: wp.array2d(dtype=wp.float64),
        envelope: wp.array2d(dtype=wp.float64),
        obs: wp.array3d(dtype=wp.float64),
    ):
        """``kernels.splitting_kernel`` for lattice b = tid, tracking z's extremes in ``z_low``/``z_high``
        (batch, N) and reducing the observables into obs[frame, b] at every frame, frame 0 (the start,
        envelope |z|) included when ``first_step`` is 0 (module docstring)."""
        b = wp.tid()
        n = x.shape[2]
        stages = drifts.shape[0]
        m = inv_mass[b]
        k = coupling[b]
        loss = lossy[b]
        mb = mass[b]
        dissipated = ZERO
        if first_step != 0:
            dissipated = lost[b, 0]
        first = int(0)
        if first_step == 0:
            first = -1  # an extra pass without a step: frame 0, the start (envelope |z|)
            for j in range(n):
                z = x[b, 0, j] - x[b, 1, j]
                z_low[b, j] = z
                z_high[b, j] = z
        compute_accelerations(x, acc, b, b, n, boundary, m, k, 0, acc, 0, 0, 0)  # no stiffness history (acc: unused)
        for step in range(first, nsteps):
            if step >= 0:
                dissipated = dissipated + lossy_kick(x, acc, b, n, kicks[0] * dt, loss, damp, 0, mb)
                for s in range(stages):
                    drift(x, b, n, drifts[s] * dt)
                    compute_accelerations(x, acc, b, b, n, boundary, m, k, 0, acc, 0, 0, 0)
                    h = kicks[s + 1] * dt
                    dissipated = dissipated + lossy_kick(x, acc, b, n, h, loss, damp, s + 1, mb)
                for j in range(n):
                    z = x[b, 0, j] - x[b, 1, j]
                    z_low[b, j] = wp.min(z_low[b, j], z)
                    z_high[b, j] = wp.max(z_high[b, j], z)
            done = first_step + step + 1
            if done % frame_every == 0:
                r = done / frame_every
                frame(
                    x, b, n, boundary, mass[b], k, spot[b], threshold, radius, contrast, z_low, z_high, envelope, obs,
                    r, dissipated,
                )  # fmt: skip
        lost[b, 0] = dissipated

    return observed_splitting


@functools.lru_cache(maxsize=None)
def block_kernel(block: int, stages: int):

    from . import block_kernels as bk
    from .thread_kernels import NO_CONTACT, ONE, ZERO, kick_loss, site_energy

    halves = 2 * block

    @wp.func
    def exchange(
        buf: wp.tile[wp.float64, halves], u: wp.float64, parity: int, nbr: wp.vec4i, boundary: int
    ) -> wp.vec2d:
        offset = parity * block
        wp.tile_assign(buf, wp.tile(u), offset=(offset,))
        left = bk.neighbour_or_wall(buf[offset + nbr[0]], u, nbr[2], boundary)
        right = bk.neighbour_or_wall(buf[offset + nbr[1]], u, nbr[3], boundary)
        return wp.vec2d(left, right)

    @wp.func
    def kick_with_loss(
        pu: wp.float64,
        pv: wp.float64,
        a: wp.vec2d,
        h: wp.float64,
        loss: int,
        damp: wp.array3d(dtype=wp.float64),
        b: int,
        i: int,
        mass: wp.float64,
    ) -> wp.vec3d:
        """``block_kernels.site_kick`` and the energy it dissipates at this site (``kernels.kick_loss``,
        exact): (u', v', lost)."""
        w = bk.site_kick(pu, pv, a, h, loss, damp, b, i)
        spent = ZERO
        if loss != 0:
            spent = kick_loss(pu, pv, a[0], a[1], damp, b, i, mass)
        return wp.vec3d(w[0], w[1], spent)

    @wp.func
    def frame(
        buf: wp.tile[wp.float64, halves],
        parity: int,
        state: wp.vec4d,
        right_u: wp.float64,
        z_low: wp.float64,
        z_high: wp.float64,
        active: bool,
        b: int,
        j: int,
        n: int,
        boundary: int,
        mass: wp.float64,
        coupling: wp.float64,
        half_width: wp.float64,
        threshold: wp.float64,
        radius: int,
        contrast: wp.float64,
        envelope: wp.array2d(dtype=wp.float64),
        obs: wp.array3d(dtype=wp.float64),
        r: int,
        lost_site: wp.float64,
    ):
        """Frame r of lattice b as block reductions; the envelope is shared through half ``parity`` of the
        tile (the caller flips parity before, as for an exchange). Idle threads contribute nothing."""
        env = ZERO
        e = ZERO
        inside = ZERO
        low = NO_CONTACT
        centre = n / 2
        if active:
            env = wp.max(z_high, -z_low)
            e = site_energy(state[0], state[1], state[2], state[3], right_u, j, n, boundary, mass, coupling)
            if wp.abs(wp.float64(j - centre)) <= half_width:
                inside = e
            low = ONE + z_low
            envelope[b, j] = env
        offset = parity * block
        wp.tile_assign(buf, wp.tile(env), offset=(offset,))
        peak = ZERO
        if active and env > threshold:
            peak = ONE
            left_low = env
            right_low = env
            for i in range(1, radius + 1):
                left = ZERO  # past the chain's end
                right = ZERO
                if j - i >= 0:
                    left = buf[offset + j - i]
                    if left >= env:
                        peak = ZERO
                if j + i < n:
                    right = buf[offset + j + i]
                    if right > env:
                        peak = ZERO
                left_low = wp.min(left_low, left)
                right_low = wp.min(right_low, right)
            if left_low > contrast * env or right_low > contrast * env:
                peak = ZERO
        mine = ZERO  # idle threads run a fake dynamics (never stored): they dissipate nothing real
        if active:
            mine = lost_site
        lost_total = wp.tile_sum(wp.tile(mine))
        peaks = wp.tile_sum(wp.tile(peak))
        total = wp.tile_sum(wp.tile(e))
        squares = wp.tile_sum(wp.tile(e * e))
        spot_total = wp.tile_sum(wp.tile(inside))
        top = wp.tile_max(wp.tile(env))
        lowest = wp.tile_min(wp.tile(low))
        if j == 0:
            obs[r, b, 0] = peaks[0]
            pr = ZERO
            if squares[0] > ZERO:
                pr = total[0] * total[0] / squares[0]
            obs[r, b, 1] = pr
            obs[r, b, 2] = spot_total[0]
            obs[r, b, 3] = top[0]
            obs[r, b, 4] = lowest[0]
            obs[r, b, 5] = total[0]
            obs[r, b, 6] = lost_total[0]

    options = {"enable_backward": False, "module": "unique", "grid_stride": False, "launch_bounds": block}

    @wp.kernel(**options)
    def observed_splitting(
        x: wp.array3d(dtype=wp.float64),
        inv_mass: wp.array(dtype=wp.float64),
        mass: wp.array(dtype=wp.float64),
        coupling: wp.array(dtype=wp.float64),
        drifts: bk.coefficients,
        kicks: bk.coefficients,
        boundary: int,
        nsteps: int,
        lossy: wp.array(dtype=wp.int32),
        damp: wp.array3d(dtype=wp.float64),
        first_step: int,
        frame_every: int,
        threshold: wp.float64,
        radius: int,
        contrast: wp.float64,
        spot: wp.array(dtype=wp.float64),
        zlo: wp.array2d(dtype=wp.float64),
        zhi: wp.array2d(dtype=wp.float64),
        lost: wp.array2d(dtype=wp.float64),
        envelope: wp.array2d(dtype=wp.float64),
        obs: wp.array3d(dtype=wp.float64),
    ):
        """``block_kernels`` splitting (damped kicks where ``lossy[b]``), a block per lattice, with the
        z extremes in registers and the frame reductions as block reductions (module docstring)."""
        b, j = wp.tid()
        n = x.shape[2]
        active = j < n
        nbr = bk.site_neighbours(j, n, boundary)
        start = bk.load_site(x, b, j, active)
        u = start[0]
        v = start[1]
        pu = start[2]
        pv = start[3]
        m = inv_mass[b]
        k = coupling[b]
        mb = mass[b]
        loss = lossy[b]
        half_width = spot[b]
        lost_site = ZERO  # energy this site has dissipated (exact over each damped kick)
        z_low = u - v
        z_high = u - v
        if active and first_step != 0:
            z_low = zlo[b, j]
            z_high = zhi[b, j]
            lost_site = lost[b, j]
        buf = wp.tile_zeros(shape=(halves,), dtype=wp.float64, storage="shared")
        parity = int(0)
        nb = exchange(buf, u, parity, nbr, boundary)
        a = bk.site_acceleration(u, v, nb[0], nb[1], m, k)
        first = int(0)
        if first_step == 0:
            first = -1  # an extra pass without a step: frame 0, the start (envelope |z|)
        for step in range(first, nsteps):
            if step >= 0:
                w = kick_with_loss(pu, pv, a, kicks[0], loss, damp, b, 0, mb)
                pu = w[0]
                pv = w[1]
                lost_site = lost_site + w[2]
                for s in range(wp.static(stages)):
                    h = drifts[s]
                    u = u + h * pu
                    v = v + h * pv
                    parity = 1 - parity
                    nb = exchange(buf, u, parity, nbr, boundary)
                    a = bk.site_acceleration(u, v, nb[0], nb[1], m, k)
                    w = kick_with_loss(pu, pv, a, kicks[s + 1], loss, damp, b, s + 1, mb)
                    pu = w[0]
                    pv = w[1]
                    lost_site = lost_site + w[2]
                z = u - v
                z_low = wp.min(z_low, z)
                z_high = wp.max(z_high, z)
            done = first_step + step + 1
            if done % frame_every == 0:
                parity = 1 - parity
                state = wp.vec4d(u, v, pu, pv)
                frame(
                    buf,
                    parity,
                    state,
                    nb[1],
                    z_low,
                    z_high,
                    active,
                    b,
                    j,
                    n,
                    boundary,
                    mb,
                    k,
                    half_width,
                    threshold,
                    radius,
                    contrast,
                    envelope,
                    obs,
                    done / frame_every,
                    lost_site,
                )
                z_low = NO_CONTACT
                z_high = -NO_CONTACT
        bk.store_site(x, b, j, active, wp.vec4d(u, v, pu, pv))
        if active:
            zlo[b, j] = z_low
            zhi[b, j] = z_high
            lost[b, j] = lost_site

    return observed_splitting
