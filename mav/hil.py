"""The simulator's end of the HIL link: ODOMETRY out, HIL_ACTUATOR_CONTROLS in.

The simulator speaks as its own MAVLink system (SIM_SYSID, MAV_COMP_ID_SYSTEM_CONTROL), like
PX4 SITL's simulator bridge. ODOMETRY carries float position (world NED), the body->world
quaternion, world-NED velocity (child_frame_id = MAV_FRAME_LOCAL_NED) and body rates.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

SIM_SYSID = 250
SIM_COMPID = mavlink2.MAV_COMP_ID_SYSTEM_CONTROL
_NAN_COV = [math.nan] + [0.0] * 20


class HilSimulatorCodec:
    def __init__(self) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=SIM_SYSID, srcComponent=SIM_COMPID)
        self.mav.robust_parsing = True

    def encode_odometry(self, t_us: int, m: tuple[float, ...]) -> bytes:
        """m = (x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r), SI, NED/FRD."""
        msg = mavlink2.MAVLink_odometry_message(
            t_us, mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_LOCAL_NED,
            m[0], m[1], m[2], [m[3], m[4], m[5], m[6]], m[7], m[8], m[9], m[10], m[11], m[12],
            _NAN_COV, _NAN_COV, 0, mavlink2.MAV_ESTIMATOR_TYPE_NAIVE, 100,
        )
        return msg.pack(self.mav)

    def decode_actuators(self, data: bytes) -> tuple[int, float, float, float, float]:
        msg = self.mav.decode(bytearray(data))
        if msg.get_msgId() != mavlink2.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS:
            raise ValueError(f"expected HIL_ACTUATOR_CONTROLS, got {msg.get_type()}")
        c = msg.controls
        return msg.time_usec, c[0], c[1], c[2], c[3]
