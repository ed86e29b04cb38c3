"""The onboard vehicle's MAVLink behaviour, driven in-process with a fixed ODOMETRY sequence."""

from __future__ import annotations

import math

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from mav import wire
from mav.onboard import (
    CAPABILITIES,
    IN_AIR,
    LAND,
    LOITER,
    OFFBOARD,
    ON_GROUND,
    POSCTL,
    TAKEOFF,
    OnboardConfig,
)

M = mavlink2
POS_ONLY, VEL_ONLY, POS_VEL = 0x0DF8, 0x0DC7, 0x0DC0
VEL_YAW, VEL_YAW_RATE = 0x09C7, 0x05C7


def stream_setpoints(rig: Rig, seconds: float, hz: float = 20.0, mask: int = POS_ONLY,
                     **kw) -> None:
    every = max(1, round(200 / hz))
    n = round(seconds * 200)
    for i in range(n):
        if i % every == 0:
            rig.setpoint(mask, **kw)
        rig.tick()


# ------------------------------------------------------------------ lockstep & HIL contract
def test_poll_touches_nothing_without_hil():
    rig = Rig()
    rig.tick(2)
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    for _ in range(5):
        assert rig.ob.poll() is False
    assert rig.ob.stats["rx_gcs"] == 0 and not rig.ob.armed     # still queued
    rig.tick()
    assert rig.ob.armed and rig.ob.stats["rx_gcs"] == 1


def test_hil_answer_fields_and_mode():
    rig = Rig()
    rig.tick(2)
    a = rig.answers[-1]         # wire order: time_usec, flags, controls[16], mode
    assert a[1] == 1 and a[-1] == M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED     # lockstep, disarmed
    assert a[2:18] == (0.0,) * 16
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick()
    assert rig.answers[-1][-1] == M.MAV_MODE_FLAG_SAFETY_ARMED | M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert all(0.0 < u < 1.0 for u in rig.u)          # armed on the ground: idle speed


@pytest.mark.parametrize("bad", [
    b"", b"\x00" * 40, b"\xfd\x05", b"garbage" * 10,
])
def test_malformed_hil_is_counted_and_not_answered(bad):
    rig = Rig()
    rig.tick()
    rig.hil.send(bad)
    assert rig.ob.poll() is False
    assert rig.hil.recv() is None
    assert rig.ob.stats["dropped_bad_hil"] == 1
    rig.tick()                                      # and the next valid one is answered


def test_hil_bad_crc_nonfinite_and_other_messages():
    rig = Rig()
    good = bytearray(wire.encode_odometry(rig.sim, 0, *rig.odo))
    good[20] ^= 0xFF                                # payload corrupted: CRC fails
    rig.hil.send(bytes(good))
    assert rig.ob.poll() is False
    nan_odo = list(rig.odo)
    nan_odo[2] = math.nan
    rig.hil.send(wire.encode_odometry(rig.sim, 0, *nan_odo))
    assert rig.ob.poll() is False
    rig.hil.send(wire.send_msg(rig.sim, M.MAVLink_heartbeat_message(1, 8, 0, 0, 0, 3)))
    assert rig.ob.poll() is False
    assert rig.hil.recv() is None
    st = rig.ob.stats
    assert (st["dropped_bad_hil"], st["hil_bad_values"], st["hil_ignored"]) == (1, 1, 1)


def test_body_frd_child_frame_velocity_is_rotated():
    rig = Rig()
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))     # heading east
    rig.hil.send(wire.encode_odometry(rig.sim, 0, 0.0, 0.0, -1.0, *q, 1.0, 0.0, 0.0, 0, 0, 0,
                                      child_frame_id=M.MAV_FRAME_BODY_FRD))
    assert rig.ob.poll()
    s = rig.ob.state
    assert (s.vx, s.vy, s.vz) == pytest.approx((0.0, 1.0, 0.0), abs=1e-6)


def test_clock_advances_only_on_hil():
    rig = Rig()
    rig.k = 1000                                      # start at t = 5 s
    rig.tick(3)
    assert rig.ob.t == pytest.approx(5.010)
    assert rig.last("api", "ATTITUDE").time_boot_ms == 5000


# ------------------------------------------------------------------ identity & heartbeat
def test_heartbeat_identity_rate_and_mode_strings():
    rig = Rig()
    rig.tick(600)                                     # 3 s
    hbs = rig.msgs("gcs", "HEARTBEAT")
    assert len(hbs) == 3 and len(rig.msgs("api", "HEARTBEAT")) == 3
    hb = hbs[0]
    assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode == M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.system_status == M.MAV_STATE_STANDBY
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert mavutil.mode_string_v10(hb) == "POSCTL"
    names = {}
    for main, sub, want in ((4, 2, "TAKEOFF"), (4, 3, "LOITER"), (4, 6, "LAND"),
                            (3, 0, "POSCTL")):
        rig.set_mode(main, sub)
        rig.tick()
        names[want] = mavutil.mode_string_v10(rig.last("gcs", "HEARTBEAT"))
        assert rig.last("gcs", "HEARTBEAT").custom_mode == main << 16 | sub << 24
    assert names == {"TAKEOFF": "TAKEOFF", "LOITER": "LOITER", "LAND": "LAND",
                     "POSCTL": "POSCTL"}
    stream_setpoints(rig, 1.2)
    rig.set_mode(6)
    rig.setpoint(POS_ONLY)
    rig.tick()
    hb = rig.last("gcs", "HEARTBEAT")
    assert mavutil.mode_string_v10(hb) == "OFFBOARD"
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.setpoint(POS_ONLY)
    rig.tick()
    hb = rig.last("gcs", "HEARTBEAT")                 # sent at once on arm / mode change
    assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == M.MAV_STATE_ACTIVE


def test_autopilot_version_and_qgc_connect_sequence():
    rig = Rig()
    rig.tick()
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    rig.cmd(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, 397)          # COMPONENT_METADATA: not here
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, 435)          # AVAILABLE_MODES: not here
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION)
    rig.send("gcs", M.MAVLink_param_request_list_message(1, 1))
    for mtype in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE,
                  M.MAV_MISSION_TYPE_RALLY):
        rig.send("gcs", M.MAVLink_mission_request_list_message(1, 1, mtype))
    rig.cmd(M.MAV_CMD_PREFLIGHT_CALIBRATION)          # anything else: UNSUPPORTED
    rig.tick(20)
    acks = [(m.command, m.result) for m in rig.msgs("gcs", "COMMAND_ACK")]
    assert acks == [
        (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_RESULT_ACCEPTED),
        (M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, M.MAV_RESULT_ACCEPTED),
        (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_RESULT_UNSUPPORTED),
        (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_RESULT_UNSUPPORTED),
        (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_RESULT_ACCEPTED),
        (M.MAV_CMD_PREFLIGHT_CALIBRATION, M.MAV_RESULT_UNSUPPORTED),
    ]
    assert all(m.target_system == 255 and m.target_component == 190
               for m in rig.msgs("gcs", "COMMAND_ACK"))
    av = rig.msgs("gcs", "AUTOPILOT_VERSION")
    assert len(av) == 2 and av[0].capabilities == CAPABILITIES
    assert av[0].capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert av[0].capabilities & M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    assert av[0].capabilities & M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    counts = rig.msgs("gcs", "MISSION_COUNT")
    assert [(m.count, m.mission_type) for m in counts] == [(0, 0), (0, 1), (0, 2)]
    assert counts[0].target_system == 255
    assert rig.msgs("api", "AUTOPILOT_VERSION") == []      # answers go to the asking link


def test_messages_for_other_systems_are_ignored():
    rig = Rig()
    rig.tick()
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=42)
    rig.send("gcs", M.MAVLink_param_request_list_message(42, 1))
    rig.tick(10)
    assert not rig.ob.armed and rig.msgs("gcs", "COMMAND_ACK") == []
    assert rig.msgs("gcs", "PARAM_VALUE") == []
    assert rig.ob.stats["not_for_us"] == 2


# ------------------------------------------------------------------ commands & modes
def test_arm_disarm_and_refusals():
    rig = Rig()
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)            # before any state: rejected
    rig.tick()
    assert rig.ack(400) == M.MAV_RESULT_TEMPORARILY_REJECTED and not rig.ob.armed
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick()
    assert rig.ack(400) == M.MAV_RESULT_ACCEPTED and rig.ob.armed
    assert rig.ob.home == (0.0, 0.0, 0.0)
    # in the air: disarm refused unless forced
    rig.odo[2] = -1.0
    rig.ob.status.landed_state = IN_AIR
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    rig.tick()
    assert rig.ack(400) == M.MAV_RESULT_DENIED and rig.ob.armed
    assert any("Disarming denied" in t for t in rig.texts())
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    rig.tick()
    assert rig.ack(400) == M.MAV_RESULT_ACCEPTED and not rig.ob.armed
    assert rig.u == (0.0, 0.0, 0.0, 0.0)
    # arming refused in AUTO.LAND
    rig.odo[2] = 0.0
    rig.ob.status.landed_state = ON_GROUND
    rig.cmd(M.MAV_CMD_NAV_LAND)
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick()
    assert rig.ob.mode == LAND and rig.ack(400) == M.MAV_RESULT_DENIED


def test_takeoff_altitude_conventions():
    rig = Rig()
    rig.tick()
    home_amsl = 71.3232
    cases = [
        ("long NaN -> MIS_TAKEOFF_ALT", lambda: rig.cmd(22, 0, 0, 0, math.nan, math.nan,
                                                        math.nan, math.nan), 1.0),
        ("long param7 AMSL", lambda: rig.cmd(22, 0, 0, 0, math.nan, 0, 0, home_amsl + 2.5), 2.5),
        ("int relative", lambda: rig.cmd_int(22, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, z=1.5), 1.5),
        ("int global AMSL", lambda: rig.cmd_int(22, M.MAV_FRAME_GLOBAL_INT, z=home_amsl + 1.7),
         1.7),
        # PX4: below home + MIS_TAKEOFF_ALT is raised to it (MAVProxy's `takeoff 1.2` sends
        # 1.2 in param7, an AMSL altitude far below home), not denied
        ("int AMSL 0.7 above home -> minimum", lambda: rig.cmd_int(
            22, M.MAV_FRAME_GLOBAL_INT, z=home_amsl + 0.7), 1.0),
        ("long param7 1.2 (MAVProxy) -> minimum", lambda: rig.cmd(22, 0, 0, 0, math.nan, 0, 0,
                                                                   1.2), 1.0),
    ]
    for what, send, rel in cases:
        rig.set_mode(3)
        send()
        rig.tick()
        assert rig.ack(22) == M.MAV_RESULT_ACCEPTED, what
        assert rig.ob.mode == TAKEOFF
        assert rig.ob.navigator.tko_z == pytest.approx(-rel, abs=1e-3), what
    assert any("Using minimum takeoff altitude: 1.00 m" in t for t in rig.texts())
    rig.set_mode(3)
    for bad in (home_amsl + 500.0, math.inf):
        rig.cmd(22, 0, 0, 0, math.nan, 0, 0, bad)
        rig.tick()
        assert rig.ack(22) == M.MAV_RESULT_DENIED and rig.ob.mode == POSCTL
    rig.cmd_int(22, M.MAV_FRAME_BODY_FRD, z=1.0)
    rig.tick()
    assert rig.ack(22) == M.MAV_RESULT_DENIED


def test_takeoff_before_arm_waits_and_yaw_param():
    rig = Rig()
    rig.tick()
    rig.cmd(22, 0, 0, 0, 90.0, math.nan, math.nan, math.nan)
    rig.tick(50)
    assert rig.ob.mode == TAKEOFF and rig.ob.landed_state == ON_GROUND
    assert rig.u == (0.0, 0.0, 0.0, 0.0)
    rig.cmd(400, 1)
    rig.tick()
    assert rig.ob.landed_state == M.MAV_LANDED_STATE_TAKEOFF
    assert rig.ob.setpoint.yaw == pytest.approx(math.pi / 2)
    assert rig.ob.setpoint.vz == -0.8          # the ramp climbs at TPL_TKO_SPEED (fed forward)
    assert min(rig.u) > 0.3


def test_do_set_mode_and_set_mode_message():
    rig = Rig()
    rig.tick()
    for main, sub, want in ((4, 3, LOITER), (3, 0, POSCTL), (4, 6, LAND), (4, 2, TAKEOFF)):
        rig.set_mode(main, sub)
        rig.tick()
        assert rig.ack(176) == M.MAV_RESULT_ACCEPTED and rig.ob.mode == want
    # MANUAL, ALTCTL, MISSION with no mission uploaded, an unknown main mode
    for main, sub in ((1, 0), (2, 0), (4, 4), (9, 0)):
        rig.set_mode(main, sub)
        rig.tick()
        assert rig.ack(176) == M.MAV_RESULT_DENIED and rig.ob.mode == TAKEOFF
    rig.cmd(176, 0, 3, 0)                                           # no CUSTOM flag
    rig.tick()
    assert rig.ack(176) == M.MAV_RESULT_DENIED
    # pymavlink's own helper (MAVProxy style): SET_MODE (#11) message
    rig.send("gcs", M.MAVLink_set_mode_message(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                               4 << 16 | 3 << 24))
    rig.tick()
    assert rig.ob.mode == LOITER
    rig.send("gcs", M.MAVLink_set_mode_message(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3 << 16))
    rig.tick()
    assert rig.ob.mode == POSCTL
    rig.cmd(M.MAV_CMD_NAV_LAND)
    rig.tick()
    assert rig.ack(21) == M.MAV_RESULT_ACCEPTED and rig.ob.mode == LAND


def test_land_on_the_ground_disarms_after_delay():
    rig = Rig()
    rig.tick()
    rig.cmd(400, 1)
    rig.tick()
    rig.cmd(21)
    rig.tick(int(0.5 * 200) - 2)
    assert rig.ob.armed
    rig.tick(4)
    assert not rig.ob.armed and "Landing detected, disarmed" in rig.texts()


# ------------------------------------------------------------------ telemetry
def test_stream_rates_and_set_message_interval():
    rig = Rig()
    rig.tick(200)                                    # 1 s
    counts = {n: len(rig.msgs("api", n)) for n in (
        "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "EXTENDED_SYS_STATE",
        "POSITION_TARGET_LOCAL_NED", "SYS_STATUS", "BATTERY_STATUS", "HEARTBEAT")}
    assert counts == {"ATTITUDE": 50, "LOCAL_POSITION_NED": 50, "GLOBAL_POSITION_INT": 10,
                      "EXTENDED_SYS_STATE": 5, "POSITION_TARGET_LOCAL_NED": 10,
                      "SYS_STATUS": 1, "BATTERY_STATUS": 1, "HEARTBEAT": 1}
    assert len(rig.msgs("gcs", "ATTITUDE")) == 20 and len(rig.msgs("gcs", "VFR_HUD")) == 4
    # per link: 10 Hz ATTITUDE on the GCS link, LOCAL_POSITION_NED off, GPI back to default
    rig.cmd(511, M.MAVLINK_MSG_ID_ATTITUDE, 100000)
    rig.cmd(511, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, -1)
    rig.cmd(511, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 0)
    rig.cmd(511, 12345, 1000)                         # not a stream here
    rig.cmd(510, M.MAVLINK_MSG_ID_ATTITUDE)
    rig.tick()
    assert [m.result for m in rig.msgs("gcs", "COMMAND_ACK")] == [0, 0, 0, 3, 0]
    assert rig.last("gcs", "MESSAGE_INTERVAL").interval_us == 100000
    t0 = rig.t_us
    rig.tick(200)
    assert len(rig.msgs("gcs", "ATTITUDE", t0)) == 10
    assert len(rig.msgs("gcs", "LOCAL_POSITION_NED", t0)) == 0
    assert len(rig.msgs("gcs", "GLOBAL_POSITION_INT", t0)) == 5
    assert len(rig.msgs("api", "ATTITUDE", t0)) == 50     # the other link is unchanged
    # legacy REQUEST_DATA_STREAM (MAVProxy): position group at 2 Hz, EXTRA2 off
    rig.send("gcs", M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_POSITION, 2,
                                                          1))
    rig.send("gcs", M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_EXTRA2, 0, 0))
    rig.tick()
    t0 = rig.t_us
    rig.tick(400)
    assert len(rig.msgs("gcs", "LOCAL_POSITION_NED", t0)) == 4
    assert len(rig.msgs("gcs", "VFR_HUD", t0)) == 0


def test_telemetry_values():
    rig = Rig()
    rig.tick()                                       # home at the origin
    rig.odo = [3.0, -4.0, -2.0, math.cos(0.25), 0.0, 0.0, math.sin(0.25), 1.0, -2.0, 0.5,
               0.1, 0.2, 0.3]
    rig.tick(60)
    lp = rig.last("api", "LOCAL_POSITION_NED")
    assert (lp.x, lp.y, lp.z, lp.vx, lp.vy, lp.vz) == pytest.approx(
        (3.0, -4.0, -2.0, 1.0, -2.0, 0.5))
    att = rig.last("api", "ATTITUDE")
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((0.0, 0.0, 0.5), abs=1e-6)
    assert (att.rollspeed, att.pitchspeed, att.yawspeed) == pytest.approx((0.1, 0.2, 0.3))
    gp = rig.last("gcs", "GLOBAL_POSITION_INT")
    lat, lon, alt = wire.FlatEarth(42.299886, -71.350447, 71.3232).to_geodetic(3.0, -4.0, -2.0)
    assert (gp.lat, gp.lon, gp.alt) == (round(lat * 1e7), round(lon * 1e7), round(alt * 1e3))
    assert gp.relative_alt == 2000 and (gp.vx, gp.vy, gp.vz) == (100, -200, 50)
    assert gp.hdg == round(math.degrees(0.5) * 100)
    assert gp.lat > 42.299886e7 and gp.lon < -71.350447e7      # north and west of the origin
    home = rig.last("gcs", "HOME_POSITION")
    assert (home.latitude, home.longitude, home.altitude) == (422998860, -713504470, 71323)
    ext = rig.last("api", "EXTENDED_SYS_STATE")
    assert ext.landed_state == M.MAV_LANDED_STATE_ON_GROUND
    ss = rig.last("gcs", "SYS_STATUS")
    assert ss.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
    assert 4000 < ss.voltage_battery < 4300 and ss.battery_remaining == 100
    bs = rig.last("gcs", "BATTERY_STATUS")
    assert bs.voltages[0] == ss.voltage_battery and bs.voltages[1] == 65535
    vfr = rig.last("gcs", "VFR_HUD")
    assert vfr.alt == pytest.approx(73.3232, abs=1e-4) and vfr.heading == 29


def test_battery_drains_faster_when_flying():
    rig = Rig()
    rig.tick()
    rig.ob.battery.step(60.0, 0, 0, 0, 0)
    idle = rig.ob.battery.consumed_mah
    rig.ob.battery.step(60.0, *(4 * [rig.ob.vehicle.u_hover]))
    hover = rig.ob.battery.consumed_mah - idle
    assert hover == pytest.approx(4.5 * 1000 / 60, rel=1e-6)   # preset hover current 4.5 A
    assert hover > 10 * idle
    v_idle = rig.ob.battery.voltage
    rig.ob.battery.step(0.005, 1, 1, 1, 1)
    assert rig.ob.battery.voltage < v_idle                 # sag under load


# ------------------------------------------------------------------ offboard setpoints
@pytest.mark.parametrize("mask,kw,want", [
    (POS_ONLY, dict(x=1, y=2, z=-3), dict(x=1, y=2, z=-3, vx=None, vz=None, yaw=None)),
    (VEL_ONLY, dict(vx=0.5, vy=-0.5, vz=0.2), dict(x=None, z=None, vx=0.5, vy=-0.5, vz=0.2)),
    (POS_VEL, dict(x=1, y=2, z=-3, vx=0.1, vy=0.2, vz=0.3),
     dict(x=1, y=2, z=-3, vx=0.1, vy=0.2, vz=0.3)),
    (VEL_YAW, dict(vx=1, yaw=1.0), dict(vx=1, yaw=1.0, yaw_rate=None)),
    (VEL_YAW_RATE, dict(vx=1, yaw_rate=0.5), dict(vx=1, yaw=None, yaw_rate=0.5)),
    (POS_ONLY & ~1024, dict(x=1, y=2, z=-1, yaw=7.0), dict(yaw=7.0 - 2 * math.pi)),
    (0x0C00, dict(x=1, y=2, z=-1), dict(x=1, vx=0.0)),    # acceleration used: ignored
    (0x0DFB, dict(z=-1.5), None),                          # z only: no horizontal -> rejected
])
def test_type_mask_semantics(mask, kw, want):
    rig = Rig()
    rig.tick()
    rig.setpoint(mask, **kw)
    rig.tick()
    of = rig.ob.status.of
    if want is None:
        assert rig.ob.stats["rejected_setpoints"] == 1
        return
    assert rig.ob.stats["setpoints"] == 1
    for k, v in want.items():
        got = getattr(of, k)
        if v is None:
            assert math.isnan(got), k
        else:
            assert got == pytest.approx(v), k


def test_body_ned_rotates_velocity_by_yaw_and_ignores_position():
    rig = Rig()
    rig.set_yaw(math.pi / 2)                      # heading east
    rig.tick()
    rig.setpoint(POS_VEL, x=5, y=5, z=-5, vx=1.0, vy=0.5, vz=-0.2,
                 frame=M.MAV_FRAME_BODY_NED)
    rig.tick()
    of = rig.ob.status.of
    assert math.isnan(of.x) and math.isnan(of.y) and math.isnan(of.z)
    assert (of.vx, of.vy, of.vz) == pytest.approx((-0.5, 1.0, -0.2), abs=1e-6)
    rig.setpoint(POS_ONLY, x=1, y=1, z=-1, frame=M.MAV_FRAME_BODY_NED)   # position only: empty
    rig.tick()
    assert rig.ob.stats["rejected_setpoints"] == 1


@pytest.mark.parametrize("kind,kw", [
    ("range", dict(mask=POS_ONLY, x=math.nan, y=0, z=-1)),
    ("range", dict(mask=POS_ONLY, x=0, y=math.inf, z=-1)),
    ("range", dict(mask=POS_ONLY, x=2e4, y=0, z=-1)),
    ("range", dict(mask=VEL_ONLY, vx=25.0)),
    ("range", dict(mask=VEL_YAW, vx=1.0, yaw=math.nan)),
    ("range", dict(mask=VEL_YAW_RATE, yaw_rate=100.0)),
    ("frame", dict(mask=POS_ONLY, frame=M.MAV_FRAME_GLOBAL_INT)),
    ("frame", dict(mask=POS_ONLY, frame=M.MAV_FRAME_LOCAL_OFFSET_NED)),
    ("mask", dict(mask=0x0FFF)),                                  # everything ignored
    ("mask", dict(mask=0x0DFA)),                                  # x without y
    ("mask", dict(mask=0x0E3F)),                                  # acceleration only
    ("target", dict(mask=POS_ONLY, target=7)),
])
def test_bad_setpoints_are_rejected_counted_and_reported_once(kind, kw):
    kw = dict(kw)            # the parameter is shared by the runs of each tick implementation
    rig = Rig()
    rig.tick()
    mask = kw.pop("mask")
    for _ in range(20):                  # 20 bad setpoints in 0.1 s: one STATUSTEXT
        rig.setpoint(mask, **kw)
        rig.tick()
    st = rig.ob.stats
    assert st["rejected_setpoints"] == 20 and st["sp_reject_" + kind] == 20
    assert st["setpoints"] == 0 and rig.ob.status.of_last_us < 0
    assert len([t for t in rig.texts("api")]) == 1
    assert all(math.isnan(v) for v in (rig.ob.status.of.x, rig.ob.status.of.vx))


def test_nan_in_ignored_fields_is_fine():
    rig = Rig()
    rig.tick()
    rig.setpoint(VEL_ONLY, x=math.nan, y=math.nan, z=math.nan, vx=1, vy=0, vz=0,
                 yaw=math.nan, yaw_rate=math.nan)
    rig.tick()
    assert rig.ob.stats["setpoints"] == 1


def test_setpoints_act_only_in_offboard():
    rig = Rig()
    rig.tick()
    rig.cmd(400, 1)
    rig.tick()
    rig.setpoint(POS_ONLY, x=3, y=3, z=-2)
    rig.tick()
    assert rig.ob.mode == POSCTL and rig.ob.setpoint.x == 0.0
    pt = rig.last("api", "POSITION_TARGET_LOCAL_NED")
    assert pt.x == 0.0 and pt.type_mask & 0x1C0 == 0x1C0


# ------------------------------------------------------------------ offboard entry & loss
@pytest.mark.parametrize("age_s,loss_s,ok", [
    (None, 1.0, False),     # no setpoint ever
    (0.005, 1.0, True),     # one setpoint just before the mode (MAVSDK's Offboard.start())
    (0.9, 1.0, True),
    (1.2, 1.0, False),      # older than COM_OF_LOSS_T
    (1.2, 2.0, True),       # ... which is the parameter
])
def test_offboard_entry_rule(age_s, loss_s, ok):
    """PX4 (offboardCheck.cpp): OFFBOARD is available while the newest setpoint is younger
    than COM_OF_LOSS_T; there is no minimum stream duration."""
    rig = Rig(offboard_loss_s=loss_s)
    rig.tick()
    if age_s is not None:
        rig.setpoint(POS_ONLY)
        rig.tick(round(age_s * 200))
    rig.set_mode(6)
    rig.tick()
    want = M.MAV_RESULT_ACCEPTED if ok else M.MAV_RESULT_TEMPORARILY_REJECTED
    assert rig.ack(176) == want
    assert (rig.ob.mode == OFFBOARD) == ok


def test_offboard_loss_failsafe_hold_then_land():
    rig = Rig(failsafe_land_s=2.0)
    rig.tick()
    rig.odo[2] = -1.0                      # pretend to fly at 1 m
    rig.ob.status.landed_state = IN_AIR
    rig.ob.status.armed = True
    stream_setpoints(rig, 1.2, 20, x=0.5, y=0.0, z=-1.0)
    rig.set_mode(6)
    stream_setpoints(rig, 1.0, 20, x=0.5, y=0.0, z=-1.0)
    rig.setpoint(POS_ONLY, x=0.5, y=0.0, z=-1.0)
    rig.tick()                             # the last setpoint
    assert rig.ob.mode == OFFBOARD and rig.ob.setpoint.x == 0.5
    rig.tick(199)                          # COM_OF_LOSS_T = 1 s: not yet
    assert rig.ob.mode == OFFBOARD
    rig.tick()
    assert rig.ob.mode == LOITER and rig.ob.status.fs_active
    assert (rig.ob.setpoint.x, rig.ob.setpoint.z) == (0.0, -1.0)   # hold where it is
    assert any("offboard setpoints lost" in t for t in rig.texts())
    stream_setpoints(rig, 0.5, 20)         # the stream coming back does not re-enter OFFBOARD
    assert rig.ob.mode == LOITER
    rig.tick(int(1.6 * 200))
    assert rig.ob.mode == LAND and rig.ob.landed_state == M.MAV_LANDED_STATE_LANDING
    assert any("landing" in t for t in rig.texts())


def test_failsafe_cancelled_by_mode_change():
    rig = Rig(failsafe_land_s=1.0)
    rig.tick()
    rig.ob.status.landed_state = IN_AIR
    stream_setpoints(rig, 1.2, 20)
    rig.set_mode(6)
    rig.setpoint(POS_ONLY)
    rig.tick(220)
    assert rig.ob.mode == LOITER
    rig.set_mode(3)
    rig.tick(400)
    assert rig.ob.mode == POSCTL


def test_arming_in_offboard_needs_the_stream():
    rig = Rig()
    rig.tick()
    stream_setpoints(rig, 1.2)
    rig.set_mode(6)
    rig.setpoint(POS_ONLY)
    rig.tick()
    rig.cmd(400, 1)
    rig.setpoint(POS_ONLY)
    rig.tick()
    assert rig.ob.armed and rig.ob.mode == OFFBOARD


# ------------------------------------------------------------------ parameters
def test_param_protocol_over_memory_links(tmp_path):
    rig = Rig()
    rig.tick()
    rig.send("gcs", M.MAVLink_param_request_list_message(1, 1))
    rig.tick(40)
    pv = rig.msgs("gcs", "PARAM_VALUE")
    n = len(rig.ob.params)
    assert len(pv) == n and n > 10
    assert sorted(m.param_index for m in pv) == list(range(n))
    assert {m.param_count for m in pv} == {n}
    int32 = {n for n in rig.ob.params.names() if rig.ob.params.spec(n).ptype == "INT32"}
    assert {m.param_id for m in pv if m.param_type == M.MAV_PARAM_TYPE_INT32} == int32
    assert all(m.param_type == M.MAV_PARAM_TYPE_REAL32 for m in pv if m.param_id not in int32)
    names = [m.param_id for m in pv]
    assert names == sorted(names) and "COM_OF_LOSS_T" in names and "MIS_TAKEOFF_ALT" in names
    ctrl_names = [s.name for s in rig.ob.status.ctrl.param_table()]
    assert set(ctrl_names) <= set(names)
    # read by name and by index
    rig.send("gcs", M.MAVLink_param_request_read_message(1, 1, b"TPL_LAND_SPEED", -1))
    idx = rig.ob.params.index("COM_OF_LOSS_T")
    rig.send("gcs", M.MAVLink_param_request_read_message(1, 1, b"", idx))
    rig.tick()
    a, b = rig.msgs("gcs", "PARAM_VALUE")[-2:]
    assert (a.param_id, a.param_value) == ("TPL_LAND_SPEED", pytest.approx(0.4))
    assert (b.param_id, b.param_index) == ("COM_OF_LOSS_T", idx)
    # set: takes effect at once, echoed on both links
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", 2.5,
                                                M.MAV_PARAM_TYPE_REAL32))
    name = ctrl_names[0]
    spec = rig.ob.status.ctrl.param_table()[0]
    new = (spec.default + spec.max) / 2 if spec.max > spec.default else spec.min
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, name.encode(), new,
                                                M.MAV_PARAM_TYPE_REAL32))
    rig.tick()
    assert rig.ob.status.of_loss_us == 2_500_000
    assert rig.ob.status.ctrl.get_param(name) == pytest.approx(new, rel=1e-6)
    for link in ("gcs", "api"):
        echo = [m for m in rig.msgs(link, "PARAM_VALUE") if m.param_id == "COM_OF_LOSS_T"]
        assert echo[-1].param_value == 2.5 and echo[-1].param_index == idx
    # bad values: STATUSTEXT and the unchanged value echoed
    for bad in (math.nan, 1e9, -5.0):
        rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", bad,
                                                    M.MAV_PARAM_TYPE_REAL32))
        rig.tick()
        assert rig.last("gcs", "PARAM_VALUE").param_value == 2.5
        assert "Param rejected" in rig.texts()[-1]
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9))
    rig.tick()
    assert rig.ob.stats["param_rejected"] == 4 and "Unknown parameter" in rig.texts()[-1]


def test_param_file_both_formats(tmp_path):
    f = tmp_path / "v.params"
    f.write_text("# QGC export\n1\t1\tMIS_TAKEOFF_ALT\t1.5\t9\n"
                 "TPL_LAND_SPEED 0.3  # plain\n\nSOME_PX4_PARAM 7\n")
    rig = Rig(param_file=str(f))
    assert rig.ob.params.get("MIS_TAKEOFF_ALT") == 1.5
    assert rig.ob.params.get("TPL_LAND_SPEED") == pytest.approx(0.3)
    assert "SOME_PX4_PARAM" in rig.ob.warnings[0]
    f.write_text("TPL_LAND_SPEED 99\n")
    with pytest.raises(ValueError, match="TPL_LAND_SPEED"):
        Rig(param_file=str(f))
    f.write_text("TPL_LAND_SPEED\n")
    with pytest.raises(ValueError, match=":1:"):
        Rig(param_file=str(f))


def test_config_validation():
    with pytest.raises(ValueError, match="vehicle"):
        OnboardConfig(vehicle="tello")
    with pytest.raises(ValueError, match="signing_key"):
        OnboardConfig(signing_key=b"short")
    with pytest.raises(ValueError, match="api_rates_hz.NOPE"):
        OnboardConfig(api_rates_hz={"NOPE": 1.0})
    with pytest.raises(ValueError, match="sysid"):
        OnboardConfig(sysid=0)


def test_custom_sysid_and_origin():
    rig = Rig(sysid=7, origin_lat_deg=47.0, origin_lon_deg=8.0, origin_alt_m=400.0)
    rig.tick()
    hb = rig.last("gcs", "HEARTBEAT")
    assert hb.get_srcSystem() == 7
    gp = rig.last("gcs", "GLOBAL_POSITION_INT")
    assert (gp.lat, gp.lon, gp.alt) == (470000000, 80000000, 400000)
    rig.cmd(400, 1, target=1)
    rig.cmd(400, 1, target=7)
    rig.tick()
    assert rig.ob.armed and len(rig.msgs("gcs", "COMMAND_ACK")) == 1


def test_timesync_ping_and_mission_clear():
    rig = Rig()
    rig.k = 200
    rig.tick()
    rig.send("gcs", M.MAVLink_timesync_message(0, 123456))
    rig.send("gcs", M.MAVLink_ping_message(99, 5, 0, 0))
    rig.send("gcs", M.MAVLink_mission_clear_all_message(1, 1, 0))
    rig.tick()
    ts = rig.last("gcs", "TIMESYNC")
    assert (ts.tc1, ts.ts1) == (1_000_000_000, 123456)
    ping = rig.last("gcs", "PING")
    assert (ping.time_usec, ping.seq, ping.target_system) == (99, 5, 255)
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_ACCEPTED


def test_deterministic_bytes_mil():
    def run() -> tuple[list[bytes], list[bytes], list[tuple]]:
        rig = Rig(decode=False)
        rig.tick()
        rig.cmd(400, 1)
        rig.cmd(22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
        rig.send("gcs", M.MAVLink_param_request_list_message(1, 1))
        rig.tick(400)
        return rig.raw["api"], rig.raw["gcs"], rig.answers

    assert run() == run()


def test_set_airframe_rebuilds_controller_and_keeps_user_params():
    rig = Rig()
    rig.tick()
    name = rig.ob.status.ctrl.param_table()[0].name
    spec = rig.ob.params.spec(name)
    new = spec.max if spec.max != spec.default else spec.min
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, name.encode(), new,
                                                M.MAV_PARAM_TYPE_REAL32))
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"TPL_LAND_SPEED", 0.25,
                                                M.MAV_PARAM_TYPE_REAL32))
    rig.tick()
    old_ctrl = rig.ob.status.ctrl
    heavier = rig.ob.vehicle.with_overrides(mass=0.07)
    rig.ob.set_airframe(heavier)
    assert rig.ob.status.ctrl is not old_ctrl and rig.ob.status.ctrl.vehicle.mass == 0.07
    assert rig.ob.params.get(name) == pytest.approx(new, rel=1e-6)
    assert rig.ob.params.get("TPL_LAND_SPEED") == pytest.approx(0.25)
    assert rig.ob.battery.u_hover == pytest.approx(heavier.u_hover)
    rig.tick()


def test_stream_rates_from_config():
    rig = Rig(api_rates_hz={"ATTITUDE": 100.0, "HEARTBEAT": 2.0}, gcs_rates_hz={})
    rig.tick(200)
    assert len(rig.msgs("api", "ATTITUDE")) == 100 and len(rig.msgs("api", "HEARTBEAT")) == 2
    assert len(rig.msgs("api", "LOCAL_POSITION_NED")) == 0
    assert rig.rx["gcs"] == [] or {m.get_type() for _, m in rig.rx["gcs"]} <= {"HOME_POSITION"}


def test_mavlink1_packets_are_understood():
    """mavutil talks MAVLink 1 until it has seen a MAVLink 2 packet."""
    rig = Rig()
    rig.tick()
    v1 = M.MAVLink(None, 255, 190)
    sp = M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, POS_ONLY, 1.0, 2.0, -1.0,
                                                         0, 0, 0, 0, 0, 0, 0, 0)
    rig.send_raw("api", sp.pack(v1, force_mavlink1=True))
    rig.send_raw("gcs", M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
                 .pack(v1, force_mavlink1=True))
    rig.tick()
    assert rig.ob.stats["setpoints"] == 1 and rig.ob.status.of.x == 1.0
    assert rig.ob.armed and rig.ob.stats["dropped_bad_api"] == 0


def test_long_statustexts_are_sent_in_chunks_and_short_ones_whole():
    """MAVLink 2 STATUSTEXT chunking (id, chunk_seq) instead of cutting at 50 characters."""
    rig = Rig()
    rig.tick()
    rig.clear()
    long = "Takeoff denied: altitude 512.3 m above home is more than the 100 m allowed here"
    rig.ob.outbox.statustext(long)
    rig.ob.outbox.statustext("short")
    rig.tick()
    msgs = rig.msgs("gcs", "STATUSTEXT")
    parts = [m for m in msgs if m.id != 0]
    assert len(parts) == 2 and parts[0].id == parts[1].id
    assert [m.chunk_seq for m in parts] == [0, 1]
    assert "".join(m.text for m in parts) == long
    assert [m.text for m in msgs if m.id == 0] == ["short"]
    rig.ob.outbox.statustext("x" * 50 + "y" * 50)                   # exactly two full chunks
    rig.tick()
    tail = [m for m in rig.msgs("gcs", "STATUSTEXT") if m.id not in (0, parts[0].id)]
    assert [len(m.text) for m in tail] == [50, 50, 0] and tail[0].id == parts[0].id + 1


def test_ftp_requests_get_an_immediate_nak():
    """MAVProxy first asks for @PARAM/param.pck over MAVLink FTP: NAK FileNotFound at once
    (no 5 s wait), with the reply's seq one more than the request's."""
    rig = Rig()
    rig.tick()
    rig.clear()
    name = b"@PARAM/param.pck?withdefaults=1"
    req = (41).to_bytes(2, "little") + bytes([0, 4, len(name), 0, 0, 0]) + bytes(4) + name
    rig.send("gcs", M.MAVLink_file_transfer_protocol_message(0, 1, 1, list(req.ljust(251,
                                                                                  b"\0"))))
    reset = (42).to_bytes(2, "little") + bytes([0, 2, 0, 0, 0, 0]) + bytes(4)
    rig.send("gcs", M.MAVLink_file_transfer_protocol_message(0, 1, 1, list(reset.ljust(251,
                                                                                    b"\0"))))
    rig.tick()
    nak, ack = (bytes(m.payload) for m in rig.msgs("gcs", "FILE_TRANSFER_PROTOCOL"))
    assert int.from_bytes(nak[0:2], "little") == 42 and nak[3] == 129 and nak[5] == 4
    assert nak[4] == 1 and nak[12] == 10                          # size 1, FileNotFound
    assert ack[3] == 128 and ack[5] == 2                          # ResetSessions: ACK
