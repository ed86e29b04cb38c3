"""Navigator: the automatic modes' flight (take-off to a height, land and detect touchdown),
airborne detection and the disarm after landing. RTL and missions belong here too."""

from __future__ import annotations

import math

from mav.onboard.commander import Commander
from mav.onboard.defs import (
    AIRBORNE_AGL_M,
    IN_AIR,
    LAND_STALL_AFTER_US,
    LOITER,
    NAN,
    OFFBOARD,
    ON_GROUND,
    TAKEOFF,
    TAKING_OFF,
    TKO_ACCEPT_M,
    TKO_EASE_S,
    TKO_SETTLE_US,
    TKO_SNAP_M,
    TOUCH_AGL_M,
    TOUCH_STALL_US,
    TOUCH_TRIG_US,
    TOUCH_VZ_MPS,
    TOUCH_VZ_TAU_S,
    M,
)
from mav.onboard.links import Outbox
from mav.onboard.status import VehicleStatus


class Navigator:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander,
                 control_dt_s: float, origin_alt_m: float) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.dt = control_dt_s
        self.origin_alt_m = origin_alt_m
        # take-off: target (world NED m, rad) and the climbing reference
        self.tko_x = self.tko_y = self.tko_z = self.tko_yaw = 0.0
        self.tko_ramp_z = 0.0
        self.tko_started = False
        self.tko_ramp_done_us = -1
        # landing: touchdown detection timers (us, -1: not running)
        self.land_t0 = 0
        self.touch_since = -1
        self.stall_since = -1
        self.vz_f = 0.0          # m/s, low-passed vertical speed (TOUCH_VZ_TAU_S)
        self.t_f = -1            # us, when vz_f was last updated (-1: restart from vz)

    # ------------------------------------------------------------------ take-off
    def cmd_takeoff(self, yaw_deg: float, alt: float, frame: int | None) -> int:
        """MAV_CMD_NAV_TAKEOFF (param4 yaw deg, param7 altitude): climb above home."""
        vs = self.vs
        if not vs.have_state or vs.home is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if not vs.armed and vs.landed_state == ON_GROUND:
            self.cmd.set_home()
        home_n, home_e, home_d = vs.home
        home_amsl = self.origin_alt_m - home_d
        default = vs.own["MIS_TAKEOFF_ALT"]
        if isinstance(alt, float) and math.isnan(alt):
            rel = default
        elif frame is None or frame in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT):
            rel = alt - home_amsl            # PX4: param7 is AMSL
        elif frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            rel = alt
        else:
            self.out.statustext(f"Takeoff denied: frame {frame} unsupported",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        if not (math.isfinite(rel) and rel <= 100.0):
            self.out.statustext(f"Takeoff denied: altitude {rel:.1f} m above home > 100",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        if rel < default:
            # PX4 (Takeoff::set_takeoff_position): an altitude below home + MIS_TAKEOFF_ALT is
            # raised to it, with a critical message when more than 0.1 m below. MAVProxy's
            # `takeoff 1.2` sends 1.2 in param7, an AMSL altitude: it climbs MIS_TAKEOFF_ALT.
            if rel < default - 0.1:
                self.out.statustext(f"Using minimum takeoff altitude: {default:.2f} m",
                                    M.MAV_SEVERITY_CRITICAL)
            rel = default
        s = vs.state
        self.tko_x, self.tko_y = s.x, s.y
        self.tko_z = home_d - rel
        self.tko_yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) else self.cmd.heading()
        self.cmd.set_mode(TAKEOFF)
        return M.MAV_RESULT_ACCEPTED

    def enter_takeoff(self) -> None:
        self.tko_started = False
        self.tko_ramp_done_us = -1

    def takeoff_from_here(self) -> None:
        """Arming on the ground in AUTO.TAKEOFF: climb from where the vehicle is."""
        if not self.tko_started:
            self.tko_x, self.tko_y = self.vs.state.x, self.vs.state.y

    def step_takeoff(self, t: int) -> None:
        vs = self.vs
        sp = vs.sp
        s = vs.state
        if not self.tko_started:
            self.tko_started = True
            self.tko_ramp_z = min(s.z, vs.home[2]) if vs.home else s.z
            sp.clear()
            sp.x, sp.y, sp.yaw = self.tko_x, self.tko_y, self.tko_yaw
            if vs.landed_state == ON_GROUND:
                vs.ctrl.reset()
                self.cmd.set_landed(TAKING_OFF)
        # the reference climbs at MPC_TKO_SPEED and eases into the target (first order,
        # TKO_EASE_S), its velocity fed forward: no windup, no overshoot
        zt = self.tko_z
        rz = self.tko_ramp_z
        rem = zt - rz
        if rem != 0.0:
            speed = vs.own["MPC_TKO_SPEED"]
            v = abs(rem) / TKO_EASE_S
            if v > speed:
                v = speed
            dz = v * self.dt
            if abs(rem) <= max(dz, TKO_SNAP_M):
                rz, v = zt, 0.0
            else:
                rz += dz if rem > 0.0 else -dz
            sp.vz = v if rem > 0.0 else -v
        else:
            sp.vz = NAN
        self.tko_ramp_z = rz
        sp.z = rz
        if rz == zt:
            if self.tko_ramp_done_us < 0:
                self.tko_ramp_done_us = t
            if abs(s.z - zt) < TKO_ACCEPT_M or t - self.tko_ramp_done_us > TKO_SETTLE_US:
                self.cmd.set_landed(IN_AIR)
                self.cmd.set_mode(LOITER)
                sp.x, sp.y, sp.z, sp.yaw = self.tko_x, self.tko_y, zt, self.tko_yaw
                self.out.statustext("Takeoff complete", M.MAV_SEVERITY_INFO)

    # ------------------------------------------------------------------ landing
    def enter_land(self) -> None:
        self.land_t0 = self.vs.t_us
        self.touch_since = self.stall_since = -1
        self.t_f = -1

    def step_land(self, t: int) -> None:
        vs = self.vs
        s = vs.state
        if vs.landed_state == ON_GROUND:
            return
        if self.t_f >= 0:
            self.vz_f += min(1.0, (t - self.t_f) * 1e-6 / TOUCH_VZ_TAU_S) * (s.vz - self.vz_f)
        else:
            self.vz_f = s.vz
        self.t_f = t
        slow = abs(self.vz_f) < TOUCH_VZ_MPS
        if slow and self.cmd.agl() < TOUCH_AGL_M:
            if self.touch_since < 0:
                self.touch_since = t
        else:
            self.touch_since = -1
        if slow and t - self.land_t0 > LAND_STALL_AFTER_US:
            if self.stall_since < 0:
                self.stall_since = t
        else:
            self.stall_since = -1
        if (self.touch_since >= 0 and t - self.touch_since >= TOUCH_TRIG_US) or (
                self.stall_since >= 0 and t - self.stall_since >= TOUCH_STALL_US):
            self.cmd.set_landed(ON_GROUND)
            vs.ground_since = t
            self.out.statustext("Touchdown", M.MAV_SEVERITY_INFO)

    # ------------------------------------------------------------------ every tick
    def detect_air_and_ground(self, t: int) -> None:
        """Airborne detection for the modes that run the controller from the ground, and the
        disarm COM_DISARM_LAND s after a landing."""
        vs = self.vs
        if (vs.armed and vs.landed_state == ON_GROUND and vs.mode in (OFFBOARD, TAKEOFF)
                and self.cmd.agl() > AIRBORNE_AGL_M):
            self.cmd.set_landed(TAKING_OFF if vs.mode == TAKEOFF else IN_AIR)
        if vs.ground_since >= 0 and vs.armed:
            if t - vs.ground_since >= int(vs.own["COM_DISARM_LAND"] * 1e6):
                vs.ground_since = -1
                self.cmd.disarm("Landing detected, disarmed")
