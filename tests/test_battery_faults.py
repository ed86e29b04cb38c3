"""Battery faults of the `[faults]` table (cosim/faults/battery.py): parsing names the bad
field; the schedule of MAV_CMD_INJECT_FAILURE commands sent on the HIL link; a run with a sag
and a drain is the same in MIL and SIL, bit for bit, and its telemetry shows both. The
vehicle's side: tests/test_onboard_battery_faults.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from cosim.apps.scripted import ScriptedApp
from cosim.errors import ScenarioError
from cosim.faults.battery import schedule
from cosim.faults.core import FaultHooks, parse_faults
from cosim.load import load_scenario, with_set
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from mav.hil import INJECT_COMPID, SIM_SYSID
from mav.links import MemoryLink

M = mavlink2
SCEN = Path(__file__).resolve().parent.parent / "scenarios"


# ------------------------------------------------------------------ parsing and schedule
@pytest.mark.parametrize("entries, field", [
    ([{"kind": "drain", "start_s": 5.0}], "faults.battery[0].remaining"),
    ([{"kind": "drain", "remaining": 1.5}], "faults.battery[0].remaining"),
    ([{"kind": "drain", "remaining": 0.1, "end_s": 9.0}], "faults.battery[0].end_s"),
    ([{"kind": "drain", "remaining": 0.1, "r_factor": 2.0}], "faults.battery[0].r_factor"),
    ([{"kind": "leak", "remaining": 0.1}], "faults.battery[0].kind"),
    ([{"remaining": 0.1}], "faults.battery[0].kind"),
    ([{"kind": "sag", "r_factor": 2.0}, {"kind": "sag", "r_factor": 0.5}],
     "faults.battery[1].r_factor"),
    ([{"kind": "sag", "drop_v": -0.1}], "faults.battery[0].drop_v"),
    ([{"kind": "sag", "start_s": 3.0}], "faults.battery[0]"),
    ([{"kind": "sag", "r_factor": 2.0, "start_s": 3.0, "end_s": 3.0}],
     "faults.battery[0].end_s"),
    ([{"kind": "sag", "r_factor": 2.0, "remaining": 0.5}], "faults.battery[0].remaining"),
    ({"kind": "sag", "drop_v": True}, "faults.battery[0].drop_v"),
    ("sag", "faults.battery"),
])
def test_bad_fields_are_named(entries, field):
    with pytest.raises(ScenarioError) as e:
        parse_faults({"battery": entries})
    assert e.value.field == field


def test_schedule_sends_the_net_sag_at_each_change_and_drains_at_their_time():
    spec = parse_faults({"battery": [
        {"kind": "sag", "start_s": 2.0, "end_s": 6.0, "r_factor": 3.0},
        {"kind": "drain", "start_s": 4.0, "remaining": 0.2},
        {"kind": "sag", "start_s": 4.0, "end_s": 8.0, "r_factor": 2.0, "drop_v": 0.1},
        {"kind": "sag", "start_s": 10.0, "drop_v": 0.3}]})
    assert spec and len(spec.battery) == 4
    assert [c[:4] for c in schedule(spec.battery)] == [
        (2.0, M.FAILURE_TYPE_WRONG, 3.0, 0.0),
        (4.0, M.FAILURE_TYPE_WRONG, 6.0, 0.1),       # both sags: factors x, drops +
        (4.0, M.FAILURE_TYPE_OFF, 0.2, 0.0),
        (6.0, M.FAILURE_TYPE_WRONG, 2.0, 0.1),
        (8.0, M.FAILURE_TYPE_OK, 0.0, 0.0),
        (10.0, M.FAILURE_TYPE_WRONG, 1.0, 0.3)]      # no end: never cleared
    assert [c[4] for c in schedule(spec.battery)][:3] == [
        ("battery sag: resistance x3 (fault 0)",),
        ("battery sag: resistance x2, -0.1 V (fault 2)",),
        ("battery drain to 20% (fault 1)",)]


def test_overlapping_sags_are_clamped_to_what_the_vehicle_accepts():
    spec = parse_faults({"battery": [{"kind": "sag", "r_factor": 100.0, "drop_v": 60.0},
                                     {"kind": "sag", "r_factor": 20.0, "drop_v": 60.0}]})
    assert [c[1:4] for c in schedule(spec.battery)] == [(M.FAILURE_TYPE_WRONG, 1000.0, 100.0)]


def test_hil_wrapper_sends_the_command_just_before_the_tick_odometry():
    a, b = MemoryLink.pair()
    no_battery = FaultHooks(parse_faults({"motor": [{"motor": 1, "thrust": 0.5}]}), 0)
    assert no_battery.wrap_link("hil", a) is a
    h = FaultHooks(parse_faults({"battery": [{"kind": "drain", "start_s": 0.012,
                                              "remaining": 0.5}]}), 0)
    hil = h.wrap_link("hil", a)
    got = []
    for k in range(5):
        h.on_odometry(k * 5000, (0.0,) * 13)
        hil.send(b"odometry %d" % k)
        while (d := b.recv()) is not None:
            got.append(d)
    assert got[:3] == [b"odometry 0", b"odometry 1", b"odometry 2"]
    assert got[4:] == [b"odometry 3", b"odometry 4"]     # the first tick at or after 12 ms
    cmd = M.MAVLink(None, 1, 1).decode(bytearray(got[3]))
    assert (cmd.get_type(), cmd.command, cmd.param1, cmd.param2, cmd.param3, cmd.param4) == (
        "COMMAND_LONG", M.MAV_CMD_INJECT_FAILURE, M.FAILURE_UNIT_SYSTEM_BATTERY,
        M.FAILURE_TYPE_OFF, 0.0, 0.5)
    assert (cmd.target_system, cmd.target_component) == (0, 0)
    assert (cmd.get_srcSystem(), cmd.get_srcComponent()) == (SIM_SYSID, INJECT_COMPID)
    assert h.fired() == [(0.012, "battery drain to 50% (fault 0)")]


# ------------------------------------------------------------------ the master: MIL == SIL
def _tlog_msgs(res, mtype: str) -> list:
    mlog = mavutil.mavlink_connection(str(res.run_dir / "flight.tlog"))
    out = []
    while (m := mlog.recv_match(type=mtype)) is not None:
        out.append(m)
    return out


@pytest.mark.flight
def test_battery_faults_mil_equals_sil_bit_for_bit():
    sc = with_set(load_scenario(SCEN / "mambo_hover.toml"), {"timing.t_final_s": 12.0, "faults": {
        "battery": [{"kind": "sag", "start_s": 6.0, "end_s": 8.0, "r_factor": 4.0,
                     "drop_v": 0.1},
                    {"kind": "drain", "start_s": 9.0, "remaining": 0.06}]}})
    mil = run_scenario(sc, RunOptions(mode="mil"))
    sil = run_scenario(sc, RunOptions(mode="sil"))
    for r in (mil, sil):
        assert r.exit_reason is ExitReason.TIME_LIMIT, r.message
        assert r.onboard_stats["faults_injected"] == 3           # sag, its end, the drain
    assert np.array_equal(mil.series, sil.series, equal_nan=True)
    assert mil.tlog.read() == sil.tlog.read()                     # every telemetry byte
    assert mil.faults == sil.faults == [(6.0, "battery sag: resistance x4, -0.1 V (fault 0)"),
                                        (9.0, "battery drain to 6% (fault 1)")]
    # what the ground station saw (SYS_STATUS at 1 Hz on both links; tlog stamps: sim time)
    volts = {round(m._timestamp, 3): m.voltage_battery for m in _tlog_msgs(mil, "SYS_STATUS")}
    assert volts[5.0] - volts[6.0] > 1000 and volts[7.0] < volts[5.0] - 1000      # mV
    assert abs(volts[8.0] - volts[5.0]) < 20
    rem = {round(m._timestamp, 3): m.battery_remaining for m in _tlog_msgs(mil, "SYS_STATUS")}
    assert rem[8.0] > 90 and rem[9.0] == rem[11.0] == 6
    texts = [m.text for m in _tlog_msgs(mil, "STATUSTEXT")]
    assert "Battery low: 6% remaining" in texts          # COM_LOW_BAT_ACT 0: warnings only


class LowBatteryLands(ScriptedApp):
    """The hover app of mambo_hover.toml, which first sets COM_LOW_BAT_ACT = 2 (land at
    critical) over its link, as a ground station would: a scenario cannot set it."""

    def on_start(self, ctx) -> None:
        super().on_start(ctx)
        ctx.client.set_param("COM_LOW_BAT_ACT", 2.0)


@pytest.mark.flight
def test_drain_mid_hover_lands_the_vehicle_through_the_failsafe_in_mil_and_sil():
    sc = with_set(load_scenario(SCEN / "mambo_hover.toml"), {"timing.t_final_s": 30.0, "faults": {
        "battery": [{"kind": "drain", "start_s": 10.0, "remaining": 0.06}]}})
    runs = {m: run_scenario(sc, RunOptions(mode=m, app_override=LowBatteryLands(sc.app.params)))
            for m in ("mil", "sil")}
    mil = runs["mil"]
    for r in runs.values():
        assert r.exit_reason is ExitReason.LANDED, r.message
        assert r.faults == [(10.0, "battery drain to 6% (fault 0)")]
    assert np.array_equal(mil.series, runs["sil"].series, equal_nan=True)
    assert mil.tlog.read() == runs["sil"].tlog.read()
    texts = [m.text for m in _tlog_msgs(mil, "STATUSTEXT")]
    assert "Battery low: 6% remaining" in texts
    assert "Failsafe: battery critical, landing" in texts
    # hovering at 1 m until the fault, then down, on the spot
    t, x, y, z = mil.recorded.columns("t", "x", "y", "z")
    k = np.searchsorted(t, 10.0)
    assert -z[k] > 0.9 and -z[-1] < 0.1 and 10.0 < t[-1] < 16.0
    assert np.hypot(x[-1] - x[k], y[-1] - y[k]) < 0.1
    modes = [((m.custom_mode >> 16) & 0xFF, m.custom_mode >> 24)   # PX4 main, sub mode
             for m in _tlog_msgs(mil, "HEARTBEAT")
             if m.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 and m._timestamp >= 9.0]
    assert modes[0] == (6, 0) and modes[-1] == (4, 6)    # OFFBOARD, then AUTO.LAND


@pytest.mark.flight
def test_shipped_battery_scenario_lands_the_same_in_mil_and_sil():
    """scenarios/mambo_seed_battery.toml: `[onboard.params]` COM_LOW_BAT_ACT = 2 reaches the
    flight stack in both modes (a parameter file: OnboardConfig.param_file / --params), and a
    cell failing mid-track lands the vehicle where it is, bit for bit the same run."""
    from cosim.outputs.report import summarize

    sc = load_scenario(Path(__file__).resolve().parents[1] / "scenarios"
                       / "mambo_seed_battery.toml")
    # its parameter, and the estimator the default sensor feed sets
    assert sc.onboard_params == (("COM_LOW_BAT_ACT", 2.0), ("TPL_EST_TYPE", 2.0))
    mil = run_scenario(sc, RunOptions(mode="mil"))
    sil = run_scenario(sc, RunOptions(mode="sil"))
    assert mil.exit_reason.value == "landed"
    assert summarize(mil)["passed"]
    assert np.array_equal(mil.series, sil.series, equal_nan=True)
    assert mil.faults == sil.faults
