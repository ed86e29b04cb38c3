"""A relative move (Parrot's `moveBy`, MAVLink's SET_POSITION_TARGET_LOCAL_NED in
MAV_FRAME_BODY_OFFSET_NED), flown the way the firmware flies one.

What is known (cited in docs/papers/visual-servoing.md, "The low level"):
- Parrot ARSDK `ardrone3.Piloting.moveBy(dX, dY, dZ, dPsi)` (arsdk-xml, xml/ardrone3.xml,
  supported by the Bebop 2 since firmware 3.3.0): a move relative to the drone's current
  position and heading (X front, Y right, Z down), the rotation dPsi does not bend it (moves
  are rectilinear), and a second moveBy interrupts the one in progress (moveByEnd with error
  "interrupted"); the moves run within the drone's autonomous-flight maxima
  (PilotingSettings setAutonomousFlightMax{Horizontal,Vertical}{Speed,Acceleration},
  ...MaxRotationSpeed: "only used during autonomous flights such as moveBy"), whose default
  values Parrot does not publish.
- ArduPilot Copter (GCS_Mavlink.cpp) takes MAV_FRAME_BODY_OFFSET_NED positions as an offset
  rotated by the current heading and added to the current position, and its yaw as relative.

So, on reception: the target is the pose *at reception* plus R(yaw) (dX, dY) and dZ, the
heading target yaw + dPsi (never relative to the previous target), and the new move replaces
the one in progress. Flown as (ours: Parrot does not publish the profile) a reference that
starts at the vehicle's position and velocity at reception and moves along the straight line
to the target at the speed min(v_max, sqrt(2 a_max remaining)), so that it stops there, its
velocity changed by at most a_max per second; v_max and a_max are the MB_XY_* limits for the
horizontal part of the line and the MB_Z_* limits for its vertical part. The low-level
controller tracks the reference with its velocity fed forward (its position loop only
corrects the lag: a pure velocity command on that profile, tried first, overshot and
oscillated about a 1 m target with the Bebop 2's 0.5 s velocity loop; the vehicle still
overshoots the reference's speed while it catches up: 1.13 m/s on a 1 m move at 1 m/s and
1 m/s^2, 1.36 m/s at 4 m/s^2; feeding the reference's acceleration forward made it worse).
The profile is the discrete one (`stop_speed`): the last step is at most a_max dt, so the
reference's velocity never jumps. The heading
reference does the same from the vehicle's turn rate, within MB_YAW_RATE_MAX and
MB_YAW_ACC_MAX, flown as a yaw-rate command (the cascade takes no rate feed-forward with a
heading setpoint, and a heading setpoint alone moved a stream of small moves at only
MC_YAW_P x dPsi per second: E2's last key on moves took 40 s). Once the references are at the
target the move has ended and the vehicle holds it (position, height, heading).

Plain floats per tick (compiled with the rest of the per-tick path).
"""

from __future__ import annotations

import math

from mav.onboard.defs import NAN
from mav.rotations import wrap_pi, yaw_from_quat

MB_ARRIVE_M = 0.0005     # m, the reference is at its target within this, once slowed down


def stop_speed(rem: float, dv: float, dt: float) -> float:
    """The speed from which braking by dv per tick of dt stops exactly `rem` ahead (the
    discrete form of sqrt(2 a rem), a = dv / dt: n ticks of braking cover n (n + 1) / 2 dv dt,
    and the last step is at most dv)."""
    return dv * (math.sqrt(0.25 + 2.0 * rem / (dv * dt)) - 0.5)


class MoveBy:
    __slots__ = ("active", "moving", "tx", "ty", "tz", "psi_t", "psi_ref", "rx", "ry", "rz",
                 "cvx", "cvy", "cvz", "vmax", "amax", "rmax", "alpha", "r_ref", "turning", "moves",
                 "ended", "interrupted")

    def __init__(self) -> None:
        self.active = False          # a relative move is the offboard setpoint in use
        self.moving = False          # still flying it (False: holding its target)
        self.tx = self.ty = self.tz = 0.0      # m, local NED target
        self.psi_t = self.psi_ref = 0.0        # rad, heading target and reference (unwrapped)
        self.rx = self.ry = self.rz = 0.0      # m, the position reference on its way
        self.cvx = self.cvy = self.cvz = 0.0   # m/s, the reference's velocity
        self.vmax = self.amax = 0.0            # along the line to the target
        self.rmax = self.alpha = 0.0           # rad/s, rad/s^2
        self.r_ref = 0.0                       # rad/s, the heading reference's rate
        self.turning = False                   # the heading reference is on its way
        self.moves = 0               # moves received
        self.ended = 0               # moves that reached their target
        self.interrupted = 0         # moves replaced by the next one before that

    def start(self, s, dx: float, dy: float, dz: float, dpsi: float, own: dict) -> None:
        """A new move from the state `s` (VehicleState) at reception: offsets (m) forward,
        right and down in the heading frame, heading change (rad); `own` the parameters."""
        yaw = yaw_from_quat(s.qw, s.qx, s.qy, s.qz)
        c, sn = math.cos(yaw), math.sin(yaw)
        ex, ey = c * dx - sn * dy, sn * dx + c * dy
        self.tx, self.ty, self.tz = s.x + ex, s.y + ey, s.z + dz
        self.psi_ref = yaw
        self.psi_t = yaw + dpsi
        self.r_ref = s.r                   # rad/s, from the vehicle's turn rate (level: r)
        self.turning = True
        self.rx, self.ry, self.rz = s.x, s.y, s.z
        self.cvx, self.cvy, self.cvz = s.vx, s.vy, s.vz
        # the limits along this line: its horizontal part within MB_XY_*, vertical MB_Z_*
        h, d = math.hypot(ex, ey), math.sqrt(ex * ex + ey * ey + dz * dz)
        vmax = amax = math.inf
        if h > 0.0:
            vmax, amax = own["MB_XY_VEL_MAX"] * d / h, own["MB_XY_ACC_MAX"] * d / h
        if dz != 0.0:
            vmax = min(vmax, own["MB_Z_VEL_MAX"] * d / abs(dz))
            amax = min(amax, own["MB_Z_ACC_MAX"] * d / abs(dz))
        if not math.isfinite(vmax):          # a pure rotation: brake with the horizontal limit
            vmax, amax = own["MB_XY_VEL_MAX"], own["MB_XY_ACC_MAX"]
        self.vmax, self.amax = vmax, amax
        self.rmax = own["MB_YAW_RATE_MAX"] * (math.pi / 180.0)
        self.alpha = own["MB_YAW_ACC_MAX"] * (math.pi / 180.0)
        if self.moving:
            self.interrupted += 1              # the move in progress is replaced
        self.active = self.moving = True
        self.moves += 1

    def stop(self) -> None:
        """Another kind of setpoint took over (or offboard ended)."""
        self.active = self.moving = self.turning = False

    def step(self, dt: float, sp) -> None:
        """One control tick of length dt (s): advances the reference, writes the setpoint."""
        if self.turning and dt > 0.0:
            self._turn(dt)
        if self.turning:            # the heading reference's rate (its lag is corrected at
            sp.yaw = NAN            # the end, by the heading loop on the target)
            sp.yaw_rate = self.r_ref
        else:
            sp.yaw = wrap_pi(self.psi_t)
            sp.yaw_rate = NAN
        if self.moving and dt > 0.0:
            self._advance(dt)
        if self.moving:
            sp.x, sp.y, sp.z = self.rx, self.ry, self.rz
            sp.vx, sp.vy, sp.vz = self.cvx, self.cvy, self.cvz
        else:
            sp.x, sp.y, sp.z = self.tx, self.ty, self.tz
            sp.vx = sp.vy = sp.vz = NAN
        sp.ax = sp.ay = NAN

    def _turn(self, dt: float) -> None:
        """The heading's profile: as the line's, with MB_YAW_RATE_MAX and MB_YAW_ACC_MAX."""
        rem = self.psi_t - self.psi_ref
        alpha = self.alpha
        dr = alpha * dt
        r = self.r_ref
        if abs(rem) <= 1e-9 and abs(r) <= dr:     # at the heading target and stopped
            self.turning = False
            self.psi_ref, self.r_ref = self.psi_t, 0.0
            return
        want = math.copysign(min(self.rmax, stop_speed(abs(rem), dr, dt)), rem)
        r += min(max(want - r, -dr), dr)
        self.r_ref = r
        if abs(r) <= dr * (1.0 + 1e-9) and r * rem >= 0.0 and (
                abs(rem) <= abs(r) * dt * (1.0 + 1e-9)):   # this step reaches the target
            self.psi_ref = self.psi_t
            return
        self.psi_ref += r * dt

    def _advance(self, dt: float) -> None:
        ex, ey, ez = self.tx - self.rx, self.ty - self.ry, self.tz - self.rz
        rem = math.sqrt(ex * ex + ey * ey + ez * ez)
        amax = self.amax
        dv = amax * dt
        cvx, cvy, cvz = self.cvx, self.cvy, self.cvz
        if rem <= MB_ARRIVE_M and cvx * cvx + cvy * cvy + cvz * cvz <= dv * dv:
            self.moving = False          # at the target and stopped: the move has ended
            self.ended += 1
            self.rx, self.ry, self.rz = self.tx, self.ty, self.tz
            self.cvx = self.cvy = self.cvz = 0.0
            return
        speed = min(self.vmax, stop_speed(rem, dv, dt))
        k = speed / rem if rem > 0.0 else 0.0
        wx, wy, wz = ex * k - cvx, ey * k - cvy, ez * k - cvz     # change wanted
        w = math.sqrt(wx * wx + wy * wy + wz * wz)
        if w > dv:
            f = dv / w
            wx, wy, wz = wx * f, wy * f, wz * f
        cvx, cvy, cvz = cvx + wx, cvy + wy, cvz + wz
        v = math.sqrt(cvx * cvx + cvy * cvy + cvz * cvz)
        self.cvx, self.cvy, self.cvz = cvx, cvy, cvz
        if v <= dv * (1.0 + 1e-9) and rem <= v * dt * (1.0 + 1e-9) and (
                cvx * ex + cvy * ey + cvz * ez >= 0.0):    # this step reaches the target
            self.rx, self.ry, self.rz = self.tx, self.ty, self.tz
            return
        self.rx += cvx * dt
        self.ry += cvy * dt
        self.rz += cvz * dt
