"""mav/rotations.py: conventions (body FRD -> world NED, Z-Y-X Euler), round trips, and scipy's
Rotation as the reference for unit and non-unit quaternions and at gimbal lock."""

import math

import numpy as np
import pytest

from mav.rotations import (
    R_from_quat,
    euler_from_quat,
    quat_conj,
    quat_from_euler,
    quat_from_R,
    quat_mul,
    rotate_body_to_world,
    rotate_ne,
    rotate_world_to_body,
    tilt_cos,
    yaw_from_quat,
)

RNG = np.random.default_rng(7)
ANGLES = [(RNG.uniform(-math.pi, math.pi), RNG.uniform(-1.4, 1.4), RNG.uniform(-math.pi, math.pi))
          for _ in range(50)]


def test_identity():
    np.testing.assert_allclose(R_from_quat([1, 0, 0, 0]), np.eye(3))
    np.testing.assert_allclose(quat_from_euler(0, 0, 0), [1, 0, 0, 0])


def test_sign_conventions():
    # yaw +90 deg: the nose (body x) points East
    R = R_from_quat(quat_from_euler(0, 0, math.pi / 2))
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # roll +: right wing (body y) goes down (+z in NED)
    R = R_from_quat(quat_from_euler(0.3, 0, 0))
    assert (R @ [0, 1, 0])[2] > 0
    # pitch +: nose (body x) goes up (-z in NED)
    R = R_from_quat(quat_from_euler(0, 0.3, 0))
    assert (R @ [1, 0, 0])[2] < 0


@pytest.mark.parametrize("rpy", ANGLES)
def test_round_trips(rpy):
    q = quat_from_euler(*rpy)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    R = R_from_quat(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    r, p, y = euler_from_quat(*q)
    np.testing.assert_allclose(R_from_quat(quat_from_euler(r, p, y)), R, atol=1e-12)
    assert yaw_from_quat(*q) == pytest.approx(y)
    q2 = quat_from_R(R)
    q = np.array(q)
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9
    # Z-Y-X composition
    c, s = math.cos, math.sin
    Rz = np.array([[c(y), -s(y), 0], [s(y), c(y), 0], [0, 0, 1]])
    Ry = np.array([[c(p), 0, s(p)], [0, 1, 0], [-s(p), 0, c(p)]])
    Rx = np.array([[1, 0, 0], [0, c(r), -s(r)], [0, s(r), c(r)]])
    np.testing.assert_allclose(Rz @ Ry @ Rx, R, atol=1e-12)


def test_quat_mul_and_conj():
    a, b = quat_from_euler(0.1, -0.2, 0.3), quat_from_euler(-0.4, 0.5, 2.0)
    np.testing.assert_allclose(R_from_quat(quat_mul(a, b)), R_from_quat(a) @ R_from_quat(b),
                               atol=1e-12)
    np.testing.assert_allclose(quat_mul(a, quat_conj(a)), [1, 0, 0, 0], atol=1e-12)


def test_unnormalised_quaternion_is_normalised_and_zero_rejected():
    np.testing.assert_allclose(R_from_quat([2, 0, 0, 0]), np.eye(3))
    with pytest.raises(ValueError, match="quaternion"):
        R_from_quat([0, 0, 0, 0])


def test_rotate_ne():
    assert rotate_ne(1.0, 0.0, 0.0) == pytest.approx((1.0, 0.0))
    assert rotate_ne(1.0, 0.0, math.pi / 2) == pytest.approx((0.0, 1.0), abs=1e-12)
    assert rotate_ne(0.0, 1.0, math.pi / 2) == pytest.approx((-1.0, 0.0), abs=1e-12)


# ---- scipy's Rotation as the reference ------------------------------------------------------
from scipy.spatial.transform import Rotation  # noqa: E402

QUATS = [tuple(RNG.normal(size=4)) for _ in range(200)]          # any norm: scipy normalises


def _scipy(q):
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w])                         # scipy is scalar last


def _matrix_of_euler(r, p, y):
    return Rotation.from_euler("ZYX", [y, p, r]).as_matrix()


@pytest.mark.parametrize("scale", [1.0, 1e-3, 0.5, 3.0, 1e3])
def test_euler_yaw_and_tilt_match_scipy_for_any_norm(scale):
    for q in QUATS:
        q = tuple(scale * v / math.sqrt(sum(c * c for c in q)) for v in q)
        ref = _scipy(q)
        yaw, pitch, roll = ref.as_euler("ZYX")
        r, p, y = euler_from_quat(*q)
        assert (r, p, y) == pytest.approx((roll, pitch, yaw), abs=1e-9)
        assert yaw_from_quat(*q) == pytest.approx(yaw, abs=1e-9)
        assert tilt_cos(*q) == pytest.approx(ref.as_matrix()[2, 2], abs=1e-12)
        np.testing.assert_allclose(R_from_quat(q), ref.as_matrix(), atol=1e-12)
        np.testing.assert_allclose(_matrix_of_euler(r, p, y), ref.as_matrix(), atol=1e-9)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2])
@pytest.mark.parametrize("scale", [1.0, 0.2, 7.0])
def test_gimbal_lock_gives_the_same_rotation(pitch, scale):
    """At pitch +-90 deg roll and yaw are not unique; the angles must still give the rotation
    (scipy warns and picks another pair)."""
    for roll, yaw in [(0.0, 0.0), (0.3, -1.1), (-2.0, 2.5), (math.pi, 0.4)]:
        q = tuple(scale * v for v in quat_from_euler(roll, pitch, yaw))
        ref = _scipy(q).as_matrix()
        r, p, y = euler_from_quat(*q)
        assert abs(p) == pytest.approx(math.pi / 2, abs=1e-7)
        np.testing.assert_allclose(_matrix_of_euler(r, p, y), ref, atol=1e-7)


def test_quat_from_euler_matches_scipy():
    for r, p, y in ANGLES:
        q = quat_from_euler(r, p, y)
        np.testing.assert_allclose(R_from_quat(q), _matrix_of_euler(r, p, y), atol=1e-12)


def test_vectors_rotate_as_scipy_says():
    v = np.array([0.3, -1.2, 2.0])
    for q in QUATS[:50]:
        q = tuple(np.array(q) / np.linalg.norm(q))
        ref = _scipy(q)
        np.testing.assert_allclose(rotate_body_to_world(*q, *v), ref.apply(v), atol=1e-12)
        np.testing.assert_allclose(rotate_world_to_body(q, v), ref.inv().apply(v), atol=1e-12)
        np.testing.assert_allclose(R_from_quat(quat_mul(q, quat_conj(q))), np.eye(3), atol=1e-12)


def test_degenerate_quaternions_never_raise_in_the_flight_functions():
    """The controller and telemetry call these every tick: a zero quaternion (a corrupt
    state) gives level angles, NaN gives NaN, never an exception."""
    assert euler_from_quat(0.0, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0)
    assert yaw_from_quat(0.0, 0.0, 0.0, 0.0) == 0.0
    assert tilt_cos(0.0, 0.0, 0.0, 0.0) == 0.0
    assert all(math.isnan(a) for a in euler_from_quat(math.nan, 0.0, 0.0, 1.0))


def test_a_unit_quaternion_gives_the_bits_of_the_unit_only_formulas():
    """Where |q|^2 rounds to 1.0 the general formulas are the unit-only ones, bit for bit."""
    for r, p, y in ANGLES:
        qw, qx, qy, qz = quat_from_euler(r, p, y)
        if qw * qw + qx * qx + qy * qy + qz * qz != 1.0:
            continue
        sp = 2.0 * (qw * qy - qz * qx)
        old = (math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy)),
               math.asin(max(-1.0, min(1.0, sp))),
               math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz)))
        assert euler_from_quat(qw, qx, qy, qz) == old
