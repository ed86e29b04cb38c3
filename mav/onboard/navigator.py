"""Navigator: the automatic modes' flight: take-off to a height, legs to a point (go-to,
DO_REPOSITION), return to launch, land and detect touchdown; airborne detection and the disarm
after landing. Missions (`mission.py`) fly their items with these."""

from __future__ import annotations

import math

from mav.onboard.channels import Outbox
from mav.onboard.commander import Commander
from mav.onboard.defs import (
    AIRBORNE_AGL_M,
    IN_AIR,
    LAND,
    LAND_STALL_AFTER_US,
    LANDING,
    LEG_FACE_M,
    LEG_SETTLE_US,
    LOITER,
    MISSION,
    NAN,
    OFFBOARD,
    ON_GROUND,
    POSCTL,
    SP_MAX_POS_M,
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
from mav.onboard.leg import Leg
from mav.onboard.status import VehicleStatus
from mav.params import ONBOARD_PARAMS
from mav.rotations import wrap_pi

RTL_IDLE, RTL_CLIMB, RTL_RETURN, RTL_DESCEND, RTL_WAIT, RTL_LAND, RTL_DONE = range(7)
RTL_PHASE_NAMES = ("idle", "climb", "return", "descend", "wait", "land", "done")


_SPEED_PARAMS = ("TPL_XY_CRUISE", "TPL_XY_CRUISE", "MPC_Z_V_AUTO_UP", "MPC_Z_V_AUTO_DN")
_RANGES = {p.name: (p.min, p.max) for p in ONBOARD_PARAMS}


def speed_range(kind: int) -> tuple[float, float]:
    """(min, max) m/s a speed of DO_CHANGE_SPEED type `kind` (0/1 horizontal, 2 climb,
    3 descent) may take: its parameter's range (PX4 clamps to its limits too)."""
    return _RANGES[_SPEED_PARAMS[kind]]


class Navigator:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander,
                 control_dt_s: float, geo) -> None:
        self.vs = vs
        self.geo = geo           # wire.FlatEarth about the local origin
        self.out = outbox
        self.cmd = commander
        self.dt = control_dt_s
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
        # legs (go-to, RTL, mission waypoints)
        self.leg = Leg()
        self.leg_active = False
        self.leg_acc_m = 0.0     # m, horizontal acceptance radius of the leg (0: NAV_ACC_RAD)
        self.leg_ref_done_us = -1
        self.speed_xy = NAN      # m/s, DO_CHANGE_SPEED overrides (NaN: the parameters)
        self.speed_up = NAN
        self.speed_dn = NAN
        # RTL: phase and the height it returns at
        self.rtl_phase = RTL_IDLE
        self.rtl_alt = 0.0
        self.rtl_t0 = 0

    # ------------------------------------------------------------------ take-off
    def cmd_takeoff(self, yaw_deg: float, alt: float, frame: int | None) -> int:
        """MAV_CMD_NAV_TAKEOFF (param4 yaw deg, param7 altitude): climb above home."""
        vs = self.vs
        if not vs.have_state or vs.home is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if not vs.armed and vs.landed_state == ON_GROUND:
            self.cmd.set_home()
        home_n, home_e, home_d = vs.home
        home_amsl = self.geo.alt0_m - home_d
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
        if self.climb(t):
            vs = self.vs
            self.cmd.set_landed(IN_AIR)
            self.cmd.set_mode(LOITER)
            sp = vs.sp
            sp.x, sp.y, sp.z, sp.yaw = self.tko_x, self.tko_y, self.tko_z, self.tko_yaw
            self.out.statustext("Takeoff complete", M.MAV_SEVERITY_INFO)

    def climb_to(self, rel_alt: float) -> None:
        """Start a take-off climb from here to `rel_alt` m above home (missions)."""
        vs = self.vs
        self.tko_x, self.tko_y = vs.state.x, vs.state.y
        self.tko_z = vs.home[2] - rel_alt
        self.tko_yaw = self.cmd.heading()
        self.enter_takeoff()

    def climb(self, t: int) -> bool:
        """The take-off climb's tick; True once it is complete (the caller moves on)."""
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
        # the reference climbs at TPL_TKO_SPEED and eases into the target (first order,
        # TKO_EASE_S), its velocity fed forward: no windup, no overshoot
        zt = self.tko_z
        rz = self.tko_ramp_z
        rem = zt - rz
        if rem != 0.0:
            speed = vs.own["TPL_TKO_SPEED"]
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
                return True
        return False

    # ------------------------------------------------------------------ legs
    def speeds(self) -> tuple[float, float, float]:
        """(horizontal, climb, descent) m/s of the automatic modes: DO_CHANGE_SPEED's or the
        parameters'."""
        own = self.vs.own
        xy, up, dn = self.speed_xy, self.speed_up, self.speed_dn
        return (xy if xy == xy else own["TPL_XY_CRUISE"], up if up == up
                else own["MPC_Z_V_AUTO_UP"], dn if dn == dn else own["MPC_Z_V_AUTO_DN"])

    def fly_to(self, x: float, y: float, z: float, yaw: float = NAN,
               accept_m: float = 0.0, speed_xy: float = NAN) -> None:
        """Start a leg from the vehicle to (x, y, z) (local NED, m). Yaw (rad): NaN faces
        along a leg of LEG_FACE_M or more and keeps the heading on a shorter one."""
        vs = self.vs
        s = vs.state
        sp = vs.sp
        if yaw != yaw:
            dx, dy = x - s.x, y - s.y
            if math.hypot(dx, dy) >= LEG_FACE_M:
                yaw = math.atan2(dy, dx)
            else:
                yaw = sp.yaw if sp.yaw == sp.yaw else self.cmd.heading()
        v_xy, v_up, v_dn = self.speeds()
        if speed_xy == speed_xy and speed_xy > 0.0:
            v_xy = speed_xy
        sp.clear()
        sp.yaw = wrap_pi(yaw)
        own = vs.own
        self.leg.start((s.x, s.y, s.z), (x, y, z), v_xy, v_up, v_dn, own["TPL_ACC_HOR"],
                       own["MPC_JERK_AUTO"])
        self.leg_active = True
        self.leg_acc_m = accept_m
        self.leg_ref_done_us = -1

    def step_leg(self, t: int) -> bool:
        """The leg's tick; True once the vehicle is at its target (within the acceptance
        radii, or LEG_SETTLE_US after the reference got there)."""
        vs = self.vs
        if not self.leg_active:
            return True
        if not self.leg.step(self.dt, vs.sp):
            return False
        if self.leg_ref_done_us < 0:
            self.leg_ref_done_us = t
        s = vs.state
        leg = self.leg
        acc = self.leg_acc_m if self.leg_acc_m > 0.0 else vs.own["NAV_ACC_RAD"]
        if (math.hypot(s.x - leg.tx, s.y - leg.ty) <= acc
                and abs(s.z - leg.tz) <= vs.own["NAV_MC_ALT_RAD"]) or (
                t - self.leg_ref_done_us >= LEG_SETTLE_US):
            self.leg_active = False
            return True
        return False

    def change_speed(self, kind: float, speed: float) -> int:
        """MAV_CMD_DO_CHANGE_SPEED (also a mission item): kind 0/1 horizontal, 2 climb,
        3 descent; speed -1 back to the parameter, -2 no change."""
        if not (math.isfinite(kind) and math.isfinite(speed)) or int(kind) not in (0, 1, 2, 3):
            self.out.statustext("Speed change denied: bad speed type or value",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        if speed == -2.0:
            return M.MAV_RESULT_ACCEPTED
        lo, hi = speed_range(int(kind))
        if speed == -1.0:
            v = NAN
        elif speed >= lo:       # below the parameter's minimum (1e-30) a leg would never end
            v = min(speed, hi)
        else:
            self.out.statustext(f"Speed change denied: {speed:g} m/s (at least {lo:g})",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        k = int(kind)
        if k <= 1:
            self.speed_xy = v
        elif k == 2:
            self.speed_up = v
        else:
            self.speed_dn = v
        if self.leg_active:
            self.leg.set_speeds(*self.speeds())
        return M.MAV_RESULT_ACCEPTED

    # ------------------------------------------------------------------ go-to
    def reposition(self, speed: float, flags: float, yaw_deg: float, lat: float, lon: float,
                   alt: float, frame: int | None) -> int:
        """MAV_CMD_DO_REPOSITION (QGC "go to location", MAVSDK goto_location): hold mode,
        flying to the point. lat/lon NaN (or both 0 in COMMAND_INT): here; alt NaN: this
        height; COMMAND_LONG and frame GLOBAL(_INT) altitudes are AMSL, the
        RELATIVE_ALT frames' above home."""
        vs = self.vs
        if not vs.have_state or vs.home is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if not vs.armed or vs.landed_state == ON_GROUND:
            self.out.statustext("Reposition denied: not flying", M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        if vs.mode == LAND or vs.landed_state == LANDING:
            self.out.statustext("Reposition denied: landing", M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        target = self.global_to_local(lat, lon, alt, frame, int_xy=frame is not None)
        if target is None:
            self.out.statustext("Reposition denied: bad position or frame",
                                M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) else NAN
        self.cmd.set_mode(LOITER)
        self.fly_to(*target, yaw=yaw, speed_xy=speed if math.isfinite(speed) else NAN)
        return M.MAV_RESULT_ACCEPTED

    def global_to_local(self, lat: float, lon: float, alt: float, frame: int | None,
                        int_xy: bool) -> tuple[float, float, float] | None:
        """A geodetic point (lat/lon in deg, or deg*1e7 when int_xy) -> local NED, or None.
        NaN lat/lon (or 0, 0 as integers) means here; NaN alt this height."""
        vs = self.vs
        s = vs.state
        if int_xy:
            here_xy = (lat == 0 and lon == 0) or not (math.isfinite(lat) and math.isfinite(lon))
            lat, lon = lat * 1e-7, lon * 1e-7
        else:
            here_xy = not (math.isfinite(lat) and math.isfinite(lon))
        geo = self.geo
        if here_xy:
            n, e = s.x, s.y
        elif abs(lat) <= 90.0 and abs(lon) <= 180.0:
            n, e, _ = geo.to_ned(lat, lon, geo.alt0_m)
        else:
            return None
        if not math.isfinite(alt):
            d = s.z
        elif frame is None or frame in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT):
            d = geo.alt0_m - alt
        elif frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            d = vs.home[2] - alt
        else:
            return None
        if not (abs(n) <= SP_MAX_POS_M and abs(e) <= SP_MAX_POS_M and abs(d) <= SP_MAX_POS_M):
            return None
        return n, e, d

    def step_loiter(self, t: int) -> None:
        """AUTO.LOITER: a go-to's leg until it is there, then hold."""
        if self.leg_active:
            self.step_leg(t)

    # ------------------------------------------------------------------ return to launch
    def enter_rtl(self) -> None:
        """PX4's RTL: climb to RTL_RETURN_ALT above home if lower, fly home at that height,
        descend to RTL_DESCEND_ALT, wait RTL_LAND_DELAY (-1: for ever), land at home."""
        vs = self.vs
        self.leg_active = False
        if vs.landed_state == ON_GROUND:
            self.rtl_phase = RTL_LAND
            self.begin_land(vs.state.x, vs.state.y)
            return
        own = vs.own
        self.rtl_alt = max(self.cmd.agl(), own["RTL_RETURN_ALT"])
        self.out.statustext(f"RTL: return at {self.rtl_alt:.1f} m above home",
                            M.MAV_SEVERITY_INFO)
        s = vs.state
        self.rtl_phase = RTL_CLIMB
        self.fly_to(s.x, s.y, vs.home[2] - self.rtl_alt)

    def step_rtl(self, t: int) -> bool:
        """RTL's tick; True once it has landed (or is waiting for ever)."""
        vs = self.vs
        ph = self.rtl_phase
        hx, hy, hz = vs.home
        if ph == RTL_CLIMB:
            if self.step_leg(t):
                self.rtl_phase = RTL_RETURN
                self.fly_to(hx, hy, hz - self.rtl_alt)
        elif ph == RTL_RETURN:
            if self.step_leg(t):
                desc = min(self.rtl_alt, vs.own["RTL_DESCEND_ALT"])
                self.rtl_phase = RTL_DESCEND
                self.fly_to(hx, hy, hz - desc)
        elif ph == RTL_DESCEND:
            if self.step_leg(t):
                self.rtl_phase = RTL_WAIT
                self.rtl_t0 = t
        elif ph == RTL_WAIT:
            delay = vs.own["RTL_LAND_DELAY"]
            if delay >= 0.0 and t - self.rtl_t0 >= int(delay * 1e6):
                self.rtl_phase = RTL_LAND
                self.out.statustext("RTL: landing at home", M.MAV_SEVERITY_INFO)
                self.begin_land(hx, hy, vs.sp.yaw)
        elif ph == RTL_LAND:
            self.step_land(t)
            if vs.landed_state == ON_GROUND:
                self.rtl_phase = RTL_DONE
        return self.rtl_phase == RTL_DONE

    # ------------------------------------------------------------------ landing
    def begin_land(self, x: float, y: float, yaw: float = NAN) -> None:
        """Descend at TPL_LAND_SPEED over (x, y) to touchdown (AUTO.LAND, RTL, missions);
        yaw NaN: the present heading."""
        vs = self.vs
        self.leg_active = False
        self.enter_land()
        sp = vs.sp
        if yaw != yaw:
            yaw = self.cmd.heading()
        sp.clear()
        sp.x, sp.y = x, y
        sp.vz = vs.own["TPL_LAND_SPEED"]
        sp.yaw = yaw
        if vs.landed_state != ON_GROUND:
            self.cmd.set_landed(LANDING)
        elif vs.armed and vs.ground_since < 0:
            vs.ground_since = vs.t_us     # already down: disarm after the delay

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
        # stalled: not descending (PX4's land detector: "hit ground" is a descent commanded
        # and no downward movement). Not |vz| small: an estimate that has no height aiding
        # near the floor (paper 1's release, below its sonar's 0.44 m) can take the
        # touchdown's deceleration into a climb it cannot correct
        if self.vz_f < TOUCH_VZ_MPS and t - self.land_t0 > LAND_STALL_AFTER_US:
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
        if (vs.armed and vs.landed_state == ON_GROUND
                and vs.mode in (OFFBOARD, TAKEOFF, MISSION, POSCTL)
                and self.cmd.agl() > AIRBORNE_AGL_M):
            self.cmd.set_landed(TAKING_OFF if vs.mode == TAKEOFF else IN_AIR)
        if vs.ground_since >= 0 and vs.armed:
            if t - vs.ground_since >= int(vs.own["COM_DISARM_LAND"] * 1e6):
                vs.ground_since = -1
                self.cmd.disarm("Landing detected, disarmed")
