"""Estimation error of a sensor-fed run (`[sensors] feed = "hil"`): the vehicle's estimate
(RunResult.estimate, logged from the ODOMETRY after each HIL answer) against the truth of the
same tick. Ticks where the vehicle had no estimate yet (NaN) are left out."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cosim.outputs.series import ESTIMATE_COLUMNS


def estimation_metrics(res) -> dict[str, Any]:
    e = res.estimate
    if e is None or not len(e):
        return {}
    n = min(len(e), res.ticks)
    t = res.recorded.columns("x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz")
    x, y, z, vx, vy, vz, qw, qx, qy, qz = (c[:n] for c in t)
    e = e[:n]
    ok = np.isfinite(e[:, 0])
    if not ok.any():
        return {}
    dp = np.sqrt((e[:, 0] - x) ** 2 + (e[:, 1] - y) ** 2 + (e[:, 2] - z) ** 2)[ok]
    dv = np.sqrt((e[:, 3] - vx) ** 2 + (e[:, 4] - vy) ** 2 + (e[:, 5] - vz) ** 2)[ok]
    roll = np.arctan2(2 * (qw * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy))
    pitch = np.arcsin(np.clip(2 * (qw * qy - qz * qx), -1.0, 1.0))
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    wrap = lambda a: (a + math.pi) % (2 * math.pi) - math.pi   # noqa: E731
    da = np.sqrt(wrap(e[:, 6] - roll) ** 2 + wrap(e[:, 7] - pitch) ** 2
                 + wrap(e[:, 8] - yaw) ** 2)[ok]
    lost = e[:, ESTIMATE_COLUMNS.index("est_lost")][ok]
    h = res.scenario.timing.tick_s
    return {"estimation_error_pos_rms_m": float(np.sqrt(np.mean(dp ** 2))),
            "estimation_error_pos_max_m": float(dp.max()),
            "estimation_error_att_rms_deg": float(np.degrees(np.sqrt(np.mean(da ** 2)))),
            "estimation_error_vel_rms_mps": float(np.sqrt(np.mean(dv ** 2))),
            "estimation_lost_s": float(lost.sum() * h)}
