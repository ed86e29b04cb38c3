"""Issue 43, item 9: a full TMPDIR ended a run in a traceback (the series spool's ENOSPC,
exit 1) and the run folder had no summary.json and no series. Now the spool holds its rows in
memory from the failed block on (cosim/outputs/series.py): one line names TMPDIR, and the run
writes everything, its series the same bytes as with room.

The full filesystem is real: a 512 kB tmpfs mounted in a user namespace (`unshare -rm`, no
privileges needed where the kernel allows user namespaces), room for the FMU's extraction
but not for the spool's first 1 MB block."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosim.outputs import series
from cosim.outputs.series import SeriesSpool

ROOT = Path(__file__).resolve().parents[1]
HOVER = ROOT / "scenarios" / "mambo_hover.toml"


def _in_full_tmpdir(tmp_path: Path, *argv: str) -> subprocess.CompletedProcess:
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1) to mount a small tmpfs")
    full = tmp_path / "full"
    full.mkdir()
    probe = subprocess.run(["unshare", "-rm", "mount", "-t", "tmpfs", "tmpfs", str(full)],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"user namespaces are not allowed here ({probe.stderr.decode().strip()})")
    script = ('mount -t tmpfs -o size=512k tmpfs "$0" && TMPDIR="$0" exec "$@"')
    return subprocess.run(["unshare", "-rm", "sh", "-c", script, str(full), sys.executable,
                           "-m", "cosim.cli", *argv], capture_output=True, text=True,
                          timeout=300)


@pytest.mark.flight
def test_a_full_tmpdir_is_one_line_and_the_run_loses_nothing(tmp_path):
    args = ["run", str(HOVER), "--set", "timing.t_final_s=30", "--quiet", "--no-plots"]
    r = _in_full_tmpdir(tmp_path, *args, "--out", str(tmp_path / "full_run"))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    lines = [x for x in r.stderr.splitlines() if x.startswith("cosim:")]
    full = tmp_path / "full"
    assert len(lines) == 1 and lines[0].startswith(f"cosim: warning: TMPDIR ({full})"), r.stderr
    assert "is full (No space left on device)" in lines[0]
    s = json.loads((tmp_path / "full_run" / "summary.json").read_text())
    assert s["passed"] and s["ticks"] == 6000 and len(s["warnings"]) == 1
    ok = subprocess.run([sys.executable, "-m", "cosim.cli", *args, "--out",
                         str(tmp_path / "room")], capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr
    for f in ("timeseries.csv", "flight.tlog"):
        assert (tmp_path / "full_run" / f).read_bytes() == (tmp_path / "room" / f).read_bytes()
    assert json.loads((tmp_path / "room" / "summary.json").read_text())["warnings"] == []


class _FullAfter:
    """A raw file that takes `room` bytes, then raises ENOSPC (after a part write)."""

    def __init__(self, f, room: int) -> None:
        self.f, self.room = f, room

    def write(self, b) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = self.f.write(b[: self.room])
        self.room -= n
        return n

    def __getattr__(self, name):
        return getattr(self.f, name)


def test_the_spool_holds_its_rows_in_memory_when_its_disk_is_full(tmp_path, monkeypatch):
    spool = SeriesSpool(tmp_path / "s.f64", ncols=3)
    spool._f = _FullAfter(spool._f, room=2 * 3 * 8 + 5)   # 2 rows and part of a third
    rows = [(float(i), -float(i), 0.5 * i) for i in range(10)]
    for i, r in enumerate(rows):
        spool.append(spool.pack(*r))
        if i % 2 == 1:
            spool.flush()
    rec = spool.finish()
    assert rec.ticks == 10 and rec.on_disk == 2 and rec.error.errno == errno.ENOSPC
    assert (tmp_path / "s.f64").stat().st_size == 2 * 3 * 8      # cut to whole blocks
    assert np.array_equal(rec.array(), np.array(rows))
    assert np.array_equal(np.concatenate(list(rec.blocks(3))), np.array(rows))
    # memory is bounded: past HELD_MAX bytes the disk's error is raised (the run ends), and
    # finish() still returns every row
    monkeypatch.setattr(series, "HELD_MAX", 4 * 3 * 8)
    spool = SeriesSpool(tmp_path / "t.f64", ncols=3)
    spool._f = _FullAfter(spool._f, room=0)
    with pytest.raises(OSError) as e:
        for r in rows:
            spool.append(spool.pack(*r))
            spool.flush()
    assert e.value.errno == errno.ENOSPC and "held in memory" in str(e.value)
    assert np.array_equal(spool.finish().array(), np.array(rows[:5]))
    assert os.path.getsize(tmp_path / "t.f64") == 0
