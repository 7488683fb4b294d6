"""The docs as a user meets them: every Python block of the README and of the user guide runs as written,
the README stays a short page, and the mkdocs site builds with ``--strict``.

Each code block runs on its own in a fresh interpreter, in an empty working directory, on the CPU
(``CUDA_VISIBLE_DEVICES`` empty), with Warp's default kernel cache: what a reader gets who copies it. A
block meant as a fragment is marked by an HTML comment ``<!-- no-test -->`` on the line before its fence.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDE = sorted((ROOT / "docs" / "guide").glob("*.md"))
README_LIMIT = 12_000  # bytes (issue #35: README <= 12 KB)
NO_TEST = "<!-- no-test -->"
FENCE = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)


def python_blocks(path: Path) -> list[tuple[str, str]]:
    """(id, code) of every ```python block of ``path`` not marked ``<!-- no-test -->``."""
    text = path.read_text()
    blocks = []
    for number, match in enumerate(FENCE.finditer(text), start=1):
        before = text[: match.start()].rstrip().splitlines()
        if before and before[-1].strip() == NO_TEST:
            continue
        line = text.count("\n", 0, match.start()) + 1
        blocks.append((f"{path.relative_to(ROOT)}:{line}#{number}", match.group(1)))
    return blocks


EXAMPLES = [block for path in [README, *GUIDE] for block in python_blocks(path)]


def test_examples_found():
    assert GUIDE, "docs/guide/*.md not found"
    assert len(python_blocks(README)) >= 2, "the README should show at least two examples"
    assert all(python_blocks(path) for path in GUIDE if path.name != "scenes.md" and path.name != "sweep.md")


def test_readme_is_short():
    size = len(README.read_bytes())
    assert size <= README_LIMIT, f"README.md is {size} bytes; keep it <= {README_LIMIT} and move the rest into docs/"


@pytest.mark.slow
@pytest.mark.parametrize("code", [code for _, code in EXAMPLES], ids=[name for name, _ in EXAMPLES])
def test_example_runs_as_written(code, tmp_path):
    (tmp_path / "example.py").write_text(code)
    env = dict(os.environ)
    env["CUDA_VISIBLE_DEVICES"] = ""  # on the CPU, as on a laptop without a GPU
    env["MPLBACKEND"] = "Agg"
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    env.pop("WARP_CACHE_PATH", None)  # Warp's default kernel cache
    result = subprocess.run(
        [sys.executable, "example.py"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, (
        f"the example failed:\n{code}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    )


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_mkdocs_build_strict(tmp_path):
    missing = [
        name for name in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python") if not _importable(name)
    ]
    if missing:
        pytest.skip(f"docs tools not installed ({', '.join(missing)}): pip install -e '.[docs]'")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "mkdocs",
            "build",
            "--strict",
            "-f",
            str(ROOT / "mkdocs.yml"),
            "-d",
            str(tmp_path / "site"),
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stdout}\n{result.stderr}"
    assert (tmp_path / "site" / "index.html").exists()
    assert (tmp_path / "site" / "api" / "continuation.branch_store" / "index.html").exists()


def _importable(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False
