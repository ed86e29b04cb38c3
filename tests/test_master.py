"""The master end to end: MIL == SIL bit for bit, determinism, failures, outputs, CLI."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from cosim.apps.scripted import ScriptedApp
from cosim.load import load_scenario, with_set
from cosim.outputs.report import write_run
from cosim.outputs.tlog import read_tlog
from cosim.sim.master import ExitReason, RunOptions, run_scenario

ROOT = Path(__file__).resolve().parent.parent
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
COSIM = [sys.executable, "-m", "cosim.cli"]


@pytest.fixture(scope="module")
def seed_runs():
    sc = load_scenario(SEED)
    return {m: run_scenario(sc, RunOptions(mode=m)) for m in ("mil", "sil")}


@pytest.fixture(scope="module")
def square_runs():
    sc = load_scenario(SQUARE)
    return {m: run_scenario(sc, RunOptions(mode=m)) for m in ("mil", "sil")}


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.flight
@pytest.mark.parametrize("runs", ["seed_runs", "square_runs"])
def test_mil_and_sil_are_bit_identical(runs, request):
    r = request.getfixturevalue(runs)
    mil, sil = r["mil"], r["sil"]
    assert mil.exit_reason is ExitReason.MISSION_COMPLETE, mil.message
    assert sil.exit_reason is ExitReason.MISSION_COMPLETE, sil.message
    assert mil.ticks > 1000
    assert _same_bits(mil.series, sil.series)
    assert mil.tlog.read() == sil.tlog.read()  # every MAVLink byte on API and GCS
    assert mil.events == sil.events


@pytest.mark.flight
def test_same_run_twice_is_identical(seed_runs):
    again = run_scenario(load_scenario(SEED), RunOptions(mode="mil"))
    assert _same_bits(again.series, seed_runs["mil"].series)
    assert again.tlog.read() == seed_runs["mil"].tlog.read()


@pytest.mark.flight
def test_seed_differs_with_noise_seed():
    sc = with_set(load_scenario(SQUARE), {"sensors.flow.flow_noise_rad_s": 0.03,
                                         "timing.t_final_s": 4.0})
    a = run_scenario(sc, RunOptions())
    b = run_scenario(sc, RunOptions())
    c = run_scenario(with_set(sc, {"seed": 1}), RunOptions())
    assert _same_bits(a.series, b.series)
    assert not _same_bits(a.series, c.series)


@pytest.mark.flight
def test_outputs_are_written_and_readable(seed_runs, tmp_path):
    res = seed_runs["mil"]
    summary = write_run(res, tmp_path)
    for name in ("summary.json", "timeseries.csv", "frames.csv", "flight.tlog",
                 "trajectory.png", "timeseries.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s == json.loads(json.dumps(summary, default=str))
    assert s["exit_reason"] == "mission_complete" and s["passed"]
    assert s["metrics"]["landing_error_m"] < 0.10
    assert s["versions"]["pymavlink"] and s["real_time_factor"] > 1
    recs = read_tlog(tmp_path / "flight.tlog")
    assert len(recs) == res.tlog.count
    # pymavlink reads our tlog: the offboard setpoints and the vehicle's heartbeats are there
    m = mavutil.mavlink_connection(str(tmp_path / "flight.tlog"))
    types = set()
    while (msg := m.recv_match()) is not None:
        types.add(msg.get_type())
    assert {"HEARTBEAT", "SET_POSITION_TARGET_LOCAL_NED", "LOCAL_POSITION_NED",
            "COMMAND_LONG", "COMMAND_ACK"} <= types
    lines = (tmp_path / "timeseries.csv").read_text().splitlines()
    assert len(lines) == res.ticks + 1 and lines[0].startswith("t,x,y,z,")


class ExplodingApp(ScriptedApp):
    def on_tick(self, t: float) -> None:
        if t >= 2.0:
            raise RuntimeError("boom")
        super().on_tick(t)


@pytest.mark.flight
def test_app_exception_stops_the_run_and_keeps_outputs(tmp_path):
    sc = load_scenario(SQUARE)
    res = run_scenario(sc, RunOptions(app_override=ExplodingApp(sc.app.params)))
    assert res.exit_reason is ExitReason.COMPONENT_ERROR
    assert res.message.startswith("app:") and "boom" in res.message
    assert res.t_end_s == pytest.approx(2.0)
    summary = write_run(res, tmp_path)
    assert summary["exit_reason"] == "component_error" and not summary["passed"]
    assert len((tmp_path / "timeseries.csv").read_text().splitlines()) == res.ticks + 1


@pytest.fixture
def onboard_procs(monkeypatch):
    """Every OnboardProcess the master starts during the test, in order."""
    import cosim.sim.sil as sil

    procs = []
    orig = sil.OnboardProcess.__init__

    def spy(self, *a, **kw):
        orig(self, *a, **kw)
        procs.append(self)

    monkeypatch.setattr(sil.OnboardProcess, "__init__", spy)
    return procs


@pytest.mark.flight
def test_onboard_process_killed_mid_run(tmp_path, onboard_procs):
    procs = onboard_procs

    class KillerApp(ScriptedApp):
        def on_tick(self, t: float) -> None:
            if t >= 3.0 and procs[0].alive():
                os.kill(procs[0].proc.pid, signal.SIGKILL)
            super().on_tick(t)

    sc = load_scenario(SQUARE)
    t0 = time.monotonic()
    res = run_scenario(sc, RunOptions(mode="sil", out_dir=tmp_path, hil_timeout_s=1.0,
                                      app_override=KillerApp(sc.app.params)))
    assert time.monotonic() - t0 < 30
    assert res.exit_reason is ExitReason.COMPONENT_ERROR
    assert res.message.startswith("onboard:") and "exited with code -9" in res.message
    assert 2.9 <= res.t_end_s <= 3.1
    write_run(res, tmp_path / "out")
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["ticks"] == res.ticks
    assert not procs[0].alive()


@pytest.mark.flight
def test_cli_run_validate_and_help(tmp_path):
    out = tmp_path / "run"
    r = subprocess.run([*COSIM, "run", str(SQUARE), "--out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "PASSED" in r.stdout and "mission_complete" in r.stdout
    assert (out / "summary.json").is_file()
    # a failing criterion gives exit status 1
    r = subprocess.run([*COSIM, "run", str(SQUARE), "--out", str(tmp_path / "f"), "--quiet",
                        "--set", "criteria.position_error_max_m=0.0001"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "FAIL" in r.stdout
    bad = tmp_path / "bad.toml"
    text = SQUARE.read_text()
    world = 'file = "worlds/empty.toml"'
    assert world in text
    bad.write_text(text.replace('preset = "mambo"', 'preset = "mambo3"')
                   .replace(world, f'file = "{ROOT / "scenarios" / "worlds" / "empty.toml"}"'))
    r = subprocess.run([*COSIM, "validate", str(bad)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert "vehicle.preset" in r.stderr and "mambo3" in r.stderr
    r = subprocess.run([*COSIM, "validate", str(SEED), str(SQUARE)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.count(": ok") == 2
    r = subprocess.run([*COSIM, "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "examples:" in r.stdout and "cosim sweep" in r.stdout


@pytest.mark.flight
def test_two_sil_runs_side_by_side(tmp_path):
    cmds = [[*COSIM, "run", str(SQUARE), "--mode", "sil", "--quiet", "--no-plots",
             "--out", str(tmp_path / f"r{i}")] for i in range(2)]
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for c in cmds]
    outs = [p.communicate(timeout=180) for p in procs]
    for p, (_o, e) in zip(procs, outs, strict=True):
        assert p.returncode == 0, e
    a, b = ((tmp_path / f"r{i}" / "timeseries.csv").read_bytes() for i in range(2))
    assert a == b


def test_sitl_answers_a_ground_station():
    """On ports the OS picks (never the well-known 14540/14550: the machine is shared)."""
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    port = gcs.port.getsockname()[1]
    api = mavutil.mavlink_connection("udpin:127.0.0.1:0")      # its API link's peer: unread
    api_port = api.port.getsockname()[1]
    proc = subprocess.Popen([*COSIM, "sitl", "--vehicle", "mambo", "--duration", "20",
                             "--gcs-remote", f"127.0.0.1:{port}", "--gcs-bind", "127.0.0.1:0",
                             "--api-remote", f"127.0.0.1:{api_port}",
                             "--api-bind", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=20)
        assert hb is not None, f"no heartbeat on {port}"
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
        assert hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR
        gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                  mavutil.mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                  0, 0, 0, 0, 0, 0)
        ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=10)
        assert ack is not None and ack.result == mavutil.mavlink.MAV_RESULT_ACCEPTED
        ver = gcs.recv_match(type="AUTOPILOT_VERSION", blocking=True, timeout=10)
        assert ver is not None
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
        gcs.close()
        api.close()


@pytest.mark.flight
def test_realtime_pacing_keeps_the_lockstep():
    sc = with_set(load_scenario(SQUARE), {"timing.t_final_s": 2.0})
    fast = run_scenario(sc, RunOptions())
    t0 = time.monotonic()
    paced = run_scenario(sc, RunOptions(realtime=True, speed=4.0))
    wall = time.monotonic() - t0
    assert wall >= 2.0 / 4.0 * 0.98          # never faster than asked (a lower bound only)
    assert _same_bits(fast.series, paced.series)


@pytest.mark.flight
def test_cli_video_pngs_and_tune(tmp_path):
    out = tmp_path / "v"
    r = subprocess.run([*COSIM, "run", str(SEED), "--out", str(out), "--quiet", "--video",
                        "--png-every", "5", "--set", "timing.t_final_s=4.0", "--no-plots"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr          # the mission cannot complete in 4 s
    assert "time_limit" in r.stdout
    videos = list(out.glob("camera.*"))
    assert videos and videos[0].stat().st_size > 1000
    pngs = sorted((out / "frames").glob("*.png"))
    assert len(pngs) == 4                      # frames 0, 5, 10, 15 of 20 (5 Hz for 4 s)
    import cv2

    img = cv2.imread(str(pngs[-1]))
    assert img.shape == (120, 160, 3)
    r = subprocess.run([*COSIM, "tune", "mambo"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "PM" in r.stdout and "alt" in r.stdout


@pytest.mark.flight
def test_fmu_error_is_named_and_outputs_kept(tmp_path, monkeypatch):
    """A NaN motor command reaches the real FMU, which rejects it with fmi2Error."""
    from mav import wire

    orig = wire.decode_hil_actuator_controls     # the master's decoder of the HIL answer

    def poisoned(*args):           # (data) or, on the sensor feed, (data, start, end)
        t, u1, u2, u3, u4 = orig(*args)
        return (t, float("nan"), u2, u3, u4) if t >= 1_500_000 else (t, u1, u2, u3, u4)

    monkeypatch.setattr(wire, "decode_hil_actuator_controls", poisoned)
    # (the framed exchange decodes the answer's frame; the typed one has no frame to poison)
    res = run_scenario(load_scenario(SQUARE), RunOptions(hil_exchange="framed"))
    assert res.exit_reason is ExitReason.COMPONENT_ERROR
    assert res.message.startswith("plant:") and "u1" in res.message
    assert res.t_end_s == pytest.approx(1.505)
    write_run(res, tmp_path)
    assert (tmp_path / "summary.json").is_file()


@pytest.mark.flight
def test_onboard_process_that_hangs_is_detected(tmp_path, onboard_procs):
    procs = onboard_procs

    class FreezerApp(ScriptedApp):
        def on_tick(self, t: float) -> None:
            if t >= 2.0 and not getattr(self, "_frozen", False):
                os.kill(procs[0].proc.pid, signal.SIGSTOP)
                self._frozen = True
            super().on_tick(t)

    sc = load_scenario(SQUARE)
    t0 = time.monotonic()
    res = run_scenario(sc, RunOptions(mode="sil", out_dir=tmp_path, hil_timeout_s=1.0,
                                      app_override=FreezerApp(sc.app.params)))
    assert time.monotonic() - t0 < 30
    assert res.exit_reason is ExitReason.COMPONENT_ERROR
    assert res.message.startswith("onboard: stopped answering")
    assert not procs[0].alive()               # the master shut the stopped process down


@pytest.mark.flight
def test_vehicle_overrides_fly_the_same_in_mil_and_sil():
    sc = with_set(load_scenario(SQUARE), {"vehicle.overrides.mass": 0.07,
                                         "vehicle.overrides.drag_xy": 0.02,
                                         "timing.t_final_s": 8.0})
    mil = run_scenario(sc, RunOptions(mode="mil"))
    sil = run_scenario(sc, RunOptions(mode="sil"))
    base = run_scenario(with_set(load_scenario(SQUARE), {"timing.t_final_s": 8.0}), RunOptions())
    assert _same_bits(mil.series, sil.series)
    assert not _same_bits(mil.series, base.series)      # the overrides did change the flight
    # SIL reports the onboard process's counters, as MIL does
    assert sil.onboard_stats["rx_hil"] == mil.onboard_stats["rx_hil"] == mil.ticks


@pytest.mark.flight
def test_landing_is_detected_with_odometry_noise():
    """PX4's land detector decides on filtered velocities; ours low-passes vz, so velocity
    noise the scenarios allow does not keep the vehicle armed on the ground (issue 12:
    before, 0.1 m/s of noise ended the seed mission 'landed before the app finished')."""
    sc = with_set(load_scenario(SEED), {"sensors.feed": "truth",
                                        "sensors.odometry_noise.vel_std_mps": 0.2,
                                        "sensors.odometry_noise.pos_std_m": 0.01})
    res = run_scenario(sc, RunOptions(mode="mil"))
    assert res.exit_reason is ExitReason.MISSION_COMPLETE, res.message
