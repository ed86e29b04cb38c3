"""Obstacle memory of the visual-servo app (issue 28, ours): where the columns seen stand, in
the vehicle's own local frame, so their clearance is kept after they have left the view.

The app knows the vehicle only through MAVLink telemetry (LOCAL_POSITION_NED, ATTITUDE) and
the image, never the truth. When a column is seen (tasks.find_obstacle), its depth along the
optical axis is Z = width / d from its apparent width d (normalised), its centre is x_o Z to
the right of the axis; the camera is `mount_x` ahead of the body's centre, level (the
stabilised stream), so the column's centre is at body (Z + mount_x, x_o Z), rotated by the
telemetry yaw and added to the telemetry position: local (n, e). A sighting within
`same_m` of a remembered column replaces it (the closer view is the more accurate one);
otherwise it is another column, remembered beside the others.

The corridor task without the image, for the nearest column not yet passed (`nearest`):
body position (x, y) from telemetry, e = c - |y| with c = clearance + width / 2 (the
half-width of the corridor the vehicle sweeps), wanted while e > 0, and its Jacobian in
[vx, vy, vz, wz]: d|y|/dt = -s vy (s = sign y, the yaw column zeroed as in
tasks.corridor_task), so J = [0, s, 0, 0] and de/dt = J nu. A column counts as passed, and
is forgotten, once it is `c` behind the body centre (x < -c).
"""

from __future__ import annotations

import math

import numpy as np

from cosim.apps.vs.tasks import Obstacle


def _finite(pos, yaw: float) -> bool:
    return all(math.isfinite(v) for v in (pos[0], pos[1], yaw))


class ObstacleMemory:
    def __init__(self, same_m: float = 0.5) -> None:
        self.columns: list[tuple[float, float]] = []
        self.same_m = same_m

    def see(self, ob: Obstacle, K: np.ndarray, width_m: float, pos, yaw: float,
            mount_x: float) -> tuple[float, float] | None:
        """Remember the column seen at `ob` from the vehicle at local `pos` (n, e, d) with
        heading `yaw` (rad); its local (n, e), or None without telemetry yet (NaN)."""
        if not _finite(pos, yaw):
            return None
        fx, cx = K[0, 0], K[0, 2]
        xl, xr = (ob.x_left_px - cx) / fx, (ob.x_right_px - cx) / fx
        Z = width_m / max(xr - xl, 1e-6)
        fwd, right = Z + mount_x, 0.5 * (xl + xr) * Z
        c, s = math.cos(yaw), math.sin(yaw)
        ne = (pos[0] + c * fwd - s * right, pos[1] + s * fwd + c * right)
        near = [i for i, (n, e) in enumerate(self.columns)
                if math.hypot(n - ne[0], e - ne[1]) < self.same_m]
        if near:
            self.columns[near[0]] = ne
        else:
            self.columns.append(ne)
        return ne

    def body(self, ne: tuple[float, float], pos, yaw: float) -> tuple[float, float]:
        """A local (n, e) in the body frame (forward, right; m)."""
        dn, de = ne[0] - pos[0], ne[1] - pos[1]
        c, s = math.cos(yaw), math.sin(yaw)
        return c * dn + s * de, -s * dn + c * de

    def nearest(self, pos, yaw: float, clearance_m: float, width_m: float
                ) -> tuple[float, float] | None:
        """The body (x, y) of the nearest column not yet passed (passed ones are forgotten),
        or None."""
        if not _finite(pos, yaw):
            return None
        c = clearance_m + 0.5 * width_m
        keep = [ne for ne in self.columns if self.body(ne, pos, yaw)[0] >= -c]
        self.columns = keep
        if not keep:
            return None
        return min((self.body(ne, pos, yaw) for ne in keep), key=lambda xy: xy[0])

    def task(self, pos, yaw: float, clearance_m: float, width_m: float
             ) -> tuple[float, np.ndarray, float] | None:
        """(e, J 1x4, x forward m) of the corridor task for the nearest column not passed,
        or None."""
        xy = self.nearest(pos, yaw, clearance_m, width_m)
        if xy is None:
            return None
        x, y = xy
        s = 1.0 if y >= 0.0 else -1.0
        return clearance_m + 0.5 * width_m - abs(y), np.array([[0.0, s, 0.0, 0.0]]), x
