"""mav.client.OffboardClient against a scripted vehicle (pymavlink on the other link end)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.client import OffboardClient
from mav.links import MemoryLink

M = mavlink2


class FakeVehicle:
    """The vehicle's end of the API link: sends what the test says, decodes what it gets."""

    def __init__(self, link: MemoryLink, sysid: int = 1, compid: int = 1, key=None) -> None:
        self.link = link
        self.mav = M.MAVLink(None, sysid, compid)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = 283996800 * 100000

    def send(self, msg) -> None:
        self.link.send(wire.send_msg(self.mav, msg))

    def received(self) -> list:
        out = []
        while (d := self.link.recv()) is not None:
            out.append(self.mav.decode(bytearray(d)))
        return out


@pytest.fixture
def pair():
    app_end, vehicle_end = MemoryLink.pair()
    return OffboardClient(app_end), FakeVehicle(vehicle_end)


def test_heartbeat_at_1hz_on_the_callers_clock(pair):
    c, v = pair
    for k in range(601):                   # 0 .. 3 s
        c.poll(k * 0.005)
    hbs = [m for m in v.received() if m.get_type() == "HEARTBEAT"]
    assert len(hbs) == 4
    hb = hbs[0]
    assert hb.type == M.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == M.MAV_AUTOPILOT_INVALID
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, M.MAV_COMP_ID_ONBOARD_COMPUTER)
    assert c.heartbeat_due(3.0) is False and c.heartbeat_due(4.0) is True
    assert c.poll(3.5) == 0                # nothing to read: returns at once


def test_commands_are_encoded_as_px4_expects(pair):
    c, v = pair
    c.arm()
    c.disarm()
    c.disarm(force=True)
    c.takeoff(1.5)
    c.land()
    c.set_mode("OFFBOARD")
    c.set_mode("AUTO.LOITER")
    c.set_mode("POSCTL")
    c.set_mode("AUTO.TAKEOFF")
    c.set_mode("AUTO.LAND")
    c.request_message(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    c.set_message_interval(M.MAVLINK_MSG_ID_ATTITUDE, 25.0)
    c.set_param("TPL_LAND_SPEED", 0.3)
    c.request_params()
    with pytest.raises(ValueError, match="unknown mode"):
        c.set_mode("ACRO!")
    msgs = v.received()
    cl = [m for m in msgs if m.get_type() == "COMMAND_LONG"]
    assert all((m.target_system, m.target_component) == (1, 1) for m in cl)
    assert [(m.command, m.param1, m.param2) for m in cl[:3]] == [
        (400, 1.0, 0.0), (400, 0.0, 0.0), (400, 0.0, 21196.0)]
    ci = [m for m in msgs if m.get_type() == "COMMAND_INT"][0]
    assert (ci.command, ci.frame, ci.z) == (22, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 1.5)
    assert cl[3].command == 21
    modes = [(int(m.param1), int(m.param2), int(m.param3)) for m in cl if m.command == 176]
    assert modes == [(1, 6, 0), (1, 4, 3), (1, 3, 0), (1, 4, 2), (1, 4, 6)]
    assert (cl[-2].command, cl[-2].param1) == (512, 148)
    assert (cl[-1].command, cl[-1].param1, cl[-1].param2) == (511, 30, 40000)
    ps = [m for m in msgs if m.get_type() == "PARAM_SET"][0]
    assert (ps.param_id, ps.param_value, ps.param_type) == ("TPL_LAND_SPEED", pytest.approx(0.3),
                                                             M.MAV_PARAM_TYPE_REAL32)
    assert [m.get_type() for m in msgs][-1] == "PARAM_REQUEST_LIST"


@pytest.mark.parametrize("call,frame,mask", [
    (lambda c: c.set_position_target(1, 2, -3), 1, 0x0DF8),
    (lambda c: c.set_position_target(1, 2, -3, yaw=0.5), 1, 0x09F8),
    (lambda c: c.set_position_target(1, 2, -3, vx=0.1, vy=0.2, vz=0.3), 1, 0x0DC0),
    (lambda c: c.set_position_target(1, 2, -3, vx=0.1, vy=0.2), 1, 0x0DE0),
    (lambda c: c.set_position_target(1, 2, -3, yaw_rate=0.2), 1, 0x05F8),
    (lambda c: c.set_velocity_target(0.5, 0, 0), 1, 0x0DC7),
    (lambda c: c.set_velocity_target(0.5, 0, 0, yaw=1.0), 1, 0x09C7),
    (lambda c: c.set_velocity_target(0.5, 0, 0, yaw_rate=0.3), 1, 0x05C7),
    (lambda c: c.set_velocity_target(0.5, 0, 0, frame="body"), 8, 0x0DC7),
])
def test_setpoint_masks_and_bytes(pair, call, frame, mask):
    c, v = pair
    c.t = 12.345
    call(c)
    data = v.link.recv()
    m = v.mav.decode(bytearray(data))
    assert m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
    assert (m.coordinate_frame, m.type_mask, m.target_system, m.target_component) == (
        frame, mask, 1, 1)
    assert m.time_boot_ms == 12345
    # the fast encoder produced exactly what pymavlink would
    ref = M.MAVLink(None, 1, M.MAV_COMP_ID_ONBOARD_COMPUTER)
    ref.seq = m.get_seq()
    assert M.MAVLink_set_position_target_local_ned_message(
        m.time_boot_ms, 1, 1, frame, mask, m.x, m.y, m.z, m.vx, m.vy, m.vz, m.afx, m.afy, m.afz,
        m.yaw, m.yaw_rate).pack(ref) == data
    with pytest.raises(ValueError, match="frame"):
        c.set_velocity_target(0, 0, 0, frame="global")


def test_telemetry_lands_in_attributes(pair):
    c, v = pair
    assert not c.heartbeat_seen and math.isnan(c.position[0])
    v.send(M.MAVLink_heartbeat_message(2, 12, 129, 4 << 16 | 3 << 24, 4, 3))
    v.send(M.MAVLink_extended_sys_state_message(0, M.MAV_LANDED_STATE_IN_AIR))
    v.send(M.MAVLink_local_position_ned_message(100, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3))
    v.send(M.MAVLink_attitude_message(100, 0.01, 0.02, 0.5, 0.1, 0.2, 0.3))
    v.send(M.MAVLink_global_position_int_message(100, 422998860, -713504470, 72323, 1000, 0, 0,
                                                 0, 0))
    v.send(M.MAVLink_home_position_message(422998860, -713504470, 71323, 0, 0, 0, [1, 0, 0, 0],
                                           0, 0, 0, 0))
    v.send(M.MAVLink_position_target_local_ned_message(100, 1, 0x0DF8, 1, 2, -1, 0, 0, 0, 0, 0,
                                                       0, 0, 0))
    v.send(M.MAVLink_sys_status_message(0, 0, 0, 0, 4100, 450, 87, 0, 0, 0, 0, 0, 0))
    v.send(M.MAVLink_statustext_message(4, b"Takeoff complete", 0, 0))
    v.send(M.MAVLink_command_ack_message(400, 0, 0, 0, 1, 191))
    v.send(M.MAVLink_param_value_message(b"TPL_LAND_SPEED", 0.4, 9, 42, 7))
    assert c.poll(2.0) == 11
    assert c.heartbeat_seen and c.armed and c.mode == "AUTO.LOITER"
    assert c.landed_state == "IN_AIR"
    assert c.position == pytest.approx((1, 2, -3)) and c.velocity == pytest.approx((.1, .2, .3))
    assert c.attitude == pytest.approx((0.01, 0.02, 0.5))
    assert c.global_position == pytest.approx((42.299886, -71.350447, 72.323, 1.0))
    assert c.home_global == pytest.approx((42.299886, -71.350447, 71.323))
    assert c.position_target[:3] == (1, 2, -1) and math.isnan(c.position_target[3])
    assert c.battery == pytest.approx((4.1, 4.5, 0.87))
    assert list(c.statustext) == [(2.0, 4, "Takeoff complete")]
    assert c.ack(400) == 0 and c.acks[400].t == 2.0
    assert c.params == {"TPL_LAND_SPEED": pytest.approx(0.4)} and c.param_count == 42
    c.arm()                                # a new command forgets its old ack
    assert c.ack(400) is None


def test_other_systems_and_garbage_are_ignored(pair):
    c, v = pair
    other = M.MAVLink(None, 9, 1)
    v.link.send(wire.send_msg(other, M.MAVLink_heartbeat_message(2, 12, 129, 6 << 16, 4, 3)))
    v.link.send(wire.send_msg(other, M.MAVLink_local_position_ned_message(0, 5, 5, 5, 0, 0, 0)))
    v.link.send(b"\x00\x01garbage")
    v.link.send(wire.send_msg(v.mav, M.MAVLink_heartbeat_message(2, 12, 1, 3 << 16, 3, 3))[:-3])
    c.poll(0.0)
    assert not c.heartbeat_seen and math.isnan(c.position[0])
    assert c.stats["dropped_bad"] == 2


def test_signed_client():
    key = bytes(range(100, 132))
    app_end, vehicle_end = MemoryLink.pair()
    c = OffboardClient(app_end, signing_key=key)
    v = FakeVehicle(vehicle_end, key=key)
    c.poll(1.0)
    c.arm()
    c.set_position_target(0, 0, -1)
    got = v.received()
    assert all(m.get_signed() for m in got) and len(got) == 3
    # signing timestamps come from the client clock: 2024-01-01 + t
    assert v.mav.signing.stream_timestamps[(0, 1, 191)] >= 283996800 * 100000 + 100000
    v.send(M.MAVLink_heartbeat_message(2, 12, 129, 6 << 16, 4, 3))
    unsigned = M.MAVLink(None, 1, 1)
    vehicle_end.send(wire.send_msg(unsigned, M.MAVLink_attitude_message(0, 9, 9, 9, 0, 0, 0)))
    c.poll(1.1)
    assert c.mode == "OFFBOARD" and math.isnan(c.attitude[0])
    assert c.stats["rejected_unsigned"] == 1
    with pytest.raises(ValueError, match="32"):
        OffboardClient(app_end, signing_key=b"x")


@pytest.mark.flight
def test_fast_telemetry_decode_matches_pymavlink(tmp_path):
    """Every datagram of a flight's API link into two clients, one with the fast decoder and
    one forced through pymavlink: the same telemetry attributes and counters throughout."""
    from pathlib import Path

    from cosim.load import load_scenario
    from cosim.outputs.tlog import read_tlog
    from cosim.sim.master import RunOptions, run_scenario

    root = Path(__file__).resolve().parent.parent
    res = run_scenario(load_scenario(root / "scenarios" / "scripted_square.toml"),
                       RunOptions(mode="mil"))
    path = tmp_path / "f.tlog"
    res.tlog.write(path)
    records = read_tlog(path)
    pairs = [MemoryLink.pair() for _ in range(2)]
    fast, slow = (OffboardClient(a) for a, _ in pairs)
    slow._fast_rx = None                          # pymavlink
    attrs = ("heartbeat_seen", "armed", "mode", "custom_mode", "system_status", "landed_state",
             "position", "velocity", "attitude", "rates", "global_position", "home",
             "position_target", "battery", "stats")
    kinds = set()
    for t_us, data in records:
        kinds.add(wire.msgid_of(data))
        for c, (_, peer) in zip((fast, slow), pairs, strict=True):
            peer.send(data)
            c.poll(t_us * 1e-6)
        for a in attrs:
            va, vb = getattr(fast, a), getattr(slow, a)
            assert repr(va) == repr(vb), (a, t_us, va, vb)
    assert {M.MAVLINK_MSG_ID_HEARTBEAT, M.MAVLINK_MSG_ID_SYS_STATUS,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
            M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED} <= kinds
    assert fast.armed is False and fast.heartbeat_seen and fast.stats["rx"] > 1000


def test_chunked_statustexts_are_joined(pair):
    c, v = pair
    text = "Takeoff denied: altitude 512.3 m above home is more than the 100 m allowed"
    for seq, i in enumerate(range(0, len(text), 50)):
        v.send(M.MAVLink_statustext_message(M.MAV_SEVERITY_WARNING, text[i:i + 50].encode(),
                                            7, seq))
    v.send(M.MAVLink_statustext_message(M.MAV_SEVERITY_INFO, b"short", 0, 0))
    c.poll(0.0)
    assert [s[2] for s in c.statustext] == [text, "short"]
