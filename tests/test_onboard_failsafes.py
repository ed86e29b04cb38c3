"""PX4-like failsafes in closed loop (MIL rig, FMU plant): GCS-link loss (NAV_DLL_ACT,
COM_DL_LOSS_T), battery levels (COM_LOW_BAT_ACT), geofence (GF_ACTION, GF_MAX_HOR_DIST,
GF_MAX_VER_DIST); each acts once, says so in a STATUSTEXT, and stays quiet when disabled."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_auto import AT_M, flying_rig, goto, pos
from test_onboard_rig import Rig

M = mavlink2


def gcs_heartbeat(rig: Rig) -> None:
    if rig.k % 200 == 0:
        rig.send("gcs", M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID,
                                                    0, 0, M.MAV_STATE_ACTIVE, 3))


def set_params(rig: Rig, **values: float) -> None:
    for name, v in values.items():
        rig.client.set_param(name, v)
    rig.tick(4)
    for name, v in values.items():
        assert rig.ob.params.get(name) == v, name


def test_gcs_loss_returns_when_asked_and_only_warns_by_default():
    rig = flying_rig()
    rig.tick(400, gcs_heartbeat)                      # a ground station is heard
    rig.tick(200 * 11)                                # then silent > COM_DL_LOSS_T (10 s)
    assert "GCS connection lost" in rig.texts() and rig.ob.mode_name == "AUTO.LOITER"
    rig.tick(400, gcs_heartbeat)
    assert "GCS connection regained" in rig.texts()
    set_params(rig, NAV_DLL_ACT=2)
    rig.tick(200 * 11)
    assert "Failsafe: GCS connection lost, returning" in rig.texts()
    assert rig.ob.mode_name == "AUTO.RTL"
    rig.run_until(lambda r: not r.ob.armed, 30.0)
    assert math.hypot(*pos(rig)[:2]) < 0.1


def test_gcs_loss_never_fires_without_a_ground_station():
    rig = flying_rig()
    set_params(rig, NAV_DLL_ACT=3)
    rig.tick(200 * 15)                                # the app's heartbeats are not a GCS's
    assert rig.ob.mode_name == "AUTO.LOITER"
    assert not [t for t in rig.texts() if "GCS" in t]


def test_battery_critical_returns_and_emergency_lands():
    rig = flying_rig()
    goto(rig, 3.0, 0.0, 1.0)
    rig.run_until(lambda r: math.dist(pos(r), (3.0, 0.0, -1.0)) < AT_M, 15.0)
    used = rig.ob.battery.consumed_mah
    # a small pack: 'low' soon, then 'critical' (return), then 'emergency' (land)
    set_params(rig, COM_LOW_BAT_ACT=3, BAT1_CAPACITY=round(used + 12.0))
    rig.run_until(lambda r: r.ob.mode_name == "AUTO.RTL", 60.0)
    texts = rig.texts()
    assert any(t.startswith("Battery low") for t in texts)
    assert "Failsafe: battery critical, returning" in texts
    rig.run_until(lambda r: r.ob.mode_name == "AUTO.LAND" or not r.ob.armed, 60.0)
    assert "Failsafe: battery emergency, landing" in rig.texts()
    rig.tick(410)                                      # BATTERY_STATUS: 0.5 Hz on GCS
    charge = rig.last("gcs", "BATTERY_STATUS").charge_state
    assert charge == M.MAV_BATTERY_CHARGE_STATE_EMERGENCY


def test_geofence_radius_returns_and_height_holds():
    rig = flying_rig()
    set_params(rig, GF_MAX_HOR_DIST=2.0, GF_ACTION=3)
    goto(rig, 4.0, 0.0, 1.0)
    rig.run_until(lambda r: r.ob.mode_name == "AUTO.RTL", 10.0)
    assert "Failsafe: geofence breached, returning" in rig.texts()
    assert 2.0 < pos(rig)[0] < 2.4
    rig.run_until(lambda r: not r.ob.armed, 30.0)
    rig = flying_rig()
    set_params(rig, GF_MAX_VER_DIST=1.5)                # GF_ACTION 2 (hold), PX4's default
    goto(rig, 0.0, 0.0, 3.0)
    rig.run_until(lambda r: "Failsafe: geofence breached, holding" in r.texts(), 10.0)
    rig.tick(600)
    assert rig.ob.mode_name == "AUTO.LOITER" and -pos(rig)[2] < 1.8
