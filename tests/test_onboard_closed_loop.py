"""Closed loop in MIL: FMU plant + onboard controller, commanded over MAVLink by OffboardClient.

arm, AUTO.TAKEOFF to 1 m, hold, OFFBOARD position square, velocity setpoints (world and body
frame), AUTO.LAND and auto-disarm, each with a stated tolerance.
"""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from cosim.plant.fmu import Y_VX, Y_VY, Y_X, Y_Y, Y_Z

M = mavlink2
HOLD_TOL_M = 0.05          # m, position hold after takeoff / at square corners
CORNER_TOL_M = 0.10        # m, a corner counts as reached
VEL_TOL_MPS = 0.10         # m/s, tracked velocity at the end of a velocity leg


def pos(rig: Rig) -> tuple[float, float, float]:
    y = rig.plant.y
    return y[Y_X], y[Y_Y], y[Y_Z]


def dist(a, b) -> float:
    return math.dist(a, b)


def takeoff_and_hold(rig: Rig, alt: float = 1.0) -> None:
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 2.0)
    c.arm()
    rig.run_until(lambda r: c.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) is not None, 0.5)
    assert c.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_ACCEPTED and c.armed
    c.takeoff(alt)
    rig.run_until(lambda r: c.ack(M.MAV_CMD_NAV_TAKEOFF) is not None, 0.5)
    assert c.ack(M.MAV_CMD_NAV_TAKEOFF) == M.MAV_RESULT_ACCEPTED
    rig.run_until(lambda r: c.mode == "AUTO.TAKEOFF" and c.landed_state == "TAKEOFF", 1.0)
    took = rig.run_until(lambda r: c.mode == "AUTO.LOITER" and c.landed_state == "IN_AIR", 8.0)
    assert took > alt / 1.0                          # climbed at TPL_TKO_SPEED, not a jump
    rig.tick(400)                                    # settle 2 s, then hold 3 s
    worst = 0.0
    for _ in range(600):
        rig.tick()
        worst = max(worst, dist(pos(rig), (0.0, 0.0, -alt)))
    assert worst < HOLD_TOL_M, f"hold error {worst:.3f} m"
    assert c.position == pytest.approx(pos(rig), abs=0.02)   # telemetry is the truth


def enter_offboard(rig: Rig, hold=(0.0, 0.0, -1.0)) -> None:
    c = rig.client

    def stream(r: Rig) -> None:
        if r.k % 4 == 0:
            c.set_position_target(*hold)

    rig.tick(240, stream)                            # 1.2 s of 50 Hz setpoints
    c.set_mode("OFFBOARD")
    rig.run_until(lambda r: c.mode == "OFFBOARD", 0.5, stream)
    assert c.ack(M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED


def land_and_disarm(rig: Rig) -> None:
    c = rig.client
    c.land()
    rig.run_until(lambda r: c.mode == "AUTO.LAND" and c.landed_state == "LANDING", 0.5)
    rig.run_until(lambda r: not c.armed, 12.0)
    assert c.landed_state == "ON_GROUND" and rig.u == (0.0, 0.0, 0.0, 0.0)
    assert pos(rig)[2] == pytest.approx(0.0, abs=0.02)
    texts = [t for _, _, t in c.statustext]
    assert "Touchdown" in texts and "Landing detected, disarmed" in texts


def test_mambo_mission_over_mavlink():
    rig = Rig(plant=True, client=True, decode=False)
    c = rig.client
    takeoff_and_hold(rig)
    enter_offboard(rig)
    # ---- 1 m square by position setpoints (50 Hz), each corner held 1 s
    for corner in ((1.0, 0.0, -1.0), (1.0, 1.0, -1.0), (0.0, 1.0, -1.0), (0.0, 0.0, -1.0)):
        def stream(r: Rig, corner=corner) -> None:
            if r.k % 4 == 0:
                c.set_position_target(*corner)

        rig.run_until(lambda r, corner=corner: dist(pos(r), corner) < CORNER_TOL_M, 6.0, stream)
        rig.tick(200, stream)
        assert dist(pos(rig), corner) < HOLD_TOL_M, corner
        assert c.position_target[:3] == pytest.approx(corner)      # what the vehicle flies
    # ---- velocity setpoints, world frame: 0.5 m/s north for 2 s, then stop
    x0 = pos(rig)[0]

    def north(r: Rig) -> None:
        if r.k % 4 == 0:
            c.set_velocity_target(0.5, 0.0, 0.0)

    rig.tick(400, north)
    y = rig.plant.y
    assert y[Y_VX] == pytest.approx(0.5, abs=VEL_TOL_MPS) and abs(y[Y_VY]) < VEL_TOL_MPS
    assert pos(rig)[0] - x0 == pytest.approx(0.85, abs=0.2)
    assert pos(rig)[2] == pytest.approx(-1.0, abs=HOLD_TOL_M)
    # ---- turn to face east (position + yaw), then 0.4 m/s forward in the BODY frame = east
    here = pos(rig)

    def face_east(r: Rig) -> None:
        if r.k % 4 == 0:
            c.set_position_target(*here, yaw=math.pi / 2)

    rig.tick(600, face_east)
    assert c.attitude[2] == pytest.approx(math.pi / 2, abs=0.05)

    def forward(r: Rig) -> None:
        if r.k % 4 == 0:
            c.set_velocity_target(0.4, 0.0, 0.0, frame="body")

    rig.tick(400, forward)
    y = rig.plant.y
    assert y[Y_VY] == pytest.approx(0.4, abs=VEL_TOL_MPS) and abs(y[Y_VX]) < VEL_TOL_MPS
    # ---- hold there and land
    stop = pos(rig)

    def hold(r: Rig) -> None:
        if r.k % 4 == 0:
            c.set_position_target(*stop)

    rig.tick(400, hold)
    land_and_disarm(rig)
    st = rig.ob.stats
    assert st["rejected_setpoints"] == 0 and st["handler_errors"] == 0
    assert st["dropped_bad_api"] == 0 and c.stats["dropped_bad"] == 0


def test_offboard_loss_in_flight_holds_then_lands():
    rig = Rig(plant=True, client=True, decode=False, failsafe_land_s=2.0)
    c = rig.client
    takeoff_and_hold(rig)
    enter_offboard(rig, hold=(0.5, 0.0, -1.0))

    def go(r: Rig) -> None:
        if r.k % 4 == 0:
            c.set_position_target(0.5, 0.0, -1.0)

    rig.tick(400, go)
    where = pos(rig)
    rig.run_until(lambda r: c.mode == "AUTO.LOITER", 1.2)      # COM_OF_LOSS_T = 1 s
    rig.tick(300)
    assert dist(pos(rig), where) < HOLD_TOL_M                    # holding where it was
    rig.run_until(lambda r: c.mode == "AUTO.LAND", 1.5)
    rig.run_until(lambda r: not c.armed, 10.0)
    assert pos(rig)[2] == pytest.approx(0.0, abs=0.02)


def test_bebop2_takeoff_hold_land():
    rig = Rig(plant=True, client=True, decode=False, vehicle="bebop2")
    takeoff_and_hold(rig, alt=1.5)
    land_and_disarm(rig)
