"""Telemetry a ground station expects (issue 13, item 4): GPS_RAW_INT, PROTOCOL_VERSION,
ODOMETRY and HIGHRES_IMU, SYS_STATUS's geofence bits. MIL, fixed ODOMETRY sequences."""

from __future__ import annotations

import importlib.util
import math
import random

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from mav import wire
from mav.rotations import rotate_body_to_world

M = mavlink2
G = 9.81
START = (57.0, 95.0)          # world N, E of the start: the local frame's origin


def _rig_away_from_world_origin() -> Rig:
    rig = Rig()
    rig.odo[0:2] = START
    rig.tick()                 # the first ODOMETRY sets the origin (and home) here
    return rig


def _frames(rig: Rig, link: str, msgid: int) -> list[bytes]:
    """Every frame with this message id the vehicle sent on `link` (raw bytes)."""
    out = []
    for d in rig.raw[link]:
        i = 0
        while i < len(d):
            end = wire.frame_end(d, i)
            if end < 0:
                break
            if wire.msgid_of(d, i) == msgid:
                out.append(bytes(d[i:end]))
            i = end
    return out


# ------------------------------------------------------------------ GPS_RAW_INT
def test_gps_raw_int_streams_a_3d_fix_at_the_global_position():
    rig = _rig_away_from_world_origin()
    rig.odo[0:3] = [START[0] + 1.0, START[1] + 1.0, -2.0]
    rig.odo[7:10] = [1.0, 1.0, 0.0]          # 1.41 m/s towards north-east
    rig.tick(400)                            # 2 s
    for link in ("api", "gcs"):
        assert len(rig.msgs(link, "GPS_RAW_INT", 5000)) == 2    # 1 Hz on both links
    gps = rig.last("gcs", "GPS_RAW_INT")
    gp = rig.last("gcs", "GLOBAL_POSITION_INT")
    assert (gps.lat, gps.lon, gps.alt) == (gp.lat, gp.lon, gp.alt)   # one conversion
    lat, lon, alt = wire.FlatEarth(42.299886, -71.350447, 71.3232).to_geodetic(1.0, 1.0, -2.0)
    assert (gps.lat, gps.lon, gps.alt) == (round(lat * 1e7), round(lon * 1e7), round(alt * 1e3))
    assert gps.fix_type == M.GPS_FIX_TYPE_3D_FIX and 6 <= gps.satellites_visible < 255
    assert 0 < gps.eph <= 200 and 0 < gps.epv <= 200          # HDOP, VDOP <= 2
    assert gps.vel == round(math.hypot(1.0, 1.0) * 100) and gps.cog == 4500
    assert gps.h_acc > 0 and gps.v_acc > 0 and gps.alt_ellipsoid == gps.alt
    t_sent = [t for t, m in rig.rx["gcs"] if m is gps][0]
    assert gps.time_usec == t_sent                           # vehicle time of its tick


def test_gps_raw_int_course_unknown_at_rest_and_in_the_status_group():
    rig = _rig_away_from_world_origin()
    rig.tick(200)
    assert rig.last("gcs", "GPS_RAW_INT").cog == 65535 and rig.last("gcs", "GPS_RAW_INT").vel == 0
    # legacy REQUEST_DATA_STREAM: EXTENDED_STATUS carries it (as on ArduPilot) ...
    rig.send("gcs", M.MAVLink_request_data_stream_message(1, 1,
                                                          M.MAV_DATA_STREAM_EXTENDED_STATUS, 4, 1))
    rig.tick()
    t0 = rig.t_us
    rig.tick(200)
    assert len(rig.msgs("gcs", "GPS_RAW_INT", t0)) == 4
    # ... and ALL (what MAVProxy sends) leaves ODOMETRY and HIGHRES_IMU off
    rig.send("gcs", M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_ALL, 4, 1))
    rig.tick(200)
    assert rig.msgs("gcs", "ODOMETRY") == [] and rig.msgs("gcs", "HIGHRES_IMU") == []


# ------------------------------------------------------------------ PROTOCOL_VERSION
def test_protocol_version_on_request_protocol_version_and_request_message():
    rig = Rig()
    rig.tick()
    rig.cmd(M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1)
    rig.tick()
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, 300)
    rig.tick()
    acks = [(m.command, m.result) for m in rig.msgs("gcs", "COMMAND_ACK")]
    assert acks == [(M.MAV_CMD_REQUEST_PROTOCOL_VERSION, M.MAV_RESULT_ACCEPTED),
                    (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_RESULT_ACCEPTED)]
    frames = _frames(rig, "gcs", 300)
    assert len(frames) == 2 and _frames(rig, "api", 300) == []     # to the asking link only
    for f in frames:
        assert f[0] == wire.MAGIC_V2                               # MAVLink 2 only, by nature
        fields = wire.decode_fast(wire.PROTOCOL_VERSION, f)        # CRC checked with 217
        assert fields is not None and fields[:3] == (200, 100, 200)
        assert fields[3:] == (0,) * 16


_PROTOCOL_VERSION_XML = """<?xml version="1.0"?>
<mavlink>
  <version>3</version>
  <dialect>0</dialect>
  <messages>
    <message id="300" name="PROTOCOL_VERSION">
      <description>Version and capability of protocol version (MAVLink minimal.xml).</description>
      <field type="uint16_t" name="version">Currently active MAVLink version number * 100</field>
      <field type="uint16_t" name="min_version">Minimum MAVLink version supported</field>
      <field type="uint16_t" name="max_version">Maximum MAVLink version supported</field>
      <field type="uint8_t[8]" name="spec_version_hash">First 8 bytes of the git hash</field>
      <field type="uint8_t[8]" name="library_version_hash">First 8 bytes of the git hash</field>
    </message>
  </messages>
</mavlink>
"""


def test_protocol_version_layout_and_crc_extra_match_pymavlinks_generator(tmp_path):
    """pymavlink's generator (mavgen) on the message's XML definition gives the CRC_EXTRA and
    layout wire.py states, and its decoder reads our frame (pymavlink's shipped dialects lack
    PROTOCOL_VERSION, so a dialect that has it is generated here, from the definition)."""
    from pymavlink.generator import mavgen

    xml = tmp_path / "pv.xml"
    xml.write_text(_PROTOCOL_VERSION_XML)
    out = tmp_path / "pvdialect.py"
    opts = mavgen.Opts(str(out), wire_protocol="2.0", language="Python3", validate=False)
    assert mavgen.mavgen(opts, [str(xml)])
    spec = importlib.util.spec_from_file_location("pvdialect", out)
    dialect = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(dialect)
    cls = dialect.MAVLink_protocol_version_message
    assert cls.crc_extra == wire.PROTOCOL_VERSION.crc_extra == 217
    assert cls.unpacker.format == wire.PROTOCOL_VERSION.st.format
    rig = Rig()
    rig.tick()
    rig.cmd(M.MAV_CMD_REQUEST_PROTOCOL_VERSION)
    rig.tick()
    (frame,) = _frames(rig, "gcs", 300)
    msg = dialect.MAVLink(None).decode(bytearray(frame))
    assert msg.get_type() == "PROTOCOL_VERSION"
    assert (msg.version, msg.min_version, msg.max_version) == (200, 100, 200)
    assert list(msg.spec_version_hash) == [0] * 8 and msg.get_srcSystem() == 1
    # and it encodes what we send, byte for byte (same seq, ids, zero-trimming)
    mav = dialect.MAVLink(None, 1, 1)
    mav.seq = frame[4]
    assert cls(200, 100, 200, [0] * 8, [0] * 8).pack(mav) == frame


# ------------------------------------------------------------------ ODOMETRY, HIGHRES_IMU
def test_odometry_and_highres_imu_are_off_by_default_and_on_by_request():
    rig = _rig_away_from_world_origin()
    rig.odo[0:3] = [START[0] + 0.5, START[1] - 0.25, -1.0]
    rig.odo[7:13] = [0.3, -0.2, 0.1, 0.01, 0.02, 0.03]
    rig.tick(200)
    for link in ("api", "gcs"):
        assert rig.msgs(link, "ODOMETRY") == [] and rig.msgs(link, "HIGHRES_IMU") == []
    rig.cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ODOMETRY, 20000)     # 50 Hz
    rig.cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 10000)  # 100 Hz
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HIGHRES_IMU, link="api")
    rig.tick()
    assert [m.result for m in rig.msgs("gcs", "COMMAND_ACK")] == [0, 0]
    assert len(rig.msgs("api", "HIGHRES_IMU")) == 1
    t0 = rig.t_us
    rig.tick(200)
    assert len(rig.msgs("gcs", "ODOMETRY", t0)) == 50
    assert len(rig.msgs("gcs", "HIGHRES_IMU", t0)) == 100
    assert rig.msgs("api", "ODOMETRY") == []                 # the other link is unchanged
    od = rig.last("gcs", "ODOMETRY")
    lp = rig.last("gcs", "LOCAL_POSITION_NED")
    assert (od.x, od.y, od.z) == pytest.approx((lp.x, lp.y, lp.z)) == (0.5, -0.25, -1.0)
    assert (od.vx, od.vy, od.vz) == pytest.approx((0.3, -0.2, 0.1))
    assert (od.rollspeed, od.pitchspeed, od.yawspeed) == pytest.approx((0.01, 0.02, 0.03))
    assert (od.frame_id, od.child_frame_id) == (M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_NED)
    assert od.estimator_type == M.MAV_ESTIMATOR_TYPE_AUTOPILOT and od.quality == 100
    assert math.isnan(od.pose_covariance[0]) and math.isnan(od.velocity_covariance[0])
    assert od.time_usec == [t for t, m in rig.rx["gcs"] if m is od][0]
    # off again
    rig.cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ODOMETRY, -1)
    rig.tick()
    t0 = rig.t_us
    rig.tick(100)
    assert rig.msgs("gcs", "ODOMETRY", t0) == []


def _imu_after(rig: Rig, n: int = 1):
    rig.cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 5000)
    rig.tick(n)
    return rig.last("gcs", "HIGHRES_IMU")


def test_highres_imu_at_rest_reads_minus_g_in_body_axes():
    rig = Rig()
    rig.tick()
    imu = _imu_after(rig, 3)
    assert (imu.xacc, imu.yacc, imu.zacc) == pytest.approx((0.0, 0.0, -G), abs=1e-5)
    assert imu.fields_updated == 0x3F                       # accel and gyro, nothing else
    # rolled 30 deg right, pitched 10 deg up, heading 70 deg, at rest: f_B = R_BW (0, 0, -g)
    cr, sr = math.cos(math.radians(15)), math.sin(math.radians(15))
    cp, sp = math.cos(math.radians(5)), math.sin(math.radians(5))
    cy, sy = math.cos(math.radians(35)), math.sin(math.radians(35))
    q = (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
         cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)
    rig.odo[3:7] = list(q)
    rig.odo[10:13] = [0.1, -0.2, 0.3]
    imu = _imu_after(rig, 2)
    want = rotate_body_to_world(q[0], -q[1], -q[2], -q[3], 0.0, 0.0, -G)
    assert (imu.xacc, imu.yacc, imu.zacc) == pytest.approx(want, abs=1e-4)
    # roll right: gravity's body y component is -g sin(roll) cos(pitch) ... as an IMU reads it
    assert imu.yacc == pytest.approx(-G * math.sin(math.radians(30)) * math.cos(math.radians(10)),
                                     abs=1e-4)
    assert (imu.xgyro, imu.ygyro, imu.zgyro) == pytest.approx((0.1, -0.2, 0.3))


def test_highres_imu_accelerating_reads_the_acceleration_minus_gravity():
    rig = Rig()
    rig.tick()
    rig.cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 5000)

    def accelerate(r: Rig) -> None:          # 2 m/s^2 north, 1 m/s^2 up, level
        r.odo[7] += 2.0 * 0.005
        r.odo[9] -= 1.0 * 0.005

    rig.tick(20, accelerate)
    imu = rig.last("gcs", "HIGHRES_IMU")
    assert (imu.xacc, imu.yacc, imu.zacc) == pytest.approx((2.0, 0.0, -G - 1.0), abs=1e-4)
    rig.set_yaw(math.pi / 2)                 # heading east: north is body -y
    rig.tick(1)
    rig.tick(1, accelerate)
    imu = rig.last("gcs", "HIGHRES_IMU")
    assert (imu.xacc, imu.yacc, imu.zacc) == pytest.approx((0.0, -2.0, -G - 1.0), abs=1e-4)


# ------------------------------------------------------------------ SYS_STATUS
def test_sys_status_geofence_bits_do_not_read_as_a_breach():
    """MAVProxy's fence module (mavproxy_fence.py, handle_sys_status) starts `healthy = True`
    and says "fence breach" when a SYS_STATUS lacks the MAV_SYS_STATUS_GEOFENCE health bit;
    no fence here: not present, not enabled, healthy."""
    rig = Rig()
    rig.tick(201)
    for link in ("api", "gcs"):
        for ss in rig.msgs(link, "SYS_STATUS"):
            bit = M.MAV_SYS_STATUS_GEOFENCE
            assert ss.onboard_control_sensors_health & bit == bit
            assert ss.onboard_control_sensors_present & bit == 0
            assert ss.onboard_control_sensors_enabled & bit == 0
            assert ss.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK


def test_stream_schedule_emits_as_the_plain_loop():
    """Telemetry streams come off a heap (Telemetry._emit_due): the same streams at the same
    ticks, in list order, as the loop over every stream it replaced, under random rate
    changes (SET_MESSAGE_INTERVAL and REQUEST_DATA_STREAM set interval and next time, then
    recompute_due)."""
    from mav.onboard.channels import Chan, Stream
    from mav.onboard.telemetry import Telemetry

    def plain_loop(ch, t, log):          # the reference: what publish did before the heap
        due = 1 << 62
        for s in ch.streams:
            iv = s.interval_us
            if iv > 0:
                nxt = s.next_us
                if t >= nxt:
                    s.emit(ch)
                    nxt += iv
                    if nxt <= t:
                        nxt = t + iv
                    s.next_us = nxt
                if nxt < due:
                    due = nxt
        ch.next_due = due

    rng = random.Random(7)
    rates = [5000, 20000, 20000, 100000, 200000, 1000000, 2000000, -1, 333333, 7000]
    logs: dict[str, list] = {"heap": [], "loop": []}
    chans = {}
    for name in logs:
        ch = Chan(name, None, None, {})
        for i, iv in enumerate(rates):
            ch.streams.append(Stream(i, iv, lambda c, i=i, log=logs[name]: log.append(i)))
        chans[name] = ch
    for k in range(40000):
        t = k * 5000
        if rng.random() < 0.003:          # a client changes a rate
            i, iv = rng.randrange(len(rates)), rng.choice(rates + [1, 12345, 5000000])
            for ch in chans.values():
                ch.streams[i].interval_us, ch.streams[i].next_us = iv, t
                ch.recompute_due()
        for name, ch in chans.items():
            if t >= ch.next_due:
                logs[name].append(("t", t))
                if name == "heap":
                    Telemetry._emit_due(ch, t)
                else:
                    plain_loop(ch, t, logs[name])
        a, b = chans["heap"], chans["loop"]
        assert a.next_due == b.next_due, t
    assert logs["heap"] == logs["loop"] and len(logs["heap"]) > 50000
