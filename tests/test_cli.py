import json
import subprocess
import sys

import pytest


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=600)


def test_list_names_scenes():
    out = _run("list")
    assert out.returncode == 0
    assert "dispersion" in out.stdout


def test_unknown_scene_and_device_are_clear_errors(tmp_path):
    out = _run("run", "nope", "--out", str(tmp_path))
    assert out.returncode != 0 and "unknown scene" in out.stderr
    out = _run("run", "dispersion", "--device", "tpu", "--out", str(tmp_path))
    assert out.returncode != 0 and "device" in out.stderr


def test_dispersion_scene(tmp_path):
    out = _run("run", "dispersion", "--quick", "--out", str(tmp_path), "--device", "cpu")
    assert out.returncode == 0, out.stderr
    summary = json.loads((tmp_path / "dispersion" / "summary.json").read_text())
    for key in ("M", "K", "acoustic_top", "optical_bottom", "optical_top", "gap_width", "lowest_optical_mode"):
        assert key in summary
    assert summary["lowest_optical_mode"] == pytest.approx(1.016551, abs=1e-6)
    assert summary["gap_width"] == pytest.approx(summary["optical_bottom"] - summary["acoustic_top"])
    assert (tmp_path / "dispersion" / "dispersion.png").stat().st_size > 10_000
    assert (tmp_path / "dispersion" / "dispersion.pdf").exists()
    assert 10 < summary["appendix_estimates"]["M"] < 100
