"""Rotations between body FRD and world NED: quaternions, Euler angles, matrices. The one place
they are written (the flight software's controllers, estimator and telemetry, the simulator's
cameras, plant adaptors and viewers all use it); compiled with the flight software
(mav/__init__.py), its scalar functions C calls for compiled callers (rotations.pxd).

Conventions (ARCHITECTURE.md "Frames"):

- quaternions are scalar first, ``q = (w, x, y, z)``, and rotate body vectors into the world:
  ``v_W = R_WB v_B`` with ``R_WB = R_from_quat(q_WB)``;
- Euler angles are the aerospace Z-Y-X sequence, ``R_WB = Rz(yaw) Ry(pitch) Rx(roll)``, in
  radians: positive roll = right side down, positive pitch = nose up, positive yaw = nose
  from North towards East.

A quaternion need not be of unit norm: the Euler angles, the yaw and ``tilt_cos`` are those of
the rotation ``q / |q|`` (every term is scaled by ``|q|^2`` and divided by it; for a quaternion
whose squared norm rounds to 1.0 that division is exact, so a unit quaternion gives the same
bits as the unit-only formulas did). ``rotate_body_to_world`` and ``rotate_world_to_body`` are
for unit quaternions (the state's); ``R_from_quat`` normalises and refuses a zero quaternion.
Tested against scipy's ``Rotation`` for unit and non-unit quaternions and at gimbal lock
(tests/test_rotations.py).
"""

from __future__ import annotations

import math

import cython
from cython.cimports.libc.math import asin as _asin
from cython.cimports.libc.math import atan2 as _atan2
from cython.cimports.libc.math import cos as _cos
from cython.cimports.libc.math import hypot as _hypot
from cython.cimports.libc.math import sin as _sin

__all__ = [
    "quat_from_euler", "euler_from_quat", "yaw_from_quat", "tilt_cos", "quat_mul", "quat_conj",
    "rotate_body_to_world", "rotate_world_to_body", "R_from_quat", "quat_from_R", "rotate_ne",
    "euler_to_world", "wrap_pi",
]

_PI = cython.declare(cython.double, math.pi)
_TWO_PI = cython.declare(cython.double, 2.0 * math.pi)


@cython.locals(cr=cython.double, sr=cython.double, cp=cython.double, sp=cython.double,
               cy=cython.double, sy=cython.double)
def quat_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """``q_WB`` (unit) of Z-Y-X Euler angles (rad): R_WB = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = _cos(0.5 * roll), _sin(0.5 * roll)
    cp, sp = _cos(0.5 * pitch), _sin(0.5 * pitch)
    cy, sy = _cos(0.5 * yaw), _sin(0.5 * yaw)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


@cython.locals(n2=cython.double, s=cython.double)
def euler_from_quat(qw: float, qx: float, qy: float, qz: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of the rotation of ``q_WB``: pitch in [-pi/2, pi/2], roll and
    yaw in [-pi, pi]. At gimbal lock (pitch +-pi/2) roll and yaw share one degree of freedom:
    roll is 0 and yaw holds the turn (scipy's choice too). A zero quaternion gives (0, 0, 0);
    NaN in, NaN out."""
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    s = 2.0 * (qw * qy - qz * qx)
    if n2 > 0.0:
        s = s / n2
    if s > 0.99999999 or s < -0.99999999:
        # near gimbal lock s says too little (a few ulps of rounding are all of 1 - |s|):
        # n2 cos(pitch) from the yaw terms; within 3e-8 of the lock roll and yaw turn about
        # the same axis and their terms are rounding noise, so roll is 0 and yaw holds the turn
        # (R[0][1] = -sin(yaw), R[1][1] = cos(yaw)), an error below 3e-8
        if not _hypot(2.0 * (qw * qz + qx * qy), n2 - 2.0 * (qy * qy + qz * qz)) > 3e-8 * n2:
            return (0.0, _asin(1.0 if s > 0.0 else -1.0),
                    _atan2(2.0 * (qw * qz - qx * qy), n2 - 2.0 * (qx * qx + qz * qz)))
    return (_atan2(2.0 * (qw * qx + qy * qz), n2 - 2.0 * (qx * qx + qy * qy)),
            _asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)),
            _atan2(2.0 * (qw * qz + qx * qy), n2 - 2.0 * (qy * qy + qz * qz)))


@cython.locals(n2=cython.double)
def yaw_from_quat(qw: float, qx: float, qy: float, qz: float) -> float:
    """Yaw (rad, ZYX, [-pi, pi]) of ``q_WB``: the heading of the body x axis from North."""
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    return _atan2(2.0 * (qw * qz + qx * qy), n2 - 2.0 * (qy * qy + qz * qz))


@cython.locals(n2=cython.double, c=cython.double)
def tilt_cos(qw: float, qx: float, qy: float, qz: float) -> float:
    """cos(roll) cos(pitch) of ``q_WB``: R_WB[2][2], how much of the body's thrust is vertical
    (0 for a zero quaternion)."""
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    c = n2 - 2.0 * (qx * qx + qy * qy)
    return c / n2 if n2 > 0.0 else c


def quat_mul(a, b) -> tuple[float, float, float, float]:
    """Hamilton product ``a * b`` (so ``R(a*b) = R(a) R(b)``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def quat_conj(q) -> tuple[float, float, float, float]:
    """Conjugate: for a unit quaternion the inverse rotation, q_BW from q_WB."""
    return (q[0], -q[1], -q[2], -q[3])


@cython.locals(tx=cython.double, ty=cython.double, tz=cython.double)
def rotate_body_to_world(qw: float, qx: float, qy: float, qz: float, bx: float, by: float,
                         bz: float) -> tuple[float, float, float]:
    """v_W = R_WB(q) v_B for a unit ``q_WB`` (v + 2w (u x v) + 2u x (u x v), u = (x, y, z))."""
    tx = 2.0 * (qy * bz - qz * by)
    ty = 2.0 * (qz * bx - qx * bz)
    tz = 2.0 * (qx * by - qy * bx)
    return (bx + qw * tx + qy * tz - qz * ty,
            by + qw * ty + qz * tx - qx * tz,
            bz + qw * tz + qx * ty - qy * tx)


def rotate_world_to_body(q, v) -> tuple[float, float, float]:
    """v_B = R_WB(q)^T v_W for a unit ``q_WB``: a world vector in body axes."""
    w, x, y, z = q
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return (r00 * v[0] + r10 * v[1] + r20 * v[2], r01 * v[0] + r11 * v[1] + r21 * v[2],
            r02 * v[0] + r12 * v[1] + r22 * v[2])


def R_from_quat(q):
    """Rotation matrix (3, 3 numpy array) of ``q = [w, x, y, z]``, normalised here; a zero or
    non-finite quaternion raises ValueError."""
    import numpy as np
    w, x, y, z = (float(v) for v in q)
    n = w * w + x * x + y * y + z * z
    if not n > 0.0 or not math.isfinite(n):
        raise ValueError(f"quaternion must be finite and non-zero, got {list(q)!r}")
    s = 2.0 / n
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    xx, xy, xz = s * x * x, s * x * y, s * x * z
    yy, yz, zz = s * y * y, s * y * z, s * z * z
    return np.array([[1.0 - (yy + zz), xy - wz, xz + wy],
                     [xy + wz, 1.0 - (xx + zz), yz - wx],
                     [xz - wy, yz + wx, 1.0 - (xx + yy)]])


def quat_from_R(R):
    """Unit quaternion ``[w, x, y, z]`` (numpy, w >= 0) of a rotation matrix (Shepperd's
    method)."""
    import numpy as np
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


def rotate_ne(fwd: float, right: float, yaw: float) -> tuple[float, float]:
    """A horizontal vector given along the heading (forward, right) in (North, East); yaw in
    rad (roll and pitch ignored: the vector lies in the horizontal plane)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return c * fwd - s * right, s * fwd + c * right


@cython.locals(sph=cython.double, cph=cython.double, sth=cython.double, cth=cython.double,
               sps=cython.double, cps=cython.double)
def euler_to_world(roll: float, pitch: float, yaw: float, x: float, y: float,
                   z: float) -> tuple[float, float, float]:
    """A body FRD vector (x, y, z) in world NED, by Z-Y-X Euler angles (rad)."""
    sph, cph, sth, cth = _sin(roll), _cos(roll), _sin(pitch), _cos(pitch)
    sps, cps = _sin(yaw), _cos(yaw)
    return (cth * cps * x + (sph * sth * cps - cph * sps) * y + (cph * sth * cps + sph * sps) * z,
            cth * sps * x + (sph * sth * sps + cph * cps) * y + (cph * sth * sps - sph * cps) * z,
            -sth * x + sph * cth * y + cph * cth * z)


def wrap_pi(a: float) -> float:
    """An angle (rad) wrapped into [-pi, pi)."""
    return (a + _PI) % _TWO_PI - _PI
