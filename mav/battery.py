"""A simple LiPo battery model for BATTERY_STATUS / SYS_STATUS (telemetry only).

Current: avionics draw plus a motor draw proportional to sum(u_i^3) (rotor power ~ omega^3),
scaled so that hover (all u = u_hover) draws the preset's hover current. Charge integrates on
the HIL clock. Voltage: cells x open-circuit voltage(state of charge) - I x R_internal (sag).
The model does not feed back into the plant: thrust does not fade with voltage.

Faults (injected by the simulator over the HIL link, `mav/onboard/inject.py`): `lose_charge`
(a failed cell, capacity lost: the usable charge drops and stays lost; `lost_mah`, not drawn
through the current sensor, so BATTERY_STATUS current_consumed does not count it) and `sag`
(the internal resistance multiplied and / or a fixed voltage drop, until `sag(1, 0)`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cython


@dataclass(frozen=True)
class BatteryParams:
    capacity_mah: float      # mAh
    cells: int               # series cells
    r_internal: float        # Ohm, whole pack
    i_avionics: float        # A, draw with motors off
    i_hover: float           # A, total draw in hover


BATTERIES: dict[str, BatteryParams] = {
    # Parrot Mambo: 660 mAh 1S LiPo, about 8 min of hover.
    "mambo": BatteryParams(capacity_mah=660.0, cells=1, r_internal=0.08, i_avionics=0.3,
                           i_hover=4.5),
    # Parrot Bebop 2: 2700 mAh 3S LiPo, about 25 min of hover.
    "bebop2": BatteryParams(capacity_mah=2700.0, cells=3, r_internal=0.03, i_avionics=1.0,
                            i_hover=6.5),
}

# LiPo open-circuit cell voltage (V) against state of charge (0..1), piecewise linear.
_OCV = ((0.0, 3.30), (0.05, 3.50), (0.10, 3.60), (0.20, 3.70), (0.50, 3.80), (0.80, 3.95),
        (1.0, 4.20))


def cell_ocv(soc: float) -> float:
    """Open-circuit voltage of one cell (V) at state of charge `soc` (0..1, clamped)."""
    if soc <= 0.0:
        return _OCV[0][1]
    for (s0, v0), (s1, v1) in zip(_OCV, _OCV[1:], strict=False):
        if soc <= s1:
            return v0 + (v1 - v0) * (soc - s0) / (s1 - s0)
    return _OCV[-1][1]


class Battery:
    """State of one pack. `step(dt, u1..u4)` each tick; read `voltage`, `current`, ..."""

    __slots__ = ("p", "u_hover", "capacity_mah", "r_internal", "_k_motor", "_i_avionics",
                 "consumed_mah", "energy_j", "current", "_v_last", "lost_mah", "r_scale",
                 "v_drop")

    def __init__(self, p: BatteryParams, u_hover: float) -> None:
        self.p = p
        self.u_hover = u_hover
        self.capacity_mah = p.capacity_mah
        self.r_internal = p.r_internal
        self._k_motor = (p.i_hover - p.i_avionics) / (4.0 * u_hover ** 3)   # A per sum(u^3)
        self._i_avionics = p.i_avionics
        self.consumed_mah = 0.0     # mAh
        self.energy_j = 0.0         # J
        self.current = p.i_avionics  # A
        self._v_last = p.cells * cell_ocv(1.0)   # V, for the energy integral
        self.lost_mah = 0.0         # mAh, charge lost to a fault (never drawn, never usable)
        self.r_scale = 1.0          # a sag fault: the internal resistance x this
        self.v_drop = 0.0           # V, a sag fault: a further fixed drop

    def configure(self, capacity_mah: float, r_internal: float) -> None:
        """Override capacity (mAh) and internal resistance (Ohm); values <= 0 keep the preset's."""
        self.capacity_mah = capacity_mah if capacity_mah > 0.0 else self.p.capacity_mah
        self.r_internal = r_internal if r_internal > 0.0 else self.p.r_internal

    @cython.locals(i=cython.double)
    def step(self, dt: float, u1: float, u2: float, u3: float, u4: float) -> None:
        """Advance `dt` seconds with motor commands u1..u4 (0..1)."""
        i = self._i_avionics + self._k_motor * (u1 * u1 * u1 + u2 * u2 * u2 + u3 * u3 * u3
                                                 + u4 * u4 * u4)
        self.current = i
        self.consumed_mah += i * dt * (1000.0 / 3600.0)
        self.energy_j += self._v_last * i * dt    # voltage refreshed when telemetry reads it

    def lose_charge(self, remaining: float) -> None:
        """A fault: the state of charge drops to `remaining` (0..1) now, if it is above it;
        the charge lost stays lost (a later capacity change keeps the mAh lost)."""
        extra = (1.0 - remaining) * self.capacity_mah - self.consumed_mah - self.lost_mah
        if extra > 0.0:
            self.lost_mah += extra

    def sag(self, r_scale: float, v_drop: float) -> None:
        """A fault: the internal resistance x `r_scale` (> 0) and a further drop of `v_drop`
        V (>= 0) from now on; `sag(1.0, 0.0)` ends it."""
        self.r_scale = r_scale
        self.v_drop = v_drop

    @property
    def used_mah(self) -> float:
        """mAh no longer available: drawn plus lost to a fault (what the warnings compare)."""
        return self.consumed_mah + self.lost_mah

    @property
    def remaining(self) -> float:
        """State of charge, 0..1."""
        soc = 1.0 - (self.consumed_mah + self.lost_mah) / self.capacity_mah
        return soc if soc > 0.0 else 0.0

    @property
    def voltage(self) -> float:
        """Terminal voltage (V) under the present current."""
        v = (self.p.cells * cell_ocv(self.remaining) - self.current * self.r_internal
             * self.r_scale - self.v_drop)
        self._v_last = v = v if v > 0.0 else 0.0
        return v

    def time_remaining_s(self) -> float:
        """Seconds left at the present current."""
        left = self.capacity_mah - self.consumed_mah - self.lost_mah
        return max(0.0, left / self.current * 3.6) if self.current > 0.0 else 0.0
