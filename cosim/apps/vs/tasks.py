"""The two upper tasks of paper 2's hierarchy (Sec. 3.1-3.2), from the image.

Avoidance: the obstacle is a vertical column of a uniform saturated colour (green in the
paper), found by colour segmentation; p1, p2 are the left and right edges of its bounding box
at mid-height (Fig. 4). Eq. 8: e_a = ||m1 - m2|| - sigma (normalised coordinates); its
Jacobian (1/d) (m1 - m2)^T (L1 - L2) (Eq. 9) with depths estimated from the apparent width
(Z = width_m / d; ours: the paper says "estimated depths" without saying how). The task is
wanted while e_a > 0 (the column looks wider than sigma: it is closer than width / sigma).

Visibility: the mean of the current points must stay near the image centre; wanted while any
point leaves a safety rectangle (`margin` of the image size on each side). e_m = c_m - c_m*
(Eqs. 10-11), Jacobian: the interaction matrix of the mean point at an estimated depth.

To first order a sideways move does not change a column's apparent width, so the width task
mostly slows the approach and steers round only through second-order couplings (measured:
it passes E1's bar with a 1 s ramp, hits it with the paper's 3 s ramp, and hits E2's
cylinder); `corridor_task` (ours, the default) pushes the column out of the corridor the
vehicle sweeps instead. See its docstring.

Both Jacobians are returned in the 4 controllable body velocities (J cTe S^T).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cosim.apps.vs.features import gray_of
from cosim.apps.vs.geometry import interaction_point
from cosim.cvthreads import single_thread


@dataclass
class Obstacle:
    x_left_px: float
    x_right_px: float
    y_mid_px: float
    area_px: int


def find_obstacle(rgb: np.ndarray, hue_deg: tuple[float, float] = (70.0, 170.0),
                  s_min: int = 90, v_min: int = 40, min_height_frac: float = 0.15
                  ) -> Obstacle | None:
    """The largest blob of obstacle colour that stands at least `min_height_frac` of the
    image tall (a column), or None (also when the blob touches the left or right border).
    Of blobs of equal area, the first in raster order (its top row, then leftmost).

    Labelled piecewise, with the same result as over the whole frame: an image column
    without obstacle colour separates blobs (8-connected ones too), so the frame splits into
    vertical strips between such columns; a strip whose coloured pixels span fewer rows than
    a column needs holds none, and each other one is labelled within its box. On one OpenCV
    thread (a parallel labelling may number the blobs in another order)."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    lo = np.array([hue_deg[0] / 2.0, s_min, v_min], dtype=np.uint8)
    hi = np.array([hue_deg[1] / 2.0, 255, 255], dtype=np.uint8)
    mask = cv2.inRange(hsv, lo, hi)
    min_h = min_height_frac * rgb.shape[0]
    if cv2.boundingRect(mask)[3] < min_h:
        return None             # nothing of obstacle colour that tall (or nothing at all)
    used = np.flatnonzero(cv2.reduce(mask, 0, cv2.REDUCE_MAX).ravel())
    breaks = np.flatnonzero(np.diff(used) > 1)
    starts = [int(used[0]), *(int(used[i + 1]) for i in breaks)]
    stops = [*(int(used[i]) + 1 for i in breaks), int(used[-1]) + 1]
    best = None                 # (area, -top, -strip, -label), (x, y, w, h, area)
    with single_thread():
        for k, (c0, c1) in enumerate(zip(starts, stops, strict=True)):
            _, y0, _, bh = cv2.boundingRect(mask[:, c0:c1])
            if bh < min_h:
                continue
            n, _, stats, _ = cv2.connectedComponentsWithStats(mask[y0:y0 + bh, c0:c1],
                                                              connectivity=8)
            for i in range(1, n):
                x, y, w, h, area = (int(v) for v in stats[i])
                if h < min_h:
                    continue
                rank = (area, -(y + y0), -k, -i)
                if best is None or rank > best[0]:
                    best = (rank, (x + c0, y + y0, w, h, area))
    if best is None:
        return None
    x, y, w, h, area = best[1]
    if x <= 0 or x + w >= rgb.shape[1]:
        return None          # cut by the image border: its width would be wrong (leaving view)
    return Obstacle(float(x), float(x + w), y + 0.5 * h, area)


def frame_work(image: np.ndarray, avoidance: bool) -> tuple[np.ndarray, Obstacle | None]:
    """What the app needs of a frame whatever its state (its `FrameStage`: on the camera
    stream's worker when pipelined): the grey image, and the column it shows (None without
    avoidance)."""
    return gray_of(image), (find_obstacle(image) if avoidance else None)


def avoidance_task(ob: Obstacle, K: np.ndarray, sigma: float, width_m: float,
                   cam_from_body: np.ndarray) -> tuple[float, np.ndarray]:
    """(e_a, J_a 1x4) of Eqs. 8-9 for the obstacle seen at `ob`."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    y = (ob.y_mid_px - cy) / fy
    m1 = np.array([(ob.x_left_px - cx) / fx, y])
    m2 = np.array([(ob.x_right_px - cx) / fx, y])
    diff = m1 - m2
    d = float(np.linalg.norm(diff))
    d = max(d, 1e-6)
    Z = width_m / d
    L = interaction_point(m1[0], m1[1], Z) - interaction_point(m2[0], m2[1], Z)
    J6 = (diff @ L) / d
    return d - sigma, (J6 @ cam_from_body).reshape(1, -1)


def corridor_task(ob: Obstacle, K: np.ndarray, width_m: float, clearance_m: float,
                  cam_from_body: np.ndarray) -> tuple[float, np.ndarray]:
    """(e_c, J_c 1x4) of the corridor task (ours): the column must leave the corridor the
    vehicle sweeps, half-width `clearance_m` (body radius and margin) plus half the column.

    In normalised coordinates the corridor's edge at the column's depth Z is
    c = (clearance + width / 2) / Z, with Z = width / d from the apparent width d, and the
    column's centre is at x_o: e_c = c - |x_o| > 0 while the column is in the way. Its
    Jacobian: dc/dt = c / Z * v_z (camera forward speed brings the edge out) minus
    sign(x_o) dx_o/dt (the interaction matrix of the centre); a column dead ahead (x_o = 0)
    is passed on its left, i.e. the vehicle dodges to the left, deterministically. The yaw
    column is zeroed: a turn would satisfy the task in the image without moving the vehicle
    out of the column's way."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    xl, xr = (ob.x_left_px - cx) / fx, (ob.x_right_px - cx) / fx
    y = (ob.y_mid_px - cy) / fy
    d = max(xr - xl, 1e-6)
    Z = width_m / d
    x_o = 0.5 * (xl + xr)
    c = (clearance_m + 0.5 * width_m) / Z
    s = 1.0 if x_o >= 0.0 else -1.0
    J6 = -s * interaction_point(x_o, y, Z)[0]
    J6[2] += c / Z
    J = (J6 @ cam_from_body).reshape(1, -1)
    J[0, 3] = 0.0     # by translation only: turning moves the column in the image, not aside
    return c - abs(x_o), J


def lateral_hold(J: np.ndarray) -> np.ndarray:
    """The corridor task's Jacobian reduced to its sideways column: while the column is out
    of view (beside the vehicle) and the task ramps down, asking for no change of it keeps
    the vehicle from sliding back towards the column but lets it go forward."""
    out = np.zeros_like(J)
    out[0, 1] = J[0, 1]
    return out


def outside_rectangle(points_px: np.ndarray, targets_px: np.ndarray, width: int, height: int,
                      margin: float) -> bool:
    """Whether a point whose target lies inside the safety rectangle is outside it now (ours:
    the paper counts every point, but a point that belongs near the border in the key image
    cannot be kept inside, and counting it keeps the task on for good)."""
    def inside(p: np.ndarray) -> np.ndarray:
        x, y = p[:, 0], p[:, 1]
        return (x >= mx) & (x <= width - mx) & (y >= my) & (y <= height - my)

    if len(points_px) == 0:
        return False
    mx, my = margin * width, margin * height
    return bool(np.any(inside(targets_px) & ~inside(points_px)))


def visibility_task(points_px: np.ndarray, K: np.ndarray, depth_m: float,
                    cam_from_body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e_m 2, J_m 2x4) of Eqs. 10-12: the mean point to the principal point."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    mx = float(np.mean((points_px[:, 0] - cx) / fx))
    my = float(np.mean((points_px[:, 1] - cy) / fy))
    e_m = np.array([mx, my])
    return e_m, interaction_point(mx, my, depth_m) @ cam_from_body


def active_intervals(log: list[tuple[float, float]]) -> list[list[float]]:
    """[[t_on, t_off], ...] where a task's activation (t, h) was > 0 (t_off NaN if still on
    at the end)."""
    out: list[list[float]] = []
    on = False
    for t, h in log:
        if h > 0.0 and not on:
            out.append([t, math.nan])
            on = True
        elif h <= 0.0 and on:
            out[-1][1] = t
            on = False
    return out
