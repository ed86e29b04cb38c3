"""Path planner and mission state machine of the line follower (paper 1, Algorithm 2, and the
released code, reference/minidrone.md §4.3-4.9), as pure logic: no I/O, no MAVLink, no numpy.

The app calls ``MissionLogic.on_ips`` at camera rate (5 Hz) with the IPS result and the
estimated position, and ``MissionLogic.setpoint`` at planner rate (200 Hz); the latter returns
``(x_ref, y_ref, z_ref, action)`` in world NED metres. ``setpoint`` does plain float arithmetic
only (no allocation besides the returned tuple).

States (``MissionState``) and what ``setpoint`` returns::

    TAKEOFF     climb to z_hover over the take-off point             action "takeoff"
    FOLLOWING   x_ref = x_est + gain_track * e (+ derivative term)   action "follow"
    LOST        hold the position where the line was lost, search    action "hold"
    END_MARKER  x_ref = x_est + gain_marker * e_marker               action "follow"
    LANDING     xy held, z_ref = 0                                   action "land"
    DONE        landed (z_est > landed_z)                            action "done"

Transitions (on camera frames unless noted)::

    TAKEOFF    -> FOLLOWING   track seen and z_est inside the hover band
    FOLLOWING  -> END_MARKER  track lost and marker seen              (reason "track_end")
    FOLLOWING  -> LOST        track lost, no marker, search_on_loss
    FOLLOWING  -> END_MARKER  track lost, no marker, not search_on_loss (released latch: holds)
    LOST       -> FOLLOWING   track seen again
    LOST       -> END_MARKER  marker seen (track not)
    LOST       -> LANDING     lost for lost_timeout                   (reason "lost")
    END_MARKER -> LANDING     marker seen now and land_delay frames ago with
                              |e(k)| + |e(k - land_delay)| <= land_max_error (reason "marker")
    any        -> LANDING     mission_timeout after the first call    (reason "timeout"; tick)
    LANDING    -> DONE        z_est > landed_z                        (tick)

Semantics:

- Errors are the IPS's, in pixels: e_x up in the image = body forward, e_y right = body
  right. They are rotated by the yaw at the frame into (North, East):
  ``dN = cos(yaw) e_x - sin(yaw) e_y``, ``dE = sin(yaw) e_x + cos(yaw) e_y``. The app flies
  with yaw 0 (body x = North), where this is the identity.
- Released rule (base = the estimate, §4.5/§4.9): ``x_ref = x_est + gain * dN`` every tick,
  with the latest frame's error held between frames. This is a position offset that the
  position loop turns into a cruise speed (template: ~2.4 m/s per m of offset), not an
  integrated setpoint as in the paper's Appendix.
- Derivative term (released, per image axis): when a new frame's error differs from the
  previous frame's by at least ``deriv_threshold`` px, add ``deriv_gain * (e(k) - e(k-1))``
  (m) for ``deriv_hold`` s. It uses the error of the current state (track or marker) and
  restarts at every state change.
- Hover band (released Z_LOW/Z_HIGH = -1.0/-1.2 around z_ref = -1.1): planner errors pass only
  while ``z_hover - hover_band < z_est < z_hover + hover_band``; outside, x_ref = x_est.
- End-Marker is latched: the track flag is not looked at any more (the ring may cross the
  line behind the drone), the marker's errors are used, and when the marker is not seen the
  position at that frame is held. The landing rule uses the error norm ``hypot(e_x, e_y)``.
- Robustness beyond the released code (``search_on_loss``, on by default): a single frame
  without the line no longer ends the following; the drone holds the position where the line
  was lost (rather than x_ref = x_est, which lets it coast) while the IPS searches the whole
  ring, and gives up (lands) after ``lost_timeout``. Mission timeout: lands.

Paper vs released (presets ``PlannerParams.paper()`` / ``PlannerParams.released()``):

================  ========================================  =============================
item              paper                                     released (variables.m)
================  ========================================  =============================
track gain        alpha, several values, not tabulated      GAIN_TRACK = 0.0038 m/px
marker gain       beta = 18e-3 m/px                         GAIN_LANDING = 0.0022 m/px
derivative term   none                                      0.002 m/px, >= 2 px, 0.2 s hold
hover height      z_H = 1 m (z_ref = -1.0)                  z_ref = -1.1 m
hover band        not stated; we use z_ref +- 0.1              -1.2 < z < -1.0
landing           when e_x = e_y = 0 (exact zero)           |e(k)| + |e(k-4)| <= 5 px
base of x_ref     previous setpoint (Alg. 2, x_{k+1}=x_k+..)  the estimate x_est
================  ========================================  =============================

Both presets use the estimate as base (the paper's integrating form needs an alpha the paper
does not give) and the released landing rule (an exact zero error never happens with a
centroid). ``paper()`` keeps the paper's beta, z_H and no derivative; track gain: released.
``released()`` also turns ``search_on_loss`` off (first loss latches End-Marker).

Observed in a kinematic closed loop (tests/test_planner.py: the template's XY loop, an 80 ms
tilt lag, the real renderer and IPS): the default completes every built-in world (landing
error < 5 mm, path error RMS 3-4 cm, ~0.25 m/s). The paper preset's beta = 18e-3 m/px with
the estimate base turns a 10 px marker error into a 0.18 m offset: the drone circles the marker
and the landing rule is never met (the mission times out). Doubling the track gain (~0.5 m/s)
overshoots the 45-90 deg corners; after a recovery the arc can lock onto the leg behind and
follow the track backwards. The released algorithm has no notion of "forward" beyond the
previous VTP direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any

import cython

__all__ = ["MissionState", "Action", "PlannerParams", "MissionLogic"]


class MissionState(StrEnum):
    TAKEOFF = "takeoff"
    FOLLOWING = "following"
    LOST = "lost"
    END_MARKER = "end_marker"
    LANDING = "landing"
    DONE = "done"


class Action(StrEnum):
    """What the app should do with the setpoint."""

    TAKEOFF = "takeoff"   # arm/take off if not yet, fly to the setpoint
    FOLLOW = "follow"     # position setpoint
    HOLD = "hold"         # position setpoint (hold while searching)
    LAND = "land"         # land at (x_ref, y_ref) (e.g. AUTO.LAND or descend to z_ref = 0)
    DONE = "done"         # landed; nothing more to do


# the members the per-tick setpoint compares and returns, as module constants (compiled, an
# Enum member looked up on its class is a call into its metaclass: ~0.9k instructions)
_S_TAKEOFF = cython.declare(object, MissionState.TAKEOFF)
_S_LOST = cython.declare(object, MissionState.LOST)
_S_LANDING = cython.declare(object, MissionState.LANDING)
_S_DONE = cython.declare(object, MissionState.DONE)
_A_TAKEOFF = cython.declare(object, Action.TAKEOFF)
_A_FOLLOW = cython.declare(object, Action.FOLLOW)
_A_HOLD = cython.declare(object, Action.HOLD)
_A_LAND = cython.declare(object, Action.LAND)
_A_DONE = cython.declare(object, Action.DONE)


@dataclass(frozen=True)
class PlannerParams:
    """Path planner parameters. Defaults: released gains + the Lost/Search robustness."""

    gain_track: float = 0.0038      # m/px, GAIN_TRACK (paper: alpha)
    gain_marker: float = 0.0022     # m/px, GAIN_LANDING (paper: beta = 18e-3)
    deriv_gain: float = 0.002       # m/px, DERIVATIVE_GAIN (0 disables)
    deriv_threshold: float = 2.0    # px, CHANGE_DERIVATIVE_ERROR_THRESHOLD
    deriv_hold: float = 0.2         # s, TIME_HOLD
    z_hover: float = -1.1           # m, NED z reference while following (negative = up)
    hover_band: float = 0.1         # m, errors pass while |z_est - z_hover| < hover_band
    land_max_error: float = 5.0     # px, MAX_ERROR_LANDING
    land_delay: int = 4             # frames, DELAY_LANDING
    search_on_loss: bool = True     # hold and search when the line is lost (False: released)
    lost_timeout: float = 3.0       # s in LOST before landing
    mission_timeout: float = 100.0  # s from the first call before landing (template TFinal)
    landed_z: float = -0.1          # m, NED z above which LANDING counts as landed
    coast_m: float = 0.0            # m flown on along the last direction after a loss before
                                    # holding (0: hold at once); lost_timeout runs from the hold

    def __post_init__(self) -> None:
        if not self.z_hover < 0.0:
            raise ValueError("z_hover is NED: it must be negative (above the floor)")
        if not 0.0 < self.hover_band < -self.z_hover:
            raise ValueError("hover_band must be in (0, -z_hover)")
        if self.land_delay < 1:
            raise ValueError("land_delay must be >= 1 frame")
        for name in ("gain_track", "gain_marker", "deriv_gain", "deriv_threshold",
                     "deriv_hold", "land_max_error", "lost_timeout", "mission_timeout",
                     "coast_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")

    @classmethod
    def released(cls, **overrides: Any) -> PlannerParams:
        """The released code exactly (first loss of the line latches End-Marker)."""
        return replace(cls(search_on_loss=False), **overrides)

    @classmethod
    def general(cls, **overrides: Any) -> PlannerParams:
        """The released gains with the robustness a user needs on tracks nobody tuned for:
        search on loss, and a loss first coasts 0.35 m on along the last direction (a missed
        frame or a gap in the line is crossed instead of searched from where it began); when
        nothing is found ahead the vehicle goes back to where it lost the line and searches
        the whole ring there (a sharp corner)."""
        return replace(cls(search_on_loss=True, coast_m=0.35), **overrides)

    @classmethod
    def paper(cls, **overrides: Any) -> PlannerParams:
        """Table I values where the paper gives them (see the module docstring)."""
        return replace(cls(gain_marker=18e-3, deriv_gain=0.0, z_hover=-1.0,
                           search_on_loss=False), **overrides)


_NAN = math.nan
_INF = math.inf


class MissionLogic:
    """The line follower's state machine and path planner (see the module docstring)."""

    def __init__(self, params: PlannerParams | None = None) -> None:
        self.params = params or PlannerParams()
        self.reset()

    def reset(self) -> None:
        p = self.params
        self.state = MissionState.TAKEOFF
        self.reason = ""                  # why LANDING was entered
        self.t_start = _NAN               # s, first call
        self.t_state = 0.0                # s, when the current state was entered
        self.transitions: list[tuple[float, str, str, str]] = []  # (t, from, to, reason)
        self._z_lo = p.z_hover - p.hover_band
        self._z_hi = p.z_hover + p.hover_band
        self._servo = False               # True: x_ref = x_est + offsets; False: hold
        self._hold_x = self._hold_y = _NAN
        self._off_n = self._off_e = 0.0   # m, gain * error, NED
        self._cos = 1.0                   # yaw of the last frame
        self._sin = 0.0
        self._der_x = self._der_y = 0.0   # m, derivative term along image x (fwd), y (right)
        self._der_x_until = self._der_y_until = -_INF
        self._prev_ex = self._prev_ey = _NAN
        self._land_hist = [_NAN] * (p.land_delay + 1)
        self._k = 0                       # frames in END_MARKER
        self._lost_xy = (_NAN, _NAN)      # where the line was lost (coasting from there)
        self._t_hold = -_INF              # s, when holding began in LOST

    # ------------------------------------------------------------------ properties
    @property
    def ips_detect_marker(self) -> bool | None:
        """What to pass as ``ImageProcessor.process(..., detect_marker=)``: the marker branch
        always in End-Marker/Lost, otherwise only when the track is not found (None)."""
        if self.state in (MissionState.END_MARKER, MissionState.LOST):
            return True
        return None

    @property
    def coasting(self) -> bool:
        """Flying on over a loss (coast_m): the IPS should search only ahead."""
        return self.state is MissionState.LOST and self._servo

    # ------------------------------------------------------------------ camera rate
    def on_ips(self, t: float, ips: Any, est_xy: tuple[float, float] | Any, est_z: float,
               yaw: float = 0.0) -> None:
        """Update with one frame's IPS result (``cosim.apps.ips.IPSResult``-like: flag_track,
        flag_marker, e_x, e_y, marker_e_x, marker_e_y), the estimated position (m NED) and
        yaw (rad) at the frame time t (s)."""
        p = self.params
        if self.t_start != self.t_start:
            self.t_start = t
        st = self.state
        if st is MissionState.LANDING or st is MissionState.DONE:
            return
        x, y = float(est_xy[0]), float(est_xy[1])
        if self._hold_x != self._hold_x:
            self._hold_x, self._hold_y = x, y
        self._cos, self._sin = math.cos(yaw), math.sin(yaw)
        S = MissionState
        if st is S.TAKEOFF:
            if ips.flag_track and self._z_lo < est_z < self._z_hi:
                self._enter(S.FOLLOWING, t, "track seen at hover height")
                self._servo_on(t, ips.e_x, ips.e_y, p.gain_track)
            elif getattr(ips, "line_e", None) is not None and self._z_lo < est_z < self._z_hi:
                self._servo_on(t, *ips.line_e, p.gain_track)   # a start beside the line
            return
        if st is S.FOLLOWING or st is S.LOST:
            if ips.flag_track:
                if st is S.LOST:
                    self._enter(S.FOLLOWING, t, "track found again")
                self._servo_on(t, ips.e_x, ips.e_y, p.gain_track)
            elif ips.flag_marker:
                self._enter(S.END_MARKER, t, "track_end")
                self._marker_frame(t, ips, x, y)
            elif st is S.FOLLOWING:
                if p.search_on_loss:
                    self._enter(S.LOST, t, "track lost")
                    if p.coast_m > 0.0 and self._servo:   # fly on with the last offsets
                        self._lost_xy = (x, y)
                        return
                else:
                    self._enter(S.END_MARKER, t, "track lost (released latch)")
                    self._land_hist_push(_NAN)
                self._hold(x, y)
                self._t_hold = t
            elif self._servo:                             # coasting
                if math.hypot(x - self._lost_xy[0], y - self._lost_xy[1]) >= p.coast_m:
                    # nothing ahead: back to where the line was lost (a sharp corner's new
                    # leg is on the ring there) and search the whole ring
                    self._hold(*self._lost_xy)
                    self._t_hold = t
            elif t - max(self.t_state, self._t_hold) >= p.lost_timeout:
                self._enter(S.LANDING, t, "lost")
                self._hold(x, y)
            return
        if st is S.END_MARKER:
            self._marker_frame(t, ips, x, y)

    # ------------------------------------------------------------------ planner rate
    @cython.locals(x=cython.double, y=cython.double, z=cython.double, dx=cython.double,
                   dy=cython.double, c=cython.double, s=cython.double)
    def setpoint(self, t: float, est_xyz: Any) -> tuple[float, float, float, Action]:
        """(x_ref, y_ref, z_ref (m NED), action) for the tick at t (s)."""
        x = est_xyz[0]
        y = est_xyz[1]
        z = est_xyz[2]
        if self.t_start != self.t_start:
            self.t_start = t
        if self._hold_x != self._hold_x:
            self._hold_x, self._hold_y = float(x), float(y)
        st = self.state
        p = self.params
        if st is _S_LANDING:
            if z > p.landed_z:
                self._enter(_S_DONE, t, "landed")
                return self._hold_x, self._hold_y, 0.0, _A_DONE
            return self._hold_x, self._hold_y, 0.0, _A_LAND
        if st is _S_DONE:
            return self._hold_x, self._hold_y, 0.0, _A_DONE
        if t - self.t_start >= p.mission_timeout:
            self._enter(_S_LANDING, t, "timeout")
            self._hold(float(x), float(y))
            return self._hold_x, self._hold_y, 0.0, _A_LAND
        if st is _S_TAKEOFF:
            if self._servo and self._z_lo < z < self._z_hi:   # acquiring the line
                return (float(x) + self._off_n, float(y) + self._off_e, p.z_hover,
                        _A_TAKEOFF)
            return self._hold_x, self._hold_y, p.z_hover, _A_TAKEOFF
        if st is _S_LOST and not self._servo:
            return self._hold_x, self._hold_y, p.z_hover, _A_HOLD
        # FOLLOWING / END_MARKER, LOST while coasting
        if not self._servo:
            return self._hold_x, self._hold_y, p.z_hover, _A_FOLLOW
        if not (self._z_lo < z < self._z_hi):
            return float(x), float(y), p.z_hover, _A_FOLLOW
        dx = self._der_x if t < self._der_x_until else 0.0
        dy = self._der_y if t < self._der_y_until else 0.0
        c, s = self._cos, self._sin
        return (float(x) + self._off_n + c * dx - s * dy,
                float(y) + self._off_e + s * dx + c * dy,
                p.z_hover, _A_FOLLOW)

    # ------------------------------------------------------------------ internals
    def _enter(self, new: MissionState, t: float, reason: str) -> None:
        self.transitions.append((t, self.state.value, new.value, reason))
        self.state = new
        self.t_state = t
        if new is MissionState.LANDING:
            self.reason = reason
        if new is MissionState.END_MARKER:
            self._land_hist = [_NAN] * (self.params.land_delay + 1)
            self._k = 0
        # restart the derivative term and its history
        self._prev_ex = self._prev_ey = _NAN
        self._der_x = self._der_y = 0.0
        self._der_x_until = self._der_y_until = -_INF

    def _hold(self, x: float, y: float) -> None:
        self._servo = False
        self._hold_x, self._hold_y = x, y

    def _servo_on(self, t: float, e_x: float, e_y: float, gain: float) -> None:
        p = self.params
        c, s = self._cos, self._sin
        self._servo = True
        self._off_n = gain * (c * e_x - s * e_y)
        self._off_e = gain * (s * e_x + c * e_y)
        if p.deriv_gain > 0.0 and self._prev_ex == self._prev_ex:
            dex, dey = e_x - self._prev_ex, e_y - self._prev_ey
            if abs(dex) >= p.deriv_threshold:
                self._der_x, self._der_x_until = p.deriv_gain * dex, t + p.deriv_hold
            if abs(dey) >= p.deriv_threshold:
                self._der_y, self._der_y_until = p.deriv_gain * dey, t + p.deriv_hold
        self._prev_ex, self._prev_ey = e_x, e_y

    def _land_hist_push(self, v: float) -> float:
        """Store this frame's error norm; return the one land_delay frames ago."""
        h = self._land_hist
        n = len(h)
        h[self._k % n] = v
        old = h[(self._k - self.params.land_delay) % n] if self._k >= self.params.land_delay \
            else _NAN
        self._k += 1
        return old

    def _marker_frame(self, t: float, ips: Any, x: float, y: float) -> None:
        p = self.params
        if ips.flag_marker:
            mx, my = ips.marker_e_x, ips.marker_e_y
            self._servo_on(t, mx, my, p.gain_marker)
            m = math.hypot(mx, my)
            old = self._land_hist_push(m)
            if old == old and m + old <= p.land_max_error:
                self._enter(MissionState.LANDING, t, "marker")
                self._hold(x, y)
        else:
            self._land_hist_push(_NAN)
            if self._servo:
                self._hold(x, y)
            self._prev_ex = self._prev_ey = _NAN
