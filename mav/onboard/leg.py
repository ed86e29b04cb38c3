"""A leg: the automatic modes' flight from one point to another (go-to, RTL, mission waypoints).

The reference moves along the straight line from the start to the target with a jerk-limited
speed profile (accelerate at up to `acc`, changing the acceleration at up to `jerk`, cruise,
brake to stop at the target); its velocity and acceleration are fed forward, as PX4's auto
flight tasks feed the position controller a smooth trajectory instead of a step. The
acceleration fed forward leads the profile's by LEG_ACC_LEAD_S (a + lead * jerk): the tilt
takes about that long to follow, and without the lead the vehicle overshot the cruise speed by
15-25 % (measured, Mambo and Bebop 2, 0.5-2 m/s). The cruise speed along the line is the
largest that keeps the horizontal part within `v_xy` and the vertical part within the climb or
descent speed.
"""

from __future__ import annotations

import math

from mav.onboard.defs import LEG_ACC_LEAD_S, LEG_SNAP_M


class Leg:
    __slots__ = ("x0", "y0", "z0", "ux", "uy", "uz", "length", "s", "v", "a", "vmax", "acc",
                 "jerk", "tx", "ty", "tz", "_h", "_dz")

    def __init__(self) -> None:
        self.x0 = self.y0 = self.z0 = 0.0
        self.tx = self.ty = self.tz = 0.0
        self.ux = self.uy = self.uz = 0.0       # unit direction
        self.length = self.s = self.v = 0.0     # m, m along, m/s along
        self.a = 0.0                            # m/s^2 along
        self.vmax = self.acc = 1.0
        self.jerk = 4.0
        self._h = self._dz = 0.0

    def start(self, start: tuple[float, float, float], target: tuple[float, float, float],
              v_xy: float, v_up: float, v_dn: float, acc: float, jerk: float) -> None:
        x0, y0, z0 = start
        tx, ty, tz = target
        self.x0, self.y0, self.z0 = x0, y0, z0
        self.tx, self.ty, self.tz = tx, ty, tz
        dx, dy, dz = tx - x0, ty - y0, tz - z0
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        self.length, self.s, self.v, self.a = length, 0.0, 0.0, 0.0
        self.acc, self.jerk = acc, jerk
        self._h, self._dz = math.hypot(dx, dy), dz
        if length > 0.0:
            self.ux, self.uy, self.uz = dx / length, dy / length, dz / length
        else:
            self.ux = self.uy = self.uz = 0.0
        self.set_speeds(v_xy, v_up, v_dn)

    def set_speeds(self, v_xy: float, v_up: float, v_dn: float) -> None:
        """The speed limits (m/s): horizontal, climb, descent; may change in flight."""
        vmax = math.inf
        if self._h > 0.0:
            vmax = v_xy * self.length / self._h
        if self._dz < 0.0:
            vmax = min(vmax, v_up * self.length / -self._dz)
        elif self._dz > 0.0:
            vmax = min(vmax, v_dn * self.length / self._dz)
        self.vmax = vmax if math.isfinite(vmax) else 0.0

    @property
    def done(self) -> bool:
        return self.s >= self.length

    def step(self, dt: float, sp) -> bool:
        """Advance the reference by dt and write it (position, velocity and acceleration
        feed-forward) into the setpoint `sp`; True once the reference is at the target."""
        rem = self.length - self.s
        acc, jerk, v, a = self.acc, self.jerk, self.v, self.a
        if rem <= LEG_SNAP_M:
            self.s, v, a = self.length, 0.0, 0.0
        else:
            # the speed wanted now: cruise, or the braking curve (started early by the
            # distance flown while the deceleration ramps in at the jerk limit)
            lead = v * acc / (2.0 * jerk)
            vd = min(self.vmax, math.sqrt(2.0 * acc * max(rem - lead, 0.0)))
            ad = min(max((vd - v) / dt, -acc), acc)
            lo, hi = a - jerk * dt, a + jerk * dt
            a = lo if ad < lo else (hi if ad > hi else ad)
            if a > 0.0:          # ease into the wanted speed instead of overshooting it
                a = min(a, math.sqrt(2.0 * jerk * max(vd - v, 0.0)))
            v = max(v + a * dt, 0.0)
            if v == 0.0 and a < 0.0:
                a = 0.0
            self.s = min(self.s + v * dt, self.length)
            if self.s >= self.length:
                v, a = 0.0, 0.0
        if self.s >= self.length:
            a_ff = 0.0
        else:
            a_ff = a + LEG_ACC_LEAD_S * (a - self.a) / dt
            a_ff = min(max(a_ff, -2.0 * acc), 2.0 * acc)
        self.v, self.a = v, a
        sp.ax, sp.ay = a_ff * self.ux, a_ff * self.uy
        if self.s >= self.length:
            sp.x, sp.y, sp.z = self.tx, self.ty, self.tz
        else:
            s = self.s
            sp.x, sp.y, sp.z = self.x0 + s * self.ux, self.y0 + s * self.uy, self.z0 + s * self.uz
        sp.vx, sp.vy, sp.vz = v * self.ux, v * self.uy, v * self.uz
        return self.s >= self.length
