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

    def take(self, n: int) -> list[float]:
        """The next n samples (n <= BLOCK)."""
        i = self.i
        j = i + n
        if j > len(self.buf):
            self.buf = self.rng.standard_normal(BLOCK).tolist()
            i, j = 0, n
        self.i = j
        return self.buf[i:j]


class Imu3:
    """Three axes of one IMU sensor: the second-order dynamics (`SecondOrder`'s filter, its
    states in flat lists), then scale, bias, noise and the limit, in one call per tick."""

    __slots__ = ("c", "st", "scale", "noise", "gauss")

    def __init__(self, wn: float, zeta: float, h: float, x0: tuple[float, ...],
                 scale: tuple[float, ...], noise: tuple[float, ...], gauss: Gauss) -> None:
        f = SecondOrder(wn, zeta, h)
        self.c = (f.b0, f.b1, f.b2, f.a1, f.a2)
        self.st = [v for x in x0 for v in (x, x, x, x)]       # per axis x1, x2, y1, y2
        self.scale, self.noise, self.gauss = scale, noise, gauss

    def read(self, u0: float, u1: float, u2: float, bias: tuple[float, ...],
             lim: float) -> tuple[float, float, float]:
        b0, b1, b2, a1, a2 = self.c
        st, sc, ns = self.st, self.scale, self.noise
        nz = self.gauss.take(3)
        out = [0.0, 0.0, 0.0]
        for i, u in ((0, u0), (1, u1), (2, u2)):
            j = 4 * i
            x1, x2, y1, y2 = st[j], st[j + 1], st[j + 2], st[j + 3]
            y = b0 * u + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2
            st[j], st[j + 1], st[j + 2], st[j + 3] = u, x1, y, y1
            v = y * sc[i] + bias[i] + ns[i] * nz[i]
            out[i] = lim if v > lim else -lim if v < -lim else v
        return out[0], out[1], out[2]


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

