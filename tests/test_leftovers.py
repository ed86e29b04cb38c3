"""Issue 43, item 15: what a SIGKILL leaves. 4 s into a real-time run, kill -9 left a 0-byte
flight.tlog (its 64 kB buffer) and an unreadable run.mcap (its per-tick topics were written
after the run, its open chunk never closed), and the run's folders in TMPDIR (the series
spool, the FMU's extraction) stayed there for ever. Now a real-time run writes its tlog and
MCAP out every simulated second, so both read up to the last second; and the folders, named
with their owner's pid (cosim/tempdirs.py), are removed by the next run once that owner is
gone.

Real runs, real SIGKILLs. How far the killed run got is read from its PNG frames (named by
their simulated time, written as they come), not from the wall clock."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cosim import tempdirs
from cosim.outputs.tlog import keep_whole_records, read_tlog

ROOT = Path(__file__).resolve().parents[1]
HANG_S = 120            # hang guards only


def _start(tmp_path: Path, *argv: str) -> subprocess.Popen:
    (tmp_path / "tmp").mkdir(exist_ok=True)
    return subprocess.Popen([sys.executable, "-m", "cosim.cli", "run", *argv, "--quiet",
                             "--no-plots"], env={**os.environ, "TMPDIR": str(tmp_path / "tmp")},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)


def _wait(what, proc: subprocess.Popen, text: str):
    deadline = time.monotonic() + HANG_S
    while not (got := what()):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, text
        time.sleep(0.02)
    return got


def _kill(proc: subprocess.Popen) -> None:
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate()


def _frame_times(folder: Path) -> list[float]:
    return sorted(float(p.stem[len("frame_"):]) for p in folder.glob("frame_*.png"))


def _mcap_last(path: Path) -> dict[str, float]:
    """Topic -> the latest log time (s) of a message that reads, reading the file as a
    stream up to its first incomplete record (the chunk open at the kill)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topic, last = {}, {}
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f).records:
                if isinstance(rec, Channel):
                    topic[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    name = topic[rec.channel_id]
                    last[name] = max(last.get(name, 0.0), rec.log_time * 1e-9)
        except Exception:           # the record cut by the kill: the end of what reads
            pass
    return last


@pytest.mark.flight
def test_a_killed_realtime_run_leaves_its_tlog_and_mcap_readable_to_the_last_second(
        tmp_path):
    out = tmp_path / "out"
    proc = _start(tmp_path, str(ROOT / "scenarios" / "mambo_seed_track.toml"), "--realtime",
                  "--mcap", "--png-every", "1", "--out", str(out))
    try:
        _wait(lambda: [t for t in _frame_times(out / "frames") if t >= 2.0], proc,
              "the run never reached t = 2 s")
    finally:
        _kill(proc)
    reached = math.floor(_frame_times(out / "frames")[-1])   # s: the run got at least here
    keep_whole_records(out / "flight.tlog")                  # a record cut by the kill
    log = read_tlog(out / "flight.tlog")
    assert log and log[-1][0] * 1e-6 >= reached - 0.1, (reached, log[-1:] and log[-1][0])
    last = _mcap_last(out / "run.mcap")
    for topic in ("/vehicle/truth", "/vehicle/estimate", "/vehicle/pose", "/app/setpoint"):
        assert last.get(topic, -1.0) >= reached - 0.01, (topic, reached, last)
    assert last.get("/camera/image", -1.0) >= reached - 0.2      # 5 Hz frames


@pytest.mark.flight
def test_the_folders_of_a_killed_run_are_removed_when_the_next_starts(tmp_path):
    tmp = tmp_path / "tmp"
    hover = str(ROOT / "scenarios" / "mambo_hover.toml")
    proc = _start(tmp_path, hover, "--set", "timing.t_final_s=3600", "--out",
                  str(tmp_path / "killed"))
    try:
        _wait(lambda: list(tmp.glob("cosim-spool-*")), proc, "no spool folder")
        dead = proc.pid
    finally:
        _kill(proc)
    left = sorted(p.name for p in tmp.iterdir())
    assert left and all(n.startswith("cosim-") and f"-{dead}-" in n for n in left), left
    # beside them: a folder of a live process (this one), one of the same pid on another
    # host or container, and one whose pid now belongs to a process started after it
    where = tempdirs.prefix("x").split("-")[3]
    alive = tmp / f"cosim-run-{os.getpid()}-{where}-aaaa"
    other = tmp / f"cosim-run-{dead}-{'0' * 8 if where != '0' * 8 else '1' * 8}-bbbb"
    reused = tmp / f"cosim-run-1-{where}-cccc"            # pid 1 started long after 1970
    for d in (alive, other, reused):
        d.mkdir()
    os.utime(reused, (0, 0))
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "run", hover, "--set",
                        "timing.t_final_s=0.5", "--out", str(tmp_path / "next"), "--quiet",
                        "--no-plots"], env={**os.environ, "TMPDIR": str(tmp)},
                       capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp.iterdir()) == sorted([alive.name, other.name])


def test_the_sweep_keeps_what_it_cannot_judge(tmp_path):
    """Only this user's folders named as ours are candidates: another program's, a file, a
    symlink stay."""
    where = tempdirs.prefix("x").split("-")[3]
    keep = [tmp_path / "cosim-run-notapid-x", tmp_path / "tmp1234", tmp_path / "cosim-run"]
    for d in keep:
        d.mkdir()
    (tmp_path / f"cosim-run-999999999-{where}-file").write_text("x")
    (tmp_path / f"cosim-run-999999998-{where}-link").symlink_to(tmp_path / "tmp1234")
    gone = tmp_path / f"cosim-run-999999997-{where}-dead"
    gone.mkdir()
    (gone / "series.f64").write_bytes(b"\0" * 64)
    assert tempdirs.sweep(tmp_path) == [gone]
    assert len(list(tmp_path.iterdir())) == 5
