"""Obstacle memory of the visual-servo app (issue 28, ours): where the last column seen
stands, in the vehicle's own local frame, so its clearance is kept after it has left the view.

The app knows the vehicle only through MAVLink telemetry (LOCAL_POSITION_NED, ATTITUDE) and
the image, never the truth. When the column is seen (tasks.find_obstacle), its depth along
the optical axis is Z = width / d from its apparent width d (normalised), its centre is
x_o Z to the right of the axis; the camera is `mount_x` ahead of the body's centre, level
(the stabilised stream), so the column's centre is at body (Z + mount_x, x_o Z), rotated by
the telemetry yaw and added to the telemetry position: local (n, e). Each sighting replaces
the last (the closest view is the most accurate one; a different column is the one now in
view).

Out of view, the column's body position (x, y) follows from telemetry; `task` gives the
corridor task without the image: e = c - |y| with c = clearance + width / 2 (the half-width
of the corridor the vehicle sweeps), wanted while e > 0, and its Jacobian in [vx, vy, vz, wz]:
d|y|/dt = -s vy (s = sign y, the yaw column zeroed as in tasks.corridor_task), so J = [0, s,
0, 0] and de/dt = J nu. The column counts as passed once it is `c` behind the body centre
(x < -c): nothing of the vehicle's corridor is level with it any more.
"""

from __future__ import annotations

import math

import numpy as np

from cosim.apps.vs.tasks import Obstacle


class ObstacleMemory:
    def __init__(self) -> None:
        self.ne: tuple[float, float] | None = None

    def forget(self) -> None:
        self.ne = None

    def see(self, ob: Obstacle, K: np.ndarray, width_m: float, pos, yaw: float,
            mount_x: float) -> None:
        """Remember the column seen at `ob`, from the vehicle at local `pos` (n, e, d) with
        heading `yaw` (rad); nothing when the telemetry is not there yet (NaN)."""
        if not all(math.isfinite(v) for v in (pos[0], pos[1], yaw)):
            return
        fx, cx = K[0, 0], K[0, 2]
        xl, xr = (ob.x_left_px - cx) / fx, (ob.x_right_px - cx) / fx
        Z = width_m / max(xr - xl, 1e-6)
        fwd, right = Z + mount_x, 0.5 * (xl + xr) * Z
        c, s = math.cos(yaw), math.sin(yaw)
        self.ne = (pos[0] + c * fwd - s * right, pos[1] + s * fwd + c * right)

    def body(self, pos, yaw: float) -> tuple[float, float] | None:
        """The remembered column in the body frame (forward, right; m), or None."""
        if self.ne is None or not all(math.isfinite(v) for v in (pos[0], pos[1], yaw)):
            return None
        dn, de = self.ne[0] - pos[0], self.ne[1] - pos[1]
        c, s = math.cos(yaw), math.sin(yaw)
        return c * dn + s * de, -s * dn + c * de

    def task(self, pos, yaw: float, clearance_m: float, width_m: float
             ) -> tuple[float, np.ndarray] | None:
        """(e, J 1x4) of the corridor task from memory, or None when nothing is remembered or
        the column is passed (then it is forgotten)."""
        xy = self.body(pos, yaw)
        if xy is None:
            return None
        c = clearance_m + 0.5 * width_m
        x, y = xy
        if x < -c:
            self.forget()
            return None
        s = 1.0 if y >= 0.0 else -1.0
        return c - abs(y), np.array([[0.0, s, 0.0, 0.0]])
