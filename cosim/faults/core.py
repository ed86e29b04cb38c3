"""Fault injection: the scenario's `[faults]` table, played through the master's hooks seam
(`cosim/sim/hooks.py`) between the parts, never inside them.

    [[faults.link]]            # a MAVLink link between the app / ground station and the vehicle
    link = "api"               # api (the app's) | gcs
    direction = "both"         # to_vehicle | from_vehicle | both
    start_s = 0.0              # active over [start_s, end_s) of simulated time (end: the run's)
    end_s = 30.0
    loss = 0.2                 # each datagram dropped with this probability
    burst_enter = 0.0          # Gilbert-Elliott bursts: a good link turns bad with this
    burst_exit = 0.3           #   probability per datagram, a bad one good again with this;
                               #   a bad link drops everything
    latency_ms = 0.0           # added one-way delay ...
    jitter_ms = 0.0            # ... plus a uniform extra in [0, jitter] (may reorder)
    duplicate = 0.0            # a datagram delivered twice with this probability
    reorder = 0.0              # a datagram held back behind the next one with this probability
    outage = false             # true: nothing passes in [start_s, end_s)

    [[faults.odometry]]        # the state estimate the vehicle receives (HIL ODOMETRY)
    kind = "dropout"           # dropout: the estimate fails (quality -1, position and velocity
                               # stale, attitude live) | bias | noise
    start_s = 20.0
    end_s = 22.0
    bias_m = [0.3, 0.0, 0.0]   # bias: added to the position N, E, D
    std_m = 0.05               # noise: extra position noise (sigma), velocity sigma std_m / 0.1 s

    [[faults.camera]]
    kind = "freeze"            # freeze (the last frame repeats) | black | drop
    start_s = 10.0
    end_s = 11.0
    p = 1.0                    # drop: the fraction of frames dropped

    [[faults.motor]]
    motor = 1                  # 1..4 (PX4 quad-X order)
    thrust = 0.5               # the fraction of its thrust left (0: dead)
    start_s = 15.0             # end_s optional

    [[faults.battery]]         # the flight stack's battery, over the HIL link as MAVLink
    kind = "sag"               # sag: voltage sag over [start_s, end_s) | drain: the charge
    start_s = 20.0             #   drops to `remaining` at start_s (cosim/faults/battery.py)
    r_factor = 3.0             # sag: internal resistance x this; drop_v: a fixed drop (V)

Wind gusts are `[[wind.gust]]` (cosim/world/wind.py). Every random choice comes from one
stream per fault seeded by (scenario seed, 9, fault index), drawn in the order datagrams and
ticks happen, so a run is deterministic and MIL == SIL holds (the wrappers sit in the master's
process on the app's end of each link in both modes; battery faults, not random, on the
master's end of the HIL link). Link time is simulated time: a delayed datagram to the vehicle
is released at the start of the tick it is due, before the app's tick and the HIL exchange;
one from the vehicle is handed to the app when due. `fired()` lists when
each fault first took effect and, at the end, what it did (datagrams dropped, ...).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.faults.battery import END, BatteryFault, HilInjector, parse_battery
from cosim.scenario.validate import boolean, integer, no_unknown, number, string


@dataclass(frozen=True)
class LinkFault:
    link: str
    direction: str
    start_s: float
    end_s: float
    loss: float
    burst_enter: float
    burst_exit: float
    latency_ms: float
    jitter_ms: float
    duplicate: float
    reorder: float
    outage: bool


@dataclass(frozen=True)
class OdometryFault:
    kind: str
    start_s: float
    end_s: float
    bias_m: tuple[float, float, float]
    std_m: float


@dataclass(frozen=True)
class CameraFault:
    kind: str
    start_s: float
    end_s: float
    p: float


@dataclass(frozen=True)
class MotorFault:
    motor: int
    thrust: float
    start_s: float
    end_s: float


@dataclass(frozen=True)
class FaultSpec:
    links: tuple[LinkFault, ...] = ()
    odometry: tuple[OdometryFault, ...] = ()
    camera: tuple[CameraFault, ...] = ()
    motors: tuple[MotorFault, ...] = ()
    battery: tuple[BatteryFault, ...] = ()
    sensors: tuple = ()       # cosim.faults.sensors.SensorFault: played by the sensor models

    def __bool__(self) -> bool:
        return bool(self.links or self.odometry or self.camera or self.motors or self.battery)


# ------------------------------------------------------------------ parsing
def _entries(raw: Mapping, key: str) -> list[tuple[str, dict]]:
    v = raw.get(key, [])
    if isinstance(v, Mapping):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(e, Mapping) for e in v):
        raise ScenarioError(f"faults.{key}", v, "a list of tables ([[faults." + key + "]])")
    return [(f"faults.{key}[{i}]", dict(e)) for i, e in enumerate(v)]


def _window(e: dict, w: str, need_end: bool = False) -> tuple[float, float]:
    start = number(e, "start_s", w, 0.0, lo=0.0, hi=1e7)
    end = number(e, "end_s", w, None if need_end else END, lo=0.0, hi=END)
    if end is None:
        raise ScenarioError(f"{w}.end_s", None, "a time in s (required for this fault)")
    if end <= start:
        raise ScenarioError(f"{w}.end_s", end, f"a time after start_s ({start:g} s)")
    return start, end


def parse_faults(raw: Mapping) -> FaultSpec:
    """The `[faults]` table -> FaultSpec; a bad field raises ScenarioError naming it."""
    no_unknown(raw, {"link", "odometry", "camera", "motor", "battery", "sensor"}, "faults")
    links, odo, cam, mot = [], [], [], []
    for w, e in _entries(raw, "link"):
        no_unknown(e, {"link", "direction", "start_s", "end_s", "loss", "burst_enter",
                       "burst_exit", "latency_ms", "jitter_ms", "duplicate", "reorder",
                       "outage"}, w)
        start, end = _window(e, w)
        p = {k: number(e, k, w, 0.0, lo=0.0, hi=1.0)
             for k in ("loss", "burst_enter", "duplicate", "reorder")}
        f = LinkFault(string(e, "link", w, "api", ("api", "gcs")),
                      string(e, "direction", w, "both", ("to_vehicle", "from_vehicle", "both")),
                      start, end, p["loss"], p["burst_enter"],
                      number(e, "burst_exit", w, 0.3, lo=0.0, hi=1.0, lo_open=True),
                      number(e, "latency_ms", w, 0.0, lo=0.0, hi=60_000.0),
                      number(e, "jitter_ms", w, 0.0, lo=0.0, hi=60_000.0),
                      p["duplicate"], p["reorder"], boolean(e, "outage", w, False))
        if not (f.outage or f.loss or f.burst_enter or f.latency_ms or f.jitter_ms
                or f.duplicate or f.reorder):
            raise ScenarioError(w, e, "at least one of loss, burst_enter, latency_ms, "
                                "jitter_ms, duplicate, reorder, outage")
        links.append(f)
    for w, e in _entries(raw, "odometry"):
        no_unknown(e, {"kind", "start_s", "end_s", "bias_m", "std_m"}, w)
        kind = string(e, "kind", w, choices=("dropout", "bias", "noise"))
        start, end = _window(e, w, need_end=kind == "dropout")
        bias = e.get("bias_m", [0.0, 0.0, 0.0])
        if (not isinstance(bias, list) or len(bias) != 3 or any(
                isinstance(b, bool) or not isinstance(b, int | float) or not abs(b) <= 100.0
                for b in bias)):
            raise ScenarioError(f"{w}.bias_m", bias, "[n, e, d] in m, each within 100")
        std = number(e, "std_m", w, 0.0, lo=0.0, hi=10.0)
        if kind == "bias" and not any(bias):
            raise ScenarioError(f"{w}.bias_m", bias, "a non-zero bias for kind = 'bias'")
        if kind == "noise" and std <= 0.0:
            raise ScenarioError(f"{w}.std_m", std, "a sigma > 0 m for kind = 'noise'")
        odo.append(OdometryFault(kind, start, end, tuple(float(b) for b in bias), std))
    for w, e in _entries(raw, "camera"):
        no_unknown(e, {"kind", "start_s", "end_s", "p"}, w)
        kind = string(e, "kind", w, choices=("freeze", "black", "drop"))
        start, end = _window(e, w, need_end=True)
        cam.append(CameraFault(kind, start, end, number(e, "p", w, 1.0, lo=0.0, hi=1.0,
                                                        lo_open=True)))
    for w, e in _entries(raw, "motor"):
        no_unknown(e, {"motor", "thrust", "start_s", "end_s"}, w)
        start, end = _window(e, w)
        mot.append(MotorFault(integer(e, "motor", w, lo=1, hi=4),
                              number(e, "thrust", w, lo=0.0, hi=1.0), start, end))
    from cosim.faults.sensors import parse_sensor_faults

    return FaultSpec(tuple(links), tuple(odo), tuple(cam), tuple(mot),
                     parse_battery(_entries(raw, "battery"), _window),
                     parse_sensor_faults(_entries(raw, "sensor"), _window))


# ------------------------------------------------------------------ the hooks
class _Direction:
    """One link fault in one direction: decides each datagram's fate, holds delayed ones."""

    def __init__(self, f: LinkFault, rng: np.random.Generator, label: str, log) -> None:
        self.f, self.rng, self.label, self.log = f, rng, label, log
        self.bad = False
        self.held: bytes | None = None          # reorder: waits behind the next datagram
        self.counts = dict.fromkeys(("dropped", "duplicated", "delayed", "reordered"), 0)

    def fate(self, t_us: int, data: bytes) -> list[tuple[int, bytes]]:
        """[(deliver at us, datagram)] for one datagram sent at t_us (empty: dropped)."""
        f, rng = self.f, self.rng
        t = t_us * 1e-6
        if not f.start_s <= t < f.end_s:
            return self._with_held(t_us, [(t_us, data)])
        self.log(t, self.label)
        if f.outage:
            self.counts["dropped"] += 1
            return []
        if f.burst_enter > 0.0:
            self.bad = (rng.random() >= f.burst_exit) if self.bad else (
                rng.random() < f.burst_enter)
        if self.bad or (f.loss > 0.0 and rng.random() < f.loss):
            self.counts["dropped"] += 1
            return []
        delay = (f.latency_ms + (rng.random() * f.jitter_ms if f.jitter_ms else 0.0)) * 1e-3
        if delay > 0.0:
            self.counts["delayed"] += 1
        due = t_us + int(round(delay * 1e6))
        out = [(due, data)]
        if f.duplicate > 0.0 and rng.random() < f.duplicate:
            self.counts["duplicated"] += 1
            out.append((due, data))
        if f.reorder > 0.0 and self.held is None and rng.random() < f.reorder:
            self.counts["reordered"] += 1
            self.held = data
            return []
        return self._with_held(t_us, out)

    def _with_held(self, t_us: int, out: list) -> list:
        if self.held is not None:
            out.append((out[-1][0] if out else t_us, self.held))
            self.held = None
        return out


class FaultyLink:
    """A link wrapper on the app's / GCS's end: to_vehicle faults on send, from_vehicle
    faults on recv, with delayed datagrams released on simulated time (integer us)."""

    def __init__(self, inner, clock, to_v: list[_Direction], from_v: list[_Direction]) -> None:
        self.inner = inner
        self._clock = clock
        self._to, self._from = to_v, from_v
        self._out: list = []     # heap of (due, seq, data) to the vehicle
        self._in: list = []      # heap of (due, seq, data) from the vehicle
        self._seq = 0

    def _route(self, dirs: list[_Direction], data: bytes, heap: list) -> list[bytes]:
        t = self._clock()
        batch = [(t, data)]
        for d in dirs:
            batch = [x for due, b in batch for x in d.fate(due, b)]
        now = []
        for due, b in batch:
            if due <= t and not heap:
                now.append(b)
            else:
                self._seq += 1
                heapq.heappush(heap, (due, self._seq, b))
        return now

    def send(self, data: bytes) -> None:
        for b in self._route(self._to, data, self._out):
            self.inner.send(b)

    def release(self, t: int) -> None:
        """Send the delayed datagrams to the vehicle due at t us (the start of a tick)."""
        out = self._out
        while out and out[0][0] <= t:
            self.inner.send(heapq.heappop(out)[2])

    def recv(self) -> bytes | None:
        t = self._clock()
        while True:
            d = self.inner.recv()
            if d is None:
                break
            for b in self._route(self._from, d, self._in):
                self._seq += 1
                heapq.heappush(self._in, (t, self._seq, b))
        if self._in and self._in[0][0] <= t:
            return heapq.heappop(self._in)[2]
        return None

    def __getattr__(self, name: str) -> Any:     # close, local_address, ... of the link
        return getattr(self.inner, name)


class FaultHooks:
    """`cosim.sim.hooks.Hooks` built from a FaultSpec."""

    def __init__(self, spec: FaultSpec, seed: int) -> None:
        self.spec = spec
        self.t = 0.0
        self.t_us = 0
        self._fired: list[tuple[float, str]] = []
        self._seen: set[str] = set()
        rng = iter(np.random.default_rng([seed, 9, i]) for i in range(1 << 20))
        self._dirs: dict[tuple[str, str], list[_Direction]] = {}
        self._all_dirs: list[_Direction] = []
        for i, f in enumerate(spec.links):
            for d in ("to_vehicle", "from_vehicle"):
                if f.direction in (d, "both"):
                    what = ("outage" if f.outage else ", ".join(
                        f"{k} {getattr(f, k):g}" for k in ("loss", "burst_enter", "latency_ms",
                                                           "jitter_ms", "duplicate", "reorder")
                        if getattr(f, k)))
                    dd = _Direction(f, next(rng), f"link {f.link} {d}: {what} (fault {i})",
                                    self._note)
                    self._dirs.setdefault((f.link, d), []).append(dd)
                    self._all_dirs.append(dd)
        self._odo_rng = [next(rng) for _ in spec.odometry]
        self._cam_rng = [next(rng) for _ in spec.camera]
        self._links: list[FaultyLink] = []
        self._last_meas: tuple | None = None
        self._last_img = None
        self.odometry_lost = False   # this tick's ODOMETRY carries quality -1

    def _note(self, t: float, what: str) -> None:
        if what not in self._seen:
            self._seen.add(what)
            self._fired.append((round(t, 6), what))

    def wrap_link(self, name: str, link):
        if name == "hil":       # battery faults: commands before the tick's ODOMETRY
            if not self.spec.battery:
                return link
            return HilInjector(link, lambda: self.t_us, self.spec.battery, self._note)
        to_v = self._dirs.get((name, "to_vehicle"), [])
        from_v = self._dirs.get((name, "from_vehicle"), [])
        if not (to_v or from_v):
            return link
        fl = FaultyLink(link, lambda: self.t_us, to_v, from_v)
        self._links.append(fl)
        return fl

    def on_odometry(self, t_us: int, meas: tuple) -> tuple:
        self.t_us = t_us
        t = self.t = t_us * 1e-6
        for fl in self._links:
            fl.release(t_us)
        out = meas
        self.odometry_lost = False
        for i, f in enumerate(self.spec.odometry):
            if not f.start_s <= t < f.end_s:
                continue
            self._note(f.start_s, f"odometry {f.kind} (fault {i})")
            if f.kind == "dropout" and self._last_meas is not None:
                # the position estimate failed (ODOMETRY quality -1): its position and velocity
                # are the last ones, attitude and rates live (the IMU still works)
                last = self._last_meas
                self.odometry_lost = True
                return (*last[0:3], *meas[3:7], *last[7:10], *meas[10:13])
            m = list(out)
            if f.kind == "bias":
                m[0] += f.bias_m[0]
                m[1] += f.bias_m[1]
                m[2] += f.bias_m[2]
            elif f.kind == "noise":
                n = self._odo_rng[i].standard_normal(6)
                for k in range(3):
                    m[k] += f.std_m * n[k]
                    m[7 + k] += f.std_m / 0.1 * n[3 + k]
            out = tuple(m)
        self._last_meas = out
        return out

    def on_frame(self, t_us: int, img):
        t = t_us * 1e-6
        for i, f in enumerate(self.spec.camera):
            if not f.start_s <= t < f.end_s:
                continue
            self._note(f.start_s, f"camera {f.kind} (fault {i})")
            if f.kind == "freeze" and self._last_img is not None:
                return self._last_img
            if f.kind == "black":
                return np.zeros_like(img)
            if f.kind == "drop" and (f.p >= 1.0 or self._cam_rng[i].random() < f.p):
                return None
        self._last_img = img
        return img

    def on_actuators(self, t_us: int, u: tuple) -> tuple:
        t = t_us * 1e-6
        for i, f in enumerate(self.spec.motors):
            if f.start_s <= t < f.end_s:
                self._note(f.start_s, f"motor {f.motor} at {100 * f.thrust:g}% thrust "
                                      f"(fault {i})")
                u = list(u)
                u[f.motor - 1] *= math.sqrt(f.thrust)    # thrust ~ u^2
                u = tuple(u)
        return u

    def fired(self) -> list[tuple[float, str]]:
        out = list(self._fired)
        for d in self._all_dirs:
            done = {k: v for k, v in d.counts.items() if v}
            if done:
                out.append((round(min(self.t, d.f.end_s), 6), d.label + " -> " + ", ".join(
                    f"{v} {k}" for k, v in done.items())))
        return out
