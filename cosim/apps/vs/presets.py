"""Parameters of the visual-servoing app: defaults, the paper's four experiments as presets.

Values from paper 2 Sec. 5 (reference/paper2-visual-servoing.md §3). Names:
- `l0`, `linf`, `l0_slope`: adaptive gain of Eq. 4 (lambda(0), lambda(inf), lambda'(0)).
- `vy_extra`: lambda_vy = lambda + vy_extra (camera y is down: the altitude gain).
- `w_ratio`: lambda_w = w_ratio * lambda.
- `t_eps_px`, `t_eps_final_px`: Eq. 7 switching thresholds (intermediate, final key).
- `avoidance`, `sigma` (a number or one per key), `lambda_a`, `obstacle_width_m`: Sec. 3.1.
  `avoidance_task`: "width" is the paper's Eq. 8 alone (it mostly slows the approach: see
  tasks.py); "corridor" (ours, default) is active while the column, estimated
  `avoid_range_m` or closer, stands in the corridor of half-width `clearance_m` + half the
  column that the vehicle sweeps, and pushes it out with gain `lambda_c`.
- `visibility`, `lambda_m`, `margin`, `visibility_depth_m`: Sec. 3.2.
- `ramp_s`: activation ramps h_a, h_m (Eq. 20); `smoothing`, `smoothing_s`, `h0`: Eqs. 28-30.
- `feedforward`, `gamma`, `p`, `rising_n`: Eqs. 31-32 and the "error rising" switch rule;
  `rising_max_px` > 0 (ours, off by default) applies that rule only while eps is below it.
  `ff_clearance_m` (ours, issue 44): feed-forward is refused at load on a taught path whose
  poses or straight legs bring the body closer than this to the room (registry.py).
- `low_level`, `moveby_dt_s`: how the command reaches the vehicle (`lowlevel.py`).
Ours, for rooms and paths nobody tuned the app for (issue 28; docs/papers/visual-servoing.md):
- `h_jump`, `h_hold_n`: the homography choice (vs/choice.py HomographyChoice): a candidate
  whose error changes by more than `h_jump` (max norm) in one cycle is not taken; the last
  error is held for at most `h_hold_n` cycles, then the preferred candidate is taken.
- `decouple`: the heading's share (R - I) m* taken out of e_v at turn keys (geometry.decouple).
- `vis_max_s`: the visibility task's longest activation, then a fresh match and as long off;
  `vis_v_max_mps`, `vis_wz_max_dps`: the bounds of the velocity it asks for on its own.
- `stall_s`, `refresh_frac`: match afresh when eps has not improved by 10 % for `stall_s`,
  or fewer than `refresh_frac` of the matched points are still tracked (vs/choice.py Refresh).
- `lk_win_px`, `track_max`: the LK window (px at the 856-px stream, odd, 11-61; scaled with
  the width as the other pixel values, but not below 11 px: features.WIN_MIN_PX) and the most
  matched points tracked, spread over the image by a grid (features.spread; 0: all). The
  paper gives neither (it needs "at least 16 image points", Sec. 5).
- `turn_deg`, `turn_t_ev`, `turn_wait_s`: a key turned more than `turn_deg` from the previous
  one also needs |e_v| < `turn_t_ev` (0: off), at most `turn_wait_s` after eps < T_eps.
Out-of-view columns are remembered in the vehicle's local frame (vs/memory.py): no parameter
beyond `obstacle_width_m`, `clearance_m` and `avoid_range_m`.

Pixel values (`t_eps_px`, `t_eps_final_px`, `outlier_px`, `rising_max_px`, and the fixed ones
of vs/features.py: RANSAC thresholds, the LK window and levels, the forward-backward bound,
GFTT spacing) are the paper's, for the Bebop 2's 856-px-wide stream; on another width they
scale with it (features.px_scale): `--set camera.width=428 --set camera.height=240` flies
with the same thresholds in scene terms (docs/performance-paper2.md has what that changes).
"""

from __future__ import annotations

from typing import Any

from cosim.apps.base import check_params
from cosim.apps.vs.lowlevel import LOW_LEVELS

DEFAULTS: dict[str, Any] = {
    "preset": "e1",
    "keys": [],                   # [n, e, d, yaw_deg] poses to teach at (render)
    "visual_path": "",            # a taught folder; "" = teach the keys into the run folder
    "takeoff_alt_m": 1.0,
    "detector": "sift",
    "n_features": 800,
    "homography": "virtual_plane",
    # typed defaults (E1's); the preset's values replace them, then the user's replace those
    "l0": 2.8, "linf": 0.1, "l0_slope": 5.0, "vy_extra": 2.5, "w_ratio": 0.5,
    "t_eps_px": 6.0, "t_eps_final_px": 6.0,
    "avoidance": True, "avoidance_task": "corridor", "sigma": [], "lambda_a": 0.01,
    "obstacle_width_m": 0.08, "clearance_m": 0.35, "lambda_c": 0.8, "avoid_range_m": 2.0,
    "visibility": True, "lambda_m": 0.2, "margin": 0.1, "visibility_depth_m": 2.0,
    "ramp_s": 1.0, "smoothing": False, "smoothing_s": 1.6, "h0": 0.2,
    "feedforward": False, "gamma": 0.75, "p": 0.5, "rising_n": 5,
    "ff_clearance_m": 0.4,        # m: feed-forward only on a taught path this clear of the room
    "rising_max_px": 0.0,         # 0: no bound (the paper's rule)
    "min_matches": 16, "min_tracked": 8, "outlier_px": 2.0,
    # tracking (features.Tracker, spread): the LK window (px at 856, odd) and the most
    # matched points tracked, spread over the image (0: all)
    "lk_win_px": 15, "track_max": 0,
    "v_max_mps": 1.0, "wz_max_dps": 60.0,
    "lost_timeout_s": 5.0, "target_timeout_s": 90.0, "hold_final_s": 1.0,
    "vision_every": 1,
    # how the command reaches the vehicle (cosim/apps/vs/lowlevel.py): "velocity" setpoints,
    # or "moveby", paper 2's ViSP setVelocity: a relative move of the command over dt per
    # vision cycle; dt = moveby_dt_s, or the vision cycle's period when 0
    "low_level": "velocity", "moveby_dt_s": 0.0,
    # issue 28 (ours): the homography choice held steady (vs/choice.py)
    "h_jump": 0.15, "h_hold_n": 5,
    # issue 28 (ours): fresh matches and the visibility task's bounds (vs/choice.py Refresh)
    "vis_max_s": 3.0, "stall_s": 4.0, "refresh_frac": 0.3,
    "vis_v_max_mps": 0.2, "vis_wz_max_dps": 15.0,
    # issue 28 (ours): turn keys need their translation too (0: the paper's eps rule alone)
    "turn_deg": 20.0, "turn_t_ev": 0.06, "turn_wait_s": 5.0,
    "decouple": True,             # at turn keys: the heading out of e_v (geometry.decouple)
}

# paper 2 Sec. 5; detector: SIFT in 5.1-5.2, Shi-Tomasi corners in 5.3. One deviation: E1's
# activation ramp is 1 s, not the paper's 3 s: with the bar 0.7 m ahead of the camera at the
# start, a 3 s ramp lets the vehicle reach the bar before the task is on (measured: collision
# at t = 6.4 s with ramp_s = 3; `--set app.params.ramp_s=3` reproduces it).
PRESETS: dict[str, dict[str, Any]] = {
    "e1": {"l0": 2.8, "linf": 0.1, "l0_slope": 5.0, "vy_extra": 2.5, "t_eps_px": 6.0,
           "t_eps_final_px": 6.0, "sigma": 0.05, "avoidance": True, "visibility": True,
           "ramp_s": 1.0, "smoothing": False, "feedforward": False, "detector": "sift"},
    "e2": {"l0": 2.8, "linf": 0.1, "l0_slope": 5.0, "vy_extra": 2.5, "t_eps_px": 12.0,
           "t_eps_final_px": 7.0, "sigma": 0.06, "avoidance": True, "visibility": True,
           "ramp_s": 1.6, "smoothing": True, "feedforward": False, "detector": "sift"},
    "e3": {"l0": 2.1, "linf": 1.0, "l0_slope": 5.0, "vy_extra": 0.1, "t_eps_px": 18.0,
           "t_eps_final_px": 7.0, "sigma": 0.05, "avoidance": False, "visibility": False,
           "ramp_s": 1.6, "smoothing": True, "feedforward": False, "detector": "gftt"},
    "e4": {"l0": 1.5, "linf": 0.8, "l0_slope": 5.0, "vy_extra": 2.0, "t_eps_px": 18.0,
           "t_eps_final_px": 7.0, "sigma": 0.05, "avoidance": False, "visibility": False,
           "ramp_s": 1.6, "smoothing": True, "feedforward": True, "detector": "gftt"},
}


def resolve(params: dict[str, Any]) -> dict[str, Any]:
    """The app's parameters: DEFAULTS, then the preset's values, then the user's; checked."""
    name = params.get("preset", DEFAULTS["preset"])
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"app.params.preset: got {name!r}; allowed: {', '.join(PRESETS)}")
    out = check_params({**PRESETS[name], **params}, DEFAULTS, "visual_servo")
    for k in ("l0", "linf", "l0_slope", "t_eps_px", "t_eps_final_px", "lambda_a", "lambda_m",
              "obstacle_width_m", "clearance_m", "lambda_c", "avoid_range_m", "outlier_px",
              "visibility_depth_m", "v_max_mps", "wz_max_dps",
              "lost_timeout_s", "target_timeout_s", "takeoff_alt_m", "h_jump", "vis_max_s",
              "stall_s", "vis_v_max_mps", "vis_wz_max_dps"):
        if not float(out[k]) > 0.0:
            raise ValueError(f"app.params.{k}: got {out[k]!r}; expected a number > 0")
    if not float(out["rising_max_px"]) >= 0.0:
        raise ValueError(f"app.params.rising_max_px: got {out['rising_max_px']!r}; expected a "
                         "number >= 0 (0: no bound)")
    for k in ("h0", "p", "gamma", "margin", "refresh_frac"):
        if not 0.0 <= float(out[k]) <= 1.0:
            raise ValueError(f"app.params.{k}: got {out[k]!r}; expected a number in [0, 1]")
    if not float(out["margin"]) < 0.5:
        raise ValueError(f"app.params.margin: got {out['margin']!r}; expected < 0.5")
    for k in ("min_matches", "min_tracked", "rising_n", "vision_every", "n_features",
              "h_hold_n"):
        if not isinstance(out[k], int) or out[k] < 1:
            raise ValueError(f"app.params.{k}: got {out[k]!r}; expected an integer >= 1")
    w = out["lk_win_px"]
    if not isinstance(w, int) or isinstance(w, bool) or not 11 <= w <= 61 or w % 2 == 0:
        raise ValueError(f"app.params.lk_win_px: got {w!r}; expected an odd integer in "
                         "[11, 61] (px at the 856-px stream; 11: features.WIN_MIN_PX)")
    n = out["track_max"]
    if (not isinstance(n, int) or isinstance(n, bool)
            or not (n == 0 or n >= out["min_matches"])):
        raise ValueError(f"app.params.track_max: got {n!r}; expected 0 (all) or an integer "
                         f">= min_matches ({out['min_matches']})")
    if out["min_tracked"] < 8 or out["min_matches"] < out["min_tracked"]:
        raise ValueError("app.params.min_tracked: a homography needs >= 8 points, and "
                         "min_matches must be >= min_tracked")
    for k in ("ramp_s", "smoothing_s", "hold_final_s", "turn_deg", "turn_t_ev", "turn_wait_s",
              "ff_clearance_m"):
        if not float(out[k]) >= 0.0:
            raise ValueError(f"app.params.{k}: got {out[k]!r}; expected a number >= 0")
    if out["low_level"] not in LOW_LEVELS:
        raise ValueError(f"app.params.low_level: got {out['low_level']!r}; allowed: "
                         f"{', '.join(LOW_LEVELS)}")
    if not 0.0 <= float(out["moveby_dt_s"]) <= 10.0:
        raise ValueError(f"app.params.moveby_dt_s: got {out['moveby_dt_s']!r}; expected a "
                         "number in [0, 10] s (0: the vision cycle's period)")
    if out["homography"] not in ("virtual_plane", "dominant_plane"):
        raise ValueError(f"app.params.homography: got {out['homography']!r}; allowed: "
                         "virtual_plane, dominant_plane")
    if out["avoidance_task"] not in ("width", "corridor"):
        raise ValueError(f"app.params.avoidance_task: got {out['avoidance_task']!r}; allowed: "
                         "width, corridor")
    if out["detector"] not in ("sift", "gftt", "orb"):
        raise ValueError(f"app.params.detector: got {out['detector']!r}; allowed: sift, "
                         "gftt, orb")
    s = out["sigma"]
    sig = s if isinstance(s, list) else [s]
    if not sig or not all(isinstance(v, int | float) and not isinstance(v, bool) and v > 0
                          for v in sig):
        raise ValueError(f"app.params.sigma: got {s!r}; expected a number > 0 or a list of "
                         "them, one per key")
    return out
