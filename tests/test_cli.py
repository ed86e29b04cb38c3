"""CLI input handling: every bad flag or value exits 2 naming it, before any work is done;
a run that ends in an error never passes; a re-used run folder never mixes two runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cosim.cli import main

ROOT = Path(__file__).resolve().parent.parent
SQ = str(ROOT / "scenarios" / "scripted_square.toml")


@pytest.mark.parametrize("argv, field", [
    (["run", SQ, "--png-every", "-3"], "--png-every"),
    (["run", SQ, "--speed", "2"], "--speed"),
    (["run", SQ, "--realtime", "--speed", "0"], "--speed"),
    (["run", SQ, "--realtime", "--speed", "inf"], "--speed"),
    (["run", SQ, "--set", "app.alpha=0.1"], "app.params.alpha"),
    (["run", SQ, "--set", "app.tolerance_m=abc"], "app.params.tolerance_m"),
    (["run", SQ, "--set", "app.name=nosuch.module:App"], "app.name"),
    (["run", SQ, "--set", "timing.camera_every=0"], "timing.camera_every"),
    (["run", SQ, "--set", "nonsense"], "--set"),
    (["run", "/nonexistent/x.toml"], "scenario"),
    (["sweep", SQ, "--set", "seed=1", "--workers", "-3"], "--workers"),
    (["sweep", SQ, "--set", "app.tolerance_m=0.1,oops"], "app.params.tolerance_m"),
    (["sitl", "--speed", "0"], "--speed"),
    (["sitl", "--gcs-bind", "127.0.0.1:99999"], "--gcs-bind"),
    (["sitl", "--api-remote", "nohost"], "--api-remote"),
    (["sitl", "--world", "atlantis"], "--world"),
    (["sitl", "-i", "255"], "--instance"),
    (["sitl", "-n", "0"], "--count"),
    (["sitl", "-i", "250", "-n", "6"], "--count"),
    (["sitl", "--spacing", "-1"], "--spacing"),
    (["sitl", "-n", "2", "--api-remote", "127.0.0.1:65535"], "--api-remote"),
    (["sitl", "--world", "room_e1", "-n", "3"], "--count"),     # the third in the east wall
    (["validate", str(ROOT)], "scenario"),
])
def test_bad_input_exits_2_naming_it(argv, field, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing may be written, and nothing here is touched
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("cosim: bad input: " + field), err
    assert not (tmp_path / "runs").exists()


def test_out_and_json_paths_are_checked_first(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("keep me")
    assert main(["run", SQ, "--out", str(f)]) == 2
    assert main(["bench", "--quick", "--json", str(tmp_path)]) == 2
    assert f.read_text() == "keep me"
    assert "--out" in capsys.readouterr().err


@pytest.mark.flight
def test_a_failed_run_never_passes_even_without_criteria(tmp_path, capsys):
    out = tmp_path / "r"
    # an app that raises at once, and criteria that would all pass: still exit 1
    bad = tmp_path / "boom.py"
    bad.write_text("from cosim.apps.scripted import ScriptedApp\n"
                   "class Boom(ScriptedApp):\n"
                   "    def on_tick(self, t):\n"
                   "        raise RuntimeError('boom')\n")
    import sys

    sys.path.insert(0, str(tmp_path))
    try:
        rc = main(["run", SQ, "--out", str(out), "--quiet", "--no-plots",
                   "--set", "app.name=boom:Boom", "--set", "criteria.must_complete=false",
                   "--set", "criteria.position_error_max_m=1.0"])
    finally:
        sys.path.remove(str(tmp_path))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["exit_reason"] == "component_error"
    assert not summary["passed"] and rc == 1
    assert "boom" in capsys.readouterr().err


@pytest.mark.flight
def test_reused_run_folder_does_not_mix_runs(tmp_path):
    out = tmp_path / "r"
    seed = str(ROOT / "scenarios" / "mambo_seed_track.toml")
    assert main(["run", seed, "--out", str(out), "--quiet", "--png-every", "2",
                 "--set", "timing.t_final_s=2.0"]) == 1
    assert len(list((out / "frames").glob("*.png"))) == 5
    assert (out / "frames.csv").is_file()
    assert main(["run", SQ, "--out", str(out), "--quiet",
                 "--set", "timing.t_final_s=2.0"]) == 1
    assert not (out / "frames.csv").exists()
    assert not list((out / "frames").glob("*.png"))
    assert json.loads((out / "summary.json").read_text())["scenario"] == "scripted_square"


@pytest.mark.parametrize("origin", ["nan,nan,nan", "100,0,0", "0,500,0", "0,0,inf", "1,2"])
def test_onboard_rejects_a_bad_geodetic_origin(origin, capsys):
    from mav.onboard import main as onboard_main

    with pytest.raises(SystemExit) as ei:
        onboard_main(["--origin", origin, "--hil-bind", "127.0.0.1:0"])
    assert ei.value.code == 2
    assert "origin" in capsys.readouterr().err


@pytest.mark.parametrize("item", ["mass=-1", "mass=abc", "weight=1", "mass", "motor_tau=nan"])
def test_onboard_rejects_a_bad_vehicle_param(item, capsys):
    from mav.onboard import main as onboard_main

    with pytest.raises(SystemExit) as ei:
        onboard_main(["--vehicle-param", item, "--hil-bind", "127.0.0.1:0"])
    assert ei.value.code == 2
    assert "--vehicle-param" in capsys.readouterr().err


@pytest.mark.parametrize("item", ["motor_tau=0", "mass=-1", "mass=abc", "mass"])
def test_tune_rejects_a_bad_vehicle_param(item, capsys):
    with pytest.raises(SystemExit) as ei:
        main(["tune", "mambo", "--vehicle-param", item])
    assert ei.value.code == 2
    assert "error" in capsys.readouterr().err
