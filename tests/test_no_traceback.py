"""Issue 31, defect 5: bad input ends in one line and exit 2, never a traceback: unhashable
kinds and presets, world files that are not tables or are nested thousands deep, values nested
thousands deep, distributions whose range overflows, malformed scheduler addresses, names too
long, outputs that are folders, and broken study folders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
S = ROOT / "scenarios"
HOVER = S / "mambo_hover.toml"
E1 = S / "bebop2_vs_e1.toml"
DEEP = "[" * 3000 + "]" * 3000


def _scenario(tmp_path: Path, src: Path, name: str, edit) -> Path:
    text = src.read_text()
    for w in ("empty", "room_e1"):
        text = text.replace(f'"worlds/{w}.toml"', f'"{S / "worlds" / w}.toml"')
    p = tmp_path / name
    p.write_text(edit(text))
    return p


def _bad(capsys, argv, *words) -> str:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("cosim"), err
    line = err.strip().splitlines()[-1]                 # the error: one line
    assert len(line) < 1500
    for w in words:
        assert w in line, err
    return err


def _world(tmp_path, body: str) -> Path:
    w = tmp_path / "w.toml"
    w.write_text(body)
    return _scenario(tmp_path, HOVER, "h.toml",
                     lambda t: t.replace(f'"{S / "worlds" / "empty"}.toml"', f'"{w}"'))


def test_unhashable_kinds_and_presets(tmp_path, capsys):
    cam = _scenario(tmp_path, HOVER, "cam.toml",
                    lambda t: t.replace("[timing]", "[camera]\nkind = []\n\n[timing]"))
    _bad(capsys, ["validate", cam], "camera.kind")
    vs = _scenario(tmp_path, E1, "vs.toml",
                   lambda t: t.replace('preset = "e1"', 'preset = ["e1"]'))
    _bad(capsys, ["validate", vs], "app.params.preset")
    _bad(capsys, ["teach", vs, "--out", tmp_path / "vp"], "app.params.preset")


@pytest.mark.parametrize("body", ["world = 3", "world = [1, 2]", "x = " + DEEP])
def test_world_files_that_are_not_tables(tmp_path, capsys, body):
    _bad(capsys, ["validate", _world(tmp_path, body)], "world.file")


def test_values_nested_thousands_deep(tmp_path, capsys):
    _bad(capsys, ["run", HOVER, "--set", f"app.x={DEEP}", "--out", tmp_path / "r"], "nested")
    _bad(capsys, ["sweep", HOVER, "--set", f"app.x=1,{DEEP}", "--out", tmp_path / "s"],
         "nested")
    _bad(capsys, ["montecarlo", HOVER, "-n", "2", "--vary", f"app.x=choice(1,{DEEP})",
                  "--out", tmp_path / "m"], "nested")
    assert not (tmp_path / "r").exists()


def test_distribution_ranges_and_scheduler_addresses(tmp_path, capsys):
    _bad(capsys, ["montecarlo", HOVER, "-n", "2", "--vary", "x=uniform(-1e308,1e308)",
                  "--out", tmp_path / "m"], "--vary")
    for addr in ("tcp://", "tcp://a:b:c", "tcp://host", "::::"):
        _bad(capsys, ["montecarlo", HOVER, "-n", "2", "--vary", "timing.t_final_s=uniform(1,2)",
                      "--out", tmp_path / "m", "--scheduler", addr], "--scheduler")


def test_names_too_long(tmp_path, capsys):
    long = "a" * 300
    _bad(capsys, ["run", HOVER, "--out", tmp_path / long], "--out")
    _bad(capsys, ["run", tmp_path / f"{long}.toml"], "scenario")
    _bad(capsys, ["validate", _world(tmp_path, "").parent / "h.toml", tmp_path / long])


def test_output_paths_of_the_wrong_kind(tmp_path, capsys):
    sc = _scenario(tmp_path, E1, "vs.toml", lambda t: t)
    (tmp_path / "file").write_text("x")
    _bad(capsys, ["teach", sc, "--out", tmp_path / "file"], "--out")
    (tmp_path / "folder.png").mkdir()
    for out in ("folder.png", "noext", "x.xyz"):
        _bad(capsys, ["render", HOVER, "--at", "57,95,-1,0", "--out", tmp_path / out], "--out")
    _bad(capsys, ["render", E1, "--at", "0,0,-1,0", "--out", tmp_path / "a.png", "--depth",
                  tmp_path / "d.jpg"], "--depth")
    for name in ("summary.json", "run.mcap"):
        out = tmp_path / f"run-{name}"
        (out / name).mkdir(parents=True)
        _bad(capsys, ["run", HOVER, "--set", "timing.t_final_s=0.5", "--out", out, "--quiet",
                      "--no-plots", "--mcap"], name)
        assert (out / name).is_dir()


MC = ["montecarlo", str(HOVER), "-n", "2", "--vary", "timing.t_final_s=uniform(0.2,0.3)",
      "--executor", "serial", "--quiet"]


def test_broken_study_folders(tmp_path, capsys):
    out = tmp_path / "mc"
    (out / "study.json").mkdir(parents=True)
    _bad(capsys, [*MC, "--out", out], "study.json")
    (out / "study.json").rmdir()
    (out / "study.json").write_text("{")
    _bad(capsys, [*MC, "--out", out], "study.json")
    (out / "study.json").unlink()
    (out / "results.csv").mkdir()
    _bad(capsys, [*MC, "--out", out], "results.csv")


@pytest.mark.flight
def test_a_junk_run_id_does_not_break_every_rerun(tmp_path, capsys):
    out = tmp_path / "mc"
    assert main([*MC, "--out", str(out)]) == 0
    table = out / "results.csv"
    lines = table.read_text().splitlines()
    junk = "abc" + lines[1][lines[1].index(","):]
    table.write_text("\n".join([lines[0], junk, *lines[1:]]) + "\n")
    assert main([*MC, "--out", str(out)]) == 0                # the two runs are there
    assert "abc" not in table.read_text()
    assert len(table.read_text().splitlines()) == 3
    assert json.loads((out / "study.json").read_text())["n"] == 2
