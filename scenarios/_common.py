"""Shared scene plumbing: the registry, output folders, summaries, figures and logging."""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import json
import logging
import os
import socket
import time
from pathlib import Path

from warpchain.store import jsonable

#: scene name -> module (in the order ``paper`` runs them)
SCENES = {
    "dispersion": "scenarios.dispersion",
    "anticontinuum": "scenarios.anticontinuum",
    "nls": "scenarios.nls",
    "breather": "scenarios.breather",
    "continuation-k": "scenarios.continuation_k",
    "continuation-omega": "scenarios.continuation_omega",
    "site-bond": "scenarios.site_bond",
    "direct-simulation": "scenarios.direct_simulation",
    "work-precision": "scenarios.work_precision",
    "stability-limits": "scenarios.stability_limits",
    "breakup-statistics": "scenarios.breakup_statistics",
    "finite-size": "scenarios.finite_size",
    "stability-atlas": "scenarios.stability_atlas",
    "monolayer": "scenarios.monolayer",
    "monolayer-spot": "scenarios.monolayer_spot",
}
#: scenes that reproduce the paper (``python -m scenarios paper``); the rest chart speed and accuracy
PAPER_SCENES = [
    "dispersion",
    "anticontinuum",
    "nls",
    "breather",
    "continuation-k",
    "continuation-omega",
    "site-bond",
    "direct-simulation",
]

log = logging.getLogger("scenarios")


@dataclasses.dataclass
class Context:
    """What a scene is run with.

    Attributes:
        out: the scene's own output folder (OUT/NAME), created.
        device: resolved Warp device (``cpu`` or ``cuda:0``).
        quick: a reduced, fast variant (CI smoke tests).
        params: the scene's parameter block (its ``Parameters`` dataclass, quick variant and
            ``--set`` overrides applied), or None for a scene without one.
        resume: continue a stored result (scenes that support it).
        command_line: the command as typed.
        overrides: the parameters given (``--set``), as given: a failure names them.
    """

    name: str
    out: Path
    device: str
    quick: bool = False
    params: object = None
    resume: bool = False
    command_line: str = ""
    overrides: dict = dataclasses.field(default_factory=dict)

    def log(self, message: str, *args) -> None:
        log.info(f"[{self.name}] " + message, *args)

    def store(self, chain=None, *, name: str = "data.zarr"):
        """The scene's zarr store OUT/NAME/``name``, created afresh, its root attributes holding the chain's
        parameters (``chain``: a ``ChainParams``), the scene's typed parameters (``scene_parameters``: its
        ``Parameters`` block as run, quick variant and ``--set`` overrides applied) and the provenance
        (package versions, device, git commit, command line)."""
        import dataclasses

        from warpchain.store import jsonable, open_store, provenance

        scene = (
            {"scene_parameters": jsonable(dataclasses.asdict(self.params))}
            if dataclasses.is_dataclass(self.params)
            else {}
        )
        return open_store(
            self.out / name,
            params=chain.as_dict() if chain is not None else None,
            provenance_info=provenance(self.device),
            attrs=scene,
        )


def progress_bars() -> bool:
    """Whether the scenes draw progress bars: only when stderr is a terminal (a log file or a pipe gets the
    log lines alone) and the log is not quiet (``-q``)."""
    import sys

    return sys.stderr.isatty() and logging.getLogger().isEnabledFor(logging.INFO)


def load_scene(name: str):
    if name not in SCENES:
        raise SystemExit(f"unknown scene {name!r}; known scenes: {', '.join(SCENES)}")
    return importlib.import_module(SCENES[name])


def parse_overrides(items) -> dict:
    """``--set KEY=VALUE`` items as {key: value}; a ValueError names an item without ``=``."""
    overrides = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set takes KEY=VALUE, got {item!r}")
        overrides[key.strip()] = value.strip()
    return overrides


def write_summary(out: Path, summary: dict) -> Path:
    """``summary.json``, whole or not at all (written beside, then renamed over)."""
    path = Path(out) / "summary.json"
    _write_whole(path, lambda tmp: tmp.write_text(json.dumps(jsonable(summary), indent=2) + "\n"))
    return path


def _write_whole(path: Path, write) -> None:
    """Run ``write(tmp)`` on a temporary file beside ``path`` and rename it over ``path``: a reader (or a full
    disk, or a kill) never leaves half a file under the real name."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def verdicts(points) -> tuple:
    """(stable, unstable, undecided): boolean masks of the points' verdicts (``stable`` True, False, or None: not
    decided, a point without a complete Floquet analysis, which a figure draws as its own kind, never as stable)."""
    import numpy as np

    flags = [p.stable for p in points]
    return tuple(np.array([f is value for f in flags], dtype=bool) for value in (True, False, None))


def read_summary(out: Path) -> dict:
    return json.loads((Path(out) / "summary.json").read_text())


def save_figure(fig, out: Path, stem: str) -> list[Path]:
    """Save a matplotlib figure as PNG and PDF, each whole or not at all; returns the paths."""
    paths = []
    for ext in ("png", "pdf"):
        path = Path(out) / f"{stem}.{ext}"
        _write_whole(path, lambda tmp: fig.savefig(tmp, dpi=150, bbox_inches="tight", format=ext))
        paths.append(path)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return paths


def tight_layout_beside_legends(fig, *extra, **kwargs) -> None:
    """``fig.tight_layout`` as if the legends (and the ``extra`` artists, say a colour bar's inset axes) were
    absent: one placed outside its axes (right of the right-hand panels, say) then hangs in the margin, which
    ``save_figure`` (bbox_inches="tight") takes in, instead of shrinking every panel to make room for it."""
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    aside = [artist for artist in [*legends, *extra] if artist.get_in_layout()]
    for artist in aside:
        artist.set_in_layout(False)
    fig.tight_layout(**kwargs)
    for artist in aside:
        artist.set_in_layout(True)


def period_envelope(field, frames_per_period: int):
    """max over each period of |field|: frames (n, N) with frame 0 at t = 0 -> (periods, N). Drawing the raw
    field would show the carrier (a stripe pair per period, blended by the renderer) and, sampled a few
    times per period, beats between the frame rate and the mode's own frequency (aliasing)."""
    import numpy as np

    per = int(frames_per_period)
    n_periods = (len(field) - 1) // per
    return np.abs(field[1 : 1 + n_periods * per]).reshape(n_periods, per, -1).max(axis=1)


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def scene_parameters(module, quick: bool, overrides: dict | None = None):
    """The scene's ``Parameters``: the quick variant from its ``QUICK`` dict, then the overrides (text typed
    after --set, read as the field's type, or values given through the API), checked against every field's
    allowed values and the class's rules across fields (``scenarios._params``). A value that is not allowed
    is a ``ValueError`` of one line naming the parameter, the value and what is allowed."""
    from ._params import API, SET, UNREADABLE, allowed_of, check, convert, kind_of, refused

    cls = getattr(module, "Parameters", None)
    overrides = dict(overrides or {})
    if cls is None:
        if overrides:
            raise ValueError(f"this scene has no parameter block; --set {', '.join(overrides)} is not accepted")
        return None
    params = cls()
    if quick:
        params = dataclasses.replace(params, **getattr(module, "QUICK", {}))
    fields = {f.name: f for f in dataclasses.fields(cls)}
    changes, given, raw = {}, {}, {}
    for key, value in overrides.items():
        if key not in fields:
            raise ValueError(f"unknown parameter {key!r} for this scene; known: {', '.join(fields)}")
        kind = kind_of(fields[key].type)
        if isinstance(value, str):
            given[key], raw[key] = SET, value
            value = convert(value, kind)
            if value is UNREADABLE:
                raise refused(f"--set {key}={raw[key]}", allowed_of(fields[key]), kind)
        else:
            given[key] = API
            if kind.base is tuple and isinstance(value, list):
                value = tuple(value)
        changes[key] = value
    params = dataclasses.replace(params, **changes)
    check(params, given, quick, raw)
    return params


class SceneFailed(RuntimeError):
    """A scene raised while it computed (an engine error, a failed solve): the command line prints this one line
    (exit 1); the scene's ``failed.json`` holds the error and its traceback, and ``__cause__`` is the error."""


class Refused(ValueError):
    """A scene's input refused before the scene wrote anything (e.g. a resume with other settings than the
    stored branch's): its folder is left as it was, summary included."""


@contextlib.contextmanager
def scene_lock(out: Path):
    """Hold an OS lock on ``out/.lock`` while a scene runs in ``out``: a second run or a resume on the same folder
    meanwhile is refused (``Refused``, one line naming the holder), so two walks never interleave in one store.

    The lock is ``flock`` on the file, not the file's existence: the kernel releases it when its process dies
    (killed, crashed, out of memory), so there are no stale locks to judge, and two processes cannot both take it.
    The file holds the holder's pid, host and start time for the message only; a file that another process
    unlinked between our open and our lock is a lock on nothing, so the lock is taken again on the file the
    path now names."""
    import fcntl

    lock, me = out / ".lock", {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()}
    for _ in range(10):
        fd = os.open(lock, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise Refused(f"{out} is in use by {_holder(lock)} (lock {lock}); wait for that run to end") from None
        except OSError as e:
            os.close(fd)
            raise Refused(
                f"{out}: cannot lock {lock} ({e.strerror or e}); is the folder on a file system without locks?"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed the file as we opened it: lock the one the path names now
    else:
        raise Refused(f"{out}: could not take the lock {lock}")
    os.ftruncate(fd, 0)
    os.write(fd, json.dumps(me).encode())
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)  # before the release, so that a waiter that got the old file retries
        os.close(fd)


def _holder(lock: Path) -> str:
    """Who holds ``lock``, from what it wrote there (for the message; the lock itself is the OS's)."""
    try:
        held = json.loads(lock.read_text())
        return f"process {int(held['pid'])} on {held['host']}"
    except (OSError, ValueError, KeyError, TypeError):  # written as we read, or not ours
        return "another process"


def run_scene(
    name: str,
    out_root: Path,
    device: str | None,
    quick: bool,
    overrides: dict | None = None,
    resume: bool = False,
    command_line: str = "",
    module=None,
) -> dict:
    """Run one scene (compute, store, summary) and then its plots (which read the stored data); ``module``:
    the scene's module when it is not registered (``benchmarks/throughput.py``)."""
    from warpchain import resolve_device

    module = module or load_scene(name)
    with _warnings_as_log_lines(name):  # a rule that solves for an orbit may warn on the way
        params = scene_parameters(module, quick, overrides)
    if resume and not getattr(module, "RESUMABLE", False):
        raise ValueError(f"scene {name!r} cannot be resumed (resumable: continuation-k, continuation-omega)")
    resolved = resolve_device(device)  # before any folder is made: a bad device leaves nothing behind
    out = Path(out_root) / name
    if resume and not out.is_dir():  # nothing to continue, and nothing (not even a failed.json) to write there
        raise ValueError(f"--resume: {out} does not exist, so there is no branch to continue; run without --resume")
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    ctx = Context(
        name=name,
        out=out,
        device=resolved,
        quick=quick,
        params=params,
        resume=resume,
        command_line=command_line,
        overrides=dict(overrides or {}),
    )
    from continuation.hostblas import blas_threads, threads_for

    try:
        with scene_lock(out):  # one run per scene folder at a time
            with blas_threads(threads_for(resolved)):  # one on the CPU device, where Warp needs the cores (hostblas)
                return _run_in(module, ctx)
    except BaseException:
        if created and not any(out.iterdir()):  # nothing was written: leave no empty folder
            out.rmdir()
        raise


def _run_in(module, ctx: Context) -> dict:
    out, params, command_line = ctx.out, ctx.params, ctx.command_line
    start = time.perf_counter()
    ctx.log("start (device %s%s) -> %s", ctx.device, ", quick" if ctx.quick else "", out)
    if params is not None:
        ctx.log("parameters: %s", ", ".join(f"{k}={v}" for k, v in dataclasses.asdict(params).items()))
    # an earlier run's summary never stands for this one: gone now, written again only when this run succeeds,
    # and a run that raises leaves failed.json (what ``compare`` and ``paper`` report) instead
    before = {name: (out / name).read_bytes() for name in ("summary.json", "failed.json") if (out / name).is_file()}
    for name in before:
        (out / name).unlink()
    try:
        with _warnings_as_log_lines(ctx.name):
            summary = module.run(ctx)
    except Refused:  # refused before anything was written: the folder stays as it was
        for name, content in before.items():
            (out / name).write_bytes(content)
        raise
    except Exception as exc:
        hint = failure_hint(exc)
        if hint and hasattr(exc, "add_note"):  # Python >= 3.11
            exc.add_note(hint)  # printed under the traceback
        _failed(ctx, exc, f"{type(exc).__name__}: {exc}" + (f" ({hint})" if hint else ""))
    summary.setdefault("wall_seconds", time.perf_counter() - start)
    if params is not None:
        summary.setdefault("parameters", dataclasses.asdict(params))
    if command_line:
        summary.setdefault("command_line", command_line)
    write_summary(out, summary)  # the figures read it
    try:
        with _warnings_as_log_lines(ctx.name):
            module.plot(out)
    except BaseException as exc:  # no summary stands beside figures that were not all drawn
        (out / "summary.json").unlink(missing_ok=True)
        if isinstance(exc, Exception):
            _failed(ctx, exc, f"drawing the figures failed: {type(exc).__name__}: {exc}")
        raise
    ctx.log("done in %.1f s", time.perf_counter() - start)
    return summary


@contextlib.contextmanager
def _warnings_as_log_lines(name: str):
    """A library's warning (numpy's "invalid value encountered", matplotlib's) while a scene runs is one log line
    naming the scene, not Python's two-line form with the source line: ``... [name] warning: RuntimeWarning: ...
    (model.py:321)``. Which warnings show (once per place) is Python's filter's choice, as before."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        log.warning("[%s] warning: %s: %s (%s:%s)", name, category.__name__, message, Path(filename).name, lineno)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def _failed(ctx: Context, exc: Exception, error: str):
    """Record a scene's failure in ``failed.json`` (the error and its traceback) and raise it: as it is when it is
    one line already (refused input, a damaged store, a full disk), else as ``SceneFailed``. Called in the
    ``except`` block that caught ``exc``."""
    import traceback

    failed = ctx.out / "failed.json"
    record = {"scene": ctx.name, "error": error, "traceback": traceback.format_exc()}
    with contextlib.suppress(OSError):  # a full disk may refuse this too: the error still reaches the user
        failed.write_text(json.dumps(record))
    given = ", ".join(f"{key}={value}" for key, value in ctx.overrides.items())
    if isinstance(exc, OSError) or (isinstance(exc, ValueError) and _raised_by_us(exc)):
        if given and "--set" not in str(exc) and hasattr(exc, "add_note"):  # which of the values given it was
            exc.add_note(f"with --set {given}")
        raise exc
    # a library's error (numpy's, scipy's, matplotlib's) does not know the scene's parameters: name those given
    raise SceneFailed(
        f"scene {ctx.name} failed: {error} (" + (f"with --set {given}; " if given else "") + f"traceback in {failed})"
    ) from exc


def _raised_by_us(exc: BaseException) -> bool:
    """Was ``exc`` raised in warpchain's own packages (a refusal worded for the user), not in a library?"""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return True
    ours = Path(__file__).resolve().parents[1]
    where = Path(frames[-1].filename).resolve()
    return any(where.is_relative_to(ours / package) for package in ("warpchain", "continuation", "sweep", "scenarios"))


def failure_hint(exc: BaseException) -> str:
    """Advice for a failure whose cause lies outside the scene: Warp's kernel cache damaged (a compiled
    module that does not load, or a ``.meta`` file that is not JSON, met while Warp loads a module)."""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    in_warp_load = any("warp" in f.filename and "context" in f.filename for f in frames[-6:])
    text = str(exc)
    if ("Failed to load" in text and "module" in text) or (in_warp_load and isinstance(exc, json.JSONDecodeError)):
        try:
            import warp

            cache = warp.config.kernel_cache_dir
        except Exception:  # noqa: BLE001
            cache = "~/.cache/warp"
        return (
            f"Warp's kernel cache at {cache} looks damaged: delete it (python -c \"import warp; "
            'warp.clear_kernel_cache()") and run again; the kernels are compiled anew'
        )
    return ""


# ----------------------------------------------------------------------------- the paper breather

#: The paper's breather: M = 30, K = 160, N = 201, w_b = 1.01. Accuracy it needs: the orbit to ~1e-8
#: relative against the ODE. The work-precision scene's smooth case (this breather over 20 periods)
#: shows kahan8 with 32 steps per period reaching 1.8e-9 with 480 force evaluations per period, the
#: cheapest method at that accuracy (yoshida6 needs 128 steps, 896 evaluations, for 8e-9).
PAPER_M, PAPER_K, PAPER_N, PAPER_OMEGA = 30.0, 160.0, 201, 1.01
BREATHER_METHOD, BREATHER_STEPS_PER_PERIOD = "kahan8", 32

_BREATHER_CACHE: dict = {}


def reference_run(method: str, params, x0, t_end: float, dt: float, chunks: int) -> tuple:
    """A run on the numpy reference (``warpchain.reference``) for the methods the Warp engine does not step (RK4),
    with ``simulate``'s step and chunks (``steps_for``, ``ensemble.chunk_plan``): the final state (4, N), and the
    times and energies at the start and at each chunk's end (as ``simulate``'s ``energy_t`` and ``energy_trace``).
    A run that turns non-finite stops there (its last energy is not finite)."""
    import numpy as np

    from warpchain import energy, reference
    from warpchain.ensemble import chunk_plan
    from warpchain.integrators import steps_for

    nsteps, dt_used = steps_for(t_end, dt)
    x = np.array(x0, dtype=np.float64)[None]
    times, energies = [0.0], [energy(params, x)[0]]
    with np.errstate(over="ignore", invalid="ignore"):  # a run past its stability limit overflows
        for first, steps, _ in chunk_plan(nsteps, 1, chunks, None, None):
            x = reference.integrate(method, params, x, dt_used, steps)["x"]
            times.append((first + steps) * dt_used)
            energies.append(energy(params, x)[0] if np.all(np.isfinite(x)) else np.nan)
            if not np.isfinite(energies[-1]):
                break
    return x[0], np.array(times), np.array(energies)


def method_run(method: str, params, x0, t_end: float, dt: float, chunks: int, device) -> tuple:
    """A run of ``method`` without an energy bound, wherever it runs: on the Warp engine of ``device`` for a splitting
    method, else (RK4) on the numpy reference (``reference_run``, the same steps and chunks). Returns the final state
    (4, N) and the times and energies at the start and at each chunk's end."""
    from warpchain import METHODS, Guard, SplittingMethod, simulate

    if not isinstance(METHODS[method], SplittingMethod):
        return reference_run(method, params, x0, t_end, dt, chunks)
    guard = Guard(chunks=chunks, max_energy_error=None)
    run = simulate(params, x0, t_end, dt, method=method, device=device, guard=guard)
    return run.x[0], run.energy_t, run.energy_trace[:, 0]


def paper_breather(device: str, log=None, *, params=None, omega: float = PAPER_OMEGA):
    """The w_b = 1.01, K = 160 breather (or that of ``params`` and ``omega``), computed from the NLS seed by
    Newton (cached per process)."""
    from continuation import find_breather, nls_seed, require
    from warpchain import ChainParams

    params = params or ChainParams(PAPER_M, PAPER_K, PAPER_N)
    key = (device, params, float(omega))
    if key not in _BREATHER_CACHE:
        result = find_breather(
            params,
            omega,
            nls_seed(params, omega),
            method=BREATHER_METHOD,
            steps_per_period=BREATHER_STEPS_PER_PERIOD,
            device=device,
            log=log,
        )
        _BREATHER_CACHE[key] = require(result)
    return _BREATHER_CACHE[key]
