"""Command line: python -m scenarios list | params [NAME ...] | run NAME [...] | paper [...] | compare A B [...]."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import re
import shlex
import sys
from pathlib import Path


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled as Ctrl-C is: the stores are flushed and marked interrupted, the exit status is 143."""


def _terminate_like_interrupt() -> None:
    """SIGTERM raises ``Terminated`` in the main thread (only there can a handler be installed)."""
    import signal
    import threading

    def handler(signum, frame):
        raise Terminated()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, handler)


if __name__ == "__main__":
    _terminate_like_interrupt()  # before the heavy imports below: a SIGTERM while they run is one line too

try:
    from ._common import PAPER_SCENES, SCENES, SceneFailed, load_scene, parse_overrides, run_scene
    from ._parallel import parse_jobs, run_parallel
except KeyboardInterrupt as _exc:  # Ctrl-C or SIGTERM while starting (importing Warp, numpy, ...)
    if __name__ != "__main__":
        raise
    _how = "terminated (SIGTERM)" if isinstance(_exc, Terminated) else "interrupted"
    print(f"{_how} while starting: nothing was computed or stored", file=sys.stderr)
    sys.exit(143 if isinstance(_exc, Terminated) else 130)


class _Parser(argparse.ArgumentParser):
    """argparse with the command line's one error style: ``error: ...`` on one line (no usage block), exit 2."""

    def error(self, message):
        self.exit(2, f"error: {message} ('{self.prog} --help' lists what it takes)\n")


def _with_notes(exc: BaseException) -> str:
    """The error's text and its notes (a failure's hint, ``scenarios._common.failure_hint``) on one line."""
    return str(exc) + "".join(f" ({note})" for note in getattr(exc, "__notes__", ()))


def main(argv=None) -> int:
    # the command as typed: the console script or the module (usage lines, the provenance's command line)
    called = "warpchain" if os.path.basename(sys.argv[0]) == "warpchain" else "python -m scenarios"
    parser = _Parser(prog=called, description=__doc__)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list the scenes")
    params = sub.add_parser("params", help="a scene's parameters: defaults, types, allowed values (for --set)")
    params.add_argument("names", nargs="*", metavar="NAME", help="scene names (default: every scene)")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--out", default="results", type=Path, help="output root (default: results/)")
    common.add_argument("--device", default=None, help="cpu or cuda (default: cuda when Warp sees a GPU)")
    common.add_argument("--quick", action="store_true", help="reduced variant for smoke tests")
    common.add_argument(
        "-q", "--quiet", action="store_true", help="warnings and errors only: no log line per point, no progress bars"
    )
    one = argparse.ArgumentParser(add_help=False)  # what applies to one scene: run, not paper
    one.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scene parameter (repeatable), e.g. --set N=401; 'params NAME' lists them",
    )
    one.add_argument(
        "--resume", action="store_true", help="continue a stored branch (continuation-k, continuation-omega)"
    )
    words = list(sys.argv[1:] if argv is None else argv)
    asked = [w for w in words[1:] if w in SCENES] if words[:1] == ["run"] and {"-h", "--help"} & set(words) else []
    run = sub.add_parser(
        "run",
        parents=[common, one],
        help="run one scene",
        # ``run NAME --help`` ends with that scene's --set keys, defaults and allowed values
        epilog="\n".join(scene_listing(asked[0])) if asked else "'run NAME --help' lists that scene's --set keys",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument("name", help="scene name (see 'list')")
    # set by ``paper --jobs``: the command its children record in their provenance
    run.add_argument("--provenance-command", default=None, help=argparse.SUPPRESS)
    paper = sub.add_parser("paper", parents=[common], help="run every paper scene")
    paper.add_argument(
        "--jobs",
        default="auto",
        help="scenes run at once, each in its own process (default auto: one per 2 usable CPU cores, at most 4; "
        "1: in order, in this process)",
    )
    compare = sub.add_parser("compare", help="do two result folders hold the same science? (exit 0 yes, 1 no)")
    compare.add_argument("a", type=Path, help="a result folder (OUT of run/paper, or one holding summaries alone)")
    compare.add_argument("b", type=Path, help="the other result folder")
    compare.add_argument("--scenes", default=None, help="comma-separated scenes to compare (default: all found)")
    compare.add_argument("--json", default=None, type=Path, metavar="FILE", help="write the differences as JSON")
    args = parser.parse_args(argv)
    _terminate_like_interrupt()
    quiet = getattr(args, "quiet", False)
    logging.basicConfig(
        level=logging.WARNING if quiet else logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S"
    )

    if args.command == "list":
        return _print(f"{name:20s} {first_sentence(load_scene(name).__doc__)}" for name in SCENES)
    if args.command == "params":
        unknown = [name for name in args.names if name not in SCENES]
        if unknown:
            parser.error(f"unknown scene {unknown[0]!r}; known scenes: {', '.join(SCENES)}")
        return _print(
            ("\n" if k else "") + "\n".join(scene_listing(name)) for k, name in enumerate(args.names or SCENES)
        )
    if args.command == "compare":  # the rules: scenarios/compare.py
        from .compare import main as compare_main

        with _closed_pipe_ends_quietly():
            return compare_main(args.a, args.b, args.scenes, args.json)
        return 1  # the reader stopped before the verdict: differences were being listed
    if args.device is not None and args.device.lower() not in ("cpu", "cuda") and not args.device.startswith("cuda:"):
        parser.error(f"--device must be cpu or cuda, got {args.device!r}")
    names = [args.name] if args.command == "run" else PAPER_SCENES
    if args.command == "run" and args.name not in SCENES:
        parser.error(f"unknown scene {args.name!r}; known scenes: {', '.join(SCENES)}")
    try:
        overrides = parse_overrides(getattr(args, "set", []))
    except ValueError as exc:
        parser.error(str(exc))
    command_line = getattr(args, "provenance_command", None) or " ".join(
        [called, *(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))]
    )
    from warpchain import store

    store.COMMAND_LINE = command_line  # every store's provenance records the command as typed
    try:
        check_output_root(args.out)
        jobs = parse_jobs(args.jobs, len(names)) if args.command == "paper" else 1
        if jobs > 1:
            from warpchain import resolve_device

            device = resolve_device(args.device)  # once, here: a missing GPU is one error, not one per scene
            failures = run_parallel(names, args.out, device, args.quick, jobs, command_line)
            for name, code, tail in failures:
                print(f"error: scene {name} failed (exit {code}); its last lines:", file=sys.stderr)
                print("\n".join("    " + line for line in tail), file=sys.stderr)
            return 0 if not failures else max(code for _, code, _ in failures)
        if args.command == "run":
            run_scene(args.name, args.out, args.device, args.quick, overrides, args.resume, command_line)
            return 0
        from warpchain import resolve_device

        device = resolve_device(args.device)  # once, here: a missing GPU is one error, not one per scene
        return run_in_order(names, args.out, device, args.quick, command_line)
    except (ValueError, OSError) as exc:  # bad input, damaged store, unusable --out: one line, exit 2
        print(f"error: {_with_notes(exc)}", file=sys.stderr)
        return 2
    except _engine_errors() as exc:  # an eigensolver worker that failed or hung, a verdict that could not be had
        print(f"error: {_with_notes(exc)}", file=sys.stderr)
        return 1
    except SceneFailed as exc:  # a scene raised: one line, its traceback in failed.json
        cause = exc.__cause__
        print(f"error: {_with_notes(cause) if isinstance(cause, _engine_errors()) else exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        stores = [Path(args.out) / name / "data.zarr" for name in names]
        if any(path.exists() for path in stores):
            resumable = args.command == "run" and getattr(load_scene(args.name), "RESUMABLE", False)
            then = "; continue with --resume" if resumable else ""
            print(f"{how}: what was stored so far is complete and marked so{then}", file=sys.stderr)
        else:
            print(f"{how} before anything was stored", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    return 0


def _engine_errors() -> tuple:
    """Errors the command line reports in one line (exit 1), not as a traceback: a worker process that failed,
    stopped or hung (``continuation.workers.WorkerError``: its traceback is its ``detail``) and a Floquet count
    that did not close on a branch (``continuation.driver.IncompleteVerdict``)."""
    from continuation.driver import IncompleteVerdict
    from continuation.workers import WorkerError

    return (WorkerError, IncompleteVerdict)


def run_in_order(names, out, device, quick: bool, command_line: str) -> int:
    """``paper --jobs 1``: the scenes one after the other in this process. A scene that raises is logged with
    its traceback and counted; the others still run; the exit status is 1 when any failed (a Ctrl-C stops all)."""
    import time
    import traceback

    log = logging.getLogger("scenarios")
    start, failures = time.perf_counter(), []
    for name in names:
        try:
            run_scene(name, out, device, quick, command_line=command_line)
        except SceneFailed as exc:  # its traceback is in its failed.json
            log.error("paper: %s", exc)
            failures.append((name, exc))
        except Exception as exc:  # failed before it computed (its parameters, its folder)
            log.error("paper: %s FAILED: %s: %s\n%s", name, type(exc).__name__, exc, traceback.format_exc())
            failures.append((name, exc))
    log.info(
        "paper: %d scenes in %.1f s, %d failed; results in %s",
        len(names),
        time.perf_counter() - start,
        len(failures),
        out,
    )
    for name, exc in failures:
        text = (
            str(exc)
            if isinstance(exc, SceneFailed)
            else f"scene {name} failed: {type(exc).__name__}: {_with_notes(exc)}"
        )
        print(f"error: {text}", file=sys.stderr)
    return 1 if failures else 0


def scene_listing(name: str) -> list[str]:
    """``params NAME``: the scene's parameters (``scenarios._params.listing``) under a header."""
    from ._params import listing

    module = load_scene(name)
    cls = getattr(module, "Parameters", None)
    head = f"{name}: {first_sentence(module.__doc__)}"
    if cls is None:
        return [head, "  no parameters"]
    return [
        head,
        f"  python -m scenarios run {name} --set KEY=VALUE (tuples comma-separated); default [--quick's], allowed:",
        *listing(cls, getattr(module, "QUICK", {})),
    ]


def first_sentence(doc: str | None) -> str:
    """The first sentence of a docstring, on one line, without reST markup."""
    text = " ".join((doc or "").strip().split("\n\n")[0].split())
    # a sentence ends at ". " before a capital, not after an abbreviation such as "Fig." or "e.g."
    match = re.search(r"(?<!\bFig)(?<!\bFigs)(?<!\be\.g)(?<!\bi\.e)(?<!\bvs)\.\s+(?=[A-Z(])", text)
    text = text if match is None else text[: match.start() + 1]
    return text.replace("``", "")


@contextlib.contextmanager
def _closed_pipe_ends_quietly():
    """A reader of stdout that stops early (``warpchain list | head``) ends the printing quietly, as Unix tools do."""
    try:
        yield
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's own flush at exit would raise again


def _print(lines) -> int:
    """Print a listing (``_closed_pipe_ends_quietly``)."""
    with _closed_pipe_ends_quietly():
        for line in lines:
            print(line)
    return 0


def _version() -> str:
    """The installed version, and the commit when run from a git checkout."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        text = version("warpchain")
    except PackageNotFoundError:
        text = "(not installed)"
    from warpchain.store import git_commit

    commit = git_commit()
    return f"{text} (commit {commit[:10]})" if commit else text


def check_output_root(out: Path) -> None:
    """Refuse an --out that is a file or cannot be written, before anything is computed."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder")
    probe = out
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"--out {out}: cannot write in {probe}")
    try:  # what access() cannot tell (a root user, /proc, a read-only mount): make it
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {out}: cannot make the folder ({exc.strerror or exc})") from None


if __name__ == "__main__":
    sys.exit(main())
