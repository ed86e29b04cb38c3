"""Battery faults on the vehicle (mav/onboard/inject.py), closed loop (MIL rig, FMU plant):
MAV_CMD_INJECT_FAILURE on the HIL link drains the pack, which fires the battery failsafe
through its normal path (warnings, COM_LOW_BAT_ACT), or sags its voltage, which shows in
SYS_STATUS / BATTERY_STATUS while it lasts; on the api and gcs links the command is DENIED and
counted; an unusable command on HIL changes nothing."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_auto import AT_M, flying_rig, goto, pos
from test_onboard_failsafes import set_params
from test_onboard_rig import Rig

from mav.battery import BATTERIES, Battery, cell_ocv
from mav.hil import INJECT_COMPID, SIM_SYSID, encode_inject_failure

M = mavlink2
SIM = M.MAVLink(None, SIM_SYSID, INJECT_COMPID)


def test_battery_model_faults():
    b = Battery(BATTERIES["mambo"], 0.5)
    b.step(10.0, 0.5, 0.5, 0.5, 0.5)                 # 10 s of hover: 4.5 A, 12.5 mAh
    drawn = b.consumed_mah
    assert drawn == pytest.approx(12.5)
    b.lose_charge(0.5)
    assert b.remaining == pytest.approx(0.5) and b.consumed_mah == drawn
    assert b.used_mah == pytest.approx(330.0)
    b.lose_charge(0.8)                               # above what is left: nothing
    assert b.remaining == pytest.approx(0.5)
    assert b.time_remaining_s() == pytest.approx(330.0 / 4.5 * 3.6)
    v0 = b.voltage
    assert v0 == pytest.approx(cell_ocv(0.5) - 4.5 * 0.08)
    b.sag(3.0, 0.2)
    assert b.voltage == pytest.approx(v0 - 2.0 * 4.5 * 0.08 - 0.2)
    b.sag(1.0, 0.0)
    assert b.voltage == pytest.approx(v0)
    b.configure(1000.0, -1.0)                        # a bigger pack: the mAh lost stay lost
    assert b.remaining == pytest.approx(1.0 - 330.0 / 1000.0)


def inject(rig, failure_type: int, p4: float = 0.0, p5: float = 0.0, data: bytes | None = None
           ) -> None:
    """The simulator's fault command on the HIL link, before the next tick's ODOMETRY: the
    vehicle handles it on its own poll (no answer on HIL)."""
    rig.hil.send(data or encode_inject_failure(SIM, failure_type, p4, p5))
    assert rig.ob.poll() is False
    assert rig.hil.recv() is None


def test_drain_mid_hover_warns_then_lands_with_com_low_bat_act_2():
    rig = flying_rig()
    set_params(rig, COM_LOW_BAT_ACT=2)
    where = pos(rig)
    rig.tick(200)
    assert rig.client.battery[2] > 0.9 and not [t for t in rig.texts() if "attery" in t]
    inject(rig, M.FAILURE_TYPE_OFF, 0.06)          # between BAT_CRIT_THR and BAT_EMERGEN_THR
    assert rig.ob.stats["faults_injected"] == 1
    rig.run_until(lambda r: r.client.mode == "AUTO.LAND", 1.0)
    texts = rig.texts()
    assert "Battery low: 6% remaining" in texts
    assert "Failsafe: battery critical, landing" in texts
    assert not [t for t in texts if "emergency" in t]
    rig.tick(410)                                  # BATTERY_STATUS: 0.5 Hz on GCS
    bs = rig.last("gcs", "BATTERY_STATUS")
    assert bs.battery_remaining == 6 and bs.charge_state == M.MAV_BATTERY_CHARGE_STATE_CRITICAL
    assert rig.last("gcs", "SYS_STATUS").battery_remaining == 6
    assert bs.current_consumed < 100               # mAh drawn: the lost charge is not drawn
    rig.run_until(lambda r: not r.ob.armed, 30.0)
    assert rig.client.landed_state == "ON_GROUND"
    assert math.hypot(pos(rig)[0] - where[0], pos(rig)[1] - where[1]) < 0.2


def test_drain_returns_with_com_low_bat_act_3():
    rig = flying_rig()
    # emergency (land) at 3 %: 6 % -> 3 % is ~20 mAh, ~16 s of flight, time to come home
    set_params(rig, COM_LOW_BAT_ACT=3, BAT_EMERGEN_THR=0.03)
    goto(rig, 3.0, 0.0, 1.0)
    rig.run_until(lambda r: math.dist(pos(r), (3.0, 0.0, -1.0)) < AT_M, 15.0)
    inject(rig, M.FAILURE_TYPE_OFF, 0.06)
    rig.run_until(lambda r: r.client.mode == "AUTO.RTL", 1.0)
    assert "Failsafe: battery critical, returning" in rig.texts()
    rig.run_until(lambda r: not r.ob.armed, 60.0)
    assert math.hypot(*pos(rig)[:2]) < 0.2          # back home
    assert not [t for t in rig.texts() if "emergency" in t]
    assert 0.03 < rig.client.battery[2] < 0.06      # drawn on the way home


def _voltages(rig, since_us: int) -> tuple[list[float], list[float]]:
    """SYS_STATUS and BATTERY_STATUS (cell 0 = the pack, 1S) voltages since a time, V."""
    return ([m.voltage_battery * 1e-3 for m in rig.msgs("gcs", "SYS_STATUS", since_us)],
            [m.voltages[0] * 1e-3 for m in rig.msgs("gcs", "BATTERY_STATUS", since_us)])


def test_sag_lowers_the_reported_voltage_in_its_window_only():
    rig = flying_rig()
    b = rig.ob.battery
    t0 = rig.t_us
    rig.tick(400)
    before = _voltages(rig, t0)
    t1 = rig.t_us
    inject(rig, M.FAILURE_TYPE_WRONG, 4.0, 0.1)    # R x4, and 0.1 V more
    rig.tick(400)
    during = _voltages(rig, t1)
    t2 = rig.t_us
    inject(rig, M.FAILURE_TYPE_OK)
    rig.tick(400)
    after = _voltages(rig, t2)
    sag = 3.0 * b.current * b.r_internal + 0.1      # hover: ~4.5 A x 0.08 Ohm x 3 + 0.1
    assert 1.0 < sag < 1.4
    for i in (0, 1):                                # SYS_STATUS, BATTERY_STATUS
        assert before[i] and during[i] and after[i]
        assert min(before[i]) - max(during[i]) == pytest.approx(sag, abs=0.02)
        assert min(after[i]) == pytest.approx(max(before[i]), abs=0.02)
    assert rig.client.battery[0] == pytest.approx(after[0][-1], abs=1e-3)
    assert not [t for t in rig.texts() if "attery" in t]       # charge: no failsafe
    assert rig.last("gcs", "BATTERY_STATUS").charge_state == M.MAV_BATTERY_CHARGE_STATE_OK
    assert rig.ob.stats["faults_injected"] == 2


def test_inject_failure_is_denied_on_api_and_gcs():
    rig = flying_rig()
    rig.tick(200)
    remaining, volts = rig.client.battery[2], rig.client.battery[0]
    for link in ("gcs", "api"):
        rig.cmd(M.MAV_CMD_INJECT_FAILURE, M.FAILURE_UNIT_SYSTEM_BATTERY, M.FAILURE_TYPE_OFF,
                0.0, 0.0, link=link)
        rig.cmd(M.MAV_CMD_INJECT_FAILURE, M.FAILURE_UNIT_SYSTEM_BATTERY,
                M.FAILURE_TYPE_WRONG, 0.0, 10.0, 1.0, link=link)
        rig.tick(2)
    assert rig.ack(M.MAV_CMD_INJECT_FAILURE, "gcs") == M.MAV_RESULT_DENIED
    assert rig.client.ack(M.MAV_CMD_INJECT_FAILURE) == M.MAV_RESULT_DENIED     # api
    st = rig.ob.stats
    assert st["inject_denied"] == 4 and st["faults_injected"] == 0
    rig.tick(400)
    assert rig.client.battery[2] == pytest.approx(remaining, abs=0.011)
    assert rig.client.battery[0] == pytest.approx(volts, abs=0.02)
    assert rig.ob.battery.lost_mah == 0.0 and rig.ob.battery.r_scale == 1.0
    assert rig.ob.mode_name == "AUTO.LOITER"


@pytest.mark.parametrize("change", [
    {"param1": M.FAILURE_UNIT_SENSOR_GPS}, {"param2": M.FAILURE_TYPE_STUCK},
    {"param3": 2.0}, {"param4": 1.5}, {"param4": math.nan},
    {"param2": M.FAILURE_TYPE_WRONG, "param5": -1.0},
    {"param2": M.FAILURE_TYPE_WRONG, "param4": 2000.0}, {"target_system": 7},
    {"command": M.MAV_CMD_NAV_LAND},
])
def test_unusable_commands_on_hil_change_nothing(change):
    rig = Rig()
    rig.tick(2)
    f = {"target_system": 0, "target_component": 0, "command": M.MAV_CMD_INJECT_FAILURE,
         "confirmation": 0, "param1": M.FAILURE_UNIT_SYSTEM_BATTERY,
         "param2": M.FAILURE_TYPE_OFF, "param3": 0.0, "param4": 0.0, "param5": 0.0,
         "param6": 0.0, "param7": 0.0} | change
    inject(rig, 0, data=M.MAVLink_command_long_message(**f).pack(SIM))
    st = rig.ob.stats
    assert (st["hil_ignored"], st["faults_injected"]) == (1, 0)
    b = rig.ob.battery
    assert (b.lost_mah, b.r_scale, b.v_drop, rig.ob.mode_name) == (0.0, 1.0, 0.0, "POSCTL")
