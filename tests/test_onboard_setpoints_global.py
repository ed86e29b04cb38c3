"""SET_POSITION_TARGET_GLOBAL_INT in OFFBOARD and the refusal of SET_ATTITUDE_TARGET (issue 13,
item 2): frames, the conversion through the origin GLOBAL_POSITION_INT is published with, the
offboard stream rule, and a closed-loop hold at the vehicle's own global position."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from cosim.plant.fmu import Y_X, Y_Y, Y_Z, Plant
from cosim.scenario.vehicles import get_vehicle
from mav import wire
from mav.onboard import OFFBOARD

M = mavlink2
POS_ONLY = 0x0DF8
START = (57.0, 95.0)          # world N, E of the start: the local frame's origin
ORIGIN = (42.299886, -71.350447, 71.3232)
QUANT_M = 0.012               # m: degE7 steps are 1.1 cm in latitude, 0.8 cm in longitude here


def global_sp(rig: Rig, lat: int, lon: int, alt: float, frame: int = M.MAV_FRAME_GLOBAL_INT,
              mask: int = POS_ONLY, yaw: float = 0.0, target: int = 1,
              link: str = "api") -> None:
    rig.send(link, M.MAVLink_set_position_target_global_int_message(
        rig.k * 5, target, 1, frame, mask, lat, lon, alt, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw,
        0.0))


def _rig_hovering_away_from_world_origin() -> Rig:
    rig = Rig()
    rig.odo[0:2] = START
    rig.tick()                               # origin and home at the start (floor, z = 0)
    rig.odo[0:3] = [START[0] + 1.3, START[1] + 1.7, -1.2]
    rig.tick(200)
    return rig


def test_global_setpoint_at_the_own_global_position_is_the_current_local_position():
    rig = _rig_hovering_away_from_world_origin()
    gp = rig.last("api", "GLOBAL_POSITION_INT")
    global_sp(rig, gp.lat, gp.lon, gp.alt / 1000.0)
    rig.tick()
    of = rig.ob.status.of
    s = rig.ob.state
    assert (s.x, s.y, s.z) == pytest.approx((1.3, 1.7, -1.2), abs=1e-4)   # from the start
    assert math.dist((of.x, of.y, of.z), (s.x, s.y, s.z)) < QUANT_M
    # the same through GLOBAL_RELATIVE_ALT_INT (above home)
    global_sp(rig, gp.lat, gp.lon, gp.relative_alt / 1000.0,
              frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    rig.tick()
    assert of.z == pytest.approx(-1.2, abs=1e-3)
    # a point 2 m north and 1 m east, 0.5 m higher, AMSL
    lat, lon, alt = wire.FlatEarth(*ORIGIN).to_geodetic(3.3, 2.7, -1.7)
    global_sp(rig, round(lat * 1e7), round(lon * 1e7), alt, mask=0x09F8, yaw=0.5)  # + yaw
    rig.tick()
    assert (of.x, of.y, of.z) == pytest.approx((3.3, 2.7, -1.7), abs=QUANT_M)
    assert of.yaw == pytest.approx(0.5) and math.isnan(of.vx)
    assert rig.ob.stats["setpoints"] == 3 and rig.ob.stats["rejected_setpoints"] == 0


def test_global_setpoints_feed_the_offboard_stream_rule():
    rig = _rig_hovering_away_from_world_origin()
    gp = rig.last("api", "GLOBAL_POSITION_INT")
    rig.set_mode(6)
    rig.tick()
    assert rig.ack(M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_TEMPORARILY_REJECTED   # no stream
    global_sp(rig, gp.lat, gp.lon, gp.alt / 1000.0)
    rig.set_mode(6)
    rig.tick()
    assert rig.ack(M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED and rig.ob.mode == OFFBOARD
    assert rig.ob.setpoint is rig.ob.status.of
    rig.tick(round(1.1 * 200))                    # silence > COM_OF_LOSS_T: the failsafe
    assert rig.ob.mode_name == "AUTO.LOITER"


@pytest.mark.parametrize("frame, words", [
    (M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, "terrain"),
    (M.MAV_FRAME_GLOBAL, "frame 0"),
    (M.MAV_FRAME_LOCAL_NED, "frame 1"),
])
def test_other_global_frames_are_refused_with_a_statustext(frame, words):
    rig = _rig_hovering_away_from_world_origin()
    gp = rig.last("api", "GLOBAL_POSITION_INT")
    for _ in range(40):                           # 40 ticks of 200 Hz: 0.2 s, one text
        global_sp(rig, gp.lat, gp.lon, 10.0, frame=frame)
        rig.tick()
    st = rig.ob.stats
    assert st["setpoints"] == 0 and st["rejected_setpoints"] == 40 and st["sp_reject_frame"] == 40
    texts = [t for t in rig.texts() if "GLOBAL_INT" in t]
    assert len(texts) == 1 and words in texts[0]
    assert math.isnan(rig.ob.status.of.x)          # never acted on


def test_bad_global_values_are_refused():
    rig = _rig_hovering_away_from_world_origin()
    gp = rig.last("api", "GLOBAL_POSITION_INT")
    global_sp(rig, 950_000_000, gp.lon, 70.0)                      # latitude > 90 deg
    global_sp(rig, gp.lat + 1_000_000, gp.lon, 70.0)               # 11 km away: out of range
    global_sp(rig, gp.lat, gp.lon, math.nan)                       # altitude not finite
    global_sp(rig, gp.lat, gp.lon, 70.0, target=7)                 # another system
    rig.tick()
    st = rig.ob.stats
    assert st["setpoints"] == 0 and st["sp_reject_range"] == 3 and st["sp_reject_target"] == 1


def test_attitude_targets_are_refused_counted_and_reported_not_silently_dropped():
    rig = Rig()
    rig.tick()
    for i in range(400):                           # 50 Hz for 2 s
        if i % 4 == 0:
            rig.send("api", M.MAVLink_set_attitude_target_message(
                i, 1, 1, 0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5))
        rig.tick()
    st = rig.ob.stats
    assert st["rejected_setpoints"] == 100 and st["sp_reject_attitude"] == 100
    assert st["setpoints"] == 0 and st["unhandled_msgs"] == 0
    texts = [t for t in rig.texts() if t.startswith("SET_ATTITUDE_TARGET")]
    assert len(texts) == 2                         # at once, then at most once a second
    assert "SET_POSITION_TARGET_LOCAL_NED" in texts[0] and "_GLOBAL_INT" in texts[0]
    rig.set_mode(6)                                # they are no offboard stream
    rig.tick()
    assert rig.ack(M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_TEMPORARILY_REJECTED


def test_closed_loop_global_setpoint_at_own_position_holds_and_moves():
    """FMU plant starting away from the world origin (so local != world): take off, stream
    GLOBAL_INT setpoints at the vehicle's own GLOBAL_POSITION_INT, OFFBOARD: it stays put;
    then a setpoint 1 m north by latitude: it goes there."""
    rig = Rig(plant=True, client=True, decode=False)
    rig.plant.close()
    rig.plant = Plant(get_vehicle("mambo"), x0=3.0, y0=-2.0)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen and not math.isnan(c.global_position[0]), 2.0)
    c.arm()
    c.takeoff(1.0)
    rig.run_until(lambda r: c.mode == "AUTO.LOITER" and c.landed_state == "IN_AIR", 10.0)
    rig.tick(400)
    gp = c.global_position
    world0 = (rig.plant.y[Y_X], rig.plant.y[Y_Y], rig.plant.y[Y_Z])
    assert math.dist(world0[:2], (3.0, -2.0)) < 0.05

    def stream(lat, lon, alt):
        def each(r: Rig) -> None:
            if r.k % 10 == 0:                      # 20 Hz
                r.client.link.send(wire.send_msg(r.client.mav, (
                    M.MAVLink_set_position_target_global_int_message(
                        r.k * 5, 1, 1, M.MAV_FRAME_GLOBAL_INT, POS_ONLY, lat, lon, alt,
                        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))))
        return each

    here = stream(round(gp[0] * 1e7), round(gp[1] * 1e7), gp[2])   # as GLOBAL_POSITION_INT
    rig.tick(40, here)
    c.set_mode("OFFBOARD")
    rig.run_until(lambda r: c.mode == "OFFBOARD", 0.5, here)
    worst = 0.0
    for _ in range(600):                           # 3 s
        rig.tick(1, here)
        worst = max(worst, math.dist((rig.plant.y[Y_X], rig.plant.y[Y_Y], rig.plant.y[Y_Z]),
                                     world0))
    assert worst < 0.03, f"drifted {worst:.3f} m from where it was"
    lat, lon, alt = wire.FlatEarth(*ORIGIN).to_geodetic(1.0, 0.0, world0[2])
    north = stream(round(lat * 1e7), round(lon * 1e7), alt)
    rig.run_until(lambda r: math.dist((r.plant.y[Y_X], r.plant.y[Y_Y]), (4.0, -2.0)) < 0.05,
                  6.0, north)
    assert rig.plant.y[Y_Z] == pytest.approx(world0[2], abs=0.05)
