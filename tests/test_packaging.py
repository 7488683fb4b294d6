"""What ``pip install .`` (not editable) ships: every package directory of the project, so that the installed
``warpchain`` imports (the package list once named the three top-level packages only and left out
``warpchain.engine``: a wheel without it failed at ``import warpchain``)."""

import pathlib

import pytest
import setuptools

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_the_package_list_covers_every_package_directory():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = config["packages"]
    shipped = (
        set(packages)
        if isinstance(packages, list)
        else set(setuptools.find_packages(where=str(ROOT), include=packages["find"]["include"]))
    )
    needed = {
        init.parent.relative_to(ROOT).as_posix().replace("/", ".")
        for top in ("warpchain", "continuation", "scenarios", "sweep")
        for init in (ROOT / top).rglob("__init__.py")
    }
    assert {"warpchain.engine", "sweep"} <= needed
    assert needed <= shipped, f"not in the wheel: {sorted(needed - shipped)}"
    assert not {name for name in shipped if name.split(".")[0] in ("tests", "benchmarks", "docs")}
