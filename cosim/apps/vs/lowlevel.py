"""How the visual-servoing app hands its 4-D command (vx, vy, vz, wz; body FRD, m/s, rad/s) to
the vehicle: the app parameter `low_level`.

- "velocity" (default): a velocity setpoint in MAV_FRAME_BODY_NED with the yaw rate, re-sent
  at least every 0.1 s; the vehicle's velocity loop flies it.
- "moveby" (paper 2's vehicle as it flew): what ViSP's `vpRobotBebop2::setVelocity(v, dt)`
  does (ViSP, modules/robot/src/real-robot/bebop2/vpRobotBebop2.cpp): the displacement
  M = vpExponentialMap::direct(v, dt) of the twist (vx, vy, vz, 0, 0, wz) over dt, sent as
  `setPosition(M, blocking = false)`, i.e. Parrot's relative move moveBy(dX, dY, dZ, dPsi),
  once per vision cycle, each interrupting the previous one. Here: a relative move in
  MAV_FRAME_BODY_OFFSET_NED (`OffboardClient.set_relative_move`), once per new command.
  dt is the vision cycle's period (`moveby_dt_s` = 0), or `moveby_dt_s` (ViSP's own example
  servoBebop2.cpp passes 1.0 s at a 40 ms loop).
"""

from __future__ import annotations

import math

LOW_LEVELS = ("velocity", "moveby")
RESEND_S = 0.1      # velocity mode: the setpoint is re-sent at least this often (offboard stream)


def twist_displacement(vx: float, vy: float, vz: float, wz: float, dt: float
                       ) -> tuple[float, float, float, float]:
    """(dX, dY, dZ, dPsi): the exponential map of the planar twist over dt, in the frame at
    its start. With a yaw rate the translation follows the arc (the body velocity turns with
    the body): dX + i dY = (vx + i vy) (e^{i theta} - 1) / (i wz), theta = wz dt; vZ and the
    heading are straight. ViSP's vpExponentialMap::direct gives the same for (vx, vy, vz, 0,
    0, wz). Series for small theta (|theta| < 1e-4: the closed form loses digits there)."""
    th = wz * dt
    if abs(th) < 1e-4:
        t2 = th * th
        s = 1.0 - t2 / 6.0 + t2 * t2 / 120.0         # sin(th) / th
        c = th / 2.0 - th * t2 / 24.0                # (1 - cos(th)) / th
    else:
        s = math.sin(th) / th
        c = (1.0 - math.cos(th)) / th
    return ((vx * s - vy * c) * dt, (vx * c + vy * s) * dt, vz * dt, th)


class LowLevel:
    """Sends the app's command the way `mode` says (see the module docstring)."""

    def __init__(self, mode: str, dt_fixed_s: float, cycle_s: float) -> None:
        if mode not in LOW_LEVELS:
            raise ValueError(f"app.params.low_level: got {mode!r}; allowed: "
                             f"{', '.join(LOW_LEVELS)}")
        self.mode = mode
        self.dt = dt_fixed_s if dt_fixed_s > 0.0 else cycle_s
        self.t_sent = -1e9
        self.moves = 0

    def send(self, client, t: float, cmd, new: bool) -> bool:
        """Send `cmd` (vx, vy, vz, wz) if due; True if something was sent."""
        if not new and (self.mode == "moveby" or t - self.t_sent < RESEND_S):
            return False
        vx, vy, vz, wz = (float(v) for v in cmd)
        if self.mode == "moveby":
            client.set_relative_move(*twist_displacement(vx, vy, vz, wz, self.dt))
            self.moves += 1
        else:
            client.set_velocity_target(vx, vy, vz, yaw_rate=wz, frame="body")
        self.t_sent = t
        return True
