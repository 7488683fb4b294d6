import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


def _run(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, cwd=cwd, timeout=600
    )


def test_list_names_scenes():
    out = _run("list")
    assert out.returncode == 0
    assert "dispersion" in out.stdout


def test_listing_into_a_closed_pipe_and_the_console_name(tmp_path, monkeypatch, capsys):
    # `warpchain list | head -1`: the reader stops early; the listing ends quietly, no traceback
    proc = subprocess.Popen(
        [sys.executable, "-m", "scenarios", "list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().startswith("dispersion")
    proc.stdout.close()
    assert proc.wait(timeout=120) == 0 and "Traceback" not in proc.stderr.read()
    proc.stderr.close()
    # and compare's list of differences (more than a pipe holds), read no further than its first line
    for side, value in (("a", 1), ("b", 2)):
        (tmp_path / side / "nls").mkdir(parents=True)
        (tmp_path / side / "nls" / "summary.json").write_text(json.dumps({f"k{i}": value for i in range(5000)}))
    proc = subprocess.Popen(
        [sys.executable, "-m", "scenarios", "compare", str(tmp_path / "a"), str(tmp_path / "b")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().startswith("nls: k0: 1 vs 2")
    proc.stdout.close()
    assert proc.wait(timeout=120) == 1 and "Traceback" not in proc.stderr.read()
    proc.stderr.close()
    # the usage names the command as typed: the console script, or python -m scenarios
    from scenarios import __main__ as cli

    for argv0, called in (
        ("/usr/local/bin/warpchain", "warpchain run"),
        ("scenarios/__main__.py", "python -m scenarios run"),
    ):
        monkeypatch.setattr(sys, "argv", [argv0, "run", "--help"])
        with pytest.raises(SystemExit):
            cli.main(["run", "--help"])
        assert f"usage: {called}" in capsys.readouterr().out


def test_unknown_scene_and_device_are_clear_errors(tmp_path):
    out = _run("run", "nope", "--out", str(tmp_path))
    assert out.returncode != 0 and "unknown scene" in out.stderr
    out = _run("run", "dispersion", "--device", "tpu", "--out", str(tmp_path))
    assert out.returncode != 0 and "device" in out.stderr


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
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
    # the fit of M, K to the continuous surface-wave model (issue 7)
    assert 20 < summary["fit_M"] < 60 and 100 < summary["fit_K"] < 350 and summary["fit_residual"] < 1e-12
    assert summary["material_set"]["contact_frequency_hz"] == 215e6
    assert set(summary["sensitivity"]) >= {"diameter", "rho_sphere", "rho_substrate", "E_substrate"}
    assert (tmp_path / "dispersion" / "fig2_fitted.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def paper_quick(tmp_path_factory):
    """``python -m scenarios paper --quick --jobs 2``: every paper scene, once, two processes at a time
    (each scene's output is that of ``run NAME``; the tests below read it)."""
    out_dir = tmp_path_factory.mktemp("paper")
    out = _run("paper", "--quick", "--jobs", "2", "--out", str(out_dir), "--device", "cpu")
    assert out.returncode == 0, out.stderr[-3000:]
    assert "paper: 8 scenes, 2 at a time in separate processes" in out.stderr
    assert "paper: 8 scenes in" in out.stderr and "0 failed" in out.stderr
    # every child's provenance records the paper command as typed
    s = json.loads((out_dir / "site-bond" / "summary.json").read_text())
    assert s["command_line"].startswith("python -m scenarios paper --quick --jobs 2")
    return out_dir


@pytest.mark.slow  # a whole scene, a resume or the docs build: the README's slow cases
def test_paper_jobs_are_checked_and_a_failing_scene_is_reported(tmp_path):
    from scenarios._parallel import auto_jobs, child_environment, parse_jobs, run_parallel

    out = _run("paper", "--jobs", "0", "--out", str(tmp_path))
    assert out.returncode == 2 and "--jobs takes a whole number >= 1" in out.stderr
    assert auto_jobs(8, cores=2) == 1 and auto_jobs(8, cores=8) == 4 and auto_jobs(2, cores=64) == 2
    assert parse_jobs("3", 8) == 3 and parse_jobs("auto", 8) == auto_jobs(8)
    env, threads = child_environment(4, environ={"OPENBLAS_NUM_THREADS": "8"}, cores=16)
    assert threads == 2 and env["OMP_NUM_THREADS"] == env["MKL_NUM_THREADS"] == "2" and env["TQDM_DISABLE"] == "1"
    assert env["WARPCHAIN_CPU_THREADS"] == "4"
    assert child_environment(4, environ={}, cores=2)[1] == 1
    # a child that fails (here: a scene that does not exist) does not stop the others; its last lines come back
    failures = run_parallel(["no-such-scene", "dispersion"], tmp_path, "cpu", True, 2, "test")
    assert [f[0] for f in failures] == ["no-such-scene"] and failures[0][1] != 0
    assert any("unknown scene" in line for line in failures[0][2])
    assert (tmp_path / "dispersion" / "summary.json").exists()


@pytest.mark.slow
def test_breather_scenes_quick(paper_quick):
    tmp_path = paper_quick
    s = json.loads((tmp_path / "breather" / "summary.json").read_text())
    for key in (
        "M",
        "K",
        "N",
        "omega",
        "energy",
        "residual",
        "newton_iterations",
        "u_center",
        "v_center",
        "max_floquet_modulus",
        "floquet_pairing_error",
        "stable",
        "method",
        "dt",
        "wall_seconds",
    ):
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


@pytest.mark.slow
def test_continuation_scenes_quick(paper_quick):
    k = json.loads((paper_quick / "continuation-k" / "summary.json").read_text())
    assert {
        "omega",
        "M",
        "N",
        "points",
        "nls_energy_at_K_end",
        "stop_reason",
        "unstable_intervals",
        "stability_changes",
        "parameters",
        "command_line",
    } <= set(k)
    assert k["stop_reason"] == "end_reached" and k["points"][-1]["K"] == 160.0 and k["points"][0]["K"] == 0.01
    assert k["parameters"]["N"] == 101 and k["ended_on_physics"]
    assert all({"K", "energy", "max_floquet_modulus", "stable", "kinds"} <= set(p) for p in k["points"])
    for iv in k["unstable_intervals"]:
        assert iv["start"] <= iv["end"] and set(iv["kinds"]) <= {"real_pair", "period_doubling", "complex_quadruplet"}
        assert isinstance(iv["localized"], bool)
    for ch in k["stability_changes"]:
        assert len(ch["bracket"]) == 2 and isinstance(ch["from_stable"], bool)
    w = json.loads((paper_quick / "continuation-omega" / "summary.json").read_text())
    assert {"K", "M", "N", "points", "stop_reason", "unstable_intervals", "stability_changes"} <= set(w)
    assert all({"omega", "energy", "max_floquet_modulus", "min_contact"} <= set(p) for p in w["points"])
    assert w["stop_reason"] in ("end_reached", "contact_lost") and w["message"]
    for name, figure in (("continuation-k", "continuation_k"), ("continuation-omega", "continuation_omega_energy")):
        assert (paper_quick / name / f"{figure}.png").exists()
    assert all({"K", "kind", "family", "located"} <= set(e) for e in k["bifurcation_points"])


@pytest.mark.slow
def test_site_bond_scene_quick(paper_quick):
    import xarray as xr
    import zarr

    out = paper_quick / "site-bond"
    s = json.loads((out / "summary.json").read_text())
    assert {"bifurcation_points", "pn_barrier", "finite_size", "asymmetric", "families"} <= set(s)
    located = [b for b in s["bifurcation_points"] if b.get("located", True) and "test_mu_minus_1" in b]
    site = [b for b in located if b["family"] == "site" and b["kind"] == "symmetry_breaking_pitchfork"]
    bond = [b for b in located if b["family"] == "bond-in-phase"]
    assert site and bond and all(abs(b["test_mu_minus_1"]) < 1e-8 for b in located)
    # the asymmetric family born at the first pitchfork ends on the bond-centred family's branch point
    asym = s["asymmetric"]
    assert asym["joins"]["joins_bond_family"] and asym["joins"]["relative_distance"] < 1e-6
    assert abs(asym["sqrt_law_exponent"] - 0.5) < 0.1 and max(asym["dop853_periodicity"]) < 1e-8
    # K = 10: the localized real pair is intrinsic, the extended quadruplets finite-size
    rows = s["finite_size"]["10"]["classification"]
    assert any(r["kind"] == "real_pair" and r["localized"] and r["class"] == "intrinsic" for r in rows)
    assert all(r["class"] == "finite-size" for r in rows if not r["localized"])
    assert [row["K"] for row in s["pn_barrier"]] == [5.0, 20.0] and s["pn_barrier"][0]["barrier"] > 0
    groups = set(zarr.open_group(str(out / "data.zarr"), mode="r").group_keys())
    assert {"site", "bond_in_phase", "bond_out_of_phase", "asymmetric", "bifurcations", "pn_barrier"} <= groups
    for group in groups:  # xarray opens every group
        xr.open_zarr(out / "data.zarr", group=group, consolidated=False)
    for figure in ("site_bond", "site_bond_floquet"):
        assert (out / f"{figure}.png").stat().st_size > 10_000


@pytest.mark.slow
def test_set_overrides_and_resume(tmp_path):
    out = _run(
        "run",
        "continuation-omega",
        "--quick",
        "--set",
        "N=41",
        "--set",
        "max_points=4",
        "--out",
        str(tmp_path),
        "--device",
        "cpu",
    )
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "continuation-omega" / "summary.json").read_text())
    assert s["N"] == 41 and s["parameters"]["max_points"] == 4 and s["stop_reason"] == "max_points"
    assert "--set N=41" in s["command_line"]
    out = _run(
        "run",
        "continuation-omega",
        "--quick",
        "--set",
        "N=41",
        "--set",
        "max_points=7",
        "--resume",
        "--out",
        str(tmp_path),
        "--device",
        "cpu",
    )
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "continuation-omega" / "summary.json").read_text())
    assert s["stop_reason"] == "max_points" and len(s["points"]) == 7
    bad = _run("run", "continuation-omega", "--set", "nope=1", "--out", str(tmp_path), "--device", "cpu")
    assert bad.returncode == 2 and "unknown parameter 'nope'" in bad.stderr
    bad = _run("run", "dispersion", "--resume", "--out", str(tmp_path), "--device", "cpu")
    assert bad.returncode == 2 and "cannot be resumed" in bad.stderr


@pytest.mark.slow
def test_direct_simulation_quick(paper_quick):
    xr = pytest.importorskip("xarray")
    s = json.loads((paper_quick / "direct-simulation" / "summary.json").read_text())
    assert {"periods", "method", "dt", "wall_seconds", "cases"} <= set(s)
    assert set(s["cases"]) == {"eigenmode-low", "breather-low", "eigenmode-high", "breather-high"}
    for case in s["cases"].values():
        assert {"energy_error", "min_contact"} <= set(case)
    assert s["cases"]["breather-high"]["energy_error"] < 1e-8
    ds = xr.open_zarr(paper_quick / "direct-simulation" / "data.zarr", group="breather-high")
    assert ds["u"].dims == ("t", "site") and ds.sizes["site"] == 201
    assert ds.sizes["t"] == s["periods"] * s["frames_per_period"] + 1


@pytest.mark.slow
@pytest.mark.parametrize("name", ["work-precision", "stability-limits", "throughput"])
def test_speed_accuracy_scenes_quick(tmp_path, name):
    if name == "throughput":  # a benchmark on the scene machinery: benchmarks/throughput.py
        script = Path(__file__).parents[1] / "benchmarks" / "throughput.py"
        args = [sys.executable, str(script), "--quick", "--out", str(tmp_path), "--device", "cpu"]
        out = subprocess.run(args, capture_output=True, text=True, cwd=tmp_path)
    else:
        out = _run("run", name, "--quick", "--out", str(tmp_path), "--device", "cpu")
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / name / "summary.json").read_text())
    if name == "work-precision":
        p = s["points"][0]
        assert {"case", "implementation", "method", "dt", "rtol", "error", "seconds"} <= set(p)
        assert {q["implementation"] for q in s["points"]} >= {"warp", "scipy"}
    elif name == "stability-limits":
        for m in s["methods"].values():
            assert {"linear_limit", "measured_limit", "order_smooth", "order_contact_loss"} <= set(m)
        assert abs(s["methods"]["verlet"]["order_smooth"] - 2) < 0.3
        assert "newton_fails_below_omega" in s and "float32" in s
    else:
        assert s["device"].startswith("cpu") and s["results"]
        assert {"implementation", "method", "batch", "site_steps_per_second"} <= set(s["results"][0])


@pytest.mark.slow
def test_finite_size_quick(tmp_path):
    """The finite-size scene: the site breather (exponentially localized) keeps its energy and its localized
    real pair at every N, its tail at round-off; the paper breather's tail does not decay; the store reads. Its
    Floquet analyses on one worker thread or three give the same summary, bit for bit."""
    out = _run("run", "finite-size", "--quick", "--out", str(tmp_path), "--device", "cpu", "--set", "workers=1")
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "finite-size" / "summary.json").read_text())
    three = tmp_path / "three"
    out = _run("run", "finite-size", "--quick", "--out", str(three), "--device", "cpu", "--set", "workers=3")
    assert out.returncode == 0, out.stderr[-3000:]
    other = json.loads((three / "finite-size" / "summary.json").read_text())

    def science(x):  # the summary without its timings, command line and parameters
        if isinstance(x, dict):
            skip = ("command_line", "parameters")
            return {k: science(v) for k, v in x.items() if "seconds" not in k and k not in skip}
        return [science(v) for v in x] if isinstance(x, list) else x

    assert science(other) == science(s)
    site, paper = s["families"]["site"], s["families"]["paper"]
    assert s["site_tail_at_round_off"] and not s["paper_tail_at_round_off"]
    assert max(r["energy"] for r in site) - min(r["energy"] for r in site) < 1e-12
    own = [[i for i in r["instabilities"] if i["localized"]] for r in site if r["instabilities"] is not None]
    assert own and all(len(x) == 1 and x[0]["kind"] == "real_pair" for x in own)
    assert len({round(x[0]["modulus"], 9) for x in own}) == 1  # the same localized pair at every N
    assert min(r["outer_amplitude"] for r in paper) > 1e-7
    import xarray as xr

    ds = xr.open_zarr(tmp_path / "finite-size" / "data.zarr", group="paper")
    assert ds.sizes["size"] == len(s["sizes"]) and "energy" in ds
    assert (tmp_path / "finite-size" / "finite_size.png").exists()


@pytest.mark.slow
def test_monolayer_quick_has_an_energy_threshold_where_the_stability_changes(tmp_path):
    """The monolayer scene (9 x 9 patches): on both lattices E(w_b) has an interior minimum, every verdict is
    complete, and the stability changes at the minimum within the refined spacing (Vakhitov-Kolokolov); the
    threshold lies above the discrete NLS's prediction; the store reads checked, with positions for the profile."""
    import warpchain as wc

    out = _run(
        "run", "monolayer", "--quick", "--out", str(tmp_path), "--device", "cpu", "--set", "check_size=13",
        "--set", "K_walk=1.25,1.5",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "monolayer" / "summary.json").read_text())
    for name in ("square", "triangular"):
        # the threshold again on a 13 x 13 patch (measured: 4.2e-4 and 5.7e-4 from 9 x 9)
        assert s[name]["size_check"]["size"] == 13 and s[name]["size_check"]["relative_difference"] < 1e-3
        walk = wc.read_store(tmp_path / "monolayer" / "data.zarr", f"{name}_K")  # the continuation in K at fixed w_b
        assert s[name]["K_walk_points"] == 2 and bool(walk.floquet_complete.all())
        assert float(walk.energy[1]) > float(walk.energy[0]) > s[name]["threshold"]["energy"]
        t, change = s[name]["threshold"], s[name]["stability_change"]
        assert t and change and change["from_stable"], name
        assert abs(t["omega"] - np.mean(change["bracket"])) < t["spacing"], name
        assert t["energy"] > 0.01  # positive: a threshold, not zero as on the chain
        assert 1.1 < s[name]["threshold_over_dnls"] < 1.3  # above the discrete NLS's (measured: 1.158, 1.263)
        ds = wc.read_store(tmp_path / "monolayer" / "data.zarr", name)
        assert bool(ds.floquet_complete.all()) and float(ds.energy.min()) >= t["energy"] - 1e-6
    assert s["square"]["threshold"]["energy"] < s["triangular"]["threshold"]["energy"]  # six neighbours cost more
    assert (tmp_path / "monolayer" / "monolayer.png").exists()
    for name, kappa in (("square", 1.0), ("triangular", 1.5)):  # the linear waves
        w = s[name]["waves"]
        edges, modes = w["band_edges"], w["lowest_optical_modes"]
        assert abs(edges["optical_bottom"] - np.sqrt(31.0 / 30.0)) < 1e-15
        assert edges["optical_bottom"] < modes[0] <= modes[1] <= modes[2] < edges["optical_top"]
        assert w["chain_equivalent_K"] == kappa * s["K"]
        path = wc.read_store(tmp_path / "monolayer" / "data.zarr", f"{name}_path")
        assert abs(float(path.optical.min()) - edges["optical_bottom"]) < 1e-12
        assert abs(float(path.acoustic.max()) - edges["acoustic_top"]) < 1e-12  # the path passes the top
    assert (tmp_path / "monolayer" / "monolayer-waves.png").exists()


@pytest.mark.slow
def test_monolayer_one_breather_on_a_patch_past_the_dense_size(tmp_path):
    """A 41 x 41 square patch (1681 sites) takes ``floquet(solver="auto")``'s probed path (the dense one stops at 1600
    sites): a complete verdict, stable, with every multiplier stored; a free or periodic patch past 41 x 41 is
    refused (Newton is dense there), naming the rule."""
    out = _run(
        "run", "monolayer", "--out", str(tmp_path), "--device", "cpu", "--set", "lattice=square", "--set", "n=41",
        "--set", "omega=1.014",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "monolayer" / "summary.json").read_text())
    assert s["floquet_path"] == "probed" and s["floquet_complete"] is True and s["stable"] is True
    assert abs(s["max_floquet_modulus"] - 1.0) < 1e-9 and abs(s["energy"] - 0.0584499326714) < 1e-9
    import warpchain as wc

    mu = wc.read_store(tmp_path / "monolayer" / "data.zarr", "square_multipliers")
    assert mu.sizes["multiplier"] == 4 * 41 * 41
    out = _run("run", "monolayer", "--out", str(tmp_path), "--device", "cpu", "--set", "n=51", "--set", "boundary=free")
    assert out.returncode == 2 and "unless boundary=fixed" in out.stderr


@pytest.mark.slow
def test_monolayer_says_where_to_walk_when_the_walk_misses_the_minimum(tmp_path):
    """At K = 0.25 the threshold lies closer to the edge than the default walk resolves: no threshold is claimed,
    and the advice (from the discrete NLS's prediction) leads to it."""
    base = ["run", "monolayer", "--quick", "--device", "cpu", "--set", "K=0.25", "--set", "lattice=square"]
    out = _run(*base, "--out", str(tmp_path / "a"))
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "a" / "monolayer" / "summary.json").read_text())["square"]
    assert s["threshold"] is None and "--set omega_start=" in s["advice"]
    advice = s["advice"].split("try ")[1].split()
    out = _run(*base, *advice, "--out", str(tmp_path / "b"))
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "b" / "monolayer" / "summary.json").read_text())["square"]
    assert s["advice"] is None and 1.0 < s["threshold_over_dnls"] < 1.06


def test_a_worker_failure_or_an_incomplete_verdict_is_one_line(tmp_path, monkeypatch, capsys):
    """An eigensolver worker that failed (its traceback kept as ``detail``) or a branch point whose Floquet count did
    not close reaches the command line as one line and exit status 1, not a traceback."""
    import scenarios.__main__ as cli
    from continuation.driver import IncompleteVerdict
    from continuation.workers import WorkerError

    for error in (
        WorkerError("Floquet slice 3 of 68 failed in eigensolver worker 123: ValueError: boom", "Traceback ..."),
        IncompleteVerdict("the Floquet count did not close at K = 2.0"),
    ):

        def fail(*args, **kwargs):
            raise error

        monkeypatch.setattr(cli, "run_scene", fail)
        assert cli.main(["run", "breather", "--out", str(tmp_path), "--device", "cpu"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"error: {error}"]


def test_a_scene_that_raises_is_one_line_with_its_traceback_in_failed_json(tmp_path, monkeypatch, capsys):
    import scenarios.__main__ as cli
    from continuation.workers import WorkerError
    from scenarios import nls

    def broken(ctx):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(nls, "run", broken)
    assert cli.main(["run", "nls", "--quick", "--out", str(tmp_path), "--device", "cpu"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    failed = tmp_path / "nls" / "failed.json"
    assert err == [f"error: scene nls failed: ZeroDivisionError: float division by zero (traceback in {failed})"]
    record = json.loads(failed.read_text())
    assert "Traceback" in record["traceback"] and "broken" in record["traceback"]

    def worker_failed(ctx):  # an engine error inside a scene keeps its own one-line message
        raise WorkerError("Floquet slice 3 of 68 failed in eigensolver worker 123: ValueError: boom", "Traceback ...")

    monkeypatch.setattr(nls, "run", worker_failed)
    assert cli.main(["run", "nls", "--quick", "--out", str(tmp_path), "--device", "cpu"]) == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: Floquet slice 3 of 68 failed in eigensolver worker 123: ValueError: boom"
    ]


def test_a_library_error_names_the_values_given_and_warnings_are_log_lines(tmp_path, monkeypatch, capsys, caplog):
    """A ValueError raised inside a library (scipy's "function value is NaN") is the scene's failure (exit 1, its
    traceback in failed.json) naming the --set values, not a refusal worded by us (exit 2); a library's warning
    while a scene runs is one log line, not Python's two lines."""
    import warnings

    import scenarios.__main__ as cli
    from scenarios import nls

    def broken(ctx):
        warnings.warn("invalid value encountered in sqrt", RuntimeWarning)
        import scipy.optimize

        scipy.optimize.brentq(lambda x: float("nan"), 0.0, 1.0)

    monkeypatch.setattr(nls, "run", broken)
    argv = ["run", "nls", "--quick", "--out", str(tmp_path), "--device", "cpu", "--set", "sweep=1.01"]
    with caplog.at_level("WARNING"):
        assert cli.main(argv) == 1
    captured = capsys.readouterr()
    failed = tmp_path / "nls" / "failed.json"
    assert captured.err.strip().splitlines() == [
        "error: scene nls failed: ValueError: The function value at x=0.0 is NaN; solver cannot continue. "
        f"(with --set sweep=1.01; traceback in {failed})"
    ]
    assert "brentq" in json.loads(failed.read_text())["traceback"]
    lines = [r.getMessage() for r in caplog.records if "warning:" in r.getMessage()]
    assert lines == [
        "[nls] warning: RuntimeWarning: invalid value encountered in sqrt (test_cli.py:%d)"
        % (broken.__code__.co_firstlineno + 1)
    ]

    def refuses(ctx):  # a refusal worded by warpchain keeps its exit 2 and its own words
        from warpchain import ChainParams

        ChainParams(M=-1.0, K=1.0, N=11)

    monkeypatch.setattr(nls, "run", refuses)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "M" in err[0]


def test_every_count_has_a_ceiling():
    """No integer parameter of any scene is unbounded above: 10**12 periods, sites or iterations is refused in one
    line before anything runs (it ran out of memory or for ever)."""
    import dataclasses

    from scenarios._common import SCENES, load_scene
    from scenarios._params import allowed_of, kind_of

    for name in SCENES:
        cls = getattr(load_scene(name), "Parameters", None)
        for field in dataclasses.fields(cls) if cls else ():
            allowed, kind = allowed_of(field), kind_of(field.type)
            if allowed is None or int not in (kind.base, kind.item) or allowed.options() is not None:
                continue
            assert allowed.le is not None or allowed.lt is not None, f"{name}: {field.name} has no upper bound"


def test_command_line_offers_what_works(tmp_path, capsys):
    """--version; paper takes neither --set nor --resume (its help does not offer them); -q prints nothing on
    success; --resume on a folder that does not exist writes nothing; extreme values are refused in one line."""
    import scenarios.__main__ as cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["--version"])
    assert stop.value.code == 0 and "0." in capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli.main(["paper", "--help"])
    text = capsys.readouterr().out
    assert "--set" not in text and "--resume" not in text and "--quiet" in text
    with pytest.raises(SystemExit) as stop:
        cli.main(["paper", "--set", "N=3"])
    assert stop.value.code == 2
    capsys.readouterr()
    missing = tmp_path / "nothing"
    assert cli.main(["run", "continuation-omega", "--resume", "--out", str(missing), "--device", "cpu"]) == 2
    assert "no branch to continue" in capsys.readouterr().err and not (missing / "continuation-omega").exists()
    for setting in ("K=1e200", "resolution=1e-300"):
        assert cli.main(["run", "continuation-omega", "--set", setting, "--out", str(tmp_path), "--device", "cpu"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: "), err
    assert cli.main(["run", "breather", "--set", "omega=1.2", "--out", str(tmp_path), "--device", "cpu"]) == 2
    assert "below the optical bottom" in capsys.readouterr().err


@pytest.mark.slow
def test_quiet_run_prints_nothing_and_breather_takes_its_parameters(tmp_path):
    out = _run(
        "run",
        "breather",
        "--quick",
        "-q",
        "--set",
        "N=41",
        "--set",
        "K=10",
        "--set",
        "omega=1.012",
        "--out",
        str(tmp_path),
        "--device",
        "cpu",
    )
    assert out.returncode == 0 and out.stderr.strip() == "", out.stderr[-2000:]
    s = json.loads((tmp_path / "breather" / "summary.json").read_text())
    assert (s["N"], s["K"], s["omega"]) == (41, 10.0, 1.012)


@pytest.mark.slow
def test_every_store_of_the_paper_reads_checked_with_units_and_long_names(paper_quick):
    """``warpchain.read_store`` opens every group of every paper scene's store; every variable and coordinate
    carries ``long_name`` and ``units`` (issue #49's target), branches are indexed by their parameter."""
    import warpchain as wc

    stores = sorted(paper_quick.glob("*/data.zarr"))
    assert len(stores) == 8  # every paper scene keeps a store
    for path in stores:
        tree = wc.read_store(path)
        assert tree.attrs["provenance"]["git_commit"] is None or tree.attrs["provenance"]["git_commit"]
        for node in tree.subtree:
            for name, var in node.ds.variables.items():
                assert var.attrs.get("long_name") and "units" in var.attrs, (path, node.path, name)
    assert wc.read_store(paper_quick / "continuation-k" / "data.zarr", "branch").energy.dims == ("K",)
    assert wc.read_store(paper_quick / "continuation-omega" / "data.zarr", "branch").energy.dims == ("omega",)


@pytest.mark.slow
def test_monolayer_spot_quick_localizes_above_the_threshold_only(tmp_path):
    """The spot experiment (41 x 41 triangular patch, the chain's K = 16: the patch's 10.7): the strong spot
    (optical energy above the discrete NLS's threshold) self-localizes against its linear control and forms a
    breather, the weak one (far below) does not; every group of the store reads checked, and the figures and the
    animation are written."""
    import warpchain as wc

    out = _run("run", "monolayer-spot", "--quick", "--out", str(tmp_path), "--device", "cpu")
    assert out.returncode == 0, out.stderr[-3000:]
    folder = tmp_path / "monolayer-spot"
    s = json.loads((folder / "summary.json").read_text())
    spots = s["per_spot"]
    weak, strong = np.argsort(spots["optical_energy_over_threshold"])
    assert spots["optical_energy_over_threshold"][weak] < 0.1 < 1.0 < spots["optical_energy_over_threshold"][strong]
    assert spots["monolayer_spread_over_linear"][weak] > 0.95 and spots["monolayer_formed"][weak] == 0
    assert spots["monolayer_spread_over_linear"][strong] < 0.8 and spots["monolayer_self_localized"][strong] == 1
    assert spots["monolayer_formed"][strong] == 1 and spots["monolayer_breathers"][strong] >= 1
    for group in ("monolayer_spots", "chain_spots", "monolayer_series", "chain_series", "movie"):
        wc.read_store(folder / "data.zarr", group)
    for name in ("monolayer-spot.png", "monolayer-spot-snapshots.png", "monolayer-spot.gif"):
        assert (folder / name).stat().st_size > 0
    # the drawings' images are the stored envelopes on the patch's grid, under the affine map to the positions
    from scenarios.monolayer_spot import _movie
    from warpchain.store import read_group

    movie, _ = _movie(folder)
    frames, _ = read_group(folder / "data.zarr", "movie")
    i, j = frames["i"].astype(int), frames["j"].astype(int)
    assert movie["images"].shape == (len(frames["t"]), 41, 41) and len(frames["t"]) == 60 + 1  # periods + t = 0
    assert np.array_equal(movie["images"][:, j, i], frames["envelope"])
    mapped = np.column_stack([i, j, np.ones(len(i))]) @ movie["matrix"].T
    np.testing.assert_allclose(mapped[:, :2], np.column_stack([frames["x"], frames["y"]]), atol=1e-12)
    assert 10 <= movie["view"] <= 20 and movie["scale"] == frames["envelope"][1:].max()


def test_every_scene_keeps_its_rules_on_its_parameters():
    """Rules across fields are read from ``Parameters.RULES``; a module-level ``RULES`` was silently ignored (the
    monolayer scenes', found 2026-11-28: their omega and size rules never ran)."""
    from scenarios._common import SCENES, load_scene

    for name in SCENES:
        module = load_scene(name)
        assert getattr(module, "RULES", None) is None, name


def test_monolayer_one_breather_reports_its_verdict(tmp_path):
    """``--set omega=...`` with one lattice: one breather, its energy, max_floquet_modulus and a complete verdict in
    summary.json (the interface issue #51 names), its state and multipliers in the store."""
    import warpchain as wc

    out = _run(
        "run", "monolayer", "--out", str(tmp_path), "--device", "cpu", "--set", "lattice=triangular",
        "--set", "n=7", "--set", "omega=1.005", "--set", "boundary=fixed",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    s = json.loads((tmp_path / "monolayer" / "summary.json").read_text())
    assert s["stable"] is True and s["floquet_complete"] and abs(s["max_floquet_modulus"] - 1) < 1e-9
    assert s["energy"] > 0 and s["residual"] < 1e-10
    m = wc.read_store(tmp_path / "monolayer" / "data.zarr", "triangular_multipliers")
    assert m.sizes["multiplier"] == 4 * 49
    near = _run(
        "run",
        "monolayer",
        "--out",
        str(tmp_path / "near"),
        "--device",
        "cpu",
        "--set",
        "lattice=square",
        "--set",
        "n=9",
        "--set",
        "omega=1.0160",
        "--set",
        "seed=dnls",
    )  # fmt: skip  (near the band edge, from the discrete NLS's seed)
    assert near.returncode == 0, near.stderr[-3000:]
    assert json.loads((tmp_path / "near" / "monolayer" / "summary.json").read_text())["residual"] < 1e-9
