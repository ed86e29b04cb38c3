"""Issue 31, defect 9: messages a user can read: an error line shows a bounded part of the bad
value; `cosim validate a b` reports every file; an odd-sized `--video` says what it drops."""

from __future__ import annotations

from pathlib import Path

from cosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
HOVER = ROOT / "scenarios" / "mambo_hover.toml"


def test_an_error_line_does_not_repeat_a_huge_value(tmp_path, capsys):
    big = "x" * 200_000
    rc = main(["run", str(HOVER), "--set", f"name={big}", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2 and "name" in err and "200002 characters" in err
    assert len(err) < 1500
