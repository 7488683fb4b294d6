"""Host linear solve of the Newton step: ``solve_linear`` against its alternatives, per BLAS thread count.

Run from the repository root (CPU only, under a minute):

    python3 benchmarks/linear_solve.py
    python3 benchmarks/linear_solve.py --threads 0,1,2,4,8 --json /tmp/linear_solve.json

What it measures (issue #15: ``scenarios/throughput.py:_monodromy`` reported 5.31 ms for the solve on a
402 x 402 Jacobian, timed by one call):

* the matrix: J = U diag(s) V^T with random orthogonal U, V and s log-spaced from 1 to 1e-6 (2-norm
  condition number 1e6), n = 402 (the paper breather's reversible shooting, 2N unknowns) and 804. J is
  stored as the Newton loop gets it: the velocity rows of an F-ordered (2n, n) column block, so a
  non-contiguous view that every variant has to copy; r is a random vector.
* the variants, each on the same J and r:
    - ``solve_linear``: ``continuation.newton.solve_linear`` as it is in this checkout;
    - ``scipy.solve+warn``: the body solve_linear had before this benchmark (scipy.linalg.solve with
      LinAlgWarning raised as an error; scipy does 1-norm, getrf, gecon, getrs and, since 1.17, a
      structure detection pass);
    - ``scipy.solve gen``: the same with ``assume_a="gen"`` (no structure detection);
    - ``lu_factor+gecon``: scipy.linalg.lu_factor, lapack.dgecon on the factors, lu_solve;
    - ``dgetrf+dgecon``: the raw LAPACK calls (dlange, dgetrf, dgecon, dgetrs) on one F-ordered copy
      (what solve_linear does since this benchmark was written);
    - ``dgetrf, no gecon``: the same without the condition estimate, to show what gecon costs;
    - ``numpy.solve``: numpy.linalg.solve (gesv; NO condition check, so not a drop-in replacement).
  Every variant with a condition check falls back to lstsq when rcond < machine epsilon, as scipy's
  LinAlgWarning does; ``rel diff`` is the distance to numpy.linalg.solve's answer.
* the timings, per variant, n and BLAS thread count: ``best`` and ``median`` of 20 calls after 3
  warm-up calls. The variants are called in turn (the order rotating every round), so that load from
  elsewhere on the machine falls on all of them alike; numpy.solve, which runs on numpy's OpenBLAS,
  is timed on its own after the others; each group starts after 0.15 s without BLAS work.
  For n = 402 only: ``idle`` the median of 3 calls each made after 0.15 s without BLAS work
  (OpenBLAS workers, by default, stop spinning after about 2^28 cycles and must then be woken);
  ``after np`` the median of 5 calls each made right after a numpy 402 x 402 matmul, whose own
  OpenBLAS workers are still spinning then (numpy and scipy wheels each carry their own OpenBLAS, so
  two thread pools compete for the cores, as in a Newton loop that does numpy work between solves).
  ``first``: the first solve_linear call of a fresh process (scipy's thread pool start-up included).
* ``_monodromy``-style: 10 repetitions of (3 untimed solve_linear calls, then one timed call), as the
  scenario does once; min / median / max of the single timed calls shows what one call can report.

Thread counts are set per child process through OPENBLAS_NUM_THREADS / OMP_NUM_THREADS /
MKL_NUM_THREADS (numpy and scipy each load their own OpenBLAS; both read these at start-up), so no
dependency is needed; ``--threads 0`` means "inherit this shell's settings". threadpoolctl, when
importable, is only used to print which BLAS libraries are loaded and with how many threads.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import scipy
import scipy.linalg
from scipy.linalg import lapack

from continuation.newton import solve_linear


SIZES = (402, 804)
WARMUP, REPEATS, IDLE_CALLS, IDLE_SECONDS, AFTER_NUMPY_CALLS = 3, 20, 3, 0.15, 5
SETTLE_SECONDS, MONODROMY_SINGLES = 0.15, 10
EPS = np.finfo(np.float64).eps
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def test_matrix(n: int, cond: float = 1e6, seed: int = 0):
    """J (n x n, 2-norm condition ``cond``) as a non-contiguous view like PeriodMap's, and r."""
    rng = np.random.default_rng(seed)
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    block = np.asfortranarray(rng.standard_normal((2 * n, n)))
    block[n:, :] = (U * np.logspace(0, -np.log10(cond), n)) @ V.T
    return block[n:, :], rng.standard_normal(n)


def old_solve_linear(J, r):
    """solve_linear's body before this benchmark, for comparison."""
    if J.shape[0] == J.shape[1]:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
                return scipy.linalg.solve(J, r, check_finite=False), False
        except (scipy.linalg.LinAlgError, scipy.linalg.LinAlgWarning, ValueError):
            pass
    return scipy.linalg.lstsq(J, r, check_finite=False)[0], True


def scipy_solve_gen(J, r):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
            return scipy.linalg.solve(J, r, check_finite=False, assume_a="gen"), False
    except (scipy.linalg.LinAlgError, scipy.linalg.LinAlgWarning, ValueError):
        return scipy.linalg.lstsq(J, r, check_finite=False)[0], True


def lu_factor_gecon(J, r):
    anorm = np.linalg.norm(J, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", scipy.linalg.LinAlgWarning)  # lu_factor warns on an exact zero pivot
        try:
            lu, piv = scipy.linalg.lu_factor(J, check_finite=False)
        except scipy.linalg.LinAlgWarning:
            return scipy.linalg.lstsq(J, r, check_finite=False)[0], True
    rcond, _ = lapack.dgecon(lu, anorm, norm="1")
    if not rcond >= EPS:
        return scipy.linalg.lstsq(J, r, check_finite=False)[0], True
    return scipy.linalg.lu_solve((lu, piv), r, check_finite=False), False


def raw_lapack(J, r, level2_threads: int | None = None):
    """dgetrf, dgecon, dgetrs; with ``level2_threads``, dgecon and dgetrs (level-2 work) on that many BLAS
    threads and dgetrf on the process's."""
    import contextlib

    from continuation.hostblas import blas_threads

    a = np.array(J, dtype=np.float64, order="F")
    anorm = lapack.dlange("1", a)
    lu, piv, info = lapack.dgetrf(a, overwrite_a=True)
    if info == 0:
        with blas_threads(level2_threads) if level2_threads else contextlib.nullcontext():
            rcond, info = lapack.dgecon(lu, anorm, norm="1")
            if info == 0 and rcond >= EPS:
                x, info = lapack.dgetrs(lu, piv, r)
                if info == 0:
                    return x, False
    return scipy.linalg.lstsq(J, r, check_finite=False)[0], True


def raw_lapack_no_gecon(J, r):
    a = np.array(J, dtype=np.float64, order="F")
    lu, piv, info = lapack.dgetrf(a, overwrite_a=True)
    if info == 0:
        x, info = lapack.dgetrs(lu, piv, r)
        if info == 0:
            return x, False
    return scipy.linalg.lstsq(J, r, check_finite=False)[0], True


def numpy_solve(J, r):
    return np.linalg.solve(J, r), False


VARIANTS = {
    "solve_linear": solve_linear,
    "scipy.solve+warn": old_solve_linear,
    "scipy.solve gen": scipy_solve_gen,
    "lu_factor+gecon": lu_factor_gecon,
    "dgetrf+dgecon": raw_lapack,
    "dgetrf, no gecon": raw_lapack_no_gecon,
    "gecon+getrs 1 thr": lambda J, r: raw_lapack(J, r, level2_threads=1),
    "numpy.solve": numpy_solve,
}


def _ms(seconds) -> float:
    return 1e3 * seconds


def _time_one(fn, J, r) -> float:
    t0 = time.perf_counter()
    fn(J, r)
    return time.perf_counter() - t0


def _interleaved(fns: dict, J, r, rounds: int, before=None) -> dict:
    """Seconds per call of each function, calling them in turn (rotating the order every round), so
    that load from elsewhere on the machine falls on all of them alike; ``before()`` precedes each call."""
    names, times = list(fns), {name: [] for name in fns}
    for k in range(rounds):
        for name in names[k % len(names) :] + names[: k % len(names)]:
            if before is not None:
                before()
            times[name].append(_time_one(fns[name], J, r))
    return times


def child(threads: int) -> dict:
    """Every measurement under the thread settings this process was started with."""
    out = {"threads": threads, "rows": []}
    J, r = test_matrix(SIZES[0])
    time.sleep(SETTLE_SECONDS)
    out["first_ms"] = _ms(_time_one(solve_linear, J, r))  # the process's first scipy BLAS call
    other = np.random.default_rng(1).standard_normal((SIZES[0], SIZES[0]))
    # numpy.solve runs on numpy's OpenBLAS, whose workers would still be spinning during the next
    # variant's call: it is timed in a group of its own
    groups = [{k: v for k, v in VARIANTS.items() if k != "numpy.solve"}, {"numpy.solve": numpy_solve}]
    for n in SIZES:
        J, r = test_matrix(n)
        reference = np.linalg.solve(J, r)
        for group in groups:
            time.sleep(SETTLE_SECONDS)  # every group starts with idle BLAS pools, whatever ran before
            _interleaved(group, J, r, WARMUP)
            times = _interleaved(group, J, r, REPEATS)
            idle = after_numpy = {}
            if n == SIZES[0]:  # the size only, to stay within a minute
                idle = _interleaved(group, J, r, IDLE_CALLS, before=lambda: time.sleep(IDLE_SECONDS))
                # numpy's own OpenBLAS: its workers keep spinning for a while after the matmul
                after_numpy = _interleaved(group, J, r, AFTER_NUMPY_CALLS, before=lambda: other @ other)
            for name, fn in group.items():
                x, fell_back = fn(J, r)
                out["rows"].append(
                    {
                        "variant": name,
                        "n": n,
                        "best_ms": _ms(min(times[name])),
                        "median_ms": _ms(statistics.median(times[name])),
                        "idle_ms": _ms(statistics.median(idle[name])) if idle else None,
                        "after_numpy_ms": _ms(statistics.median(after_numpy[name])) if after_numpy else None,
                        "rel_diff_vs_numpy": float(np.linalg.norm(x - reference) / np.linalg.norm(reference)),
                        "fell_back": bool(fell_back),
                    }
                )
    J, r = test_matrix(SIZES[0])
    time.sleep(SETTLE_SECONDS)
    singles = []
    for _ in range(MONODROMY_SINGLES):
        for _ in range(3):
            solve_linear(J, r)
        singles.append(_time_one(solve_linear, J, r))
    out["monodromy_style_ms"] = [_ms(t) for t in singles]
    return out


def environment() -> dict:
    env = {
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "platform": platform.platform(),
        "processor": _cpu_model(),
        "os.cpu_count": os.cpu_count(),
        "sched_getaffinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "thread_env": {k: os.environ.get(k) for k in THREAD_VARS},
        "numpy_blas": _blas(np),
        "scipy_blas": _blas(scipy),
        "blas_libraries_loaded": _loaded_blas(),
    }
    try:
        import threadpoolctl

        env["threadpoolctl"] = [
            {k: d.get(k) for k in ("internal_api", "prefix", "version", "num_threads", "threading_layer", "filepath")}
            for d in threadpoolctl.threadpool_info()
        ]
    except ImportError:
        env["threadpoolctl"] = "not installed (thread counts are set per child process by environment variables)"
    return env


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def _blas(module) -> str:
    try:
        blas = module.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{blas.get('name')} {blas.get('version')} ({blas.get('openblas configuration', '')})"
    except Exception as exc:  # older releases: no mode="dicts"
        return f"unavailable ({exc})"


def _loaded_blas() -> list | str:
    """Shared libraries with BLAS in their name mapped into this process (Linux)."""
    try:
        lines = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return "unavailable"
    names = {line.split()[-1] for line in lines if any(k in line.lower() for k in ("blas", "mkl", "lapack"))}
    return sorted(names)


def _cell(value, width: int) -> str:
    return f"{value:>{width}.3f}" if value is not None else f"{'-':>{width}}"


def run_child(threads: int) -> dict:
    env = dict(os.environ)
    if threads > 0:
        env.update({k: str(threads) for k in THREAD_VARS})
    proc = subprocess.run(
        [sys.executable, __file__, "--child", str(threads)], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", default="0,1,2,4", help="BLAS thread counts, 0 = inherit (default 0,1,2,4)")
    parser.add_argument("--json", help="also write every measurement to this file")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return

    env = environment()
    print("environment:")
    for key, value in env.items():
        if isinstance(value, list):
            print(f"  {key}:")
            for item in value:
                print(f"    {item}")
        else:
            print(f"  {key}: {value}")
    inherited = "/".join(f"{k}={v}" for k, v in env["thread_env"].items() if v) or "BLAS default"
    results = [run_child(int(t)) for t in args.threads.split(",")]

    print(f"\ncond(J) = 1e6; threads 0 = inherited ({inherited})")
    print(f"best / median: of {REPEATS} calls after {WARMUP} warm-up calls, variants called in turn")
    print(f"idle: median of {IDLE_CALLS} calls, each after {IDLE_SECONDS} s without BLAS work (n = {SIZES[0]} only)")
    print(
        f"after np: median of {AFTER_NUMPY_CALLS} calls, each right after a numpy {SIZES[0]}x{SIZES[0]} matmul (idem)"
    )
    print("rel diff: |x - numpy.linalg.solve| / |numpy.linalg.solve|")
    head = ("variant", "n", "threads", "best ms", "median ms", "idle ms", "after np ms", "rel diff")
    print("{:<18} {:>4} {:>7} {:>8} {:>9} {:>8} {:>11} {:>9}".format(*head))
    for res in results:
        for row in res["rows"]:
            print(
                f"{row['variant']:<18} {row['n']:>4} {res['threads']:>7} {row['best_ms']:>8.3f} "
                f"{row['median_ms']:>9.3f} {_cell(row['idle_ms'], 8)} {_cell(row['after_numpy_ms'], 11)} "
                f"{row['rel_diff_vs_numpy']:>9.1e}" + ("  (fell back to lstsq)" if row["fell_back"] else "")
            )
    print(f"\nsolve_linear, n = {SIZES[0]}: first call in a fresh process, and _monodromy-style single calls")
    print(f"{'threads':>7} {'first ms':>9} {'single min':>10} {'median':>8} {'max':>8}")
    for res in results:
        s = res["monodromy_style_ms"]
        print(
            f"{res['threads']:>7} {res['first_ms']:>9.3f} {min(s):>10.3f} {statistics.median(s):>8.3f} {max(s):>8.3f}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps({"environment": env, "results": results}, indent=1))
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
