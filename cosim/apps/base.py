"""The offboard app contract: what the master calls, and what an app may use.

An app is the software under test, a companion-computer program. It sees the vehicle only
through MAVLink (`ctx.client`, an `mav.client.OffboardClient` on the API link; positions in
the vehicle's local NED frame, origin at its start: a world point w is `ctx.local(*w)`) and,
if the scenario has a camera, through frames. The master calls it synchronously in the tick order of
ARCHITECTURE.md: `on_frame` when a frame is delivered (before `on_tick`), then `on_tick` every
tick. Neither may block. A frame is delivered on the tick it is captured, or later with the
camera stream's latency (`[camera] latency_s`, `jitter_s`): `on_frame(t, image)` gets the
delivery time `t`, and `ctx.frame_time` is the frame's capture time.

Write your own as a class with this shape and name it in a scenario as `app.name =
"package.module:Class"`; it is constructed as `Class(params: dict)` and should reject unknown
parameters with ValueError.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from pymavlink.dialects.v20.common import MAV_CMD_COMPONENT_ARM_DISARM as ARM_DISARM
from pymavlink.dialects.v20.common import MAV_RESULT_DENIED

NAN = math.nan
# Bounds of app parameters (issue 31). Every number an app takes (a distance in m, a time in
# s, a gain, a count) is within APP_NUMBER_MAX in magnitude: beyond it is a typo or a unit
# error, and 1e308 overflows arithmetic. The take-off height is at most 120 m above ground,
# the ceiling of the EU open category (Regulation (EU) 2019/947) and of FAA Part 107 (400 ft).
APP_NUMBER_MAX = 1e6
TAKEOFF_ALT_MAX_M = 120.0


@dataclass
class AppContext:
    client: Any                     # mav.client.OffboardClient (the API link)
    tick_s: float                   # s, master tick (5 ms)
    frame_period_s: float | None    # s, time between camera frames, None without camera
    rng: np.random.Generator        # seeded from the scenario seed: use it, not global random
    home_ned: tuple[float, float, float]   # m, start position (world NED); apps may know it
    # s, capture time of the frame being handed to on_frame (its `t` is the delivery time,
    # later by the camera stream's latency and jitter: docs/cameras.md); NaN before a frame
    frame_time: float = NAN

    def local(self, n: float, e: float, d: float) -> tuple[float, float, float]:
        """A world NED point in the vehicle's local frame (MAVLink LOCAL_NED: origin at the
        start, where its estimator initialised, as on a PX4 vehicle)."""
        return n - self.home_ned[0], e - self.home_ned[1], d - self.home_ned[2]


class FrameStage:
    """An app's pure per-frame image work (a function of the frame alone: a grey conversion,
    a colour segmentation), which a pipelined camera stream computes in its worker (a render
    process, or thread) right after the render, while the plant and the flight stack step
    on (issue 29).

    An app that has one sets ``frame_stage = FrameStage(fn)`` and calls
    ``self.frame_stage(image)`` in ``on_frame``: that returns what the stream computed for
    that very frame object, or computes ``fn(image)`` there (a sequential stream, or a frame
    a camera fault replaced). ``fn`` must not read or change the app's state, so the flight is
    the same either way, bit for bit; OpenCV runs on one thread in a pipelined run
    (cosim/cvthreads.py), so what it computes does not depend on the other thread.
    A value of None is not kept: ``fn`` is then computed again in ``__call__``.
    """

    def __init__(self, fn: Callable[[np.ndarray], Any]) -> None:
        self.fn = fn
        self._image: np.ndarray | None = None
        self._value: Any = None

    def offer(self, image: np.ndarray, value: Any) -> None:
        """What the stream computed for `image` (on the main thread, at delivery)."""
        self._image, self._value = image, value

    def __call__(self, image: np.ndarray) -> Any:
        if image is self._image:
            value = self._value
            self._image = self._value = None
            return value
        return self.fn(image)


@runtime_checkable
class OffboardApp(Protocol):
    phase: str                      # current phase name, recorded every tick
    done: bool                      # the app considers its mission finished
    events: list[tuple[float, str]]  # (t s, name): 'takeoff_command', 'following', 'land_command'
    setpoint: list[float]           # [x, y, z] m NED, last position setpoint sent (NaN: none)

    def on_start(self, ctx: AppContext) -> None: ...

    def on_frame(self, t: float, image: np.ndarray) -> None: ...

    # Optional, a method of the app's class: ``frames_wanted() -> bool``, False while
    # ``on_frame`` would not look at a frame (before the mission, while landing). The camera
    # stream then does not render the frames captured meanwhile, and does not hand them to
    # ``on_frame``, unless something else sees every frame (a video, a fault);
    # cosim/sensors/stream.py, cosim/sim/master.py frames_wanted.

    def on_tick(self, t: float) -> None: ...

    def metrics(self) -> dict[str, float]: ...


def check_params(params: dict[str, Any], defaults: dict[str, Any], app: str) -> dict[str, Any]:
    """Merge `params` over `defaults`; unknown names and wrong types raise ValueError.

    A default of None stands for a number whose value comes from elsewhere (a preset)."""
    out = dict(defaults)
    for k, v in params.items():
        if k not in defaults:
            raise ValueError(
                f"app.params.{k}: unknown parameter for {app}; known: {', '.join(sorted(defaults))}"
            )
        d = defaults[k]
        like = "a number" if d is None else f"a value like {d!r}"
        if d is None:  # a number whose default comes from elsewhere (e.g. a preset)
            d = 0.0
        if isinstance(d, bool) != isinstance(v, bool) or (
            isinstance(d, int | float) and not isinstance(v, int | float)
        ) or (isinstance(d, str) and not isinstance(v, str)):
            raise ValueError(f"app.params.{k}: got {v!r}; expected {like}")
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"app.params.{k}: got {v!r}; expected a finite number")
        if isinstance(v, int | float) and not isinstance(v, bool) and abs(v) > APP_NUMBER_MAX:
            raise ValueError(f"app.params.{k}: got {v!r}; expected a number within "
                             f"+-{APP_NUMBER_MAX:g}")
        out[k] = v
    return out


@dataclass
class FlightSequencer:
    """The PX4-style prelude and ending every offboard app needs.

    arm -> AUTO.TAKEOFF to `takeoff_alt_m` -> stream setpoints for `stream_before_s` -> OFFBOARD
    -> (the app flies) -> `land()` -> AUTO.LAND -> disarmed. Commands that get no answer are
    retried every `retry_s`. All timing is on the simulation clock `t`. Arming denied with a
    "Preflight Fail: ..." STATUSTEXT (the vehicle's IMU is implausible: no retry mends it) ends
    the prelude: state "refused", `refused` the text (the run ends there, cosim/sim/exits.py).
    """

    takeoff_alt_m: float = 1.0
    stream_before_s: float = 1.2
    retry_s: float = 1.0
    state: str = "idle"
    _t_sent: float = -1e9
    _t_stream: float = NAN
    events: list[tuple[float, str]] = field(default_factory=list)
    refused: str = ""

    def __post_init__(self) -> None:
        alt = self.takeoff_alt_m
        if not (isinstance(alt, int | float) and 0.0 < alt <= TAKEOFF_ALT_MAX_M):
            raise ValueError(f"app.params.takeoff_alt_m: got {alt!r}; expected a height in "
                             f"(0, {TAKEOFF_ALT_MAX_M:g}] m")

    def step(self, t: float, client: Any, hold: tuple[float, float, float]) -> bool:
        """Advance the prelude; True once the vehicle is in OFFBOARD and the app may fly.

        `hold` is the setpoint streamed while waiting to enter OFFBOARD.
        """
        st = self.state
        if st == "flying":
            return True
        retry = t - self._t_sent >= self.retry_s
        if st == "idle":
            if client.heartbeat_seen:
                self.state = "arming"
        elif st == "arming":
            if client.armed:
                self.state = "takeoff"
                self._t_sent = -1e9
            elif self.preflight_failed(client):
                self.state = "refused"
                self.events.append((t, "arming_refused"))
            elif retry:
                client.arm()
                self._t_sent = t
        elif st == "takeoff":
            if retry and client.mode != "AUTO.TAKEOFF" and client.landed_state != "IN_AIR":
                client.takeoff(self.takeoff_alt_m)
                if not self.events or self.events[-1][1] != "takeoff_command":
                    self.events.append((t, "takeoff_command"))
                self._t_sent = t
            if client.landed_state == "IN_AIR" and client.mode == "AUTO.LOITER":
                self.state = "streaming"
                self._t_stream = t
        elif st == "streaming":
            client.set_position_target(*hold)
            if t - self._t_stream >= self.stream_before_s:
                if client.mode == "OFFBOARD":
                    self.state = "flying"
                    self.events.append((t, "offboard"))
                    return True
                if retry:
                    client.set_mode("OFFBOARD")
                    self._t_sent = t
        elif st == "landing":
            if not client.armed:
                self.state = "landed"
            elif retry and client.mode != "AUTO.LAND":
                client.land()
                self._t_sent = t
        return False

    def preflight_failed(self, client: Any) -> bool:
        """Whether the last arm was denied with a "Preflight Fail" (kept in `refused`)."""
        if client.ack(ARM_DISARM) != MAV_RESULT_DENIED:
            return False
        for t_text, _, text in reversed(client.statustext):
            if t_text < self._t_sent:
                break
            if text.startswith("Preflight Fail"):
                self.refused = text
                return True
        return False

    def land(self, t: float, client: Any) -> None:
        if self.state not in ("landing", "landed"):
            client.land()
            self._t_sent = t
            self.state = "landing"
            self.events.append((t, "land_command"))
