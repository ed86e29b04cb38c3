"""The simulator's end of the HIL link: ODOMETRY out, HIL_ACTUATOR_CONTROLS in.

The simulator speaks as its own MAVLink system (SIM_SYSID, MAV_COMP_ID_SYSTEM_CONTROL), like
PX4 SITL's simulator bridge. ODOMETRY carries float position (world NED), the body->world
quaternion, world-NED velocity (child_frame_id = MAV_FRAME_LOCAL_NED) and body rates.
Both directions use the fast codec of mav/wire.py (byte-identical to pymavlink's, tested).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from mav import wire

SIM_SYSID = 250
SIM_COMPID = mavlink2.MAV_COMP_ID_SYSTEM_CONTROL


class HilSimulatorCodec:
    def __init__(self) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=SIM_SYSID, srcComponent=SIM_COMPID)

    def encode_odometry(self, t_us: int, m: tuple[float, ...]) -> bytes:
        """m = (x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r), SI, NED/FRD."""
        return wire.encode_odometry(self.mav, t_us, *m, estimator_type=1, quality=100)

    def decode_actuators(self, data: bytes) -> tuple[int, float, float, float, float]:
        f = wire.decode_fast(wire.HIL_ACTUATOR_CONTROLS, data)
        if f is None:
            raise ValueError(f"not a valid HIL_ACTUATOR_CONTROLS frame ({len(data)} bytes)")
        return f[0], f[2], f[3], f[4], f[5]
