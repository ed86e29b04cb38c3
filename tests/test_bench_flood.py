"""The flood figure of `cosim bench` (cosim/bench/flood.py), run briefly: its figures
are there, the flooded runs answered every HIL tick and flew the same flight as the unflooded
ones, and what was sent is accounted for. No timing is asserted (machines are shared)."""

from __future__ import annotations

import math

import pytest

from cosim.bench.flood import FloodProbe, _heartbeats, flood_pool, format_flood
from mav import wire


def test_flood_pool_is_seeded_and_mixed():
    from pymavlink.dialects.v20 import common as M

    pool = flood_pool(n=300)
    assert pool == flood_pool(n=300) and len(pool) == 300 and len(set(pool)) > 250
    mav = M.MAVLink(None)
    kinds = {"garbage": 0, "heartbeat": 0, "addressed": 0}
    for d in pool:
        try:
            msg = mav.decode(bytearray(d))
        except Exception:
            kinds["garbage"] += 1
            continue
        if msg.get_type() == "HEARTBEAT":
            kinds["heartbeat"] += 1
            assert msg.get_srcSystem() in (2, 255)
        else:
            kinds["addressed"] += 1
            target = getattr(msg, "target_system", getattr(msg, "target", None))
            assert target == 7, msg               # never an order for our system (1)
    assert all(n >= 90 for n in kinds.values()), kinds


def test_heartbeat_listener_counts_the_vehicles_only():
    from pymavlink.dialects.v20 import common as M

    hb = M.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3)
    ours = wire.send_msg(M.MAVLink(None, 1, 1), hb)
    other = wire.send_msg(M.MAVLink(None, 2, 1), hb)
    att = wire.send_msg(M.MAVLink(None, 1, 1), M.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0))
    assert _heartbeats(ours, 1) == 1 and _heartbeats(other, 1) == 0
    assert _heartbeats(att + ours + ours, 1) == 2 and _heartbeats(b"\xfd\x09junk", 1) == 0
    probe = FloodProbe(0, 10, 1.0, 5000)
    for k in range(4):
        probe.on_odometry(k * 5000, ())
    assert len(probe.tick_wall) == 3 and probe.flood is None and probe.flood_end_k is None


@pytest.mark.flight
def test_bench_flood_briefly():
    from cosim.bench.flood import bench_flood

    d = bench_flood(t_final_s=1.0, flood_wall_s=0.5, realtime_s=0.5)
    assert d["target"] == "gcs" and d["rate_asked_hz"] == 70_000
    for name, ticks in (("lockstep", 200), ("realtime", 100)):
        p = d[name]
        assert p["same_flight"], name                  # the flood changed nothing in flight
        assert math.isfinite(p["rtf_ratio"]) and p["rtf_ratio"] > 0
        for run in ("none", "flood"):
            r = p[run]
            assert r["exit_reason"] == "time_limit" and r["ticks"] == ticks, (name, run)
            assert r["answered_all"] and r["hil_ticks_handled"] == ticks, (name, run)
            assert 0 < r["window_s"] <= ticks * 0.005
            for key in ("window_rtf", "tick_wall_median_us", "tick_wall_p99_us",
                        "tick_wall_max_ms"):
                assert math.isfinite(r[key]) and r[key] > 0, (name, run, key)
            assert 0.0 <= r["hb_gap_max_sim_s"] <= 1.0, (name, run)
            assert r["window_heartbeats"] >= 1
        st, f = p["flood"]["onboard_stats"], p["flood"]["sender"]
        assert f["sent"] > 0 and f["wall_s"] > 0 and f["cpu_s"] >= 0
        assert st["rx_gcs"] > 0 and st.get("handler_errors", 0) == 0
        assert "rx_gcs" not in p["none"]["onboard_stats"]      # 0: nothing came unflooded
        # handled + dropped by the kernel + never read = what was sent, none counted twice
        assert 0 <= p["flood"]["left_queued_at_exit"] <= f["sent"] - st["rx_gcs"]
    text = "\n".join(format_flood(d))
    for label in ("flood on the vehicle's gcs port", "lockstep as fast as it goes",
                  "real time, speed 1", "largest gap, vehicle time", "dropped_kernel_gcs",
                  "drain_deferred", "every HIL tick answered: yes"):
        assert label in text, label
