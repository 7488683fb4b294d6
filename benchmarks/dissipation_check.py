#!/usr/bin/env python
"""Referee for ``warpchain.observe``'s ``dissipated`` observable (energy lost to damping).

WHAT IT CHECKS
--------------
On the breakup-statistics scene's Gaussian spot (``scenarios/breakup_statistics.py``: chain M = 30,
K = 160, N = 201, fixed ends; substrate velocity impulse u'_j(0) = A exp(-(j - c)^2 / (2 W^2))
(1 + noise xi_j), c = N // 2, xi_j from ``np.random.default_rng((seed, realisation))``, the scene's
rule; everything else at rest) with linear losses (``warpchain/losses.py``)::

    M u_j'' + K (2 u_j - u_{j-1} - u_{j+1}) + f(z_j) = - M gamma_s u_j' - mu gamma_c (u_j' - v_j')
      v_j''                                 - f(z_j) =                 + mu gamma_c (u_j' - v_j')

(mu = M / (M + 1); gamma_c: contact damping, a force on the relative velocity z' = u' - v' of the
substrate bead and its resonator, equal and opposite; gamma_s: substrate damping, a drag on u' only)
it integrates these equations with scipy's DOP853 at tight tolerances together with the extra state

    D' = P = sum_j [ M gamma_s u_j'^2 + mu gamma_c (u_j' - v_j')^2 ]       (losses.dissipation)

over ``periods`` periods T = 2 pi / 1.01 (the scene's period), giving reference values E_ref(T)
(the Hamiltonian, ``warpchain.energy``) and D_ref(T). Exactly, E(t) + D(t) = E(0).

It then runs the project's ``warpchain.observe`` (as ``observe_batch`` in the scene calls it:
frame_every = steps per period, the scene's Observation parameters) on the same state and losses with
each METHOD/STEPS_PER_PERIOD (dt = T / steps) and prints, at t = periods T:

    |E - E_ref|, |D - D_ref|, |E + D - E0|         (E, D: observe's last frame; E0 = energy(x0))

and, unless --no-oracle, a numpy oracle of the *same* splitting scheme (reference.accelerations,
losses.kick_matrices, reference.damped_kick: the kernels' arithmetic) that accumulates, per damped
kick, both
  * D_trap : the trapezoid rule h/2 (P(w_before) + P(w_after)) (what observe did before 2026-11-25: second order);
  * D_exact: the exact integral of P over the kick's exact damped flow, by the energy balance of the
             kick (q, hence a, fixed):  int_0^h P ds = a^T Mm int_0^h w ds - [KE(w_after) - KE(w_before)],
             int_0^h w ds = F w0 + Phi a,  F = int_0^h exp(-G s) ds (kick_matrices' F),
             Phi = int_0^h F(s) ds (from a 6x6 expm), Mm = diag(M, 1).
The oracle's columns show what an exact ``dissipated`` gives: |D_exact - D_ref|
fall like the scheme's energy error (|E - E_ref|), not 4x per halving of dt. ``obs-oracle`` compares
observe's D with the oracle's D_trap and D_exact (observe's is exact since
2026-11-25: ~1e-15 from D_exact); ``dx`` is the max difference of the final states
(observe vs oracle; both integrate the same scheme).

HOW TO RUN
----------
    python benchmarks/dissipation_check.py   # the defaults below, a few tens of seconds + Warp compile
    python benchmarks/dissipation_check.py --methods kahan6/32,kahan8/64 --periods 20 --gamma-c 1e-2
    python benchmarks/dissipation_check.py --no-oracle --no-ref-check   # fastest
    python benchmarks/dissipation_check.py --project /path/to/other/checkout  # referee another copy of warpchain
                                                                     # (put first on sys.path)

Runtime on the 2-core CPU box, defaults: ~23 s of CPU (60-100 s wall when the box is shared); DOP853 ~2-7 s
per solve, observe < 2 s per method (Warp kernels cached after the first compile), the numpy oracle the
rest (kahan8/256: 12800 steps x 16 kicks, 20-45 s).

Options (see --help): --A 0.4 --W 20 --gamma-c 1e-3 --gamma-s 0 (the scene's (1e-3, 0) damping case)
--periods 50 --methods kahan6/32,kahan8/64,kahan8/128,kahan8/256 --rtol 1e-13 --atol 1e-13
--noise/--seed/--realisation (default: the scene's noise 0.02, seed 20261122, realisation 0; --noise 0 for
a clean Gaussian) --device cpu --out dissipation-check.json. --ref-check re-solves DOP853 at rtol, atol
x 100 and reports the difference, a loose bound on the reference's own error (on by default). Measured on
the default case: the rtol = atol = 1e-13 reference agrees with a 1e-14 solve to 4e-11 in E and 2e-13 in D,
and |E_ref + D_ref - E0| = 4e-11; so |E - E_ref| around 1e-10 (kahan8 rows) is at the reference's floor.
--layout block runs observe's block kernels (the GPU layout; on the CPU Warp emulates the blocks, N <= its
block limit): both layouts hold their own trapezoid accumulation, so check both after a fix.

Exit status: 0 (the script reports; it does not judge). The JSON holds every number of the table plus the
set-up, the reference's self-consistency |E_ref + D_ref - E0| and timings.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

DEFAULT_METHODS = "kahan6/32,kahan8/64,kahan8/128,kahan8/256"


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--project",
        default=str(Path(__file__).resolve().parents[1]),
        help="warpchain checkout (put on sys.path for `scenarios`)",
    )
    p.add_argument("--A", type=float, default=0.4, help="impulse amplitude (substrate velocity)")
    p.add_argument("--W", type=float, default=20.0, help="Gaussian width in sites")
    p.add_argument("--gamma-c", type=float, default=1e-3, help="contact damping rate (on u' - v')")
    p.add_argument("--gamma-s", type=float, default=0.0, help="substrate damping rate (on u')")
    p.add_argument("--periods", type=float, default=50.0, help="run length in periods T = 2 pi / 1.01")
    p.add_argument("--methods", default=DEFAULT_METHODS, help="comma list of METHOD/STEPS_PER_PERIOD")
    p.add_argument("--rtol", type=float, default=1e-13)
    p.add_argument("--atol", type=float, default=1e-13)
    p.add_argument("--noise", type=float, default=None, help="relative impulse noise (default: the scene's)")
    p.add_argument("--seed", type=int, default=None, help="noise seed (default: the scene's)")
    p.add_argument("--realisation", type=int, default=0, help="noise realisation r (rng((seed, r)))")
    p.add_argument("--impulse", default=None, help="velocity | displacement (default: the scene's)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--layout", default="auto", help="observe's kernel layout (auto: thread on cpu)")
    p.add_argument("--no-oracle", action="store_true", help="skip the numpy oracle (D_trap / D_exact)")
    p.add_argument("--no-ref-check", action="store_true", help="skip the looser second DOP853 solve")
    p.add_argument("--out", default="dissipation-check.json")
    return p.parse_args(argv)


def parse_methods(text):
    out = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        name, _, spp = item.partition("/")
        if not spp:
            raise SystemExit(f"method {item!r}: expected METHOD/STEPS_PER_PERIOD, e.g. kahan8/64")
        out.append((name, int(spp)))
    return out


# ----------------------------------------------------------------------------- the reference (DOP853)


def damped_rhs(params, gamma_c, gamma_s):
    """f(t, y), y = [x (4, N) flattened, D]: the lossy equations written out from losses.py's docstring
    (independently of losses.damping_matrix / rhs_flat) and D' = dissipated power."""
    from warpchain import model

    N, M = params.N, params.M
    mu = M / (M + 1.0)

    def f(t, y):
        x = y[:-1].reshape(1, 4, N)
        pu, pv = x[0, 2], x[0, 3]
        rel = pu - pv
        acc = model.accelerations(params, x)[0]
        out = np.empty_like(y)
        out[0:N] = pu
        out[N : 2 * N] = pv
        # M u'' = ... - M gs u' - mu gc (u' - v');   v'' = ... + mu gc (u' - v')
        out[2 * N : 3 * N] = acc[0] - gamma_s * pu - (mu * gamma_c / M) * rel
        out[3 * N : 4 * N] = acc[1] + mu * gamma_c * rel
        out[-1] = np.sum(M * gamma_s * pu * pu + mu * gamma_c * rel * rel)
        return out

    return f


def reference_solve(params, x0, t_end, gamma_c, gamma_s, rtol, atol):
    from scipy.integrate import solve_ivp

    from warpchain import energy

    y0 = np.concatenate([x0.ravel(), [0.0]])
    t0 = time.perf_counter()
    sol = solve_ivp(damped_rhs(params, gamma_c, gamma_s), (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=atol)
    wall = time.perf_counter() - t0
    if not sol.success:
        raise RuntimeError(f"DOP853 failed: {sol.message}")
    xT = sol.y[:-1, -1].reshape(4, params.N)
    return {
        "x": xT,
        "E": float(energy(params, xT)[0]),
        "D": float(sol.y[-1, -1]),
        "nfev": int(sol.nfev),
        "steps": int(len(sol.t) - 1),
        "wall_seconds": wall,
        "rtol": rtol,
        "atol": atol,
    }


# ----------------------------------------------------------------------------- numpy oracle of the scheme


def _phi(G, h):
    """Phi = int_0^h F(s) ds, F(s) = int_0^s exp(-G r) dr (top-right block of a 6x6 exponential)."""
    from scipy.linalg import expm

    aug = np.zeros((6, 6))
    aug[:2, :2] = -G * h
    aug[:2, 2:4] = np.eye(2) * h
    aug[2:4, 4:6] = np.eye(2) * h
    return expm(aug)[:2, 4:6]


def oracle(params, x0, method_name, dt, nsteps, gamma_c, gamma_s):
    """The splitting scheme observe runs (reference.step's arithmetic), accumulating the trapezoid D and the
    exact per-kick D (module docstring). Returns final x, D_trap, D_exact."""
    from warpchain import reference
    from warpchain.integrators import get_method
    from warpchain.losses import Damping, damping_matrix, kick_matrices, power_coefficients, power

    meth = get_method(method_name)
    M = params.M
    Mb = np.array([M])
    inv_M = reference.inverse_mass(Mb)
    Kb = np.array([params.K])
    damping = Damping(gamma_c, gamma_s)
    coeff = np.ascontiguousarray(
        kick_matrices(meth.kicks, dt, Mb, damping, 1)[:, :, :8]
    )  # E, F (later entries: unused)
    pc = power_coefficients(Mb, damping, 1)
    G = damping_matrix(M, gamma_c, gamma_s)
    kicks = [float(k) for k in meth.kicks]
    drifts = [float(c) for c in meth.drifts]
    hs = [k * dt for k in kicks]
    F = [coeff[0, i, 4:8].reshape(2, 2) for i in range(len(kicks))]
    Phi = [_phi(G, h) for h in hs]
    x = np.array(x0, dtype=np.float64).reshape(1, 4, params.N).copy()
    d_trap = 0.0
    d_exact = 0.0

    def kick(i, acc):
        nonlocal d_trap, d_exact
        pu0, pv0 = x[0, 2].copy(), x[0, 3].copy()
        au, av = acc[0, 0], acc[0, 1]
        before = power(x, pc)[0]
        reference.damped_kick(x, acc, coeff[:, i])
        pu1, pv1 = x[0, 2], x[0, 3]
        d_trap += hs[i] * 0.5 * (before + power(x, pc)[0])
        # int_0^h w ds = F w0 + Phi a ; work of the (frozen) conservative force minus the kinetic change
        F_, P_ = F[i], Phi[i]
        iu = F_[0, 0] * pu0 + F_[0, 1] * pv0 + P_[0, 0] * au + P_[0, 1] * av
        iv = F_[1, 0] * pu0 + F_[1, 1] * pv0 + P_[1, 0] * au + P_[1, 1] * av
        work = np.sum(M * au * iu + av * iv)
        dke = np.sum(0.5 * M * (pu1 - pu0) * (pu1 + pu0) + 0.5 * (pv1 - pv0) * (pv1 + pv0))
        d_exact += work - dke

    acc = reference.accelerations(params, x, inv_M, Kb)
    for _ in range(nsteps):
        kick(0, acc)
        for i, c in enumerate(drifts):
            x[:, :2] += c * dt * x[:, 2:]
            acc = reference.accelerations(params, x, inv_M, Kb)
            kick(i + 1, acc)
    return x[0], float(d_trap), float(d_exact)


# ----------------------------------------------------------------------------- main


def main(argv=None):
    args = parse_args(argv)
    if args.project and args.project not in sys.path:
        sys.path.insert(0, args.project)
    import warpchain
    from scenarios._common import PAPER_K, PAPER_M, PAPER_N, PAPER_OMEGA
    from scenarios.breakup_statistics import Parameters, initial_states
    from warpchain import ChainParams, energy
    from warpchain.losses import Damping, dissipation
    from warpchain.observe import Observation, observe

    scene = Parameters()
    P = Parameters(
        noise=scene.noise if args.noise is None else args.noise,
        seed=scene.seed if args.seed is None else args.seed,
        impulse=scene.impulse if args.impulse is None else args.impulse,
    )
    params = ChainParams(PAPER_M, PAPER_K, PAPER_N)  # the scene's chain (boundary: ChainParams' default)
    T = 2 * np.pi / PAPER_OMEGA
    t_end = args.periods * T
    x0 = initial_states(params.N, args.A, [args.W], args.realisation + 1, P)[args.realisation]
    E0 = float(energy(params, x0)[0])
    methods = parse_methods(args.methods)
    damping = Damping(args.gamma_c, args.gamma_s)

    # the reference's right-hand side against the project's own (rhs_flat) and the power against losses.dissipation
    from warpchain.losses import rhs_flat

    probe = x0.copy()
    probe[3] = 0.05 * np.cos(np.arange(params.N))  # some relative velocity, so the damping terms are exercised
    mine = damped_rhs(params, args.gamma_c, args.gamma_s)(0.0, np.concatenate([probe.ravel(), [0.0]]))
    theirs = rhs_flat(params, None, None, args.gamma_c, args.gamma_s)(0.0, probe.ravel())
    rhs_agreement = float(np.max(np.abs(mine[:-1] - theirs)))
    power_agreement = float(abs(mine[-1] - dissipation(probe[None], params.M, damping)[0]))

    print(f"warpchain {warpchain.__version__} from {os.path.dirname(warpchain.__file__)}")
    print(
        f"scene: M={params.M:g} K={params.K:g} N={params.N} boundary={params.boundary}; {P.impulse} impulse "
        f"A={args.A:g} W={args.W:g} noise={P.noise:g} seed=({P.seed}, {args.realisation}); "
        f"gamma_c={args.gamma_c:g} gamma_s={args.gamma_s:g}; T=2pi/{PAPER_OMEGA:g}={T:.6f}, "
        f"{args.periods:g} periods (t={t_end:.4f}); E0={E0:.12g}"
    )
    print(
        f"check: referee rhs vs losses.rhs_flat max diff {rhs_agreement:.1e}; "
        f"power vs losses.dissipation {power_agreement:.1e}"
    )

    ref = reference_solve(params, x0, t_end, args.gamma_c, args.gamma_s, args.rtol, args.atol)
    ref_balance = ref["E"] + ref["D"] - E0
    print(
        f"DOP853 rtol={args.rtol:g} atol={args.atol:g}: E_ref={ref['E']:.15g} D_ref={ref['D']:.15g} "
        f"|E_ref+D_ref-E0|={abs(ref_balance):.2e} "
        f"({ref['steps']} steps, {ref['nfev']} f-evals, {ref['wall_seconds']:.1f} s)"
    )
    ref_err = None
    if not args.no_ref_check:
        loose = reference_solve(params, x0, t_end, args.gamma_c, args.gamma_s, args.rtol * 100, args.atol * 100)
        ref_err = {
            "rtol": loose["rtol"],
            "atol": loose["atol"],
            "dE": abs(loose["E"] - ref["E"]),
            "dD": abs(loose["D"] - ref["D"]),
            "dx": float(np.max(np.abs(loose["x"] - ref["x"]))),
            "wall_seconds": loose["wall_seconds"],
        }
        print(
            f"reference error estimate (vs rtol={loose['rtol']:g}): |dE|={ref_err['dE']:.1e} |dD|={ref_err['dD']:.1e} "
            f"max|dx|={ref_err['dx']:.1e}  (a loose upper bound on the tight solve's error)"
        )

    rows = []
    for name, spp in methods:
        observation = Observation(
            frame_every=spp,
            threshold=scene.threshold,
            radius=scene.radius,
            contrast=scene.contrast,
            spot=args.W,
            lag_frames=scene.velocity_lag,
        )
        t0 = time.perf_counter()
        run = observe(
            params,
            x0[None],
            t_end,
            T / spp,
            observation=observation,
            method=name,
            damping=damping,
            device=args.device,
            layout=args.layout,
            max_energy_error=None,  # report, never raise: the referee judges
        )
        wall = time.perf_counter() - t0
        E = float(run["energy"][-1, 0])
        D = float(run["dissipated"][-1, 0])
        row = {
            "method": name,
            "steps_per_period": spp,
            "dt": run.dt,
            "nsteps": run.nsteps,
            "t_final": float(run.t[-1]),
            "layout": run.layout,
            "E": E,
            "D": D,
            "E_host": float(energy(params, run.x)[0]),
            "err_E": abs(E - ref["E"]),
            "err_D": abs(D - ref["D"]),
            "balance": abs(E + D - E0),
            "min_contact": float(np.min(run["min_contact"][:, 0])),
            "observe_seconds": wall,
        }
        if not args.no_oracle:
            t1 = time.perf_counter()
            xo, d_trap, d_exact = oracle(params, x0, name, run.dt, run.nsteps, args.gamma_c, args.gamma_s)
            row.update(
                {
                    "D_trap_oracle": d_trap,
                    "D_exact_oracle": d_exact,
                    "err_D_exact_oracle": abs(d_exact - ref["D"]),
                    "err_D_trap_oracle": abs(d_trap - ref["D"]),
                    "observe_minus_trap": abs(D - d_trap),
                    "observe_minus_exact": abs(D - d_exact),
                    "balance_exact_oracle": abs(float(energy(params, xo)[0]) + d_exact - E0),
                    "dx_observe_oracle": float(np.max(np.abs(xo - run.x[0]))),
                    "oracle_seconds": time.perf_counter() - t1,
                }
            )
        rows.append(row)
        print(
            f"  ran {name}/{spp}: observe ({run.layout} layout, {run.device}) {wall:.1f} s"
            + ("" if args.no_oracle else f", oracle {row['oracle_seconds']:.1f} s")
        )

    # the table
    head = f"{'method':>12} {'dt':>8} {'steps':>6} {'|E-Eref|':>9} {'|D-Dref|':>9} {'ratio':>5} {'|E+D-E0|':>9}"
    if not args.no_oracle:
        head += f" {'|Dex-Dref|':>10} {'|E+Dex-E0|':>10} {'obs-trap':>8} {'obs-exact':>9} {'dx':>7}"
    print()
    print(
        f"at t = {t_end:.4f} ({args.periods:g} periods); E_ref = {ref['E']:.12g}, D_ref = {ref['D']:.12g}, "
        f"E0 = {E0:.12g}"
    )
    print(head)
    prev = prev_m = None
    for r in rows:
        ratio = (
            f"{prev / r['err_D']:5.2f}" if prev is not None and r["err_D"] > 0 and r["method"] == prev_m else "    -"
        )
        line = (
            f"{r['method'] + '/' + str(r['steps_per_period']):>12} {r['dt']:8.5f} {r['nsteps']:6d} "
            f"{r['err_E']:9.2e} {r['err_D']:9.2e} {ratio} {r['balance']:9.2e}"
        )
        if not args.no_oracle:
            line += (
                f" {r['err_D_exact_oracle']:10.2e} {r['balance_exact_oracle']:10.2e} {r['observe_minus_trap']:8.1e} "
                f"{r['observe_minus_exact']:9.1e} {r['dx_observe_oracle']:7.1e}"
            )
        print(line)
        prev, prev_m = r["err_D"], r["method"]
    print(
        "ratio: |D-Dref| of the row above / this row (same method; 4 = second order in dt). "
        "Dex: the oracle's exact per-kick dissipation; obs-trap / obs-exact: |D_observe - D_oracle|; "
        "dx: max|x_observe - x_oracle|."
    )

    result = {
        "what": "observe's dissipated vs DOP853 with D' = P as an extra state (see referee.py's docstring)",
        "setup": {
            "M": params.M,
            "K": params.K,
            "N": params.N,
            "boundary": params.boundary,
            "A": args.A,
            "W": args.W,
            "impulse": P.impulse,
            "noise": P.noise,
            "seed": [P.seed, args.realisation],
            "gamma_c": args.gamma_c,
            "gamma_s": args.gamma_s,
            "period": T,
            "periods": args.periods,
            "t_final": t_end,
            "E0": E0,
            "device": args.device,
        },
        "checks": {"rhs_vs_rhs_flat": rhs_agreement, "power_vs_losses_dissipation": power_agreement},
        "reference": {k: v for k, v in ref.items() if k != "x"} | {"balance": ref_balance, "error_estimate": ref_err},
        "rows": rows,
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
