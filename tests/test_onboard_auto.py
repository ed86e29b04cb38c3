"""The automatic modes in closed loop (MIL rig, FMU plant): go-to (DO_REPOSITION), speed
changes, RTL, missions flown from the ground, and POSCTL from MANUAL_CONTROL sticks.

Every check is on the plant's true state, with a stated tolerance."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from cosim.plant.fmu import Y_VX, Y_VY, Y_X, Y_Y, Y_Z

M = mavlink2
AT_M = 0.10            # m, a target counts as reached
LAND_TOL_M = 0.10      # m, landed this close to where it should


def pos(rig: Rig) -> tuple[float, float, float]:
    y = rig.plant.y
    return y[Y_X], y[Y_Y], y[Y_Z]


def speed(rig: Rig) -> float:
    y = rig.plant.y
    return math.hypot(y[Y_VX], y[Y_VY])


def flying_rig(alt: float = 1.0, **kw) -> Rig:
    rig = Rig(plant=True, client=True, **kw)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 2.0)
    c.arm()
    rig.tick(10)
    c.takeoff(alt)
    rig.run_until(lambda r: c.mode == "AUTO.LOITER", 10.0)
    rig.tick(200)
    return rig


def goto(rig: Rig, n: float, e: float, rel_alt: float, speed_mps: float = -1.0) -> None:
    lat, lon, _ = rig.ob.geo.to_int(n, e, 0.0)
    rig.cmd_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, speed_mps,
                M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0.0, math.nan, lat, lon, rel_alt)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_DO_REPOSITION) == M.MAV_RESULT_ACCEPTED


def upload(rig: Rig, items: list, link: str = "gcs", mission_type: int = 0) -> int:
    """The mission protocol's upload as a ground station runs it; returns MISSION_ACK.type."""
    rig.send(link, M.MAVLink_mission_count_message(1, 1, len(items), mission_type))
    served = 0
    for _ in range(400):
        rig.tick()
        reqs = rig.msgs(link, "MISSION_REQUEST_INT")
        for m in reqs[served:]:
            rig.send(link, items[m.seq])
        served = len(reqs)
        acks = rig.msgs(link, "MISSION_ACK")
        if acks:
            return acks[-1].type
    raise AssertionError("no MISSION_ACK")


def waypoint(rig: Rig, seq: int, n: float, e: float, rel_alt: float,
             cmd: int = M.MAV_CMD_NAV_WAYPOINT, p1: float = 0.0, p2: float = 0.0):
    lat, lon, _ = rig.ob.geo.to_int(n, e, 0.0)
    return M.MAVLink_mission_item_int_message(
        1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 1, p1, p2, 0.0, math.nan,
        lat, lon, rel_alt, 0)


def test_goto_flies_at_the_cruise_speed_and_change_speed_applies_in_flight():
    rig = flying_rig()
    vmax = [0.0]

    def peak(r: Rig) -> None:
        vmax[0] = max(vmax[0], speed(r))

    goto(rig, 4.0, 0.0, 1.2)
    assert rig.ob.mode_name == "AUTO.LOITER"
    t = rig.run_until(lambda r: math.dist(pos(r), (4.0, 0.0, -1.2)) < AT_M, 15.0, peak)
    fast = vmax[0]
    # TPL_XY_CRUISE 1 m/s (overshoot < 8 %), TPL_ACC_HOR 1 m/s^2: 4 m in about 5.5 s
    assert 0.95 < fast < 1.08 and 4.5 < t < 8.0, (fast, t)
    rig.cmd(M.MAV_CMD_DO_CHANGE_SPEED, 1, 0.4, -1)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_DO_CHANGE_SPEED) == M.MAV_RESULT_ACCEPTED
    rig.tick(400)
    vmax[0] = 0.0
    goto(rig, 0.0, 0.0, 1.2)
    t = rig.run_until(lambda r: math.dist(pos(r), (0.0, 0.0, -1.2)) < AT_M, 25.0, peak)
    assert 0.37 < vmax[0] < 0.47 and t > 9.0, (vmax[0], t)   # while turning round
    for bad in ((1, -5), (7, 1.0), (1, math.inf)):
        rig.cmd(M.MAV_CMD_DO_CHANGE_SPEED, *bad)
        rig.tick(2)
        assert rig.ack(M.MAV_CMD_DO_CHANGE_SPEED) == M.MAV_RESULT_DENIED


def test_reposition_refused_on_the_ground_and_with_bad_positions():
    rig = Rig(plant=True, client=True)
    rig.run_until(lambda r: r.client.heartbeat_seen, 2.0)
    goto_lat, goto_lon, _ = rig.ob.geo.to_int(1.0, 0.0, 0.0)
    rig.cmd_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, -1, 1, 0,
                math.nan, goto_lat, goto_lon, 1.0)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_DO_REPOSITION) == M.MAV_RESULT_DENIED
    assert "Reposition denied: not flying" in rig.texts()
    rig = flying_rig()
    far_lat = rig.ob.geo.to_int(20_000.0, 0.0, 0.0)[0]        # 20 km: out of reach
    for frame, lat in ((M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, far_lat),
                       (M.MAV_FRAME_BODY_FRD, goto_lat)):
        rig.cmd_int(M.MAV_CMD_DO_REPOSITION, frame, -1, 1, 0, math.nan, lat, goto_lon, 1.0)
        rig.tick(2)
        assert rig.ack(M.MAV_CMD_DO_REPOSITION) == M.MAV_RESULT_DENIED
    assert math.dist(pos(rig), (0.0, 0.0, -1.0)) < AT_M         # it did not move


def test_rtl_climbs_returns_descends_and_lands_at_home():
    rig = flying_rig(alt=1.0)
    goto(rig, 3.0, -2.0, 1.0)
    rig.run_until(lambda r: math.dist(pos(r), (3.0, -2.0, -1.0)) < AT_M, 15.0)
    rig.cmd(M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == M.MAV_RESULT_ACCEPTED
    assert rig.ob.mode_name == "AUTO.RTL"
    top = [0.0]
    where_top = [None]

    def track(r: Rig) -> None:
        if -pos(r)[2] > top[0]:
            top[0], where_top[0] = -pos(r)[2], pos(r)

    rig.run_until(lambda r: not r.ob.armed, 40.0, track)
    # RTL_RETURN_ALT 1.5 m: it climbed to 1.5 m before leaving (the top is near the start)
    assert top[0] == pytest.approx(1.5, abs=0.1)
    n, e, _ = pos(rig)
    assert math.hypot(n, e) < LAND_TOL_M and abs(pos(rig)[2]) < 0.02
    texts = rig.texts()
    assert texts.index("RTL: return at 1.5 m above home") < texts.index(
        "RTL: landing at home") < texts.index("Touchdown")
    # arming again in AUTO.RTL is refused, a new mode first
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_DENIED


def test_rtl_hovers_when_land_delay_is_minus_one():
    rig = flying_rig(alt=2.0)
    rig.client.set_param("RTL_LAND_DELAY", -1.0)
    rig.tick(4)
    rig.client.set_mode("AUTO.RTL")
    rig.tick(4)
    # already above RTL_RETURN_ALT: no climb; descends to RTL_DESCEND_ALT and waits there
    rig.tick(200 * 12)
    assert rig.ob.armed and rig.ob.mode_name == "AUTO.RTL"
    assert math.dist(pos(rig), (0.0, 0.0, -1.0)) < AT_M


def test_mission_from_the_ground_four_waypoints_then_land():
    rig = Rig(plant=True, client=True)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 2.0)
    corners = [(2.0, 0.0), (2.0, 2.0), (0.0, 2.0)]
    items = [waypoint(rig, i, n, e, 1.0, p1=1.0 if i == 1 else 0.0)
             for i, (n, e) in enumerate(corners)]
    items.append(waypoint(rig, 3, 0.0, 0.0, 1.0, cmd=M.MAV_CMD_NAV_LAND))
    assert upload(rig, items) == M.MAV_MISSION_ACCEPTED
    c.arm()
    rig.tick(10)
    rig.set_mode(4, 4)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED
    passed = {i: math.inf for i in range(3)}

    def closest(r: Rig) -> None:
        for i, (n, e) in enumerate(corners):
            passed[i] = min(passed[i], math.dist(pos(r), (n, e, -1.0)))

    rig.run_until(lambda r: not r.ob.armed, 60.0, closest)
    assert all(d < AT_M for d in passed.values()), passed
    assert [m.seq for m in rig.msgs("gcs", "MISSION_ITEM_REACHED")] == [0, 1, 2, 3]
    cur = rig.last("gcs", "MISSION_CURRENT")
    assert (cur.seq, cur.total, cur.mission_state) == (3, 4, 5)     # MISSION_STATE_COMPLETE
    assert math.hypot(*pos(rig)[:2]) < LAND_TOL_M
    texts = rig.texts()
    assert "Mission started" in texts and "Mission finished, landed" in texts


def test_mission_speed_item_loiter_and_rtl_item():
    rig = flying_rig(alt=1.0)
    items = [M.MAVLink_mission_item_int_message(1, 1, 0, M.MAV_FRAME_MISSION,
                                                M.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 1, 0.5, -1, 0,
                                                0, 0, 0.0, 0),
             waypoint(rig, 1, 3.0, 0.0, 1.0),
             waypoint(rig, 2, 3.0, 0.0, 1.0, cmd=M.MAV_CMD_NAV_LOITER_TIME, p1=2.0),
             M.MAVLink_mission_item_int_message(1, 1, 3, M.MAV_FRAME_MISSION,
                                                M.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 1, 0, 0, 0,
                                                0, 0, 0, 0.0, 0)]
    assert upload(rig, items) == M.MAV_MISSION_ACCEPTED
    vmax = [0.0]
    rig.client.set_mode("AUTO.MISSION")
    rig.run_until(lambda r: [m.seq for m in r.msgs("gcs", "MISSION_ITEM_REACHED")] == [1],
                  20.0, lambda r: vmax.__setitem__(0, max(vmax[0], speed(r))))
    assert 0.45 < vmax[0] < 0.55                                   # the speed item applied
    t_loiter = rig.t
    rig.run_until(lambda r: len(r.msgs("gcs", "MISSION_ITEM_REACHED")) == 2, 10.0)
    rig.run_until(lambda r: not r.ob.armed, 40.0)
    assert [m.seq for m in rig.msgs("gcs", "MISSION_ITEM_REACHED")] == [1, 2, 3]
    assert rig.t - t_loiter > 2.0
    assert math.hypot(*pos(rig)[:2]) < LAND_TOL_M


def test_posctl_sticks_take_off_fly_hold_and_land():
    rig = Rig(plant=True, client=True)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 2.0)
    sticks = [0, 0, 500, 0]

    def joystick(r: Rig) -> None:
        if r.k % 8 == 0:      # 25 Hz, as QGroundControl's virtual joystick
            r.send("gcs", M.MAVLink_manual_control_message(1, *sticks, 0))

    c.arm()
    rig.tick(100, joystick)
    assert rig.ob.mode_name == "POSCTL" and pos(rig)[2] == pytest.approx(0.0, abs=1e-3)
    sticks[2] = 900                                          # throttle up: take off
    rig.run_until(lambda r: pos(r)[2] < -1.0, 5.0, joystick)
    sticks[2] = 500                                          # centre: hold the height
    rig.tick(400, joystick)
    z_hold = pos(rig)[2]
    rig.tick(400, joystick)
    assert abs(pos(rig)[2] - z_hold) < 0.05 and rig.ob.landed_state == M.MAV_LANDED_STATE_IN_AIR
    sticks[0] = 1000                                         # full pitch forward: north
    rig.tick(600, joystick)
    assert 0.8 < rig.plant.y[Y_VX] < 1.2                      # TPL_VEL_MANUAL 1 m/s
    sticks[0] = 0
    rig.tick(600, joystick)
    held = pos(rig)
    rig.tick(400, joystick)
    assert math.dist(pos(rig), held) < 0.05 and held[0] > 2.0
    sticks[3] = 1000                                          # yaw right at MPC_MAN_Y_MAX
    rig.tick(100, joystick)
    assert rig.plant.y[Y_X] == pytest.approx(held[0], abs=0.1)
    sticks[3] = 0
    sticks[2] = 0                                            # throttle down: land, disarm
    rig.run_until(lambda r: not r.ob.armed, 15.0, joystick)
    assert pos(rig)[2] == pytest.approx(0.0, abs=0.02)
    assert "Touchdown" in rig.texts()


def test_posctl_sticks_silent_count_as_centred():
    rig = Rig(plant=True, client=True)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 2.0)
    c.arm()
    rig.tick(10)
    for _ in range(200):                     # 1 s of throttle up, then silence
        rig.send("gcs", M.MAVLink_manual_control_message(1, 0, 0, 900, 0, 0))
        rig.tick()
    rig.tick(200 * 4)
    z = pos(rig)[2]
    rig.tick(400)
    assert z < -0.2 and abs(pos(rig)[2] - z) < 0.05     # holds its height, no climb away
    rig.send("gcs", M.MAVLink_manual_control_message(2, 0, 0, 900, 0, 0))   # not for us
    rig.tick(2)
    assert rig.ob.stats["not_for_us"] >= 1
