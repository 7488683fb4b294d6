"""The same science from every way of running: ``paper --quick`` with its scenes one after the other in one
process and two at a time in child processes, and site-bond with one worker thread and with four, compare
equal (``python -m scenarios compare``). On a GPU machine the same check is ``paper --device cuda`` against a
CPU run of the same commit (``benchmarks/results/README.md``, "The CPU reference")."""

import subprocess
import sys

import pytest

from scenarios.compare import main as compare


def _scenes(*args, cwd):
    done = subprocess.run(
        [sys.executable, "-m", "scenarios", *args, "--device", "cpu"], cwd=cwd, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]


@pytest.mark.slow
def test_paper_in_order_and_in_parallel_and_site_bond_workers_agree(tmp_path, capsys):
    _scenes("paper", "--quick", "--jobs", "1", "--out", str(tmp_path / "jobs1"), cwd=tmp_path)
    _scenes("paper", "--quick", "--jobs", "2", "--out", str(tmp_path / "jobs2"), cwd=tmp_path)
    assert compare(tmp_path / "jobs1", tmp_path / "jobs2") == 0, capsys.readouterr().out
    assert "same science: 8 scenes" in capsys.readouterr().out
    for workers in (1, 4):
        out = str(tmp_path / f"workers{workers}")
        _scenes("run", "site-bond", "--quick", "--set", f"workers={workers}", "--out", out, cwd=tmp_path)
    assert compare(tmp_path / "workers1", tmp_path / "workers4") == 0, capsys.readouterr().out
