"""Wind: a steady mean, discrete 1-cos gusts and Dryden-type turbulence from a seeded stream.

Scenario `[wind]` (all optional; the plant takes the wind as an input every tick, NED m/s):

    [wind]
    n_mps = 0.5                # the mean wind, blowing towards North ...
    e_mps = 0.0                # ... East and down
    d_mps = 0.0

    [[wind.gust]]              # a discrete gust, "1 - cos" shape (MIL-F-8785C / MIL-HDBK-1797)
    start_s = 20.0
    duration_s = 3.0           # the gust rises and falls over this time
    amplitude_mps = 1.5        # peak speed added to the mean
    direction_deg = 90.0       # blowing towards (from North towards East)
    d_mps = 0.0                # optional vertical peak (down positive)

    [wind.turbulence]          # continuous turbulence, seeded by the scenario seed
    intensity_mps = 0.3        # sigma of each horizontal component (vertical: 0.5 sigma)
    length_m = 10.0            # scale length L

Turbulence is each component's first-order Dryden form (the longitudinal spectrum
sigma^2 2L/(pi V) / (1 + (L w / V)^2)), i.e. a Gauss-Markov process with time constant L / V,
discretised exactly per tick: x+ = a x + sigma sqrt(1 - a^2) n, a = exp(-V h / L). V is the
mean wind speed, at least 1 m/s (a hovering vehicle in still air still sees eddies pass).
The vertical sigma is half the horizontal one (near the ground). Same seed, same wind.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.scenario.validate import no_unknown, number


@dataclass(frozen=True)
class Gust:
    start_s: float
    duration_s: float
    amplitude_mps: float
    direction_deg: float
    d_mps: float = 0.0

    def at(self, t: float) -> tuple[float, float, float]:
        s = (t - self.start_s) / self.duration_s
        if not 0.0 <= s <= 1.0:
            return 0.0, 0.0, 0.0
        f = 0.5 * (1.0 - math.cos(2.0 * math.pi * s))
        a = math.radians(self.direction_deg)
        return (f * self.amplitude_mps * math.cos(a), f * self.amplitude_mps * math.sin(a),
                f * self.d_mps)


@dataclass(frozen=True)
class WindSpec:
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gusts: tuple[Gust, ...] = ()
    turbulence: tuple[float, float] | None = None     # (intensity m/s, length m)

    @property
    def steady(self) -> bool:
        return not self.gusts and self.turbulence is None


def parse_wind(wd: Mapping[str, Any]) -> WindSpec:
    no_unknown(wd, {"n_mps", "e_mps", "d_mps", "gust", "turbulence"}, "wind")
    mean = tuple(number(wd, k, "wind", 0.0, lo=-30.0, hi=30.0) for k in ("n_mps", "e_mps",
                                                                          "d_mps"))
    gl = wd.get("gust", [])
    if isinstance(gl, Mapping):
        gl = [gl]
    if not isinstance(gl, list):
        raise ScenarioError("wind.gust", gl, "a table or an array of tables ([[wind.gust]])")
    gusts = []
    for i, g in enumerate(gl):
        w = f"wind.gust[{i}]"
        if not isinstance(g, Mapping):
            raise ScenarioError(w, g, "a table")
        no_unknown(g, {"start_s", "duration_s", "amplitude_mps", "direction_deg", "d_mps"}, w)
        gusts.append(Gust(
            start_s=number(g, "start_s", w, lo=0.0, hi=1e6),
            duration_s=number(g, "duration_s", w, lo=0.0, lo_open=True, hi=1e4),
            amplitude_mps=number(g, "amplitude_mps", w, lo=0.0, hi=30.0),
            direction_deg=number(g, "direction_deg", w, 0.0, lo=-360.0, hi=360.0),
            d_mps=number(g, "d_mps", w, 0.0, lo=-10.0, hi=10.0)))
    turb = None
    if "turbulence" in wd:
        tb = wd["turbulence"]
        if not isinstance(tb, Mapping):
            raise ScenarioError("wind.turbulence", tb, "a table")
        no_unknown(tb, {"intensity_mps", "length_m"}, "wind.turbulence")
        turb = (number(tb, "intensity_mps", "wind.turbulence", lo=0.0, hi=10.0),
                number(tb, "length_m", "wind.turbulence", 10.0, lo=0.1, lo_open=False,
                       hi=1e4))
        if turb[0] == 0.0:
            turb = None
    return WindSpec(mean=mean, gusts=tuple(gusts), turbulence=turb)  # type: ignore[arg-type]


class WindField:
    """The wind at each tick (call `at(k)` with k = 0, 1, 2, ... in order)."""

    def __init__(self, spec: WindSpec, tick_s: float, seed: int) -> None:
        self.spec = spec
        self.h = tick_s
        self.x = np.zeros(3)
        self.rng = np.random.default_rng([seed, 3])
        if spec.turbulence is not None:
            sigma, L = spec.turbulence
            V = max(1.0, math.hypot(spec.mean[0], spec.mean[1]))
            self.a = math.exp(-V * tick_s / L)
            self.sig = np.array([sigma, sigma, 0.5 * sigma])
            self.x = self.sig * self.rng.standard_normal(3)    # start in the stationary state
            self.b = self.sig * math.sqrt(1.0 - self.a * self.a)

    def at(self, k: int) -> tuple[float, float, float]:
        n, e, d = self.spec.mean
        t = k * self.h
        for g in self.spec.gusts:
            gn, ge, gd = g.at(t)
            n, e, d = n + gn, e + ge, d + gd
        if self.spec.turbulence is not None:
            if k > 0:
                self.x = self.a * self.x + self.b * self.rng.standard_normal(3)
            n, e, d = n + float(self.x[0]), e + float(self.x[1]), d + float(self.x[2])
        return n, e, d
