"""Issue 43, item 12: a stopped render process froze the run without a word (SIGSTOP on it:
the loop waited for its next frame for ever). Now the wait on the render pipe has a timeout
(`[camera] render_timeout_s`): the process is ended and the run with `component_error:
camera`, everything recorded. A real run, its real render process, a real SIGSTOP."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.sensors.stream import RENDER_TIMEOUT_S, split_stream

ROOT = Path(__file__).resolve().parents[1]
HANG_S = 120            # a hang guard only


def _forks(pid: int) -> set[int]:
    """The children of `pid` that are forks of it (its command line): the render process,
    or a child between its fork and its exec (another program soon)."""
    out = set()
    try:
        me = Path(f"/proc/{pid}/cmdline").read_bytes()
        for t in Path(f"/proc/{pid}/task").iterdir():
            for x in (t / "children").read_text().split():
                try:
                    if Path(f"/proc/{x}/cmdline").read_bytes() == me:
                        out.add(int(x))
                except OSError:
                    pass
    except OSError:
        pass
    return out


def _render_process(proc: subprocess.Popen) -> int:
    """The run's render process: a fork of it still one 0.3 s later."""
    deadline = time.monotonic() + HANG_S
    while True:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no render process"
        first = _forks(proc.pid)
        time.sleep(0.3)
        kept = first & _forks(proc.pid)
        if kept:
            return min(kept)


@pytest.mark.flight
def test_a_stopped_render_process_ends_the_run_with_a_camera_error(tmp_path):
    # the hover for an hour, with a delayed downward camera: its frames are rendered in a
    # forked process (--render-worker on)
    sc = tmp_path / "hover_cam.toml"
    sc.write_text((ROOT / "scenarios" / "mambo_hover.toml").read_text().replace(
        'file = "worlds/', f'file = "{ROOT}/scenarios/worlds/').replace(
        "[app]", "[camera]\nwidth = 160\nheight = 120\nlatency_s = 0.1\n"
                 "render_timeout_s = 2.0\n\n[app]") + "\n")
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", str(sc), "--set", "timing.t_final_s=3600",
         "--set", "timing.camera_every=8", "--render-worker", "on", "--video", "--out",
         str(out), "--quiet", "--no-plots"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        render = _render_process(proc)            # forked at the first capture
        os.kill(render, signal.SIGSTOP)
        _, err = proc.communicate(timeout=HANG_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 1, err
    s = json.loads((out / "summary.json").read_text())
    assert s["exit_reason"] == "component_error"
    assert s["message"].startswith("camera: RuntimeError: the render process")
    assert "did not answer within 2 s" in s["message"] and "stopped (SIGSTOP)" in s["message"]
    assert s["ticks"] > 0
    assert (out / "timeseries.csv").read_text().count("\n") - 1 == s["ticks"]
    assert (out / "flight.tlog").stat().st_size > 0 and (out / "camera.mp4").stat().st_size > 0
    assert not Path(f"/proc/{render}").exists() or \
        Path(f"/proc/{render}/stat").read_text().split()[2] == "Z"    # ended, not left stopped
    assert "Traceback" not in err


def test_the_render_timeout_is_checked():
    assert split_stream({}, "camera", "down")[1].render_timeout_s == RENDER_TIMEOUT_S
    assert split_stream({"render_timeout_s": 5}, "camera", "down")[1].render_timeout_s == 5.0
    for bad in (0, -1, 1e9, "5", True):
        with pytest.raises(ScenarioError, match="camera.render_timeout_s"):
            split_stream({"render_timeout_s": bad}, "camera", "down")
