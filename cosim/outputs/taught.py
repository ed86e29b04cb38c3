"""Metrics of a run against the path an app was taught (teach-and-repeat, paper 2).

The app exposes `reference_poses` (the true poses its key images were taken at: [n, e, d m,
yaw deg], never given to its controller) and reports `goal_time_s` (when it reached the last
key) in its metrics. From the recorded true state:
- final_pose_error_m / final_yaw_error_deg: the vehicle at goal_time_s against the last key.
- path_error_rms_m / path_error_max_m: 3-D distance from the vehicle to the taught polyline
  (the vehicle's position when the repeat began, then the keys in order), over the repeat
  (from the app's 'repeat' event to goal_time_s, or to the end of the run).
- mean_forward_speed_mps: mean body-forward speed over the same span; repeat_time_s its
  length; taught_path_length_m the polyline's length and taught_path_speed_mps that length
  over repeat_time_s when the goal was reached (paper 2's "7.71 m in 51.32 s").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _yaw(qw, qx, qy, qz):
    return np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def distance_to_polyline(P: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Distance of each row of P (N x 3) to the polyline through the rows of V (M x 3)."""
    if len(V) == 1:
        return np.linalg.norm(P - V[0], axis=1)
    best = np.full(len(P), np.inf)
    for a, b in zip(V[:-1], V[1:], strict=False):
        ab = b - a
        L2 = float(ab @ ab)
        s = np.zeros(len(P)) if L2 == 0.0 else np.clip((P - a) @ ab / L2, 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(P - (a + s[:, None] * ab), axis=1))
    return best


def taught_metrics(res, app_metrics: dict[str, Any]) -> dict[str, Any]:
    poses = np.array(res.reference_poses, dtype=float)
    t, x, y, z, vx, vy, qw, qx, qy, qz = res.recorded.columns(
        "t", "x", "y", "z", "vx", "vy", "qw", "qx", "qy", "qz")
    m: dict[str, Any] = {}
    if len(t) == 0:
        return m
    t_rep = next((tt for tt, name in res.events if name == "repeat"), None)
    t_goal = app_metrics.get("goal_time_s")
    if t_rep is None:
        return m
    t_end = t_goal if t_goal is not None else float(t[-1])
    span = (t >= t_rep) & (t <= t_end)
    if not span.any():
        return m
    i0 = int(np.argmax(span))
    P = np.column_stack((x[span], y[span], z[span]))
    V = np.vstack(([x[i0], y[i0], z[i0]], poses[:, :3]))
    d = distance_to_polyline(P, V)
    m["path_error_rms_m"] = float(np.sqrt(np.mean(d**2)))
    m["path_error_max_m"] = float(d.max())
    yaw = _yaw(qw[span], qx[span], qy[span], qz[span])
    m["mean_forward_speed_mps"] = float(np.mean(vx[span] * np.cos(yaw) + vy[span] * np.sin(yaw)))
    m["repeat_time_s"] = float(t_end - t_rep)
    m["taught_path_length_m"] = float(np.sum(np.linalg.norm(np.diff(V, axis=0), axis=1)))
    if t_goal is not None and t_end > t_rep:
        m["taught_path_speed_mps"] = m["taught_path_length_m"] / m["repeat_time_s"]
    if t_goal is not None:
        i = min(int(np.searchsorted(t, t_goal)), len(t) - 1)
        n, e, dd, yaw_deg = poses[-1]
        m["final_pose_error_m"] = math.dist((x[i], y[i], z[i]), (n, e, dd))
        err = math.degrees(float(_yaw(qw[i], qx[i], qy[i], qz[i]))) - yaw_deg
        m["final_yaw_error_deg"] = abs((err + 180.0) % 360.0 - 180.0)
    return m
