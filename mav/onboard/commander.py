"""Commander: arming and disarming, modes and the rules for changing them, landed state, home.

A mode's entry actions set the setpoint that mode flies (the navigator runs the automatic
modes; the offboard part owns the offboard setpoint).
"""

from __future__ import annotations

import math

from mav.onboard.channels import Outbox
from mav.onboard.defs import (
    AIRBORNE_AGL_M,
    IN_AIR,
    LAND,
    LANDING,
    LOITER,
    MISSION,
    MODE_BY_PX4,
    MODE_NAMES,
    OFFBOARD,
    ON_GROUND,
    POSCTL,
    PX4_MAIN_AUTO,
    RTL,
    TAKEOFF,
    TAKING_OFF,
    M,
)
from mav.onboard.status import VehicleStatus
from mav.rotations import yaw_from_quat

# the modes that need a local position (PX4's mode requirements): denied while it is lost
NEEDS_POSITION = frozenset((POSCTL, TAKEOFF, LOITER, MISSION, RTL, OFFBOARD))


class Commander:
    def __init__(self, vs: VehicleStatus, outbox: Outbox) -> None:
        self.vs = vs
        self.out = outbox
        self.navigator = None      # set by the vehicle (mav.onboard.navigator.Navigator)
        self.offboard = None       # set by the vehicle (mav.onboard.offboard.Offboard)
        self.mission = None        # set by the vehicle (mav.onboard.mission.Mission)
        self.manual = None         # set by the vehicle (mav.onboard.manual.Manual)
        self.preflight = None      # () -> str | None: why arming must wait (set by the vehicle)

    # ------------------------------------------------------------------ state helpers
    def heading(self) -> float:
        """Heading (rad) of the current state; computed on demand, not every tick."""
        s = self.vs.state
        return yaw_from_quat(s.qw, s.qx, s.qy, s.qz)

    def hold_here(self) -> None:
        sp = self.vs.sp
        s = self.vs.state
        sp.clear()
        sp.x, sp.y, sp.z, sp.yaw = s.x, s.y, s.z, self.heading()

    def set_landed(self, ls: int) -> None:
        vs = self.vs
        if ls != vs.landed_state:
            vs.landed_state = ls
            vs.ext_now = True

    def agl(self) -> float:
        """Height above home, m (0 before there is a home)."""
        home = self.vs.home
        return home[2] - self.vs.state.z if home is not None else 0.0

    def motors_idle(self) -> bool:
        """Armed but on the ground in a mode that does not take off: idle speed (POSCTL takes
        off when the throttle stick asks to climb)."""
        vs = self.vs
        return vs.landed_state == ON_GROUND and (
            vs.mode in (LOITER, LAND, RTL) or vs.mode == POSCTL and not vs.man_climb)

    def set_home(self) -> None:
        s = self.vs.state
        self.vs.home = (s.x, s.y, s.z)
        self.vs.home_now = True

    # ------------------------------------------------------------------ modes
    def set_mode(self, mode: int) -> None:
        """Enter `mode` (already checked allowed). Entry actions set the mode's setpoint."""
        vs = self.vs
        prev = vs.mode
        vs.mode = mode
        vs.fs_active = False
        if mode != prev:
            vs.hb_now = True
        self.navigator.leg_active = False
        if mode in (POSCTL, LOITER):
            if prev != mode:
                self.hold_here()
                if mode == POSCTL:
                    self.manual.enter()
            if vs.landed_state in (TAKING_OFF, LANDING):
                self.set_landed(IN_AIR if self.agl() > AIRBORNE_AGL_M else ON_GROUND)
        elif mode == LAND:
            self.navigator.begin_land(vs.state.x, vs.state.y)
        elif mode == RTL:
            self.navigator.enter_rtl()
        elif mode == MISSION:
            self.mission.enter()
        elif mode == OFFBOARD:
            if vs.armed and vs.landed_state == ON_GROUND:
                vs.ctrl.reset()
            if vs.landed_state in (TAKING_OFF, LANDING):
                self.set_landed(IN_AIR)
        elif mode == TAKEOFF:
            self.navigator.enter_takeoff()
        if mode != OFFBOARD:
            self.offboard.moveby.stop()       # a relative move ends with offboard
        vs.setpoint = vs.of if mode == OFFBOARD else vs.sp

    def request_mode(self, base_mode: float, main: float, sub: float) -> int:
        """A PX4 custom mode (main, sub) asked by SET_MODE or MAV_CMD_DO_SET_MODE."""
        if not (math.isfinite(base_mode) and int(base_mode) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            self.out.statustext("Mode change denied: base_mode needs CUSTOM_MODE_ENABLED",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        key = (int(main) if math.isfinite(main) else -1, int(sub) if math.isfinite(sub) else -1)
        if key[0] != PX4_MAIN_AUTO and key[1] == -1:
            key = (key[0], 0)
        mode = MODE_BY_PX4.get(key)
        if mode is None:
            self.out.statustext(f"Mode change denied: mode {key[0]}/{key[1]} unsupported",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        return self.try_mode(mode)

    def position_denied(self, mode: int) -> bool:
        """Whether `mode` is refused because the position estimate is lost (PX4 refuses the
        modes that need a local position: hold, position, take-off, mission, return,
        offboard); says so."""
        if self.vs.pos_lost_us < 0 or mode not in NEEDS_POSITION:
            return False
        self.out.statustext(f"{MODE_NAMES[mode]} denied: no local position",
                            M.MAV_SEVERITY_CRITICAL)
        return True

    def try_mode(self, mode: int) -> int:
        vs = self.vs
        if mode == vs.mode:
            return M.MAV_RESULT_ACCEPTED
        if self.position_denied(mode):
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == OFFBOARD and not self.offboard.stream_ok():
            self.out.statustext("Switching to OFFBOARD denied: no setpoint stream",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == TAKEOFF:
            if not vs.have_state:
                return M.MAV_RESULT_TEMPORARILY_REJECTED
            return self.navigator.cmd_takeoff(math.nan, math.nan, None)
        if not vs.have_state:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == MISSION and not self.mission.can_start():
            return M.MAV_RESULT_DENIED
        self.set_mode(mode)
        return M.MAV_RESULT_ACCEPTED

    # ------------------------------------------------------------------ arming
    def arm(self) -> int:
        vs = self.vs
        if vs.armed:
            return M.MAV_RESULT_ACCEPTED
        if not vs.have_state:
            self.out.statustext("Arming denied: no position estimate yet",
                                M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        why = self.preflight() if self.preflight is not None else None
        if why:
            self.out.statustext(why if why.startswith("Preflight Fail") else
                                f"Arming denied: {why}", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_DENIED
        if vs.mode in (LAND, RTL):
            self.out.statustext(f"Arming denied: vehicle is in {MODE_NAMES[vs.mode]}",
                                M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_DENIED
        if vs.mode == MISSION and not self.mission.can_start():
            return M.MAV_RESULT_DENIED
        if vs.mode == OFFBOARD and not self.offboard.stream_ok():
            self.out.statustext("Arming denied: no offboard setpoints", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if vs.landed_state == ON_GROUND:
            self.set_home()
            if vs.mode == TAKEOFF:
                self.navigator.takeoff_from_here()
        vs.armed = True
        vs.ground_since = -1
        vs.ctrl.reset()
        vs.hb_now = True
        self.out.statustext("Armed", M.MAV_SEVERITY_INFO)
        return M.MAV_RESULT_ACCEPTED

    def disarm(self, text: str = "Disarmed") -> None:
        vs = self.vs
        if vs.armed:
            vs.armed = False
            vs.hb_now = True
            vs.ground_since = -1
            self.out.statustext(text, M.MAV_SEVERITY_INFO)
