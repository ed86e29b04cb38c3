"""Sensor models: plant outputs -> what the onboard stack is told (today: ODOMETRY).

Noise is drawn from the run's seeded generator, one draw per tick in a fixed order, so a run
is reproducible bit for bit. Without noise the measurement is the truth, untouched.
"""

from __future__ import annotations

import math
from operator import itemgetter

import numpy as np

from cosim.plant.fmu import Y_P, Y_Q, Y_QW, Y_QX, Y_QY, Y_QZ, Y_R, Y_VX, Y_VY, Y_VZ, Y_X, Y_Y, Y_Z
from cosim.scenario.records import SensorNoise

_TRUTH = itemgetter(Y_X, Y_Y, Y_Z, Y_QW, Y_QX, Y_QY, Y_QZ, Y_VX, Y_VY, Y_VZ, Y_P, Y_Q, Y_R)


class OdometrySensor:
    """Ground truth -> odometry tuple (x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r)."""

    def __init__(self, noise: SensorNoise, rng: np.random.Generator) -> None:
        self.noise = noise
        self.rng = rng
        self.noisy = noise.any
        self._std = np.array(
            [noise.pos_std_m] * 3 + [noise.att_std_rad] * 3 + [noise.vel_std_mps] * 3
            + [noise.rate_std_radps] * 3
        )
        if not self.noisy:   # the truth, picked out of y in C (operator.itemgetter): the same
            self.measure = _TRUTH  # tuple as `measure` below, without a Python call per tick

    def measure(self, y: list[float]) -> tuple[float, ...]:
        if not self.noisy:
            return (y[Y_X], y[Y_Y], y[Y_Z], y[Y_QW], y[Y_QX], y[Y_QY], y[Y_QZ],
                    y[Y_VX], y[Y_VY], y[Y_VZ], y[Y_P], y[Y_Q], y[Y_R])
        n = (self.rng.standard_normal(12) * self._std).tolist()
        # attitude noise: q_meas = q_true * dq(small rotation vector in body axes)
        ax, ay, az = n[3], n[4], n[5]
        ang = math.sqrt(ax * ax + ay * ay + az * az)
        if ang > 0.0:
            s = math.sin(0.5 * ang) / ang
            dw, dx, dy, dz = math.cos(0.5 * ang), ax * s, ay * s, az * s
        else:
            dw, dx, dy, dz = 1.0, 0.0, 0.0, 0.0
        w, x, yq, z = y[Y_QW], y[Y_QX], y[Y_QY], y[Y_QZ]
        qw = w * dw - x * dx - yq * dy - z * dz
        qx = w * dx + x * dw + yq * dz - z * dy
        qy = w * dy - x * dz + yq * dw + z * dx
        qz = w * dz + x * dy - yq * dx + z * dw
        return (y[Y_X] + n[0], y[Y_Y] + n[1], y[Y_Z] + n[2], qw, qx, qy, qz,
                y[Y_VX] + n[6], y[Y_VY] + n[7], y[Y_VZ] + n[8],
                y[Y_P] + n[9], y[Y_Q] + n[10], y[Y_R] + n[11])
