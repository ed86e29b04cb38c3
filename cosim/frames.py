"""Rotations between body FRD and world NED: quaternions, matrices, Euler angles.

Conventions (ARCHITECTURE.md):
- quaternions are scalar first, ``q = [w, x, y, z]``, unit norm, and rotate body vectors into
  the world: ``v_W = R_WB @ v_B`` with ``R_WB = R_from_quat(q_WB)``;
- Euler angles are the aerospace Z-Y-X sequence: ``R_WB = Rz(yaw) @ Ry(pitch) @ Rx(roll)``,
  radians. Positive roll = right wing down, positive pitch = nose up, positive yaw = nose
  turns from North towards East.

The functions take and return plain floats or small numpy arrays; the scalar helpers
(``yaw_from_quat``) avoid numpy so they are cheap on a 200 Hz path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "R_from_quat",
    "quat_from_R",
    "quat_from_euler",
    "euler_from_quat",
    "quat_mul",
    "quat_conj",
    "yaw_from_quat",
    "rotate_ne",
]


def R_from_quat(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix (3, 3) of the unit quaternion ``q = [w, x, y, z]`` (normalised here)."""
    w, x, y, z = (float(v) for v in q)
    n = w * w + x * x + y * y + z * z
    if not n > 0.0 or not math.isfinite(n):
        raise ValueError(f"quaternion must be finite and non-zero, got {list(q)!r}")
    s = 2.0 / n
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    xx, xy, xz = s * x * x, s * x * y, s * x * z
    yy, yz, zz = s * y * y, s * y * z, s * z * z
    return np.array(
        [
            [1.0 - (yy + zz), xy - wz, xz + wy],
            [xy + wz, 1.0 - (xx + zz), yz - wx],
            [xz - wy, yz + wx, 1.0 - (xx + yy)],
        ]
    )


def quat_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` (w >= 0) of a rotation matrix (Shepperd's method)."""
    m = np.asarray(R, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    qa = np.array(q)
    qa /= np.linalg.norm(qa)
    return -qa if qa[0] < 0.0 else qa


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``q_WB`` for Z-Y-X Euler angles (rad): R_WB = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def euler_from_quat(q: Sequence[float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of ``q_WB``; pitch in [-pi/2, pi/2], yaw in (-pi, pi]."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sp = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch = math.asin(sp)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def yaw_from_quat(q: Sequence[float]) -> float:
    """Yaw (rad, (-pi, pi]) of ``q_WB``: heading of the body x axis, from North towards East."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def quat_mul(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Hamilton product ``a * b`` (so ``R(a*b) = R(a) @ R(b)``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dtype=float,
    )


def quat_conj(q: Sequence[float]) -> np.ndarray:
    """Conjugate (the inverse rotation for a unit quaternion): q_BW from q_WB."""
    return np.array([q[0], -q[1], -q[2], -q[3]], dtype=float)


def rotate_ne(fwd: float, right: float, yaw: float) -> tuple[float, float]:
    """A horizontal vector given along the heading (forward, right) expressed in (North, East).

    ``fwd`` is along the yaw-rotated body x axis, ``right`` along the yaw-rotated body y axis;
    yaw in rad. Roll and pitch are ignored (the vector lies in the horizontal plane).
    """
    c, s = math.cos(yaw), math.sin(yaw)
    return c * fwd - s * right, s * fwd + c * right
