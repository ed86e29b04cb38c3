"""Hostile or unlucky input around a run's outputs (issue 14 item 7): a scenario name that
would write outside the output root, a NUL in it, TOML nested 5000 deep: each a clear error
(exit 2 naming the field), never a traceback or a file outside the run folder."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, parse_scenario

BASE = {"vehicle": {"preset": "mambo"},
        "world": {"arena": {"n_min": 0, "n_max": 4, "e_min": 0, "e_max": 4}}}


@pytest.mark.parametrize("name", ["../../escape", "a/b", "x\x00y", "", ".hidden", "a" * 81,
                                  "tab\there"])
def test_a_name_that_is_not_a_folder_name_is_refused(name):
    with pytest.raises(ScenarioError, match="^name:"):
        parse_scenario({**BASE, "name": name})


def test_a_name_from_the_file_name_is_made_safe(tmp_path):
    f = tmp_path / "my scenario (v2).toml"
    f.write_text('[vehicle]\npreset = "mambo"\n[world]\n'
                 'arena = { n_min = 0, n_max = 4, e_min = 0, e_max = 4 }\n')
    assert load_scenario(f).name == "my_scenario__v2_"


def test_deep_nesting_is_a_clear_error(tmp_path):
    f = tmp_path / "deep.toml"
    f.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "validate", str(f)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "scenario" in r.stderr and "Traceback" not in r.stderr


def test_run_with_an_escaping_name_writes_nothing_outside(tmp_path):
    f = tmp_path / "evil.toml"
    f.write_text('name = "../../escaped"\n[vehicle]\npreset = "mambo"\n[world]\n'
                 'arena = { n_min = 0, n_max = 4, e_min = 0, e_max = 4 }\n')
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "run", str(f)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "name" in r.stderr
    assert not (tmp_path.parent / "escaped-mil").exists() and not Path("escaped-mil").exists()


ROOT = Path(__file__).resolve().parents[1]
SQUARE = str(ROOT / "scenarios" / "scripted_square.toml")


def _cosim(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, timeout=120, cwd=cwd)


def test_an_unwritable_out_is_a_clear_error():
    r = _cosim("run", SQUARE, "--out", "/proc/cosim-cannot-write-here", "--quiet")
    assert r.returncode == 2 and "--out" in r.stderr and "Traceback" not in r.stderr


def test_a_second_run_into_a_busy_folder_fails_at_once(tmp_path):
    from cosim.outputs.folder import claim_run_folder

    out = tmp_path / "busy"
    with claim_run_folder(out):                   # a run is writing there now
        r = _cosim("run", SQUARE, "--out", str(out), "--quiet",
                   "--set", "timing.t_final_s=1.0")
        assert r.returncode == 2 and "no other run" in r.stderr
        assert not (out / "summary.json").exists()
    r = _cosim("run", SQUARE, "--out", str(out), "--quiet", "--no-plots",
               "--set", "timing.t_final_s=1.0")
    assert (out / "summary.json").exists(), r.stderr   # free again once the first is done


def _children(pid: int) -> set[int]:
    out = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        f = task / "children"
        if f.exists():
            out |= {int(x) for x in f.read_text().split()}
    return out


def test_sigterm_writes_what_was_recorded_and_leaves_no_onboard_process(tmp_path):
    """Issue 14 item 7: SIGTERM to `cosim run` exited with no message and no outputs and left
    the onboard child running. Now: exit 143, summary and time series written (exit reason
    'interrupted'), the SIL onboard process gone."""
    import json
    import os
    import signal
    import time

    out = tmp_path / "r"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", str(ROOT / "scenarios" / "mambo_hover.toml"),
         "--mode", "sil", "--set", "timing.t_final_s=3600", "--out", str(out), "--quiet",
         "--no-plots"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120          # bounded wait for the run to be under way
        while time.monotonic() < deadline and not (
                (out / "flight.tlog").exists() and (out / "flight.tlog").stat().st_size > 0):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        kids = _children(proc.pid)
        assert kids, "the SIL onboard process should be running"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err and "signal 15" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["exit_reason"] == "interrupted" and summary["ticks"] > 0
    rows = (out / "timeseries.csv").read_text().count("\n") - 1
    assert rows == summary["ticks"]
    for pid in kids:                                  # no orphan onboard process
        assert not os.path.exists(f"/proc/{pid}") or \
            Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"


def _short_run():
    from cosim.load import load_scenario
    from cosim.sim.master import RunOptions, run_scenario

    sc = load_scenario(ROOT / "scenarios" / "mambo_hover.toml")
    sc = replace(sc, timing=replace(sc.timing, t_final_s=1.0))
    return run_scenario(sc, RunOptions())


@pytest.mark.flight
def test_disk_full_leaves_no_truncated_file_and_no_summary_claiming_success(tmp_path,
                                                                           monkeypatch):
    """Issue 14 item 7: disk full gave a traceback, a truncated CSV and a summary.json saying
    mission_complete. Now each file is written whole or not at all, the summary lists what
    failed and does not pass; if even the summary cannot be written, a clear OutputError."""
    import errno
    import json

    from cosim.errors import OutputError
    from cosim.outputs import report

    res = _short_run()
    real = report.write_series

    def full(r, path):                           # ENOSPC after part of the file
        real(r, path)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report, "write_series", full)
    out = tmp_path / "o"
    summary = report.write_run(res, out, plots=False)
    assert not (out / "timeseries.csv").exists() and not list(out.glob("*.part"))
    saved = json.loads((out / "summary.json").read_text())
    assert saved["passed"] is False and summary["passed"] is False
    assert saved["output_errors"] == ["timeseries.csv: No space left on device"]
    assert "output not written: timeseries.csv" in report.one_screen(saved)
    real_replace = report.os.replace

    def no_summary(src, dst):
        if str(dst).endswith("summary.json"):
            raise OSError(errno.ENOSPC, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(report.os, "replace", no_summary)
    with pytest.raises(OutputError, match="disk full writing .*summary.json"):
        report.write_run(res, tmp_path / "o2", plots=False)
    assert not (tmp_path / "o2" / "summary.json").exists()
