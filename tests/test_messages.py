"""Issue 31, defect 9: messages a user can read: an error line shows a bounded part of the bad
value; `cosim validate a b` reports every file; an odd-sized `--video` says what it drops."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
HOVER = ROOT / "scenarios" / "mambo_hover.toml"


def test_an_error_line_does_not_repeat_a_huge_value(tmp_path, capsys):
    big = "x" * 200_000
    rc = main(["run", str(HOVER), "--set", f"name={big}", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2 and "name" in err and "200002 characters" in err
    assert len(err) < 1500


def test_validate_checks_every_file_and_reports_each(tmp_path, capsys):
    bad1 = tmp_path / "bad1.toml"
    bad1.write_text("name = 3\n")
    bad2 = tmp_path / "bad2.toml"
    bad2.write_text("[[[")
    rc = main(["validate", str(bad1), str(HOVER), str(bad2), str(HOVER)])
    out, err = capsys.readouterr()
    assert rc == 2
    assert out.count(": ok (") == 2
    assert "bad1.toml" in err and "bad2.toml" in err and "2 of 4 files are bad" in err


@pytest.mark.flight
def test_an_odd_sized_video_says_what_it_drops(tmp_path, capsys):
    import cv2

    out = tmp_path / "r"
    rc = main(["run", str(HOVER), "--set", "timing.t_final_s=0.5", "--set",
               "camera.width=161", "--set", "camera.height=121", "--video", "--out", str(out),
               "--quiet", "--no-plots"])
    err = capsys.readouterr().err
    assert rc in (0, 1)
    assert "161x121" in err and "160x120" in err
    ok, frame = cv2.VideoCapture(str(out / "camera.mp4")).read()
    assert ok and frame.shape[:2] == (120, 160)               # what the warning says
