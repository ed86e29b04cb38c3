"""Offboard control: SET_POSITION_TARGET_LOCAL_NED with PX4's type_mask rules, in LOCAL_NED
and BODY_NED, and as a relative move in BODY_OFFSET_NED (`moveby.py`);
SET_POSITION_TARGET_GLOBAL_INT turned into the same local setpoint; the refusal
of SET_ATTITUDE_TARGET; and the rule for when offboard setpoints count as a live stream."""

from __future__ import annotations

import math

import cython

from mav import wire
from mav.onboard.channels import Chan, Outbox
from mav.onboard.commander import Commander
from mav.onboard.defs import (
    FRAME_BODY_NED,
    FRAME_BODY_OFFSET_NED,
    FRAME_LOCAL_NED,
    IGN_VX,
    IGN_VY,
    IGN_VZ,
    IGN_X,
    IGN_Y,
    IGN_YAW,
    IGN_YAW_RATE,
    IGN_Z,
    NAN,
    SP_MAX_POS_M,
    SP_MAX_VEL_MPS,
    SP_MAX_YAW_RAD,
    SP_MAX_YAW_RATE,
    M,
)
from mav.onboard.moveby import MoveBy
from mav.onboard.status import VehicleStatus
from mav.rotations import wrap_pi
from mav.types import Setpoint

# a 200 Hz setpoint's constants as C values (compiled: on_setpoint checks it in C, not with
# a Python int or float made per comparison)
_IGN_VX = cython.declare(cython.long, IGN_VX)
_IGN_VY = cython.declare(cython.long, IGN_VY)
_IGN_VZ = cython.declare(cython.long, IGN_VZ)
_IGN_X = cython.declare(cython.long, IGN_X)
_IGN_Y = cython.declare(cython.long, IGN_Y)
_IGN_YAW_RATE = cython.declare(cython.long, IGN_YAW_RATE)
_IGN_YAW = cython.declare(cython.long, IGN_YAW)
_IGN_Z = cython.declare(cython.long, IGN_Z)
_FRAME_BODY_NED = cython.declare(cython.long, FRAME_BODY_NED)
_FRAME_BODY_OFFSET_NED = cython.declare(cython.long, FRAME_BODY_OFFSET_NED)
_FRAME_LOCAL_NED = cython.declare(cython.long, FRAME_LOCAL_NED)
_SP_MAX_POS_M = cython.declare(cython.double, SP_MAX_POS_M)
_SP_MAX_VEL_MPS = cython.declare(cython.double, SP_MAX_VEL_MPS)
_SP_MAX_YAW_RAD = cython.declare(cython.double, SP_MAX_YAW_RAD)
_SP_MAX_YAW_RATE = cython.declare(cython.double, SP_MAX_YAW_RATE)
_NAN = cython.declare(cython.double, NAN)

FRAME_GLOBAL_INT = M.MAV_FRAME_GLOBAL_INT                       # altitude AMSL
FRAME_GLOBAL_REL_ALT_INT = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT  # altitude above home
FRAME_GLOBAL_TERRAIN_ALT_INT = M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT


class Offboard:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander, sysid: int,
                 compid: int, geo: wire.FlatEarth | None = None) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.sysid, self.compid = sysid, compid
        self.geo = geo          # the flat-earth origin GLOBAL_POSITION_INT is published with
        self.moveby = MoveBy()  # the relative move in progress (BODY_OFFSET_NED setpoints)

    def handlers(self) -> dict:
        """The setpoint messages handled here besides the local one (decoded by pymavlink)."""
        return {
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT: self.on_global_setpoint_msg,
            M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET: self.on_attitude_target_msg,
        }

    def stream_ok(self) -> bool:
        # PX4 (commander, HealthAndArmingChecks/checks/offboardCheck.cpp): offboard is
        # available while the newest setpoint is younger than COM_OF_LOSS_T; no minimum
        # stream duration (MAVSDK's Offboard.start() sends one setpoint, then the mode).
        vs = self.vs
        return vs.t_us - vs.of_last_us <= vs.of_loss_us

    def on_setpoint_msg(self, ch: Chan, msg) -> None:
        """A SET_POSITION_TARGET_LOCAL_NED decoded by pymavlink (signed links, MAVLink 1)."""
        self.on_setpoint(ch, (msg.time_boot_ms, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz,
                              msg.afx, msg.afy, msg.afz, msg.yaw, msg.yaw_rate, msg.type_mask,
                              msg.target_system, msg.target_component, msg.coordinate_frame))

    @cython.locals(x=cython.double, y=cython.double, z=cython.double, vx=cython.double,
                   vy=cython.double, vz=cython.double, yaw=cython.double,
                   yaw_rate=cython.double, mask=cython.long, frame=cython.long,
                   pxy=cython.long, vxy=cython.long, use_pxy=cython.bint, use_vxy=cython.bint,
                   use_pz=cython.bint, use_vz=cython.bint, use_yaw=cython.bint,
                   use_rate=cython.bint, c=cython.double, s=cython.double, of=Setpoint,
                   vs=VehicleStatus)
    def on_setpoint(self, ch: Chan, f: tuple) -> None:
        """SET_POSITION_TARGET_LOCAL_NED in wire order (see wire.py)."""
        (_, x, y, z, vx, vy, vz, _ax, _ay, _az, yaw, yaw_rate, mask, tsys, tcomp, frame) = f
        if tsys != self.sysid or tcomp not in (0, self.compid):
            return self.reject("target", f"setpoint for system {tsys}/{tcomp} rejected")
        if frame == _FRAME_BODY_NED:
            mask |= _IGN_X | _IGN_Y | _IGN_Z          # PX4: position is ignored in BODY_NED
        elif frame == _FRAME_BODY_OFFSET_NED:
            return self.relative_move(x, y, z, yaw, mask)
        elif frame != _FRAME_LOCAL_NED:
            return self.reject("frame", f"setpoint frame {frame} unsupported (1, 8 or 9)")
        pxy = mask & (_IGN_X | _IGN_Y)
        vxy = mask & (_IGN_VX | _IGN_VY)
        use_pxy, use_vxy = pxy == 0, vxy == 0
        use_pz, use_vz = not mask & _IGN_Z, not mask & _IGN_VZ
        use_yaw, use_rate = not mask & _IGN_YAW, not mask & _IGN_YAW_RATE
        if (pxy not in (0, _IGN_X | _IGN_Y) or vxy not in (0, _IGN_VX | _IGN_VY)
                or not (use_pxy or use_vxy) or not (use_pz or use_vz)):
            return self.reject("mask", f"setpoint type_mask 0x{mask:04X} unsupported")
        if use_pxy and not (abs(x) <= _SP_MAX_POS_M and abs(y) <= _SP_MAX_POS_M) or (
                use_pz and not abs(z) <= _SP_MAX_POS_M):
            return self.reject("range", "setpoint position not finite or out of range")
        if use_vxy and not (abs(vx) <= _SP_MAX_VEL_MPS and abs(vy) <= _SP_MAX_VEL_MPS) or (
                use_vz and not abs(vz) <= _SP_MAX_VEL_MPS):
            return self.reject("range", "setpoint velocity not finite or out of range")
        if use_yaw and not abs(yaw) <= _SP_MAX_YAW_RAD or (
                use_rate and not abs(yaw_rate) <= _SP_MAX_YAW_RATE):
            return self.reject("range", "setpoint yaw not finite or out of range")
        if frame == _FRAME_BODY_NED and use_vxy:
            yaw_now = self.cmd.heading()
            c, s = math.cos(yaw_now), math.sin(yaw_now)
            vx, vy = c * vx - s * vy, s * vx + c * vy
        vs = self.vs
        self.moveby.stop()
        of = vs.of
        of.x = x if use_pxy else _NAN
        of.y = y if use_pxy else _NAN
        of.z = z if use_pz else _NAN
        of.vx = vx if use_vxy else _NAN
        of.vy = vy if use_vxy else _NAN
        of.vz = vz if use_vz else _NAN
        of.yaw = wrap_pi(yaw) if use_yaw else _NAN
        of.yaw_rate = yaw_rate if use_rate else _NAN
        vs.of_last_us = vs.t_us
        vs.stats["setpoints"] += 1

    def relative_move(self, x: float, y: float, z: float, yaw: float, mask: int) -> None:
        """MAV_FRAME_BODY_OFFSET_NED: a relative move of (x forward, y right, z down) in the
        heading frame from where the vehicle is now, and a heading change `yaw` (0 when
        ignored), as ArduPilot Copter takes the frame (GCS_Mavlink.cpp: offset rotated by the
        heading, added to the current position; yaw relative) and as Parrot's moveBy works.
        All three offsets are needed; velocities, accelerations and the yaw rate are
        ignored. A new move replaces the one in progress (`moveby.py`)."""
        if mask & (IGN_X | IGN_Y | IGN_Z):
            return self.reject("mask", f"setpoint type_mask 0x{mask:04X}: a relative move "
                                       "(frame 9) needs x, y and z")
        if not (abs(x) <= SP_MAX_POS_M and abs(y) <= SP_MAX_POS_M and abs(z) <= SP_MAX_POS_M):
            return self.reject("range", "setpoint position not finite or out of range")
        use_yaw = not mask & IGN_YAW
        if use_yaw and not abs(yaw) <= SP_MAX_YAW_RAD:
            return self.reject("range", "setpoint yaw not finite or out of range")
        vs = self.vs
        mb = self.moveby
        mb.start(vs.state, x, y, z, yaw if use_yaw else 0.0, vs.own)
        mb.step(0.0, vs.of)                    # the setpoint at once (the next tick flies it)
        vs.of_last_us = vs.t_us
        vs.stats["setpoints"] += 1

    def on_global_setpoint_msg(self, ch: Chan, msg) -> None:
        """SET_POSITION_TARGET_GLOBAL_INT, as PX4 takes it (mavlink_receiver.cpp,
        handle_message_set_position_target_global_int): lat/lon projected into the local frame
        about its reference (here the flat-earth origin GLOBAL_POSITION_INT is published with,
        so the vehicle's own GLOBAL_POSITION_INT is where it is); altitude AMSL in GLOBAL_INT,
        above home in GLOBAL_RELATIVE_ALT_INT; velocities NED, yaw and yaw rate as given. Then
        the very rules of SET_POSITION_TARGET_LOCAL_NED (type_mask, ranges, the stream).
        GLOBAL_TERRAIN_ALT_INT needs a terrain estimate (PX4 drops it without one; there is
        none here): refused with a STATUSTEXT, as any other frame."""
        frame = msg.coordinate_frame
        if frame == FRAME_GLOBAL_TERRAIN_ALT_INT:
            return self.reject("frame", "SET_POSITION_TARGET_GLOBAL_INT frame 11 (terrain) "
                                        "unsupported: no terrain estimate; use 5 or 6")
        if frame not in (FRAME_GLOBAL_INT, FRAME_GLOBAL_REL_ALT_INT):
            return self.reject("frame", f"SET_POSITION_TARGET_GLOBAL_INT frame {frame} "
                                        "unsupported (5 GLOBAL_INT or 6 RELATIVE_ALT)")
        mask = msg.type_mask
        x = y = z = math.nan
        if not mask & (IGN_X | IGN_Y):
            lat, lon = msg.lat_int, msg.lon_int
            if not (-900_000_000 <= lat <= 900_000_000 and -1_800_000_000 <= lon <= 1_800_000_000):
                return self.reject("range", "setpoint latitude/longitude out of range")
            x, y, _ = self.geo.to_ned(lat * 1e-7, lon * 1e-7, self.geo.alt0_m)
        if not mask & IGN_Z:
            if frame == FRAME_GLOBAL_INT:
                z = self.geo.alt0_m - msg.alt
            elif self.vs.home is not None:
                z = self.vs.home[2] - msg.alt
            else:
                return self.reject("range", "setpoint relative altitude: no home yet")
        self.on_setpoint(ch, (msg.time_boot_ms, x, y, z, msg.vx, msg.vy, msg.vz, msg.afx,
                              msg.afy, msg.afz, msg.yaw, msg.yaw_rate, mask, msg.target_system,
                              msg.target_component, FRAME_LOCAL_NED))

    def on_attitude_target_msg(self, ch: Chan, msg) -> None:
        """SET_ATTITUDE_TARGET: the controller takes position, velocity and yaw setpoints, not
        attitude and thrust, so it is refused, counted and reported at once (at most once a
        second), never silently dropped until the offboard failsafe fires."""
        if msg.target_system != self.sysid or msg.target_component not in (0, self.compid):
            return self.reject("target", f"setpoint for system {msg.target_system}/"
                                         f"{msg.target_component} rejected")
        self.reject("attitude", "SET_ATTITUDE_TARGET unsupported: send velocity or position "
                                "with SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT")

    def reject(self, kind: str, text: str) -> None:
        st = self.vs.stats
        st["rejected_setpoints"] += 1
        key = "sp_reject_" + kind
        st[key] = st.get(key, 0) + 1
        self.out.warn_rate_limited(kind, text)
