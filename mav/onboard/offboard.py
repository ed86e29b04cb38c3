"""Offboard control: SET_POSITION_TARGET_LOCAL_NED with PX4's type_mask rules, in LOCAL_NED
and BODY_NED, and the rule for when offboard setpoints count as a live stream."""

from __future__ import annotations

import math

from mav.onboard.commander import Commander
from mav.onboard.defs import (
    FRAME_BODY_NED,
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
    wrap_pi,
)
from mav.onboard.links import Chan, Outbox
from mav.onboard.status import VehicleStatus


class Offboard:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander, sysid: int,
                 compid: int) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.sysid, self.compid = sysid, compid

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

    def on_setpoint(self, ch: Chan, f: tuple) -> None:
        """SET_POSITION_TARGET_LOCAL_NED in wire order (see wire.py)."""
        (_, x, y, z, vx, vy, vz, _ax, _ay, _az, yaw, yaw_rate, mask, tsys, tcomp, frame) = f
        if tsys != self.sysid or tcomp not in (0, self.compid):
            return self.reject("target", f"setpoint for system {tsys}/{tcomp} rejected")
        if frame == FRAME_BODY_NED:
            mask |= IGN_X | IGN_Y | IGN_Z          # PX4: position is ignored in BODY_NED
        elif frame != FRAME_LOCAL_NED:
            return self.reject("frame", f"setpoint frame {frame} unsupported (1 or 8)")
        pxy = mask & (IGN_X | IGN_Y)
        vxy = mask & (IGN_VX | IGN_VY)
        use_pxy, use_vxy = pxy == 0, vxy == 0
        use_pz, use_vz = not mask & IGN_Z, not mask & IGN_VZ
        use_yaw, use_rate = not mask & IGN_YAW, not mask & IGN_YAW_RATE
        if (pxy not in (0, IGN_X | IGN_Y) or vxy not in (0, IGN_VX | IGN_VY)
                or not (use_pxy or use_vxy) or not (use_pz or use_vz)):
            return self.reject("mask", f"setpoint type_mask 0x{mask:04X} unsupported")
        if use_pxy and not (abs(x) <= SP_MAX_POS_M and abs(y) <= SP_MAX_POS_M) or (
                use_pz and not abs(z) <= SP_MAX_POS_M):
            return self.reject("range", "setpoint position not finite or out of range")
        if use_vxy and not (abs(vx) <= SP_MAX_VEL_MPS and abs(vy) <= SP_MAX_VEL_MPS) or (
                use_vz and not abs(vz) <= SP_MAX_VEL_MPS):
            return self.reject("range", "setpoint velocity not finite or out of range")
        if use_yaw and not abs(yaw) <= SP_MAX_YAW_RAD or (
                use_rate and not abs(yaw_rate) <= SP_MAX_YAW_RATE):
            return self.reject("range", "setpoint yaw not finite or out of range")
        if frame == FRAME_BODY_NED and use_vxy:
            yaw_now = self.cmd.heading()
            c, s = math.cos(yaw_now), math.sin(yaw_now)
            vx, vy = c * vx - s * vy, s * vx + c * vy
        vs = self.vs
        of = vs.of
        of.x = x if use_pxy else NAN
        of.y = y if use_pxy else NAN
        of.z = z if use_pz else NAN
        of.vx = vx if use_vxy else NAN
        of.vy = vy if use_vxy else NAN
        of.vz = vz if use_vz else NAN
        of.yaw = wrap_pi(yaw) if use_yaw else NAN
        of.yaw_rate = yaw_rate if use_rate else NAN
        vs.of_last_us = vs.t_us
        vs.stats["setpoints"] += 1

    def reject(self, kind: str, text: str) -> None:
        st = self.vs.stats
        st["rejected_setpoints"] += 1
        key = "sp_reject_" + kind
        st[key] = st.get(key, 0) + 1
        self.out.warn_rate_limited(kind, text)
