"""Fault injection ([faults], cosim/faults/core.py): each fault kind does what it says, from a
seeded stream; the shipped fault scenarios pass their criteria; MIL == SIL with faults; the
onboard stack's answer to a failed estimate (ODOMETRY quality -1)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_onboard_auto import flying_rig, pos

from cosim.faults.core import FaultHooks, parse_faults
from cosim.load import load_scenario
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from mav import wire
from mav.links import MemoryLink

SCEN = Path(__file__).resolve().parent.parent / "scenarios"


def hooks_for(seed: int = 0, **tables) -> FaultHooks:
    return FaultHooks(parse_faults(tables), seed)


def pump(h: FaultHooks, link, peer, n_ticks: int, per_tick: int = 1) -> list[tuple[float, bytes]]:
    """Send `per_tick` numbered datagrams per 5 ms tick through `link` to the vehicle side;
    returns (t received, datagram) as the vehicle end sees them."""
    got, k = [], 0
    for tick in range(n_ticks):
        h.on_odometry(tick * 5000, (0.0,) * 13)
        while (d := peer.recv()) is not None:
            got.append((h.t, d))
        for _ in range(per_tick):
            link.send(k.to_bytes(4, "little"))
            k += 1
        while (d := peer.recv()) is not None:
            got.append((h.t, d))
    return got


def wrapped(h: FaultHooks, name: str = "api"):
    a, b = MemoryLink.pair()
    return h.wrap_link(name, a), b


def test_loss_rate_and_determinism():
    spec = {"link": [{"link": "api", "direction": "to_vehicle", "loss": 0.3}]}
    runs = []
    for _ in range(2):
        h = hooks_for(seed=4, **spec)
        link, peer = wrapped(h)
        runs.append([d for _, d in pump(h, link, peer, 4000)])
    assert runs[0] == runs[1]                                # same seed, same datagrams
    assert 0.27 < 1 - len(runs[0]) / 4000 < 0.33
    h = hooks_for(seed=5, **spec)
    link, peer = wrapped(h)
    assert [d for _, d in pump(h, link, peer, 4000)] != runs[0]  # another seed, other losses
    assert "3" in h.fired()[-1][1] and "dropped" in h.fired()[-1][1]


def test_latency_jitter_duplicate_reorder_outage_and_window():
    h = hooks_for(link=[{"link": "api", "direction": "to_vehicle", "latency_ms": 50.0,
                         "start_s": 1.0, "end_s": 2.0}])
    link, peer = wrapped(h)
    got = pump(h, link, peer, 600)
    sent_at = {i.to_bytes(4, "little"): i * 0.005 for i in range(600)}
    lag = [t - sent_at[d] for t, d in got]
    assert all(abs(x) < 1e-9 for x, (t, _) in zip(lag, got, strict=True) if t < 1.0)
    inside = [x for x, (_, d) in zip(lag, got, strict=True) if 1.0 <= sent_at[d] < 1.95]
    assert inside and all(abs(x - 0.05) < 1e-9 for x in inside)   # released at its tick
    assert len(got) == 600                                        # nothing lost
    h = hooks_for(link=[{"link": "api", "direction": "to_vehicle", "duplicate": 0.5,
                         "reorder": 0.2}])
    link, peer = wrapped(h)
    got = [int.from_bytes(d, "little") for _, d in pump(h, link, peer, 2000)]
    assert 2700 < len(got) < 3300 and set(got) == set(range(2000))
    assert any(b < a for a, b in zip(got, got[1:], strict=False))      # some reordered
    h = hooks_for(link=[{"link": "gcs", "outage": True, "start_s": 0.5, "end_s": 1.0}])
    link, peer = wrapped(h, "gcs")
    got = pump(h, link, peer, 400)
    assert len(got) == 300 and not any(0.5 <= t < 1.0 for t, _ in got)
    assert wrapped(h, "api")[0].__class__ is MemoryLink             # no api fault: unwrapped


def test_from_vehicle_direction_and_bursts():
    h = hooks_for(link=[{"link": "api", "direction": "from_vehicle", "burst_enter": 0.05,
                         "burst_exit": 0.2}])
    app_end, vehicle_end = wrapped(h)
    got = []
    for tick in range(4000):
        h.on_odometry(tick * 5000, (0.0,) * 13)
        vehicle_end.send(tick.to_bytes(4, "little"))
        while (d := app_end.recv()) is not None:
            got.append(int.from_bytes(d, "little"))
    lost = sorted(set(range(4000)) - set(got))
    runs = np.diff(np.flatnonzero(np.diff(lost) != 1))
    # Gilbert-Elliott: mean burst 1 / 0.2 = 5 datagrams, bad 0.05 / 0.25 = 20 % of the time
    assert 0.15 < len(lost) / 4000 < 0.25 and 3.5 < float(np.mean(runs)) < 7.0


def test_odometry_camera_and_motor_faults():
    h = hooks_for(odometry=[{"kind": "dropout", "start_s": 0.01, "end_s": 0.02},
                            {"kind": "bias", "start_s": 0.03, "bias_m": [1.0, 0.0, 0.0]},
                            {"kind": "noise", "start_s": 0.0, "end_s": 0.005, "std_m": 0.1}],
                  camera=[{"kind": "freeze", "start_s": 1.0, "end_s": 2.0},
                          {"kind": "black", "start_s": 2.0, "end_s": 3.0},
                          {"kind": "drop", "start_s": 3.0, "end_s": 4.0, "p": 0.5}],
                  motor=[{"motor": 2, "thrust": 0.25, "start_s": 5.0}])
    m = tuple(float(i) for i in range(13))
    noisy = h.on_odometry(0, m)
    assert noisy != m and noisy[3:7] == m[3:7] and not h.odometry_lost
    h.on_odometry(5000, m)
    m2 = tuple(v + 10.0 for v in m)
    out = h.on_odometry(10000, m2)
    assert h.odometry_lost and out[0:3] == m[0:3] and out[7:10] == m[7:10]
    assert out[3:7] == m2[3:7] and out[10:13] == m2[10:13]          # attitude, rates live
    assert h.on_odometry(30000, m)[0] == m[0] + 1.0 and not h.odometry_lost
    a, b = np.full((2, 2), 7, np.uint8), np.full((2, 2), 9, np.uint8)
    assert h.on_frame(0, a) is a and h.on_frame(1_000_000, b) is a      # frozen
    assert not h.on_frame(2_000_000, b).any()                           # black
    drops = [h.on_frame(3_000_000 + i, b) is None for i in range(400)]
    assert 150 < sum(drops) < 250
    assert h.on_actuators(4_000_000, (0.5,) * 4) == (0.5,) * 4
    assert h.on_actuators(5_000_000, (0.5,) * 4)[1] == pytest.approx(0.25)   # thrust x 0.25
    kinds = " ".join(w for _, w in h.fired())
    for k in ("dropout", "bias", "noise", "freeze", "black", "drop", "motor 2 at 25%"):
        assert k in kinds


def _run(name: str, mode: str = "mil"):
    res = run_scenario(load_scenario(SCEN / f"{name}.toml"), RunOptions(mode=mode))
    from cosim.outputs.report import summarize

    return res, summarize(res)


@pytest.mark.flight
def test_seed_mission_lands_on_the_marker_with_20_percent_loss():
    res, s = _run("mambo_seed_lossy")
    assert s["passed"], s["criteria"]
    assert res.onboard_stats["setpoints"] < 0.85 * res.ticks / 1   # setpoints were lost
    assert any("dropped" in w for _, w in res.faults)


@pytest.mark.flight
def test_offboard_outage_holds_then_lands_where_it_held():
    res, s = _run("mambo_seed_outage")
    assert s["passed"], s["criteria"]
    assert res.exit_reason is ExitReason.LANDED
    texts = _statustexts(res)
    assert "Failsafe: offboard setpoints lost, holding position" in texts
    assert "Failsafe: offboard not back, landing" in texts


@pytest.mark.flight
def test_odometry_dropout_does_not_fly_away():
    res, s = _run("mambo_seed_dropout")
    assert s["passed"], s["criteria"]
    assert res.onboard_stats["odometry_lost"] == 400        # 2 s of ticks with quality -1
    t, x, y = res.recorded.columns("t", "x", "y")
    k0, k1 = np.searchsorted(t, [30.0, 32.0])
    drift = np.hypot(x[k0:k1] - x[k0], y[k0:k1] - y[k0]).max()
    assert drift < 0.3          # it was flying 0.1 m/s: momentum, braked by drag


@pytest.mark.flight
def test_faults_mil_equals_sil_bit_for_bit():
    mil, _ = _run("mambo_seed_lossy")
    sil, _ = _run("mambo_seed_lossy", "sil")
    assert np.array_equal(mil.series, sil.series, equal_nan=True)
    assert mil.faults == sil.faults


def test_position_estimate_lost_in_flight_holds_level_then_lands():
    rig = flying_rig()
    where = pos(rig)
    rig.hil = Lost(rig.hil, rig.sim)
    rig.tick(200 * 3)
    texts = rig.texts()
    assert "Position estimate lost, holding level" in texts
    assert "Failsafe: no position estimate, landing" in texts
    assert rig.ob.armed and math.dist(pos(rig), where) < 0.3          # no fly-away
    rig.hil = rig.hil.inner
    rig.run_until(lambda r: not r.ob.armed, 15.0)
    assert "Position estimate regained" in rig.texts()
    assert math.hypot(pos(rig)[0] - where[0], pos(rig)[1] - where[1]) < 0.3


class Lost:
    """The rig's simulator end of the HIL link, sending every ODOMETRY with quality -1."""

    def __init__(self, inner, mav) -> None:
        self.inner, self.mav = inner, mav

    def send(self, data: bytes) -> None:
        f = wire.decode_fast(wire.ODOMETRY, data)
        self.inner.send(wire.encode_odometry(self.mav, f[0], *f[1:14], quality=-1))

    def recv(self):
        return self.inner.recv()


def _statustexts(res) -> list[str]:
    """The STATUSTEXTs of a run's tlog, chunks joined (both links: each text twice)."""
    from pymavlink import mavutil

    out, last = [], None
    mlog = mavutil.mavlink_connection(str(res.run_dir / "flight.tlog"))
    while (m := mlog.recv_match(type="STATUSTEXT")) is not None:
        if m.id and m.chunk_seq > 0 and last is not None and last[0] == m.id:
            out[-1] += m.text
        else:
            out.append(m.text)
        last = (m.id, m.chunk_seq)
    return out
