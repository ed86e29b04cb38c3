"""Sensor building blocks in plain floats (they run every 5 ms tick): seeded Gaussian noise
drawn in blocks, and the IMU's second-order sensor dynamics (reference/minidrone.md §2.1).
"""

from __future__ import annotations

import math

import cython
import numpy as np

BLOCK = 4096                 # normals drawn per refill (one numpy call per 4096 samples)


class Gauss:
    """Standard normal samples from one seeded stream, in a fixed order: `take(n)` (a list) or,
    compiled code, `at(n)` (the index in `buf` of the next n). Per scenario seed and per
    sensor: seed [scenario seed, 11, sensor index]."""

    __slots__ = ("rng", "buf", "i")

    def __init__(self, seed: int, sensor: int) -> None:
        self.rng = np.random.default_rng([seed, 11, sensor])
        self.buf = _block(np.empty(0))
        self.i = 0

    @cython.locals(i=cython.Py_ssize_t, j=cython.Py_ssize_t)
    def at(self, n: int) -> int:
        """The next n samples are buf[i:i + n] (n <= BLOCK; a block's tail shorter than n is
        skipped)."""
        i = self.i
        j = i + n
        if j > len(self.buf):
            self.buf = _block(self.rng.standard_normal(BLOCK))
            i, j = 0, n
        self.i = j
        return i

    @cython.locals(i=cython.Py_ssize_t, k=cython.Py_ssize_t)
    def take(self, n: int) -> list[float]:
        """The next n samples (n <= BLOCK)."""
        i = self.at(n)
        return [self.buf[k] for k in range(i, i + n)]


def _block(draws: np.ndarray):
    """A block of draws as `Gauss.buf` holds it: compiled, the numpy array itself, read as C
    doubles through a typed memoryview (imu.pxd); interpreted, a list of Python floats (numpy
    scalars would otherwise flow on into the readings). The same float64 values either way."""
    return draws if cython.compiled else draws.tolist()


class Imu3:
    """Three axes of one IMU sensor: the second-order dynamics (`SecondOrder`'s filter; per
    axis i its last inputs x1i, x2i and outputs y1i, y2i), then scale, bias, noise and the
    limit, in one call per tick: `read(u0, u1, u2, bias0, bias1, bias2, lim)`, the reading in
    o0, o1, o2 (C doubles when compiled: imu.pxd)."""

    __slots__ = ("b0", "b1", "b2", "a1", "a2", "x10", "x20", "y10", "y20", "x11", "x21", "y11",
                 "y21", "x12", "x22", "y12", "y22", "sc0", "sc1", "sc2", "ns0", "ns1", "ns2",
                 "gauss", "o0", "o1", "o2")

    def __init__(self, wn: float, zeta: float, h: float, x0: tuple[float, ...],
                 scale: tuple[float, ...], noise: tuple[float, ...], gauss: Gauss) -> None:
        f = SecondOrder(wn, zeta, h)
        self.b0, self.b1, self.b2, self.a1, self.a2 = f.b0, f.b1, f.b2, f.a1, f.a2
        self.x10 = self.x20 = self.y10 = self.y20 = x0[0]      # settled at x0
        self.x11 = self.x21 = self.y11 = self.y21 = x0[1]
        self.x12 = self.x22 = self.y12 = self.y22 = x0[2]
        self.sc0, self.sc1, self.sc2 = scale
        self.ns0, self.ns1, self.ns2 = noise
        self.gauss = gauss
        self.o0 = self.o1 = self.o2 = 0.0

    @cython.locals(i=cython.Py_ssize_t, buf=cython.double[::1], b0=cython.double,
                   b1=cython.double, b2=cython.double, a1=cython.double, a2=cython.double,
                   y0=cython.double, y1=cython.double, y2=cython.double, v=cython.double,
                   n0=cython.double, n1=cython.double, n2=cython.double)
    def read(self, u0: float, u1: float, u2: float, bias0: float, bias1: float, bias2: float,
             lim: float) -> None:
        """The reading in o0, o1, o2."""
        g = self.gauss
        i = g.at(3)
        buf = g.buf
        n0, n1, n2 = buf[i], buf[i + 1], buf[i + 2]      # C doubles when compiled
        b0, b1, b2, a1, a2 = self.b0, self.b1, self.b2, self.a1, self.a2
        y0 = b0 * u0 + b1 * self.x10 + b2 * self.x20 - a1 * self.y10 - a2 * self.y20
        self.x20, self.x10, self.y20, self.y10 = self.x10, u0, self.y10, y0
        y1 = b0 * u1 + b1 * self.x11 + b2 * self.x21 - a1 * self.y11 - a2 * self.y21
        self.x21, self.x11, self.y21, self.y11 = self.x11, u1, self.y11, y1
        y2 = b0 * u2 + b1 * self.x12 + b2 * self.x22 - a1 * self.y12 - a2 * self.y22
        self.x22, self.x12, self.y22, self.y12 = self.x12, u2, self.y12, y2
        v = y0 * self.sc0 + bias0 + self.ns0 * n0
        self.o0 = lim if v > lim else -lim if v < -lim else v
        v = y1 * self.sc1 + bias1 + self.ns1 * n1
        self.o1 = lim if v > lim else -lim if v < -lim else v
        v = y2 * self.sc2 + bias2 + self.ns2 * n2
        self.o2 = lim if v > lim else -lim if v < -lim else v


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

