"""Records shared by the onboard stack's parts (estimator -> controller, modes -> controller).

Plain mutable objects with __slots__ and float fields, preallocated once and updated in place
on the control path (embedded style: no allocation per tick). World NED, body FRD, SI units.
"""

from __future__ import annotations

import math

NAN = math.nan


class VehicleState:
    """The estimate the controller acts on (today: ground truth from ODOMETRY)."""

    __slots__ = ("t", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r")

    def __init__(self) -> None:
        self.t = 0.0                               # s, vehicle (HIL) clock
        self.x = self.y = self.z = 0.0             # m, world NED
        self.vx = self.vy = self.vz = 0.0          # m/s, world NED
        self.qw, self.qx, self.qy, self.qz = 1.0, 0.0, 0.0, 0.0  # body->world, scalar first
        self.p = self.q = self.r = 0.0             # rad/s, body FRD rates


class Setpoint:
    """What the controller should track. NaN in a field means "not commanded".

    Horizontal: position (x, y) with optional velocity feed-forward (vx, vy), or velocity only
    (x, y NaN); an optional acceleration feed-forward (ax, ay, m/s^2, world) adds the tilt it
    needs (the automatic modes' trajectories set it). Vertical: position z, or velocity vz
    only (z NaN). Heading: yaw (rad), or yaw_rate (rad/s) when yaw is NaN; both NaN holds the
    current heading.
    `armed` False means motors off (u = 0).
    """

    __slots__ = ("x", "y", "z", "vx", "vy", "vz", "yaw", "yaw_rate", "armed", "ax", "ay")

    def __init__(self) -> None:
        self.x = self.y = self.z = NAN
        self.vx = self.vy = self.vz = NAN
        self.yaw = self.yaw_rate = NAN
        self.ax = self.ay = NAN
        self.armed = False

    def clear(self) -> None:
        self.x = self.y = self.z = NAN
        self.vx = self.vy = self.vz = NAN
        self.yaw = self.yaw_rate = NAN
        self.ax = self.ay = NAN
