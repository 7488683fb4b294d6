"""Compact the dated benchmark result folders into one JSON per set, and use the CPU paper reference.

    python benchmarks/results/compact.py build --commit b167e7d          # every set, raw files read from git
    python benchmarks/results/compact.py build --commit REV h200-2026-11-22k h100-2026-11-25/engine-split
    python benchmarks/results/compact.py unpack benchmarks/results/cpu-2core-2026-11-25b.json /tmp/ref
    python benchmarks/results/compact.py compare benchmarks/results/cpu-2core-2026-11-25b.json results
    python benchmarks/results/compact.py size

``build`` reads a set's raw files with ``git show REV:benchmarks/<set>/...`` (they were deleted from the
working tree and stay in history) and writes ``benchmarks/results/<set>.json``; a new set still in the
working tree is read from there with ``--commit WORKTREE``. ``unpack`` writes a set's ``paper_summaries`` as
``<folder>/<scene>/summary.json``, the layout ``python -m scenarios compare`` reads; ``compare`` unpacks into a
temporary folder and runs that comparison against a result folder. The format is described in
``benchmarks/results/README.md``.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import re
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parent
ROOT = RESULTS.parents[1]
BENCH = "benchmarks"
LIMIT = 1_000_000  # bytes of benchmarks/results/ in all (issue #35 item 6)

#: sub-folders of a dated folder that the docs and code cite on their own: a set each
SUBSETS = (
    "h100-2026-11-25/9fb3bfb",
    "h100-2026-11-25/engine-split",
    "h200-2026-11-22b/two-per-block",
    "h200-2026-11-25/5a574a7",
    "h200-2026-11-25/f5f67b4",
)
#: sets whose paper summaries are a science reference, kept value for value (``paper_summaries``)
REFERENCE_SETS = ("cpu-2core-2026-11-25b",)
SET_RE = re.compile(r"^(cpu-2core|h100x2|h100|h200)-\d{4}-\d{2}-\d{2}[a-z]?$")
SIGNIFICANT = 8  # digits kept of a float in a JSON outside the reference summaries (|l| - 1 of 1e-4 keeps 4)
SMALL, SMALL_DIGITS = 0.01, 4  # below SMALL in magnitude (differences, errors, |l| - 1) 4 digits are kept
TABLE_DIGITS = 6  # digits kept of a throughput summary's rates, ratios and times (the docs quote 3 or 4)
LONG_LIST = 12  # a longer list of numbers in a large JSON keeps only its count
SHORT_RECORDS = 6  # a longer list of records in a cited large JSON keeps only its count (and headlines)
LARGE_JSON = 6000  # bytes: a raw JSON above this is shrunk (long lists) unless cited, below kept whole
SMALL_TEXT = 1200  # characters: a cleaned text output up to this is kept whole, a longer one its tail
TAIL_LINES, TAIL_CHARS = 2, 240
#: raw files the docs or code comments quote from (a path or a set's numbers): kept whole (texts cleaned,
#: JSONs with every list), the other large ones shrunk to a headline; every number a set's README quotes is
#: in its ``notes`` anyway
CITED = {
    "cpu-2core-2026-11-25": ("dissipation-check.txt",),
    "h200-2026-11-22b": ("ncu.txt",),
    "h200-2026-11-22": ("chord-compare.txt",),
    "h200-2026-11-22c": ("summary.json",),
    "h200-2026-11-22e": ("sites-per-thread.txt",),
    "h200-2026-11-22h": ("linear-solve.txt",),
    "h200-2026-11-22i": ("slices-pageable.txt", "tangent-variants.txt", "tangent-variants-final.txt"),
    "h200-2026-11-22j": (
        "tangent-variants.txt",
        "ncu-base-run.txt",
        "ncu-base-run-review.txt",
        "newton-profile-blas.txt",
    ),
    "h200-2026-11-22k": (
        "sites-variants-third.txt",
        "sites-variants-first.txt",
        "sites-variants.txt",
        "state-dependence.txt",
    ),
    "h200-2026-11-22l": ("timeline-805.txt", "preload.txt"),
    "h200-2026-11-22m": (
        "timeline-32768-locked.txt",
        "slices-final.txt",
        "slices-review.txt",
        "timeline-805.txt",
        "timeline-8192.txt",
        "timeline-805-locked.txt",
    ),
    "h200-2026-11-22n": (
        "slices-record-pool.txt",
        "host-copy.txt",
        "slices-grown.txt",
        "slices-upload-thread.txt",
        "slices-staged.txt",
    ),
    "h200-2026-11-22o": ("slices.txt", "timeline-on-device.txt", "timeline-on-device-first.txt"),
    "h200-2026-11-25/f5f67b4": ("long-lattice.log", "sites-check.log"),
}
#: cited large JSONs whose short lists of records (at most SHORT_RECORDS) are kept too
RECORDS = (
    "cpu-2core-2026-11-22g/check-omega.json",
    "cpu-2core-2026-11-22g/check-K.json",
    "h200-2026-11-25/5a574a7/finite-size-summary.json",
)
#: throughput summaries whose whole table is kept (docs/performance.md prints their tables; the CPU sets'
#: are small); every other keeps its ratios, the monodromy and simulate()'s ratios (what the docs quote of
#: "the other scene runs")
MAIN_THROUGHPUT = (
    "cpu-2core-2026-11-21/throughput-summary.json",
    "cpu-2core-2026-11-22b/throughput-summary.json",
    "cpu-2core-2026-11-22e/throughput-summary.json",
    "h100-2026-11-25/9fb3bfb/throughput-summary.json",
    "h200-2026-11-22b/throughput-summary.json",
    "h200-2026-11-22o/throughput-summary.json",
)
NCU_RE = re.compile(r"\)x\(|Duration|Registers Per Thread|stalled waiting|This stall type represents")
LOG_RE = re.compile(r"done in|scenes in| failed|same science|differences|Error|error:|disagree|unstable \(|branch:")
PROGRESS_RE = re.compile(r"%\||it/s\]|s/it\]|\r")
STATS_RE = re.compile(r";? stats \{[^}]*\}|, median +[\d.]+ ms|, Context \d+, Stream \d+, Device \d+, CC [\d.]+")


# -- raw files ---------------------------------------------------------------------------------------------


class Source:
    """Raw files of benchmarks/ at a git commit (or in the working tree: commit WORKTREE)."""

    def __init__(self, commit: str):
        self.worktree = commit == "WORKTREE"
        self.commit = "WORKTREE" if self.worktree else _git("rev-parse", commit).decode().strip()

    def files(self, folder: str) -> dict[str, int]:
        """{path relative to benchmarks/: size in bytes} of every file under benchmarks/<folder>."""
        if self.worktree:
            base = ROOT / BENCH
            return {
                str(p.relative_to(base)): p.stat().st_size
                for p in sorted((base / folder).rglob("*"))
                if p.is_file() and "__pycache__" not in p.parts
            }
        out = {}
        for line in _git("ls-tree", "-r", "-l", self.commit, f"{BENCH}/{folder}/").decode().splitlines():
            meta, path = line.split("\t", 1)
            out[path[len(BENCH) + 1 :]] = int(meta.split()[3])
        return out

    def read(self, path: str) -> bytes:
        if self.worktree:
            return (ROOT / BENCH / path).read_bytes()
        return _git("show", f"{self.commit}:{BENCH}/{path}")

    def sets(self) -> list[str]:
        if self.worktree:
            tops = [p.name for p in (ROOT / BENCH).iterdir() if p.is_dir()]
        else:
            tops = _git("ls-tree", "--name-only", "-d", self.commit, f"{BENCH}/").decode().split()
            tops = [t.split("/", 1)[1] for t in tops]
        names = []
        for top in sorted(t for t in tops if SET_RE.match(t)):
            names += [top] if self.files_outside(top) else []
            names += [s for s in SUBSETS if s.startswith(top + "/")]
        return names

    def files_outside(self, folder: str) -> dict[str, int]:
        """A set's files: its folder's, less those of sub-folders that are sets of their own."""
        inner = [s + "/" for s in SUBSETS if s.startswith(folder + "/")]
        return {p: n for p, n in self.files(folder).items() if not any(p.startswith(s) for s in inner)}


def _git(*args: str) -> bytes:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True, capture_output=True).stdout


# -- compacting --------------------------------------------------------------------------------------------


def rounded(obj, digits: int | None = None):
    """obj with its floats rounded: to ``digits`` significant digits, by default SMALL_DIGITS below
    SMALL (differences, errors, |l| - 1) and SIGNIFICANT above (moduli near 1 keep their 1e-9)."""
    if isinstance(obj, float):
        if not math.isfinite(obj) or obj == 0:
            return obj
        d = digits or (SMALL_DIGITS if abs(obj) < SMALL else SIGNIFICANT)
        return float(f"{obj:.{d}g}")
    if isinstance(obj, dict):
        return {k: rounded(v, digits) for k, v in obj.items()}
    if isinstance(obj, list):
        return [rounded(v, digits) for v in obj]
    return obj


def shrunk(obj, records: int = 0):
    """A large JSON's headline: every scalar and short list of scalars kept; a list of at most ``records``
    records kept (shrunk); a longer list as its count, with how many of its points are unstable (records
    with a ``stable`` verdict) and its largest multiplier of each kind (records with a ``modulus``)."""
    if isinstance(obj, dict):
        return {k: shrunk(v, records) for k, v in obj.items()}
    if isinstance(obj, list):
        if all(not isinstance(x, (dict, list)) for x in obj) and len(obj) <= LONG_LIST:
            return rounded(obj)
        if len(obj) <= records:
            return [shrunk(v, records) for v in obj]
        head = {"count": len(obj)}
        if all(isinstance(x, dict) and isinstance(x.get("stable"), bool) for x in obj):
            head["unstable"] = sum(not x["stable"] for x in obj)
        if all(isinstance(x, dict) and isinstance(x.get("modulus"), (int, float)) for x in obj):
            top = {}
            for x in obj:
                key = f"{x.get('kind')}, {'localized' if x.get('localized') else 'extended'}"
                if key not in top or x["modulus"] > top[key]["modulus"]:
                    top[key] = x
            head["largest_by_kind"] = {k: shrunk(v, records) for k, v in sorted(top.items())}
        return head
    return rounded(obj)


def records_encoded(obj):
    """obj with every list of at least four dicts of the same keys (in the same order) as
    ``{"_columns": keys, "_rows": [[values], ...]}``: lossless (``records_decoded`` gives back the same JSON,
    key order included) and a third smaller for the branch scenes' points."""
    if isinstance(obj, dict):
        return {k: records_encoded(v) for k, v in obj.items()}
    if isinstance(obj, list):
        if len(obj) >= 4 and all(isinstance(x, dict) for x in obj) and len({tuple(x) for x in obj}) == 1:
            keys = list(obj[0])
            return {"_columns": keys, "_rows": [[records_encoded(x[k]) for k in keys] for x in obj]}
        return [records_encoded(v) for v in obj]
    return obj


def records_decoded(obj):
    """The inverse of ``records_encoded``."""
    if isinstance(obj, dict):
        if set(obj) == {"_columns", "_rows"}:
            return [dict(zip(obj["_columns"], map(records_decoded, row))) for row in obj["_rows"]]
        return {k: records_decoded(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [records_decoded(v) for v in obj]
    return obj


def paper_summaries(path: Path) -> dict:
    """{scene: summary.json as written by the run} of a set with ``paper_summaries``."""
    return records_decoded(json.loads(Path(path).read_text())["paper_summaries"])


def scalars(summary: dict) -> dict:
    """A scene summary's top-level scalars (wall_seconds, stop reasons, sizes): what a run's log quotes."""
    return {k: rounded(v) for k, v in summary.items() if not isinstance(v, (dict, list))}


THROUGHPUT_ROW = ("implementation", "method", "batch", "site_steps_per_second", "sites_per_thread")


def throughput(s: dict, whole: bool) -> dict:
    """A throughput scene summary: the rows as ``rows`` under ``row_keys`` (what ``benchmarks/throughput_table.py``
    reads), the ratios, the monodromy and simulate()'s rows; a run that is not the set's main one keeps the
    ratios, the monodromy and simulate()'s ratios only."""
    out = {k: s[k] for k in ("device", "cpu", "N", "dt", "timing", "command_line") if k in s}
    if whole:
        out["row_keys"] = list(THROUGHPUT_ROW)
        out["rows"] = [[r.get(k) for k in THROUGHPUT_ROW] for r in s.get("results", [])]
    ratios = dict(s.get("ratios", {}))
    if not whole:
        ratios = {k: v for k, v in ratios.items() if k not in ("over_numpy", "over_thread_layout", "over_jax")}
    out["ratios"] = ratios
    if "monodromy" in s:
        out["monodromy"] = s["monodromy"]
    sim = s.get("simulate")
    if sim:
        rows = sim.get("rows", [])
        if not whole:
            rows = [
                {k: v for k, v in r.items() if k == "batch" or k.endswith(("_over_kernel", "gb_per_second"))}
                for r in rows
            ]
        out["simulate"] = {"record_every": sim.get("record_every"), "rows": rows}
    if whole and s.get("kernel_properties"):
        out["kernel_properties"] = [
            {k: r[k] for k in ("kernel", "register_count", "occupancy") if k in r} for r in s["kernel_properties"]
        ]
    return rounded(out, TABLE_DIGITS)


def text(raw: bytes, name: str, whole: bool) -> str:
    """A text output, cleaned: runs of blanks collapsed, progress bars and per-call stats dicts dropped; an
    ncu report down to the lines that carry its numbers; a log down to its lines of results and timings;
    an uncited long output to its last lines."""
    lines = [re.sub(r"[ \t]+", " ", line).rstrip() for line in raw.decode(errors="replace").splitlines()]
    lines = [STATS_RE.sub("", line) for line in lines if not PROGRESS_RE.search(line) and line.strip()]
    if re.search(
        r"(^|[-_])ncu([-_.]|$)", name
    ):  # kernel names shortened: a.<locals>.b for a__locals__b, no _cuda_kernel_forward
        lines = [
            line.strip().replace("__locals__", ".").replace("_cuda_kernel_forward", "")
            for line in lines
            if NCU_RE.search(line)
        ]
    elif ("log" in name or name.endswith(".log")) and not whole:
        keep = [line for line in lines if LOG_RE.search(line)][-10:]
        return "\n".join(keep + [line for line in lines[-3:] if line not in keep])
    out = "\n".join(lines)
    if whole or len(out) <= SMALL_TEXT:
        return out
    tail = "\n".join(lines[-TAIL_LINES:])[-TAIL_CHARS:]
    return f"[last lines of {len(lines)}; the whole file is in git history]\n{tail}"


def paper_member(path: str) -> str | None:
    """The scene of a paper summary path (``<...>/<scene>/summary.json``), else None."""
    parts = path.split("/")
    return parts[-2] if parts[-1] == "summary.json" and len(parts) >= 2 else None


def compact_file(path: str, raw: bytes, whole: bool, main_throughput: bool, records: int = 0) -> object:
    name = path.rsplit("/", 1)[-1]
    if name.endswith(".json"):
        data = json.loads(raw)
        if name.startswith("throughput-summary"):
            return throughput(data, main_throughput)
        if paper_member(path) and isinstance(data, dict):
            return {"wall_seconds": rounded(data.get("wall_seconds"))}
        return rounded(data) if whole or len(raw) <= LARGE_JSON else shrunk(data, records)
    if name.endswith(".tgz"):
        members = {}
        with tarfile.open(fileobj=io.BytesIO(raw)) as tar:
            for m in tar.getmembers():
                if m.isfile() and m.name.endswith("summary.json"):
                    members[m.name] = rounded(json.loads(tar.extractfile(m).read()).get("wall_seconds"))
        return {"wall_seconds": members}
    if name.endswith((".txt", ".log", ".md")):
        return text(raw, name, whole or name.endswith(".md"))
    return None  # PNG and other binaries: listed in raw_files only


def compact_set(src: Source, name: str) -> dict:
    folder_files = src.files_outside(name) if name not in SUBSETS else src.files(name)
    prefix = name + "/"
    rel = {p[len(prefix) :]: n for p, n in folder_files.items()}
    readme = src.read(prefix + "README.md").decode() if "README.md" in rel else ""
    devices = {p: text(src.read(prefix + p), p, True) for p in rel if re.search(r"(^|/)(\w+-)?device(-\w+)?\.txt$", p)}
    out = {
        "set": name,
        "raw_files_at": src.commit,
        "commit": _commit(name, readme),
        "device": _device(name, devices),
        "notes": readme.strip(),
        "raw_files": rel,
    }
    results, summaries = {}, {}
    for p in rel:
        if p == "README.md" or p in devices:
            continue
        raw = src.read(prefix + p)
        scene = paper_member(p)
        if name in REFERENCE_SETS and scene and p.startswith("paper/"):
            summary = json.loads(raw)
            if records_decoded(records_encoded(summary)) != summary or "_columns" in raw.decode():
                raise ValueError(f"{p}: the records encoding would not give it back")
            summaries[scene] = records_encoded(summary)
            continue
        key = f"{name}/{p}"
        records = SHORT_RECORDS if key in RECORDS else 0
        value = compact_file(p, raw, p in CITED.get(name, ()), key in MAIN_THROUGHPUT, records)
        if value is not None and value != "":
            same = [q for q, v in results.items() if v == value and len(json.dumps(value)) > 200]
            results[p] = f"same as {same[0]}" if same else value
    if summaries:
        out["paper_summaries"] = dict(sorted(summaries.items()))
    out["results"] = results
    return out


def _commit(name: str, readme: str) -> str | None:
    last = name.rsplit("/", 1)[-1]
    if re.fullmatch(r"[0-9a-f]{7,40}", last):
        return last
    hit = re.search(r"commits? `?([0-9a-f]{7,40})\b", readme)
    return hit.group(1) if hit else None


def _device(name: str, devices: dict) -> str:
    for key in sorted(devices, key=lambda k: (k != "device.txt", k)):
        lines = [line for line in devices[key].splitlines() if "NVIDIA" in line or "Model name" in line]
        if lines:
            return "; ".join(lines[:2])
    kind = name.split("-", 1)[0]
    return {
        "cpu": "this project's 2-core CPU (AMD EPYC, 2 cores)",
        "h100": "one NVIDIA H100 80GB HBM3",
        "h100x2": "two NVIDIA H100 80GB HBM3 of one host",
        "h200": "one NVIDIA H200",
    }.get(kind, kind)


def dumps(data: dict) -> str:
    """One line per top-level key, and per entry of the dicts raw_files, paper_summaries and results."""
    lines = ["{"]
    items = list(data.items())
    for i, (key, value) in enumerate(items):
        comma = "," if i < len(items) - 1 else ""
        if isinstance(value, dict) and key in ("raw_files", "paper_summaries", "results", "devices") and value:
            lines.append(f" {json.dumps(key)}: {{")
            sub = list(value.items())
            for j, (k, v) in enumerate(sub):
                inner = json.dumps(v, ensure_ascii=False, separators=(",", ":"))
                lines.append(f"  {json.dumps(k)}: {inner}{',' if j < len(sub) - 1 else ''}")
            lines.append(f" }}{comma}")
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value, ensure_ascii=False, separators=(',', ':'))}{comma}")
    return "\n".join(lines + ["}"]) + "\n"


def path_of(name: str) -> Path:
    return RESULTS / f"{name}.json"


def build(commit: str, names: list[str]) -> None:
    src = Source(commit)
    for name in names or src.sets():
        path = path_of(name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(dumps(compact_set(src, name)))
        print(f"{path.relative_to(ROOT)}: {path.stat().st_size} bytes")
    size()


def size() -> int:
    total = sum(p.stat().st_size for p in RESULTS.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    print(f"benchmarks/results/: {total} bytes in all (limit {LIMIT})")
    return 0 if total <= LIMIT else 1


# -- the CPU paper reference -------------------------------------------------------------------------------


def unpack(path: Path, folder: Path) -> list[str]:
    """Write a set's paper_summaries as folder/<scene>/summary.json; the scenes written."""
    summaries = paper_summaries(path)
    for scene, summary in summaries.items():
        (Path(folder) / scene).mkdir(parents=True, exist_ok=True)
        (Path(folder) / scene / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return list(summaries)


def compare(path: Path, other: Path, scenes: str | None = None) -> int:
    """``python -m scenarios compare`` of a set's paper_summaries (A) against a result folder (B)."""
    from scenarios.compare import main as compare_main

    with tempfile.TemporaryDirectory() as tmp:
        unpack(path, Path(tmp))
        return compare_main(Path(tmp), Path(other), scenes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="write benchmarks/results/<set>.json from the raw files")
    b.add_argument("--commit", required=True, help="git commit holding the raw files, or WORKTREE")
    b.add_argument("sets", nargs="*", help="sets (default: every dated folder at that commit)")
    u = sub.add_parser("unpack", help="write a set's paper_summaries as <folder>/<scene>/summary.json")
    u.add_argument("json", type=Path)
    u.add_argument("folder", type=Path)
    c = sub.add_parser("compare", help="python -m scenarios compare of a set's paper_summaries against a folder")
    c.add_argument("json", type=Path)
    c.add_argument("folder", type=Path)
    c.add_argument("--scenes", default=None)
    sub.add_parser("size", help="bytes of benchmarks/results/ against the 1 MB limit")
    args = parser.parse_args(argv)
    if args.command == "build":
        build(args.commit, args.sets)
        return 0
    if args.command == "unpack":
        print("\n".join(unpack(args.json, args.folder)))
        return 0
    if args.command == "compare":
        return compare(args.json, args.folder, args.scenes)
    return size()


if __name__ == "__main__":
    sys.exit(main())
