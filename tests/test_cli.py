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


def test_breather_scenes_quick(tmp_path):
    for name in ("anticontinuum", "nls", "breather"):
        out = _run("run", name, "--quick", "--out", str(tmp_path), "--device", "cpu")
        assert out.returncode == 0, out.stderr
    s = json.loads((tmp_path / "breather" / "summary.json").read_text())
    for key in ("M", "K", "N", "omega", "energy", "residual", "newton_iterations", "u_center", "v_center",
                "max_floquet_modulus", "floquet_pairing_error", "stable", "method", "dt", "wall_seconds"):
        assert key in s, key
    assert s["residual"] <= 1e-10 and s["floquet_pairing_error"] <= 1e-8
    assert s["direct_simulation"]["max_relative_deviation"] < 1e-8
    assert s["u_center"] > 0 > s["v_center"]
    n = json.loads((tmp_path / "nls" / "summary.json").read_text())
    assert {"nls_energy", "numerical_energy", "profile_max_difference"} <= set(n)
    assert n["numerical_energy"] == pytest.approx(s["energy"], rel=1e-12)
    a = json.loads((tmp_path / "anticontinuum" / "summary.json").read_text())
    assert a["period"] == pytest.approx(2 * 3.141592653589793 / 1.01, rel=1e-9)
    for name in ("anticontinuum", "nls", "breather"):
        assert (tmp_path / name / f"{name}.png").exists()
