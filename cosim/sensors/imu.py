"""Sensor building blocks in plain floats (they run every 5 ms tick): seeded Gaussian noise
drawn in blocks, and the IMU's second-order sensor dynamics (reference/minidrone.md §2.1).
"""

from __future__ import annotations

import math

import numpy as np

BLOCK = 4096                 # normals drawn per refill (one numpy call per 4096 samples)


class Gauss:
    """Standard normal samples from one seeded stream, in a fixed order: `next()`.
    Per scenario seed and per sensor: seed [scenario seed, 11, sensor index]."""

    __slots__ = ("rng", "buf", "i")

    def __init__(self, seed: int, sensor: int) -> None:
        self.rng = np.random.default_rng([seed, 11, sensor])
        self.buf: list[float] = []
        self.i = 0

    def next(self) -> float:
        i = self.i
        if i >= len(self.buf):
            self.buf = self.rng.standard_normal(BLOCK).tolist()
            i = 0
        self.i = i + 1
        return self.buf[i]


class SecondOrder:
    """wn^2 / (s^2 + 2 zeta wn s + wn^2), discretised with the bilinear transform (prewarped
    at wn) at step h; one instance per axis, unity DC gain. Starts settled at `x0`."""

    __slots__ = ("b0", "b1", "b2", "a1", "a2", "x1", "x2", "y1", "y2")

    def __init__(self, wn: float, zeta: float, h: float, x0: float = 0.0) -> None:
        k = wn / math.tan(wn * h / 2.0)          # prewarped 2/h
        w2 = wn * wn
        a0 = k * k + 2.0 * zeta * wn * k + w2
        self.b0 = w2 / a0
        self.b1 = 2.0 * w2 / a0
        self.b2 = w2 / a0
        self.a1 = (2.0 * w2 - 2.0 * k * k) / a0
        self.a2 = (k * k - 2.0 * zeta * wn * k + w2) / a0
        self.x1 = self.x2 = self.y1 = self.y2 = x0

    def step(self, x: float) -> float:
        y = (self.b0 * x + self.b1 * self.x1 + self.b2 * self.x2
             - self.a1 * self.y1 - self.a2 * self.y2)
        self.x2, self.x1 = self.x1, x
        self.y2, self.y1 = self.y1, y
        return y


def clamp(v: float, lim: float) -> float:
    return lim if v > lim else -lim if v < -lim else v
