"""An app that flies a fixed list of setpoints: the reference mission for tests and tuning.

Parameters (scenario `[app.params]`):
- `takeoff_alt_m` (m): AUTO.TAKEOFF altitude above the floor.
- `waypoints`: list of [n, e, d, hold_s] position setpoints, world NED (m) and the time (s) to
  stay within `tolerance_m` before going to the next; an optional fifth number is the heading
  (yaw_deg, from North towards East) to hold there (else the heading is not commanded).
- `velocity_legs`: list of [vn, ve, vd, duration_s] velocity setpoints flown after the
  waypoints, each for its duration.
- `tolerance_m` (m), `setpoint_every` (ticks between setpoints; 1 = 200 Hz).
Metrics: `position_error_max_m`, the largest distance to a waypoint at the moment it was
counted as reached plus the hold time (so a hold that wanders is seen).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cosim.apps.base import NAN, AppContext, FlightSequencer, check_params

DEFAULTS: dict[str, Any] = {
    "takeoff_alt_m": 1.0,
    "waypoints": [],
    "velocity_legs": [],
    "tolerance_m": 0.10,
    "setpoint_every": 4,
}


def _rows(value: Any, name: str, width: int, optional: int = 0) -> list[tuple[float, ...]]:
    """Rows of `width` numbers (or up to `optional` more; missing ones are NaN)."""
    n = f"{width}" if not optional else f"{width} to {width + optional}"
    if not isinstance(value, list):
        raise ValueError(f"app.params.{name}: expected a list of [{n} numbers] rows")
    rows = []
    for i, r in enumerate(value):
        if (not isinstance(r, list) or not width <= len(r) <= width + optional
                or not all(isinstance(x, int | float) and not isinstance(x, bool)
                           and math.isfinite(x) for x in r)):
            raise ValueError(f"app.params.{name}[{i}]: got {r!r}; expected {n} finite numbers")
        rows.append(tuple(float(x) for x in r) + (NAN,) * (width + optional - len(r)))
    return rows


class ScriptedApp:
    def __init__(self, params: dict[str, Any]) -> None:
        p = check_params(params, DEFAULTS, "scripted")
        self.waypoints = _rows(p["waypoints"], "waypoints", 4, optional=1)
        self.legs = _rows(p["velocity_legs"], "velocity_legs", 4)
        if not self.waypoints and not self.legs:
            raise ValueError("app.params: scripted needs `waypoints` or `velocity_legs`")
        self.tol = float(p["tolerance_m"])
        self.every = int(p["setpoint_every"])
        if self.every < 1:
            raise ValueError("app.params.setpoint_every: expected an integer >= 1")
        self.seq = FlightSequencer(takeoff_alt_m=float(p["takeoff_alt_m"]))
        self.events = self.seq.events
        self.phase = "prelude"
        self.done = False
        self.setpoint = [NAN, NAN, NAN]
        self._i = 0                   # index in waypoints, then in legs
        self._t_in = NAN              # s, when the current waypoint was first within tolerance
        self._t_leg = NAN
        self._k = 0
        self._err_max = 0.0

    def on_start(self, ctx: AppContext) -> None:
        self.ctx = ctx
        self.client = ctx.client
        self._hold = (0.0, 0.0, -float(self.seq.takeoff_alt_m))   # local: above the start
        # the waypoints are world NED (the scenario's frame); the vehicle flies local NED
        self.waypoints = [(*ctx.local(n, e, d), hold, yaw) for n, e, d, hold, yaw
                          in self.waypoints]

    def on_frame(self, t: float, image: np.ndarray) -> None:
        pass

    def on_tick(self, t: float) -> None:
        c = self.client
        c.poll(t)
        self._k += 1
        if self.phase == "prelude":
            if self.seq.step(t, c, self._hold):
                self.phase = "waypoints" if self.waypoints else "velocity"
                self._t_leg = t
            return
        if self.phase == "waypoints":
            n, e, d, hold, yaw_deg = self.waypoints[self._i]
            self.setpoint[0], self.setpoint[1], self.setpoint[2] = n, e, d
            if self._k % self.every == 0:
                c.set_position_target(n, e, d, yaw=math.radians(yaw_deg))
            px, py, pz = c.position
            err = math.sqrt((px - n) ** 2 + (py - e) ** 2 + (pz - d) ** 2)
            if math.isnan(self._t_in):
                if err <= self.tol:
                    self._t_in = t
            else:
                self._err_max = max(self._err_max, err)
                if t - self._t_in >= hold:
                    self._i += 1
                    self._t_in = NAN
                    if self._i == len(self.waypoints):
                        self._i = 0
                        self.phase = "velocity" if self.legs else "landing"
                        self._t_leg = t
            return
        if self.phase == "velocity":
            vn, ve, vd, dur = self.legs[self._i]
            self.setpoint[0] = self.setpoint[1] = self.setpoint[2] = NAN
            if self._k % self.every == 0:
                c.set_velocity_target(vn, ve, vd)
            if t - self._t_leg >= dur:
                self._i += 1
                self._t_leg = t
                if self._i == len(self.legs):
                    self.phase = "landing"
            return
        if self.phase == "landing":
            self.seq.land(t, c)
            self.seq.step(t, c, self._hold)
            if self.seq.state == "landed":
                self.phase = "done"
                self.done = True

    def metrics(self) -> dict[str, float]:
        return {"position_error_max_m": self._err_max}
