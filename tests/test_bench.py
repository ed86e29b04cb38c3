"""`cosim bench --quick` through the CLI: it runs, and every figure it reports is present and
positive. No timing is asserted (machines are shared and noisy)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
COSIM = [sys.executable, "-m", "cosim.cli"]


def _figures(d, path=""):
    """Every per-figure dict (one with a 'median') and every number in the breakdown."""
    if isinstance(d, dict):
        if "median" in d:
            yield path, d
        for k, v in d.items():
            if isinstance(v, dict):
                yield from _figures(v, f"{path}.{k}")


@pytest.mark.flight
def test_bench_quick_reports_every_figure(tmp_path):
    out = tmp_path / "bench.json"
    r = subprocess.run([*COSIM, "bench", "--quick", "--json", str(out)], capture_output=True,
                       text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    expected = ["plant_step", "controller_update", "udp_hil_roundtrip", "render", "ips",
                "mission_mil", "mission_sil", "vision", "flood", "peers"]
    for key in expected:
        assert key in res, key
    peers = res["peers"]                                # RotorPy flown side by side
    rp = peers["peers"]["rotorpy"]
    assert peers["ours_x_real_time"] > 0 and rp["x_real_time"] > 0
    assert rp["ratio"] == pytest.approx(peers["ours_x_real_time"] / rp["x_real_time"])
    assert "RotorPy (SE3, 100 Hz, no sensors)" in r.stdout and "ours / it" in r.stdout
    gpd = peers["peers"]["gym_pybullet_drones"]         # not on PyPI: flown where installed
    try:
        import gym_pybullet_drones  # noqa: F401
    except ImportError:
        assert "pip install --no-deps" in gpd["missing"] and gpd["missing"] in r.stdout
    else:
        assert gpd["ratio"] == pytest.approx(peers["ours_x_real_time"] / gpd["x_real_time"])
    figs = dict(_figures(res))
    assert len(figs) >= len(expected) + 5 + 2          # + codec figures + end-to-end figures
    for name, d in figs.items():
        for k in ("median", "min", "max"):
            assert math.isfinite(d[k]) and d[k] > 0, (name, k, d[k])
        assert d["min"] <= d["median"] <= d["max"], name
    v = res["vision"]                       # paper 2: a SIFT match costs more than a servo cycle
    assert v["match_sift_856x480"]["median"] > v["servo_cycle_856x480"]["median"] > 0
    est = res["mission_mil_estimate"]           # issue 27: on the estimate, its target
    assert est["exit_reason"] == "mission_complete"
    pairs = est["ratio_pairs"]                  # flown in pairs back to back, the median ratio
    assert len(pairs) == 5 and est["ratio_to_truth_fed"] == sorted(pairs)[2]
    assert est["target"] == 0.6 * est["truth_fed_pairs"]["median"]
    assert est["meets_target"] == (est["ratio_to_truth_fed"] >= 0.6)
    be = res["mil_tick_breakdown_estimate"]["parts_us_per_tick"]   # its own lines
    for name in ("sensor models + HIL_SENSOR & co.", "  onboard estimator (decode + filters)",
                 "HIL answer + estimate decode"):
        assert be[name] > 0, name
    assert "ODOMETRY encode" not in be and "sensor model" not in be   # truth-fed parts
    for mode in ("mission_mil", "mission_sil"):
        m = res[mode]
        assert m["exit_reason"] == "mission_complete"
        assert m["sim_time_s"] > 0 and m["us_per_tick"] > 0
    b = res["mil_tick_breakdown"]
    assert b["ticks"] > 0 and b["loop_us_per_tick"] > 0
    parts = b["parts_us_per_tick"]
    for name in ("plant step", "ODOMETRY encode", "HIL exchange (onboard)", "app on_tick",
                 "camera render (per tick)", "  onboard controller"):
        assert parts[name] > 0, name
    assert all(math.isfinite(v) for v in parts.values())
    floor = res["floor_us_per_tick"]
    assert len(floor) >= 9
    for name, v in floor.items():
        assert math.isfinite(v) and v > 0, name
    assert floor["total"] < b["loop_us_per_tick"]
    # the report names every figure
    for label in ("plant step", "render 160x120 frame", "seed mission MIL (tick loop)",
                  "seed mission SIL (end to end)", "MIL tick breakdown", "floor:",
                  "flood on the vehicle's gcs port", "seed mission MIL on the estimate",
                  "estimate-fed / truth-fed MIL (same run", "MIL tick breakdown on the estimate",
                  "paper 2 E2 mission (x real time)", "front-camera tick of E2"):
        assert label in r.stdout, label
    p2 = res["paper2"]                      # issue 29: E2 flown, its camera tick in parts
    assert p2["E2"]["exit_reason"] == "mission_complete" and p2["E2"]["sim_time_s"] > 30
    parts = p2["breakdown"]["ms_per_frame"]
    for name in ("render", "detection (column)", "tracking (LK, outlier test)",
                 "matching at key changes", "homography / law"):
        assert parts[name] > 0, name
    assert p2["breakdown"]["frames"] > 800 and p2["breakdown"]["camera_tick_ms"] > sum(
        v for k, v in parts.items() if k != "rest of the app's frame") * 0.999
    assert p2["breakdown"]["rendered"] < p2["breakdown"]["frames"]   # take-off not rendered
    pl = p2["breakdown"]["pipelined"]            # the same mission flown whole, pipelined
    assert pl["wall_s"] > 0.5 and pl["main_cpu_s"] > 0.5 and pl["worker_cpu_s"] > 0.5
    e2 = p2["E2"]                                # a study run's CPU: the run + its renderer
    assert len(e2["run_cpu_s"]) == len(e2["cpu_s"]) == 1
    if pl["worker"] == "process":
        assert e2["run_cpu_s"][0] > e2["cpu_s"][0] + 0.5
    assert "CPU s per run (a study run's cost) = (this process, all its threads" in r.stdout


def test_the_peer_row_says_how_to_install_a_missing_peer(monkeypatch):
    from cosim.bench import peers

    monkeypatch.setitem(sys.modules, "rotorpy", None)       # as if not installed
    monkeypatch.setitem(sys.modules, "gym_pybullet_drones", None)
    d = peers.bench_peers(1)
    rotorpy = "RotorPy is not installed: pip install '.[peers]'"
    assert d == {"rounds": 1, "peers": {"gym_pybullet_drones": {"missing": peers.GPD_INSTALL},
                                        "rotorpy": {"missing": rotorpy}}}
    assert "not on PyPI" in peers.GPD_INSTALL and "--no-deps" in peers.GPD_INSTALL
    assert peers.format_peers(d) == [f"  against a peer: {peers.GPD_INSTALL}",
                                     f"  against a peer: {rotorpy}"]
