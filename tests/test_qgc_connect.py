"""ACCEPTANCE: QGroundControl's connect sequence, played with pymavlink against `cosim sitl`.

What QGC (a desktop application, not run here) does on a new PX4 vehicle, in its order
(reference/mavlink.md, "What a ground station needs"): heartbeat from 255/190, AUTOPILOT_VERSION
by REQUEST_MESSAGE, PROTOCOL_VERSION by MAV_CMD_REQUEST_PROTOCOL_VERSION, the metadata it may
skip (COMPONENT_METADATA, AVAILABLE_MODES: UNSUPPORTED), the parameter list, mission, fence and
rally downloads (count 0, each acknowledged with MISSION_ACK as QGC does), HOME_POSITION by
MAV_CMD_GET_HOME_POSITION; meanwhile its GPS indicator needs GPS_RAW_INT with a fix, and
SYS_STATUS must not read as a geofence breach. On free loopback ports; every wait is bounded
and on what the vehicle sends, ~2 s.
"""

from __future__ import annotations

import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from sitl_proc import free_udp_port, sitl
from test_onboard_rig import Rig

from mav import wire

M = mavlink2
STEP_S = 15.0


class Gcs:
    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255,
                                               source_component=190)
        self.seen: dict[str, list] = {}

    def wait(self, cond, what: str, timeout_s: float = STEP_S):
        """Receive until cond(message) is true for one; returns it (all are kept in seen)."""
        end = time.monotonic() + timeout_s
        while True:
            left = end - time.monotonic()
            assert left > 0, f"vehicle: {what} not within {timeout_s} s"
            m = self.conn.recv_match(blocking=True, timeout=min(left, 0.2))
            if m is None:
                continue
            self.seen.setdefault(m.get_type(), []).append(m)
            if cond(m):
                return m

    def ack(self, command: int):
        return self.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command,
                         f"COMMAND_ACK {command}")

    def command(self, command: int, *params: float):
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        return self.ack(command)


def test_qgroundcontrol_connect_sequence(tmp_path):
    gcs_port = free_udp_port()
    g = Gcs(gcs_port)
    try:
        with sitl(tmp_path, gcs_port=gcs_port, speed=4.0):
            hb = g.wait(lambda m: m.get_type() == "HEARTBEAT", "heartbeat")
            assert (hb.autopilot, hb.type) == (M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_QUADROTOR)
            assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
            g.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                      M.MAV_STATE_ACTIVE)

            ack = g.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            assert ack.result == M.MAV_RESULT_ACCEPTED
            assert (ack.target_system, ack.target_component) == (255, 190)
            av = g.wait(lambda m: m.get_type() == "AUTOPILOT_VERSION", "AUTOPILOT_VERSION")
            assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2

            assert g.command(M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1).result == 0
            # pymavlink's dialects lack PROTOCOL_VERSION: it arrives as UNKNOWN_300
            pv = g.wait(lambda m: m.get_type() == "UNKNOWN_300", "PROTOCOL_VERSION")
            fields = wire.decode_fast(wire.PROTOCOL_VERSION, bytes(pv.get_msgbuf()))
            assert fields is not None and fields[:3] == (200, 100, 200)   # CRC_EXTRA 217 ok

            for msgid in (397, 435):               # COMPONENT_METADATA, AVAILABLE_MODES
                ack = g.command(M.MAV_CMD_REQUEST_MESSAGE, msgid)
                assert ack.result == M.MAV_RESULT_UNSUPPORTED          # QGC skips them

            g.conn.mav.param_request_list_send(1, 1)
            first = g.wait(lambda m: m.get_type() == "PARAM_VALUE", "PARAM_VALUE")
            n = first.param_count
            got = {first.param_index}
            g.wait(lambda m: m.get_type() == "PARAM_VALUE" and (got.add(m.param_index) or
                                                                len(got) == n), "all params")
            assert got == set(range(n)) and n > 30
            assert {m.param_count for m in g.seen["PARAM_VALUE"]} == {n}

            for mtype in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE,
                          M.MAV_MISSION_TYPE_RALLY):
                g.conn.mav.mission_request_list_send(1, 1, mtype)
                mc = g.wait(lambda m, t=mtype: m.get_type() == "MISSION_COUNT"
                            and m.mission_type == t, f"MISSION_COUNT type {mtype}")
                assert mc.count == 0 and (mc.target_system, mc.target_component) == (255, 190)
                g.conn.mav.mission_ack_send(1, 1, M.MAV_MISSION_ACCEPTED, mtype)

            assert g.command(M.MAV_CMD_GET_HOME_POSITION).result == M.MAV_RESULT_ACCEPTED
            home = g.wait(lambda m: m.get_type() == "HOME_POSITION", "HOME_POSITION")
            gps = g.wait(lambda m: m.get_type() == "GPS_RAW_INT", "GPS_RAW_INT")
            assert gps.fix_type == M.GPS_FIX_TYPE_3D_FIX and gps.satellites_visible >= 6
            assert abs(gps.lat - home.latitude) < 20 and abs(gps.lon - home.longitude) < 20
            gp = g.wait(lambda m: m.get_type() == "GLOBAL_POSITION_INT", "GLOBAL_POSITION_INT")
            assert abs(gp.lat - gps.lat) < 20 and abs(gp.alt - gps.alt) < 20      # one source
            ss = g.wait(lambda m: m.get_type() == "SYS_STATUS", "SYS_STATUS")
            fence = M.MAV_SYS_STATUS_GEOFENCE
            assert ss.onboard_control_sensors_health & fence               # no breach ...
            assert not ss.onboard_control_sensors_enabled & fence          # ... and no fence
            assert ss.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
            texts = [m.text for m in g.seen.get("STATUSTEXT", [])]
            assert not any("Unknown" in t or "rejected" in t for t in texts), texts
    finally:
        g.conn.close()


def test_the_same_sequence_in_mil_leaves_nothing_unhandled():
    rig = Rig()
    rig.tick()
    rig.send("gcs", M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                                M.MAV_STATE_ACTIVE, 3))
    for msgid in (M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 397, 435):
        rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, msgid)
    rig.cmd(M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1)
    rig.send("gcs", M.MAVLink_param_request_list_message(1, 1))
    for mtype in (0, 1, 2):
        rig.send("gcs", M.MAVLink_mission_request_list_message(1, 1, mtype))
        rig.send("gcs", M.MAVLink_mission_ack_message(1, 1, M.MAV_MISSION_ACCEPTED, mtype))
    rig.cmd(M.MAV_CMD_GET_HOME_POSITION)
    rig.tick(200)
    st = rig.ob.stats
    assert st["unhandled_msgs"] == 0 and st["unknown_msgs"] == 0 and st["handler_errors"] == 0
    assert len(rig.msgs("gcs", "PARAM_VALUE")) == len(rig.ob.params)
    assert [m.result for m in rig.msgs("gcs", "COMMAND_ACK")] == [0, 3, 3, 0, 0]
