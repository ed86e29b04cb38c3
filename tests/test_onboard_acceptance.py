"""ACCEPTANCE: a plain pymavlink ground station flies a simulated Mambo in SIL.

The onboard stack runs as its own process (`python -m mav.onboard`, ports chosen by the OS).
The test plays the simulator: it steps the FMU plant (cosim.plant.Plant) and exchanges
ODOMETRY / HIL_ACTUATOR_CONTROLS with the process over UDP, as fast as lockstep allows. The
ground station is `mavutil.mavlink_connection('udpin:127.0.0.1:PORT')` and uses only the
pymavlink API (param_fetch_all, command_long_send, set_mode, set_position_target_local_ned_send,
motors_armed, flightmode, messages). Written as a generator that yields once per simulator
tick, so the script reads like a blocking GCS script while the simulation stays in lockstep.

Mission: connect, read all parameters, arm, take off to 1 m (PX4 style: param7 AMSL), switch
to OFFBOARD, fly a 1 m square by position setpoints, then the same square by velocity
setpoints, land and see the vehicle disarm.
"""

from __future__ import annotations

import math
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import UdpSim

from cosim.sim.sil import OnboardProcess
from mav.links import UdpLink

M = mavlink2
POS_MASK = 0x0DF8                   # position only
VEL_MASK = 0x0DC7                   # velocity only
ALT_M = 1.0
SQUARE = ((1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0))
CORNER_TOL_M = 0.10                 # m, corner reached
VEL_LEG_S, VEL_MPS = 2.0, 0.5       # each velocity leg: 0.5 m/s for 2 s = 1 m
VEL_SQUARE_TOL_M = 0.25             # m, where the velocity square ends vs where it started


def gcs_script(gcs, sim: UdpSim, log: list[str]):
    """The ground station. Each `yield` lets the simulation advance one tick (5 ms)."""

    def wait(cond, timeout_s: float, what: str):
        end = sim.k + round(timeout_s * 200)
        while not cond():
            assert sim.k < end, f"GCS: {what} not within {timeout_s} s (t = {sim.t:.2f} s)"
            yield

    def sleep(seconds: float, every=None, period_s: float = 0.05):
        n = round(seconds * 200)
        k_every = round(period_s * 200)
        for i in range(n):
            if every is not None and i % k_every == 0:
                every()
            yield

    def msg(mtype: str):
        return gcs.messages.get(mtype)

    def ack_for(command: int):
        a = msg("COMMAND_ACK")
        return a.result if a is not None and a.command == command else None

    def command(command: int, *params: float) -> None:
        gcs.messages.pop("COMMAND_ACK", None)
        p = list(params) + [0.0] * (7 - len(params))
        gcs.mav.command_long_send(1, 1, command, 0, *p)

    def local():
        m = msg("LOCAL_POSITION_NED")
        return (m.x, m.y, m.z)

    def setpoint(mask: int, x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0) -> None:
        gcs.mav.set_position_target_local_ned_send(
            int(sim.t * 1000), 1, 1, M.MAV_FRAME_LOCAL_NED, mask, x, y, z, vx, vy, vz,
            0, 0, 0, 0, 0)

    # ---- connect: heartbeat, identity, parameters
    yield from wait(lambda: msg("HEARTBEAT") is not None, 2.0, "heartbeat")
    hb = msg("HEARTBEAT")
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4 and hb.type == M.MAV_TYPE_QUADROTOR
    gcs.target_system, gcs.target_component = hb.get_srcSystem(), hb.get_srcComponent()
    gcs.param_fetch_all()
    yield from wait(lambda: msg("PARAM_VALUE") is not None
                    and len(gcs.params) == msg("PARAM_VALUE").param_count, 3.0, "parameters")
    log.append(f"{sim.t:6.2f} s  read {len(gcs.params)} parameters")
    assert gcs.params["MIS_TAKEOFF_ALT"] == 1.0 and "COM_OF_LOSS_T" in gcs.params
    yield from wait(lambda: msg("HOME_POSITION") is not None
                    and msg("GLOBAL_POSITION_INT") is not None, 3.0, "home position")
    home_amsl = msg("HOME_POSITION").altitude * 1e-3

    # ---- arm and take off (PX4: param7 is AMSL)
    command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    yield from wait(lambda: ack_for(400) is not None, 0.5, "arm ack")
    assert ack_for(400) == M.MAV_RESULT_ACCEPTED
    yield from wait(gcs.motors_armed, 1.0, "armed heartbeat")
    command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, home_amsl + ALT_M)
    yield from wait(lambda: ack_for(22) is not None, 0.5, "takeoff ack")
    assert ack_for(22) == M.MAV_RESULT_ACCEPTED
    yield from wait(lambda: gcs.flightmode == "LOITER"
                    and msg("EXTENDED_SYS_STATE").landed_state == M.MAV_LANDED_STATE_IN_AIR,
                    8.0, "takeoff complete")
    yield from sleep(2.0)
    rel = msg("GLOBAL_POSITION_INT").relative_alt * 1e-3
    assert abs(rel - ALT_M) < 0.05, rel
    log.append(f"{sim.t:6.2f} s  hovering at {rel:.3f} m")

    # ---- OFFBOARD: stream first, then switch (pymavlink's PX4 mode helper)
    hold = local()
    yield from sleep(1.5, lambda: setpoint(POS_MASK, *hold))
    gcs.messages.pop("COMMAND_ACK", None)
    gcs.set_mode("OFFBOARD")
    yield from wait(lambda: ack_for(176) is not None, 0.5, "mode ack")
    assert ack_for(176) == M.MAV_RESULT_ACCEPTED
    yield from wait(lambda: gcs.flightmode == "OFFBOARD", 1.0, "OFFBOARD heartbeat")

    # ---- 1 m square by position setpoints (20 Hz), each corner held 1 s
    for cx, cy in SQUARE:
        corner = (cx, cy, -ALT_M)

        def go(corner=corner) -> None:
            setpoint(POS_MASK, *corner)

        yield from sleep(0.05, go)
        end = sim.k + 8 * 200
        while math.dist(local(), corner) > CORNER_TOL_M:
            assert sim.k < end, f"corner {corner} not reached"
            if sim.k % 10 == 0:
                go()
            yield
        yield from sleep(1.0, go)
        assert math.dist(sim.pos, corner) < 0.05, (corner, sim.pos)
        target = msg("POSITION_TARGET_LOCAL_NED")           # what the vehicle flies
        assert (target.x, target.y, target.z) == corner
        log.append(f"{sim.t:6.2f} s  corner {corner} reached, error "
                   f"{math.dist(sim.pos, corner):.3f} m")

    # ---- the same square by velocity setpoints: N, E, S, W at 0.5 m/s for 2 s each
    start = sim.pos
    for vx, vy in ((VEL_MPS, 0.0), (0.0, VEL_MPS), (-VEL_MPS, 0.0), (0.0, -VEL_MPS)):
        yield from sleep(VEL_LEG_S, lambda vx=vx, vy=vy: setpoint(VEL_MASK, vx=vx, vy=vy))
        v = msg("LOCAL_POSITION_NED")
        assert abs(v.vx - vx) < 0.1 and abs(v.vy - vy) < 0.1, (v.vx, v.vy)
    yield from sleep(1.0, lambda: setpoint(VEL_MASK))
    err = math.dist(sim.pos[:2], start[:2])
    assert err < VEL_SQUARE_TOL_M and abs(sim.pos[2] + ALT_M) < 0.05, sim.pos
    log.append(f"{sim.t:6.2f} s  velocity square closed within {err:.3f} m")

    # ---- land
    command(M.MAV_CMD_NAV_LAND)
    yield from wait(lambda: ack_for(21) is not None, 0.5, "land ack")
    assert ack_for(21) == M.MAV_RESULT_ACCEPTED
    yield from wait(lambda: gcs.flightmode == "LAND", 1.0, "LAND heartbeat")
    yield from wait(lambda: not gcs.motors_armed(), 10.0, "disarmed after landing")
    assert msg("EXTENDED_SYS_STATE").landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert abs(sim.pos[2]) < 0.02
    log.append(f"{sim.t:6.2f} s  landed and disarmed at {sim.pos[0]:.2f}, {sim.pos[1]:.2f}")


@pytest.mark.flight
def test_pymavlink_gcs_flies_a_sil_mambo(tmp_path):
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255,
                                     source_component=190)
    gcs_port = gcs.port.getsockname()[1]
    api_sink = UdpLink(("127.0.0.1", 0))           # no app in this run: a quiet API peer
    log: list[str] = []
    wall0 = time.perf_counter()
    with OnboardProcess("mambo", api_sink.local_address, ("127.0.0.1", gcs_port),
                        tmp_path / "onboard.log", hil_timeout_s=5.0) as proc:
        sim = UdpSim(proc.ports["hil"], vehicle="mambo")
        try:
            for _ in gcs_script(gcs, sim, log):
                sim.tick()
                while gcs.recv_match(blocking=False) is not None:   # mavutil stores them
                    pass
                while api_sink.recv() is not None:
                    pass
        finally:
            sim.close()
            gcs.close()
            api_sink.close()
    wall = time.perf_counter() - wall0
    print("\n".join(log) + f"\n{sim.t:.1f} s of flight in {wall:.1f} s wall "
          f"({sim.t / wall:.0f}x real time)")
    text = (tmp_path / "onboard.log").read_text()
    assert "exit 0" in text and "handler_errors" not in text
