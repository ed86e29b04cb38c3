"""Rotation helpers: conventions (body FRD -> world NED, Z-Y-X Euler) and round trips."""

import math

import numpy as np
import pytest

from cosim.frames import (
    R_from_quat,
    euler_from_quat,
    quat_conj,
    quat_from_euler,
    quat_from_R,
    quat_mul,
    rotate_ne,
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
    r, p, y = euler_from_quat(q)
    np.testing.assert_allclose(R_from_quat(quat_from_euler(r, p, y)), R, atol=1e-12)
    assert yaw_from_quat(q) == pytest.approx(y)
    q2 = quat_from_R(R)
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
