"""SLOW: `cosim sitl` runs for hours of simulated time with flat memory (issue 14, item 2: it
used to record every tick in memory, ~13 MB/min). Two hours of simulated time flat out
(--speed far above what the machine reaches), RSS sampled from /proc; the growth after the
first tenth must stay within a few MB, whatever the machine's speed."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sitl_proc import free_udp_port

SIM_S = 7200.0


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


@pytest.mark.slow
def test_sitl_memory_is_flat_over_hours_of_simulated_time(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sitl", "--speed", "100000", "--duration",
         str(SIM_S), "--out", str(tmp_path / "run"),
         "--api-remote", f"127.0.0.1:{free_udp_port()}", "--api-bind", "127.0.0.1:0",
         "--gcs-remote", f"127.0.0.1:{free_udp_port()}", "--gcs-bind", "127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    samples: list[int] = []
    try:
        while proc.poll() is None:
            samples.append(_rss_kb(proc.pid))
            time.sleep(0.5)
        err = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
    assert proc.returncode == 0, err
    assert "duration reached" in err
    samples = [s for s in samples if s > 0]
    assert len(samples) >= 10, samples
    settled = samples[len(samples) // 10:]
    growth_mb = (max(settled) - settled[0]) / 1024
    print(f"RSS {settled[0] / 1024:.0f} -> {max(settled) / 1024:.0f} MB over {SIM_S:.0f} s "
          f"of simulated time ({len(samples)} samples)")
    assert growth_mb < 8.0, samples
