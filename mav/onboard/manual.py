"""Manual flight in POSCTL from MANUAL_CONTROL (QGroundControl's virtual joystick, a gamepad,
MAVSDK's ManualControl): PX4's position mode.

Sticks (MANUAL_CONTROL x, y, r in -1000..1000, z 0..1000 with 500 the centre): pitch and roll
command a horizontal velocity in the heading frame (TPL_VEL_MANUAL at full stick), the throttle
a climb or descent rate (MPC_Z_V_AUTO_UP / _DN at full stick), yaw a yaw rate (MPC_MAN_Y_MAX).
Inside the deadzone TPL_HOLD_DZ an axis holds: once the vehicle has slowed down, position,
height or heading is locked where it is. On the ground, throttle above the centre takes off;
held down after touchdown, the land detector disarms as in AUTO.LAND. Sticks silent for
COM_RC_LOSS_T count as centred (the vehicle holds; PX4's RC-loss action is not modelled).
"""

from __future__ import annotations

import math

from mav.onboard.channels import Chan
from mav.onboard.commander import Commander
from mav.onboard.defs import IN_AIR, NAN, ON_GROUND
from mav.onboard.status import VehicleStatus

LOCK_SPEED_MPS = 0.2        # an axis released locks its position once slower than this
LOCK_YAW_RATE = 0.2         # rad/s, likewise for the heading


class Manual:
    def __init__(self, vs: VehicleStatus, commander: Commander, navigator, sysid: int) -> None:
        self.vs = vs
        self.cmd = commander
        self.nav = navigator
        self.sysid = sysid
        self.sticks = (0.0, 0.0, 0.5, 0.0)     # pitch, roll, throttle 0..1, yaw
        self.last_us = -(1 << 62)
        self.enter()

    def enter(self) -> None:
        """POSCTL entered: nothing flies from the sticks until they move."""
        self.engaged = False
        self.xy_locked = self.z_locked = self.yaw_locked = True
        self.vs.man_climb = False

    def on_manual_control(self, ch: Chan, msg) -> None:
        vs = self.vs
        if msg.target != self.sysid:
            vs.stats["not_for_us"] += 1
            return
        x, y, z, r = msg.x, msg.y, msg.z, msg.r
        if not (-1000 <= x <= 1000 and -1000 <= y <= 1000 and -1000 <= z <= 1000
                and -1000 <= r <= 1000):
            vs.stats["manual_rejected"] = vs.stats.get("manual_rejected", 0) + 1
            return
        self.sticks = (x * 1e-3, y * 1e-3, min(max(z * 1e-3, 0.0), 1.0), r * 1e-3)
        self.last_us = vs.t_us
        vs.stats["manual_inputs"] = vs.stats.get("manual_inputs", 0) + 1

    def step(self, t: int) -> None:
        """POSCTL's tick (armed)."""
        vs = self.vs
        own = vs.own
        dz = own["TPL_HOLD_DZ"]
        fresh = t - self.last_us <= int(own["COM_RC_LOSS_T"] * 1e6)
        fx, fy, thr, fr = self.sticks if fresh else (0.0, 0.0, 0.5, 0.0)
        fx, fy = _dead(fx, dz), _dead(fy, dz)
        fz, fr = _dead(2.0 * thr - 1.0, dz), _dead(fr, dz)
        if not self.engaged:
            if fx == 0.0 and fy == 0.0 and fz == 0.0 and fr == 0.0:
                return              # holding where POSCTL was entered
            self.engaged = True
        vs.man_climb = fz > 0.0
        if vs.landed_state == ON_GROUND:
            if not vs.man_climb:
                return              # idling on the ground (commander.motors_idle)
            vs.ground_since = -1    # taking off again: no disarm after the last touchdown
        if fz >= 0.0:
            self.nav.t_f = -1       # the land detector restarts with the next descent
        sp, s = vs.sp, vs.state
        # horizontal: velocity in the heading frame, or hold
        if fx != 0.0 or fy != 0.0:
            v = own["TPL_VEL_MANUAL"]
            psi = self.cmd.heading()
            c, si = math.cos(psi), math.sin(psi)
            sp.x = sp.y = NAN
            sp.vx, sp.vy = v * (c * fx - si * fy), v * (si * fx + c * fy)
            self.xy_locked = False
        elif not self.xy_locked:
            if math.hypot(s.vx, s.vy) < LOCK_SPEED_MPS:
                sp.x, sp.y, sp.vx, sp.vy = s.x, s.y, NAN, NAN
                self.xy_locked = True
            else:
                sp.x = sp.y = NAN
                sp.vx = sp.vy = 0.0
        # vertical: climb rate, or hold
        if fz != 0.0:
            sp.z = NAN
            sp.vz = -fz * (own["MPC_Z_V_AUTO_UP"] if fz > 0.0 else own["MPC_Z_V_AUTO_DN"])
            self.z_locked = False
            if fz < 0.0 and vs.landed_state == IN_AIR:
                self.touchdown(t)
        elif not self.z_locked:
            if abs(s.vz) < LOCK_SPEED_MPS:
                sp.z, sp.vz = s.z, NAN
                self.z_locked = True
            else:
                sp.z, sp.vz = NAN, 0.0
        # heading: rate, or hold
        if fr != 0.0:
            sp.yaw = NAN
            sp.yaw_rate = fr * math.radians(own["MPC_MAN_Y_MAX"])
            self.yaw_locked = False
        elif not self.yaw_locked and abs(s.r) < LOCK_YAW_RATE:
            sp.yaw, sp.yaw_rate = self.cmd.heading(), NAN
            self.yaw_locked = True
        elif not self.yaw_locked:
            sp.yaw, sp.yaw_rate = NAN, 0.0

    def touchdown(self, t: int) -> None:
        """Throttle down near the ground: AUTO.LAND's land detector decides touchdown."""
        nav = self.nav
        if nav.touch_since < 0 and nav.t_f < 0:
            nav.enter_land()
        nav.step_land(t)
        if self.vs.landed_state == ON_GROUND:
            self.vs.man_climb = False
            self.z_locked = True


def _dead(v: float, dz: float) -> float:
    """Deadzone with the remaining travel rescaled to 0..1, as PX4's stick expo does."""
    a = abs(v)
    if a <= dz or dz >= 1.0:
        return 0.0
    return math.copysign(min((a - dz) / (1.0 - dz), 1.0), v)

