"""The ICUAS 2021 line follower (Terlizzi, Silano et al.) as a MAVLink offboard app.

The Image Processing System (`cosim.apps.ips`, paper Algorithm 1) runs on every camera frame
(5 Hz); the path planner and mission state machine (`cosim.apps.planner`, Algorithm 2 and the
released code) run every tick (200 Hz) and stream SET_POSITION_TARGET_LOCAL_NED position
setpoints to the vehicle. The app reaches the vehicle only through MAVLink: arm, AUTO.TAKEOFF
to the hover height, OFFBOARD, setpoints, AUTO.LAND. It flies with yaw 0 and never commands
yaw (the paper's drone only translates).

Parameters (`[app.params]`), all optional:
- `preset`: "general" (the default: for tracks nobody tuned for; it passes the seed
  mission's golden summary within tolerance), "released" (the released Simulink code's
  values, exactly) or "paper" (Table I). "general": pixel constants from the camera model, the
  hover height and `line_width_m` / `marker_radius_m` / `lookahead_m`, `camera_vfov_deg`,
  `camera_below_cog_m`; adaptive threshold; a disc-shaped marker so a sharp corner is not
  taken for it; nearest-branch tracking; a loss first coasts `coast_m` (0.35 m) on. See the
  docstrings of ips.py and planner.py for the differences.
- `alpha` (m/px): track gain (released GAIN_TRACK = 0.0038); `beta` (m/px): marker gain.
  The general preset scales the default `alpha`, `beta` and `deriv_gain` by the camera height
  over the seed's (1.0 m): a metre on the floor is fewer pixels from higher up, so the same
  offset in metres (the same speed) needs a gain in m/px in proportion to the height. A gain
  the user gives is taken as given, at any height (released / paper: never scaled).
- `deriv_gain` (m/px), `hover_alt_m` (m above the floor), `search_on_loss` (bool),
  `lost_timeout_s`, `mission_timeout_s` (s).
- `k_t` (threshold), `r_min_px`, `r_max_px`, `arc_width_rad`: IPS overrides.
- `search_nearest` (bool, default true): after a miss, follow the ring branch nearest the last
  direction; false is the released code's centroid of all ring pixels.
- `along_line`, `measured_width` (bool, default true; the general preset only): the
  look-ahead point measured along the line from the drone (a hairpin's other leg or a line
  crossing further on is not taken for the way on; at a crossing the way that continues the
  heading), and a track erosion no wider than the line in view (a line thinner than
  `line_width_m` is not eroded away). Both false: the general preset of issue 12.
- `setpoint_every` (ticks between setpoints; 1 = the paper's 200 Hz planner rate).
"""

from __future__ import annotations

from typing import Any

import cython
import numpy as np

from cosim.apps.base import (
    NAN,
    TAKEOFF_ALT_MAX_M,
    AppContext,
    FlightSequencer,
    check_params,
)
from cosim.apps.ips import ImageProcessor, IPSParams
from cosim.apps.planner import Action, MissionLogic, MissionState, PlannerParams

DEFAULTS: dict[str, Any] = {
    "preset": "general",
    "alpha": None,
    "beta": None,
    "deriv_gain": None,
    "hover_alt_m": None,
    "search_on_loss": True,
    "lost_timeout_s": 3.0,
    "mission_timeout_s": 100.0,
    "k_t": None,
    "r_min_px": None,
    "r_max_px": None,
    "arc_width_rad": None,
    "search_nearest": True,
    "setpoint_every": 1,
    # the "general" preset derives its pixel constants from these (ignored by the others)
    "camera_vfov_deg": 45.0,
    "camera_below_cog_m": 0.1,
    "line_width_m": 0.10,
    "marker_radius_m": 0.10,
    "lookahead_m": 0.19,
    "coast_m": None,
    "along_line": True,
    "measured_width": True,
}


# The camera height the default gains (the released code's, in m/px) were tuned at: the
# template's z_ref = -1.1 m with the camera 0.1 m below the centre of gravity
# (reference/minidrone.md §4), computed as the general preset computes a flight's, so that the
# default flight's scale is exactly 1.0.
SEED_CAMERA_HEIGHT_M = -PlannerParams().z_hover - DEFAULTS["camera_below_cog_m"]
# the planner's gains in m/px, scaled with the camera height by the general preset
GAINS_PER_PX = ("gain_track", "gain_marker", "deriv_gain")

# the phase names the master records, by mission state
_PHASE = {s: s.value for s in MissionState}
# what the per-tick path compares with, as module constants (compiled, an Enum member looked up
# on its class is a call into its metaclass)
_FOLLOWING = cython.declare(object, MissionState.FOLLOWING)
_LAND = cython.declare(object, Action.LAND)
_DONE = cython.declare(object, Action.DONE)

PRESETS = ("released", "paper", "general")

# why the planner landed -> the app's outcome; only "marker" is its goal (a landing on what it
# took for the marker: the landing error, against the world's marker, says whether it was)
OUTCOMES = {
    "marker": "goal_reached: landed on the marker it saw",
    "lost": "aborted: line lost for lost_timeout_s",
    "timeout": "aborted: mission_timeout_s reached",
    "none": "not finished",
}


# the planner's / IPS's names -> the parameter a user writes (errors name the latter)
USER_NAMES = {"gain_track": "alpha", "gain_marker": "beta", "deriv_gain": "deriv_gain",
              "z_hover": "hover_alt_m", "lost_timeout": "lost_timeout_s",
              "mission_timeout": "mission_timeout_s", "r_min": "r_min_px",
              "r_max": "r_max_px", "arc_width": "arc_width_rad", "k_t": "k_t"}


def _user_error(msg: str, p: dict[str, Any]) -> ValueError:
    """A planner / IPS check's message in the user's names: app.params.NAME: got V; ..."""
    import re

    found = [(m.start(), k) for k in USER_NAMES if (m := re.search(rf"\b{k}\b", msg))]
    for k in sorted(USER_NAMES, key=len, reverse=True):
        msg = re.sub(rf"\b{k}\b", USER_NAMES[k], msg)
    if not found:
        return ValueError(f"app.params: {msg}")
    name = USER_NAMES[min(found)[1]]
    return ValueError(f"app.params.{name}: got {p.get(name)!r}; expected {msg}")


def _overrides(p: dict[str, Any], mapping: dict[str, str]) -> dict[str, float]:
    """The parameters the user gave (not None), renamed to the planner's / IPS's names."""
    return {dst: float(p[src]) for src, dst in mapping.items() if p[src] is not None}


class LineFollowerApp:
    def __init__(self, params: dict[str, Any]) -> None:
        p = check_params(params, DEFAULTS, "line_follower")
        if p["preset"] not in PRESETS:
            raise ValueError(f"app.params.preset: got {p['preset']!r}; allowed: "
                             + ", ".join(PRESETS))
        pl = _overrides(p, {"alpha": "gain_track", "beta": "gain_marker",
                            "deriv_gain": "deriv_gain"})
        if p["hover_alt_m"] is not None:
            if not 0.0 < p["hover_alt_m"] <= TAKEOFF_ALT_MAX_M:
                raise ValueError(f"app.params.hover_alt_m: got {p['hover_alt_m']!r}; "
                                 f"expected a height above the floor in (0, "
                                 f"{TAKEOFF_ALT_MAX_M:g}] m")
            pl["z_hover"] = -float(p["hover_alt_m"])
        pl["search_on_loss"] = bool(p["search_on_loss"])
        pl["lost_timeout"] = float(p["lost_timeout_s"])
        pl["mission_timeout"] = float(p["mission_timeout_s"])
        ip = _overrides(p, {"k_t": "k_t", "r_min_px": "r_min", "r_max_px": "r_max",
                            "arc_width_rad": "arc_width"})
        ip["search_nearest"] = bool(p["search_nearest"])
        if p["coast_m"] is not None:
            pl["coast_m"] = float(p["coast_m"])
        maker_pl = getattr(PlannerParams, p["preset"])
        maker_ip = getattr(IPSParams, p["preset"])
        if p["preset"] == "general":          # pixel constants from the camera and height
            hover = -maker_pl(**pl).z_hover if "z_hover" not in pl else -pl["z_hover"]
            cam_h = hover - float(p["camera_below_cog_m"])
            # the gains are m/px: scaled by the camera height against the seed's, the offset
            # per frame in floor metres (and so the speed) is the height's seed one; a gain the
            # user gives stays as given. At the seed height the scale is exactly 1.0.
            scale = cam_h / SEED_CAMERA_HEIGHT_M
            seed_gains = maker_pl()
            for name in GAINS_PER_PX:
                if name not in pl:
                    pl[name] = getattr(seed_gains, name) * scale
            geo = {"camera_height_m": cam_h, "vfov_deg": float(p["camera_vfov_deg"]),
                   "line_width_m": float(p["line_width_m"]),
                   "marker_radius_m": float(p["marker_radius_m"]),
                   "lookahead_m": float(p["lookahead_m"])}
            ip = {**geo, **ip, "along_line": bool(p["along_line"]),
                  "measured_width": bool(p["measured_width"])}
            if "r_min" in ip or "r_max" in ip:
                raise ValueError("app.params.r_min_px: the general preset derives the ring "
                                 "from lookahead_m; set that instead")
        try:
            self.planner_params = maker_pl(**pl)
            self.ips_params = maker_ip(**ip)
        except ValueError as exc:
            raise _user_error(str(exc), p) from None
        self.every = int(p["setpoint_every"])
        if self.every < 1:
            raise ValueError("app.params.setpoint_every: expected an integer >= 1")
        self.ips = ImageProcessor(self.ips_params)
        self.logic = MissionLogic(self.planner_params)
        self.seq = FlightSequencer(takeoff_alt_m=-self.planner_params.z_hover,
                                   stream_before_s=1.05)
        self.events = self.seq.events
        self.phase = "prelude"
        self.done = False
        self.setpoint = [NAN, NAN, NAN]
        self.frame_log: list[tuple[float, bool, bool, float, float]] = []
        self._k = 0
        self._following_logged = False

    def on_start(self, ctx: AppContext) -> None:
        self.client = ctx.client
        self._hold = (0.0, 0.0, self.planner_params.z_hover)   # local: above the start

    def on_frame(self, t: float, image: np.ndarray) -> None:
        c = self.client
        if self.seq.state != "flying":
            self.frame_log.append((t, False, False, 0.0, 0.0))
            return
        r = self.ips.process(image, detect_marker=self.logic.ips_detect_marker,
                             forward_only=self.logic.coasting)
        self.frame_log.append((t, r.flag_track, r.flag_marker, r.e_x, r.e_y))
        x, y, z = c.position
        self.logic.on_ips(t, r, (x, y), z, c.attitude[2])

    def on_tick(self, t: float) -> None:
        c = self.client
        c.poll(t)
        self._k += 1
        seq = self.seq
        if seq.state != "flying" and seq.state not in ("landing", "landed"):
            self.phase = "prelude"
            seq.step(t, c, self._hold)
            return
        if seq.state == "flying":
            x_ref, y_ref, z_ref, action = self.logic.setpoint(t, c.position)
            st = self.logic.state
            self.phase = _PHASE[st]       # (Enum.value is a Python-level descriptor call)
            if st is _FOLLOWING and not self._following_logged:
                self.events.append((t, "following"))
                self._following_logged = True
            if action is _LAND or action is _DONE:
                seq.land(t, c)
            else:
                sp = self.setpoint
                sp[0], sp[1], sp[2] = x_ref, y_ref, z_ref
                if self._k % self.every == 0:
                    c.set_position_target(x_ref, y_ref, z_ref, 0.0)
                return
        # landing: AUTO.LAND at the current position, until disarmed
        self.phase = "landing"
        self.setpoint[0] = self.setpoint[1] = self.setpoint[2] = NAN
        seq.step(t, c, self._hold)
        if seq.state == "landed":
            self.phase = "done"
            self.done = True

    @property
    def outcome(self) -> str:
        reason = self.logic.reason or "none"
        return OUTCOMES.get(reason, f"aborted: {reason}")

    @property
    def goal_reached(self) -> bool:
        return self.logic.reason == "marker"

    def metrics(self) -> dict[str, Any]:
        return {"landing_reason": self.logic.reason or "none",
                "outcome": self.outcome, "goal_reached": self.goal_reached,
                "transitions": [list(tr) for tr in self.logic.transitions]}
