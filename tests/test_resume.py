"""A resumed branch keeps what the stored walk found (its events: stability changes, Krein passes, foam), and a
resume with settings other than the stored branch's is refused with one line that names them."""

import json

from scenarios.__main__ import main


def _summary(out):
    return json.loads((out / "continuation-omega" / "summary.json").read_text())


def test_resume_keeps_the_events_and_refuses_other_settings(tmp_path, capsys):
    args = ["run", "continuation-omega", "--quick", "--device", "cpu", "--out", str(tmp_path)]
    assert main(args) == 0
    first = _summary(tmp_path)
    assert first["stability_changes"] and first["krein_crossings_recorded"] > 0
    assert main(args + ["--resume"]) == 0  # a finished branch: nothing to add, nothing lost
    again = _summary(tmp_path)
    for key in ("stability_changes", "unstable_intervals", "events", "krein_crossings_recorded", "unresolved_bubbles"):
        assert again[key] == first[key], key
    capsys.readouterr()
    assert main(args + ["--resume", "--set", "K=100", "--set", "steps_per_period=64"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "K = 160.0 (stored) vs 100.0" in err and "steps_per_period = 32" in err
    assert _summary(tmp_path)["points"] == first["points"]  # the refused resume wrote nothing
