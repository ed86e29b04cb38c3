"""Real-time mode and host stalls (issue 14 item 3): after a 2 s stall the loop used to run the
missed ticks back to back, with no new setpoints from a real-time client, and the offboard-loss
failsafe fired. Now the pacing skips the lost time and reports it. The wall clock is a fake
here (the master's `time`), so the test does not depend on the machine's speed."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.load import load_scenario, with_set
from cosim.sim import master
from cosim.sim.master import RunOptions, run_scenario

ROOT = Path(__file__).resolve().parents[1]


class FakeClock:
    """perf_counter advances only by sleeps, and once by a 2 s stall at the N-th reading."""

    def __init__(self, stall_at: int, stall_s: float) -> None:
        self.now = 100.0
        self.reads = 0
        self.stall_at, self.stall_s = stall_at, stall_s
        self.sleeps_after_stall: list[float] = []
        self.stalled = False

    def perf_counter(self) -> float:
        self.reads += 1
        if self.reads == self.stall_at:
            self.now += self.stall_s
            self.stalled = True
        return self.now

    def sleep(self, s: float) -> None:
        if self.stalled:
            self.sleeps_after_stall.append(s)
        self.now += s


@pytest.mark.flight
def test_a_host_stall_is_skipped_not_replayed(monkeypatch):
    clock = FakeClock(stall_at=400, stall_s=2.0)
    monkeypatch.setattr(master, "time", clock)
    sc = with_set(load_scenario(ROOT / "scenarios" / "scripted_square.toml"),
                  {"timing.t_final_s": 4.0})
    res = run_scenario(sc, RunOptions(realtime=True, speed=1.0))
    assert res.ticks == 800
    assert res.realtime_stalls == 1
    assert abs(res.realtime_lost_s - 2.0) < 0.01
    # after the stall the loop is paced again at once: every later tick sleeps its 5 ms
    # (before the fix: ~400 ticks ran back to back without sleeping)
    n_after = 800 - (400 - 3)
    assert len(clock.sleeps_after_stall) >= n_after - 2
    assert all(abs(s - 0.005) < 1e-6 for s in clock.sleeps_after_stall[1:])
