"""Scene parameters: every field of every scene states its allowed values beside it (``scenarios._params``), the
defaults and the --quick variants pass them, and a value that is not allowed, typed after --set or given through
the API, is one line naming the parameter, the value and what is allowed, before the scene writes anything."""

import dataclasses
import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from scenarios._common import SCENES, load_scene, run_scene, scene_parameters
from scenarios._params import allowed_of, kind_of, show


def _benchmark(name: str):
    """A benchmark built on the scene machinery (``benchmarks/NAME.py``), loaded from its file."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # a dataclass reads its module's namespace
    spec.loader.exec_module(module)
    return module


MODULES = {name: load_scene(name) for name in SCENES} | {"throughput": _benchmark("throughput")}


def _numeric(kind) -> bool:
    return (kind.item if kind.base is tuple else kind.base) in (int, float)


def _cases(pick):
    return [
        pytest.param(name, f.name, id=f"{name}:{f.name}")
        for name, module in MODULES.items()
        for f in dataclasses.fields(module.Parameters)
        if pick(kind_of(f.type))
    ]


def _field(name, key):
    return next(f for f in dataclasses.fields(MODULES[name].Parameters) if f.name == key)


def _refused(name, overrides, quick=True) -> str:
    with pytest.raises(ValueError) as err:
        scene_parameters(MODULES[name], quick, overrides)
    message = str(err.value)
    assert "\n" not in message and message.strip() == message
    return message


def _replace_first(default, value):
    """A tuple field's default with its first element replaced (the field's other checks still pass)."""
    return (value, *default[1:])


def test_every_scene_has_a_parameter_block_and_every_field_a_declared_range():
    for name, module in MODULES.items():
        cls = getattr(module, "Parameters", None)
        assert cls is not None, name
        for f in dataclasses.fields(cls):
            allowed = allowed_of(f)
            assert allowed is not None and allowed.help, f"{name}: {f.name} has no param(...) with a description"
            kind = kind_of(f.type)  # a type the --set reader knows
            if _numeric(kind):
                bounded = any(b is not None for b in (allowed.ge, allowed.gt, allowed.le, allowed.lt))
                assert bounded or allowed.options() is not None, f"{name}: {f.name} has no bounds"
            if kind.base is str:
                assert allowed.options() is not None or f.name == "scheduler", f"{name}: {f.name}: no choices"


@pytest.mark.parametrize("quick", [False, True], ids=["default", "quick"])
@pytest.mark.parametrize("name", list(SCENES))
def test_defaults_and_quick_pass_their_own_ranges(name, quick):
    module = MODULES[name]
    P = scene_parameters(module, quick)
    assert isinstance(P, module.Parameters)
    for key, value in (getattr(module, "QUICK", {}) if quick else {}).items():
        assert getattr(P, key) == value


AUDIT = [
    ("breakup-statistics", "final_frames", "0", "must be an integer in [1, 10000] (periods over which the final count"),
    ("breakup-statistics", "impulse", "foo", "must be one of velocity, displacement"),
    ("breakup-statistics", "realisations", "-1", "must be an integer in [0, 10000000]"),
    ("breakup-statistics", "periods", "0", "must be an integer in [1, 100000]"),
    ("breakup-statistics", "threshold", "-1", "must be a finite number > 0"),
    ("breakup-statistics", "method", "rk4", "must be one of verlet, yoshida4, yoshida6, kahan6, kahan8"),
    ("continuation-omega", "omega_min", "nan", "must be a finite number > 0"),
    ("continuation-k", "N", "1", "must be an integer in [31, 3201]"),
    ("continuation-omega", "N", "1", "must be an integer in [2, 3201]"),
    ("site-bond", "N", "1", "must be an integer in [19, 3201]"),
    ("continuation-k", "K_start", "0", "must be a finite number > 0"),
    ("site-bond", "K_start", "0", "must be a finite number > 0"),
    # a rule that cannot be weighed (the stability limit of a chain too stiff to step) names the key given
    ("continuation-k", "K_end", "1e308", "no stable dt (the stiffness overflows)"),
    ("breather", "N", "1602", "must be an integer in [3, 1601]"),
    ("direct-simulation", "periods", "10000", "needs periods x frames_per_period <= 1e5 frames"),
    ("work-precision", "contact_loss_scale", "1e-300", "must be a finite number in [1, 100]"),
]


@pytest.mark.parametrize("name, key, value, expected", AUDIT, ids=[f"{a[0]}:{a[1]}={a[2]}" for a in AUDIT])
def test_the_audits_bad_values_are_one_line_errors(name, key, value, expected):
    message = _refused(name, {key: value})
    assert message.startswith(f"--set {key}={value}: ") and expected in message
    typed = kind_of(_field(name, key).type)
    if typed.base in (int, float):  # the same value through the API
        api = _refused(name, {key: typed.base(float(value))})
        assert api.startswith(f"parameter {key}=") and expected in api


@pytest.mark.parametrize("name, key", _cases(lambda kind: _numeric(kind)))
def test_nan_and_inf_are_refused(name, key):
    f = _field(name, key)
    kind, allowed = kind_of(f.type), allowed_of(f)
    assert not allowed.nan
    default = getattr(MODULES[name].Parameters(), key)
    for bad in (math.nan, math.inf, -math.inf):
        api = _replace_first(default, bad) if kind.base is tuple else bad
        assert key in _refused(name, {key: api}, quick=False)
        typed = show(api)  # nan, inf, -inf as typed after --set
        assert _refused(name, {key: typed}, quick=False).startswith(f"--set {key}={typed}: must be ")


def _outside(allowed, item: type) -> list:
    """Values clearly outside the declared range: below its lower bound, above its upper, not a choice."""
    out = []
    for bound in (allowed.ge, allowed.gt):
        if bound is not None:
            out.append(item(bound) - 1 if item is int else bound - max(1.0, abs(bound)))
    for bound in (allowed.le, allowed.lt):
        if bound is not None:
            out.append(item(bound) + 1 if item is int else bound + max(1.0, abs(bound)))
    options = allowed.options()
    if options is not None:
        out.append(max(options) + 1)
    return out


@pytest.mark.parametrize("name, key", _cases(lambda kind: _numeric(kind)))
def test_clearly_out_of_range_values_are_refused(name, key):
    f = _field(name, key)
    kind, allowed = kind_of(f.type), allowed_of(f)
    item = kind.item if kind.base is tuple else kind.base
    default = getattr(MODULES[name].Parameters(), key)
    outside = _outside(allowed, item)
    assert outside, f"{name}: {key} declares no range"
    for bad in outside:
        value = _replace_first(default, bad) if kind.base is tuple else bad
        message = _refused(name, {key: show(value)}, quick=False)
        assert message.startswith(f"--set {key}={show(value)}: must be {allowed.describe(kind)}"), message
        assert key in _refused(name, {key: value}, quick=False)
    if kind.base is int:  # a fraction is not an integer
        assert _refused(name, {key: "1.5"}, quick=False).startswith(
            f"--set {key}=1.5: must be {allowed.describe(kind)}"
        )
        if allowed.multiple_of:
            odd = getattr(MODULES[name].Parameters(), key) + 1
            assert f"must be {allowed.describe(kind)}" in _refused(name, {key: str(odd)}, quick=False)


@pytest.mark.parametrize(
    "name, overrides, named, fragment",
    [
        ("breakup-statistics", {"final_frames": "100"}, "final_frames", "final_frames <= periods (periods = 80)"),
        ("breakup-statistics", {"periods": "3"}, "periods", "final_frames <= periods"),
        ("breakup-statistics", {"steps_per_period": "8"}, "steps_per_period", "steps_per_period >= 12"),
        ("breakup-statistics", {"steps_per_period": "30"}, "steps_per_period", "a multiple of 4 with fields on"),
        ("breakup-statistics", {"check_steps_per_period": "4"}, "check_steps_per_period", ">= 9 with checks on"),
        ("breakup-statistics", {"workers": "2", "scheduler": "tcp://h:8786"}, "workers", "not both"),
        ("continuation-omega", {"omega_min": "1.02"}, "omega_min", "the optical band bottom"),
        ("continuation-omega", {"ds": "2"}, "ds", "ds_min <= ds <= ds_max"),
        ("continuation-k", {"K_start": "200"}, "K_start", "K_start < K_end"),
        ("continuation-k", {"K_end": "1"}, "K_end", "every profile_K in (K_start, K_end]"),
        ("continuation-k", {"omega": "1.02"}, "omega", "omega < w0 = sqrt((M + 1) / M) = 1.01653005"),
        ("continuation-k", {"steps_per_period": "6"}, "steps_per_period", "steps_per_period >= 10 for kahan8"),
        ("continuation-omega", {"method": "verlet", "omega_min": "0.2"}, "method", "steps_per_period >= 74"),
        ("site-bond", {"sqrt_amplitudes": "0.01,0.01"}, "sqrt_amplitudes", "distinct"),
        ("site-bond", {"finite_size_K": "200"}, "finite_size_K", "every finite_size_K in (K_start, K_end]"),
        ("site-bond", {"ds": "0.4", "ds_max": "0.5"}, "ds", "out_of_phase_ds_max"),
        ("anticontinuum", {"omega": "0.01"}, "omega", "continuation.anticontinuum_orbit finds none"),
        ("anticontinuum", {"amplitude_max": "1e-4"}, "amplitude_max", "amplitude_min < amplitude_max"),
        ("stability-limits", {"newton_floor": "1.02"}, "newton_floor", "newton_floor <= 1.01 - newton_step"),
        ("throughput", {"dt": "0.4"}, "dt", "dt < 0.340372657"),
        ("throughput", {"record_every": "500"}, "record_every", "record_every <= simulate_steps"),
        ("work-precision", {"numpy_steps_per_period": "8,64"}, "numpy_steps_per_period", ">= 19"),
    ],
)
def test_rules_across_fields_name_the_parameter_given(name, overrides, named, fragment):
    message = _refused(name, overrides)
    assert message.startswith(f"--set {named}={overrides[named]}: needs ") and fragment in message, message


def test_set_values_read_as_the_fields_types():
    throughput, work = MODULES["throughput"], MODULES["work-precision"]
    P = scene_parameters(throughput, True, {"batches_cpu": "1, 64", "max_steps": "2e5", "monodromy": "yes"})
    assert P.batches_cpu == (1, 64) and all(type(b) is int for b in P.batches_cpu)
    assert P.max_steps == 200_000 and type(P.max_steps) is int and P.monodromy is True
    assert scene_parameters(work, True, {"numpy_steps_per_period": ""}).numpy_steps_per_period == ()
    assert scene_parameters(throughput, True, {"simulate_batches_cpu": [64, 805]}).simulate_batches_cpu == (64, 805)
    omega = MODULES["continuation-omega"]
    assert scene_parameters(omega, True, {"max_points": "none", "max_seconds": "30"}).max_seconds == 30.0
    assert scene_parameters(omega, True, {"max_points": "7"}).max_points == 7
    assert "or none" in _refused("continuation-omega", {"max_points": "0"})
    assert _refused("breather", {"general_seed_near_solution": "maybe"}).endswith(
        "must be true or false (seed the general formulation next to the solution, not from the NLS profile)"
    )
    assert "must be one of 1, 2, 4, 8, 16, 32" in _refused("direct-simulation", {"frames_per_period": "5"})
    assert "must be an integer" in _refused("breakup-statistics", {"periods": True})  # a bool is no integer


def test_an_api_override_is_refused_before_the_scene_makes_its_folder(tmp_path):
    with pytest.raises(ValueError, match=r"^parameter final_frames=0: must be an integer in \[1, 10000\]"):
        run_scene("breakup-statistics", tmp_path, "cpu", True, overrides={"final_frames": 0})
    assert not any(tmp_path.iterdir())


def test_cli_prints_one_line_and_writes_nothing(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "scenarios", "run", "breakup-statistics", "--quick", "--device", "cpu"]
        + ["--set", "final_frames=0", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2
    assert out.stderr.strip() == (
        "error: --set final_frames=0: must be an integer in [1, 10000] (periods over which the final count is a median)"
    )
    assert not list(tmp_path.rglob("summary.json")) and not any(tmp_path.iterdir())


def test_params_lists_defaults_types_and_ranges(capsys):
    from scenarios.__main__ import main

    assert main(["params", "breakup-statistics"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("breakup-statistics: Breakup statistics:")
    assert "  final_frames (int) = 10  [--quick: 5]\n      allowed: an integer in [1, 10000]\n" in text
    assert "      periods over which the final count is a median\n" in text
    assert "    final_frames, periods: final_frames <= periods" in text
    assert main(["params"]) == 0
    every = capsys.readouterr().out
    assert all(f"\n{name}: " in "\n" + every for name in SCENES)
    assert "  profile_K (tuple[float]) = 5,20,160" in every
    with pytest.raises(SystemExit):
        main(["params", "nope"])


def test_the_parameters_a_summary_records_pass_again():
    """A summary's recorded parameters (JSON: tuples as lists) given back through the API pass."""
    for name, module in MODULES.items():
        recorded = json.loads(json.dumps(dataclasses.asdict(scene_parameters(module, True))))
        assert scene_parameters(module, True, recorded) == scene_parameters(module, True), name
