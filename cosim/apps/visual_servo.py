"""Paper 2 (Toro-Arcila, Becerra, Arechavaleta): teach-and-repeat hierarchical visual
servoing on the Bebop 2, as a MAVLink offboard app.

Teach: a visual path (`cosim/apps/vs/visual_path.py`), taught by rendering the listed key
poses (`keys`) into the run folder, or read from a folder (`visual_path`, e.g. taught by
`cosim teach --fly`). Repeat, per vision cycle (one camera frame, or every `vision_every`-th):
at a target change, match the frame with key k (SIFT / Shi-Tomasi / ORB, ratio test, seeded
RANSAC) and sort the points; otherwise track them with pyramidal LK. Then the homography of a
virtual plane (fallback: dominant plane), the visual error of Eq. 2, the adaptive gain of
Eq. 4, the law of Eq. 3, the camera-to-body transform of Eqs. 5-6, feed-forward (Eqs. 31-32,
with the "error rising over the last five cycles" switch; none towards the last key, ours:
a constant feed-forward would hold the vehicle off the final pose), the hierarchy avoidance >
visibility > servoing (Eqs. 13-20) and the target-change smoothing (Eqs. 28-30). Switch on
eps < T_eps (Eq. 7); at the last key, hold `hold_final_s` and land.
For rooms and paths nobody tuned it for (issue 28, ours): the homography choice is held
steady by a consistency test (vs/choice.py), the heading is taken out of e_v (decouple),
columns out of view are remembered in the vehicle's local frame until passed (vs/memory.py),
the visibility task is bounded in time and velocity and tracks are matched afresh when they
thin out or stall, and a turn key needs its translation too.

The vehicle is reached only through MAVLink: arm, AUTO.TAKEOFF to `takeoff_alt_m`, OFFBOARD,
SET_POSITION_TARGET_LOCAL_NED velocity setpoints in MAV_FRAME_BODY_NED with yaw rate at the
vision rate, AUTO.LAND. Lost features or a failed homography: zero velocity (hover) and
re-match every cycle; after `lost_timeout_s` (or `target_timeout_s` on one key) the app lands
and reports `outcome` = "aborted: <why>" (never "goal_reached").
Parameters: cosim/apps/vs/presets.py.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np

from cosim.apps.base import NAN, AppContext, FlightSequencer, FrameStage
from cosim.apps.vs import geometry as G
from cosim.apps.vs import visual_path as VP
from cosim.apps.vs.choice import HomographyChoice, Refresh
from cosim.apps.vs.features import (
    Detector,
    Tracker,
    homographies,
    match,
    px_scale,
    robust_inliers,
    sort_points,
    spread,
)
from cosim.apps.vs.lowlevel import LowLevel
from cosim.apps.vs.memory import ObstacleMemory
from cosim.apps.vs.presets import resolve
from cosim.apps.vs.tasks import (
    Obstacle,
    active_intervals,
    avoidance_task,
    corridor_task,
    frame_work,
    lateral_hold,
    outside_rectangle,
    visibility_task,
)

FRAME_COLUMNS = ("t", "target", "eps_px", "n_points", "homography", "e_vx", "e_vy", "e_vz",
                 "e_wx", "e_wy", "e_wz", "lambda", "h_a", "h_m", "h_t", "vx", "vy", "vz",
                 "wz", "ff_vx", "ff_vy", "ff_vz", "ff_wz", "obstacle_px")
H_CODE = {"failed": -1.0, "dominant_plane": 0.0, "virtual_plane": 1.0, "held": 0.5}


class VisualServoApp:
    frame_columns = FRAME_COLUMNS

    def __init__(self, params: dict[str, Any]) -> None:
        p = resolve(params)
        self.p = p
        keys = p["keys"]
        if not isinstance(keys, list) or not all(
                isinstance(r, list) and len(r) == 4 and all(
                    isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                    for v in r) for r in keys):
            raise ValueError("app.params.keys: expected a list of [n, e, d, yaw_deg] rows")
        if not keys and not p["visual_path"]:
            raise ValueError("app.params.keys: give the poses to teach at, or visual_path")
        self.teach_poses = [tuple(float(v) for v in r) for r in keys]
        self.seq = FlightSequencer(takeoff_alt_m=float(p["takeoff_alt_m"]))
        self.events = self.seq.events
        self.phase = "prelude"
        self.done = False
        self.setpoint = [NAN, NAN, NAN]
        self.frame_log: list[tuple[float, ...]] = []
        self.outcome = "not_started"
        self.path: VP.VisualPath | None = None
        self.reference_poses: list[tuple[float, float, float, float]] = []
        self._cmd = np.zeros(4)
        self._new_cmd = False
        self._frame_i = 0
        self.k = 0
        self._t_target = NAN
        self._lost_since = NAN
        self._t_goal = NAN
        self._eps_hist: list[float] = []
        self._switches: list[tuple[float, int, str]] = []
        self._rematches = 0
        self._ha_log: list[tuple[float, float]] = []
        self._hm_log: list[tuple[float, float]] = []
        self._dnu_max = 0.0
        self._last_J_a = None
        self.memory = ObstacleMemory()
        # the per-frame image work, on the stream's worker when it is pipelined
        self.frame_stage = FrameStage(functools.partial(frame_work,
                                                        avoidance=bool(p["avoidance"])))

    # ---------------------------------------------------------------- set-up
    def prepare(self, scenario, run_dir: Path) -> None:
        """Before the flight: teach (render) the keys into the run folder, or read the
        visual path the scenario names (relative to the scenario file)."""
        p = self.p
        if p["visual_path"]:
            folder = VP.folder_of(p["visual_path"], scenario.source)
        else:
            folder = VP.teach_by_render(scenario, self.teach_poses, run_dir / "visual_path",
                                        p["detector"], p["n_features"])
        self.path = VP.load(folder, scenario.camera)
        self.reference_poses = self.path.poses

    def on_start(self, ctx: AppContext) -> None:
        if self.path is None:
            raise RuntimeError("visual_servo: prepare() was not called (no visual path)")
        p, vp = self.p, self.path
        self.client = ctx.client
        self.seed = int(ctx.rng.integers(0, 2**31 - 1))
        self._hold = (0.0, 0.0, -float(p["takeoff_alt_m"]))   # local: above the start
        self.K = vp.K
        self.W, self.H = vp.size
        self.px = px_scale(self.W)     # the pixel thresholds are the 856-px stream's
        self.det = Detector(vp.detector, vp.n_features)
        self.tracker = Tracker(win=p["lk_win_px"])
        self.body_from_cam = G.body_from_camera_matrix(vp.mount_B)
        self.cam_from_body = G.camera_from_body_matrix(vp.mount_B)
        self.h_a = G.Ramp(p["ramp_s"])
        self.h_m = G.Ramp(p["ramp_s"])
        self.h_t = G.Ramp(p["smoothing_s"], 1.0)
        s = p["sigma"]
        self.sigmas = s if isinstance(s, list) else [s]
        pairs = (VP.key_pair_errors(vp, self.det, self.K, p["homography"], self.seed,
                                    p["min_tracked"], self.px)
                 if p["feedforward"] or p["turn_t_ev"] > 0.0 or p["decouple"] else [])
        # Eqs. 31-32: gamma S eTc nu_c(I*_k, I*_k+1)
        self.nu_p = [p["gamma"] * (self.body_from_cam @ self._law(e)[0]) if e is not None
                     else np.zeros(4) for e in pairs] if p["feedforward"] else []
        # turn keys (issue 28, ours): key k+1 is turned from key k by more than turn_deg (the
        # yaw part of e_w, 2 sin(angle), camera y); the first key's turn is not known. They
        # need their translation (turn_t_ev) and are servoed decoupled (decouple)
        turn = 2.0 * math.sin(math.radians(p["turn_deg"]))
        self.turn_key = [False] + [e is not None and abs(float(e[4])) > turn for e in pairs]
        self.turn_key += [False] * (len(vp.keys) - len(self.turn_key))
        self._t_eps_ok = NAN
        self._e = np.zeros(6)
        self.hchoice = HomographyChoice(p["homography"], p["h_jump"], p["h_hold_n"],
                                        p["decouple"], math.radians(p["turn_deg"]))
        self.refresh = Refresh(p["vis_max_s"], p["stall_s"], p["refresh_frac"])
        self.low = LowLevel(p["low_level"], float(p["moveby_dt_s"]),
                            (ctx.frame_period_s or 0.0) * p["vision_every"])

    def _law(self, e: np.ndarray) -> tuple[np.ndarray, float]:
        p = self.p
        lam = G.adaptive_gain(float(np.linalg.norm(e)), p["l0"], p["linf"], p["l0_slope"])
        return G.control_law(e, lam, p["vy_extra"], p["w_ratio"]), lam

    # ---------------------------------------------------------------- per frame
    def frames_wanted(self) -> bool:
        """Whether `on_frame` looks at frames now (OffboardApp): not before the repeat
        starts, nor once it has ended."""
        return self.seq.state == "flying" and self.phase in ("matching", "servo", "final")

    def on_frame(self, t: float, image: np.ndarray) -> None:
        if not self.frames_wanted():
            return
        self._frame_i += 1
        if self._frame_i % self.p["vision_every"]:
            return
        if self.phase == "final":
            self._command(t, np.zeros(4))
            if t - self._t_goal >= self.p["hold_final_s"]:
                self._finish(t, "goal_reached")
            return
        gray, ob = self.frame_stage(image)
        if self.phase == "matching":
            self._match(t, gray)
        if self.phase == "servo":
            self._servo(t, gray, ob)
        self._prev = gray

    def _match(self, t: float, gray: np.ndarray) -> None:
        tgt, cur, ratio = self._match_key(gray, self.seed + self.k)
        if len(tgt) >= self.p["min_matches"]:
            self._use_points(t, tgt, cur, ratio)
            self.phase = "servo"
            self._lost_since = NAN
            self._eps_hist = []
            return
        self._rematches += 1
        self._hover(t, "few matches")

    def _match_key(self, gray: np.ndarray, seed: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This frame matched with the current key: (key points, frame points, match ratios)."""
        key = self.path.keys[self.k]
        pts, desc = self.det.detect(gray)
        return match(self.det, key.pts, key.desc, pts, desc, seed, px=self.px, quality=True)

    def _use_points(self, t: float, tgt: np.ndarray, cur: np.ndarray, ratio: np.ndarray
                    ) -> None:
        """Servo on a freshly matched point set from now on: at most `track_max` of them,
        spread over the image, the most distinct matches first (features.spread)."""
        keep = spread(cur, self.p["track_max"], self.W, self.H, ratio)
        self.tgt, self.cur = sort_points(tgt[keep], cur[keep])
        self.hchoice.reset()
        self.refresh.matched(t, len(self.tgt))

    def _fresh_match(self, t: float, gray: np.ndarray, salt: int) -> bool:
        """Match this frame with the key afresh (vs/choice.py Refresh); on enough matches
        servo on them. Whether it did."""
        tgt, cur, ratio = self._match_key(gray, self.seed + 7 * salt)
        if len(tgt) < self.p["min_matches"]:
            return False
        self._use_points(t, tgt, cur, ratio)
        self._rematches += 1
        return True

    def _hover(self, t: float, why: str) -> None:
        """Zero velocity; give up after lost_timeout_s without a usable view."""
        self._command(t, np.zeros(4))
        if math.isnan(self._lost_since):
            self._lost_since = t
        elif t - self._lost_since >= self.p["lost_timeout_s"]:
            self._finish(t, f"aborted: {why} at key {self.k + 1} for "
                            f"{self.p['lost_timeout_s']:g} s")

    def _servo(self, t: float, gray: np.ndarray, ob: Obstacle | None) -> None:
        p = self.p
        if self._eps_hist:       # not the frame the points were matched on: track them
            new, keep = self.tracker.track(self._prev, gray, self.cur)
            head_lost = not keep[:3].all()
            self.cur, self.tgt = new[keep], self.tgt[keep]
            # points that drifted off their match (LK on a repeated texture, an occlusion):
            # outliers of the epipolar geometry between current and target go
            inl = robust_inliers(self.cur, self.tgt, self.seed + len(self.cur),
                                 p["outlier_px"], self.px)
            if inl.sum() >= p["min_tracked"] and not inl.all():
                head_lost = head_lost or not inl[:3].all()
                self.cur, self.tgt = self.cur[inl], self.tgt[inl]
            if head_lost:        # a point of the virtual plane is gone: sort again
                self.tgt, self.cur = sort_points(self.tgt, self.cur)
                self.hchoice.reset()      # another virtual plane: its error starts anew
        if len(self.cur) < p["min_tracked"]:
            self.phase = "matching"
            self._hover(t, "features lost")
            return
        eps = float(np.mean(np.linalg.norm(self.cur - self.tgt, axis=1)))
        why = self.refresh.due(t, len(self.cur), eps)
        if why is not None:
            if why == "visibility":
                self.h_m.set(t, 0.0)
            if self._fresh_match(t, gray, 11 * self.k + len(self._switches)):
                eps = float(np.mean(np.linalg.norm(self.cur - self.tgt, axis=1)))
        e, used = self.hchoice.choose(homographies(self.cur, self.tgt, self.K, p["homography"],
                                                   self.seed + len(self.cur), px=self.px),
                                      self.turn_key[self.k])
        if e is None:
            self.phase = "matching"
            self._hover(t, "homography failed")
            return
        self._lost_since = NAN
        self._e = e
        nu_c, lam = self._law(e)
        nu_v = self.body_from_cam @ nu_c
        ff = np.zeros(4)
        if self.nu_p and 1 <= self.k < len(self.path.keys) - 1:   # none at the last key
            ff = self.nu_p[self.k - 1]
            nu_v = p["p"] * nu_v + (1.0 - p["p"]) * ff
        J_a, edot_a, ob_px = (self._avoidance(t, ob, float(nu_v[0])) if p["avoidance"]
                              else (None, 0.0, 0.0))
        h_a = self.h_a.value(t)
        # visibility (Sec. 3.2)
        J_m = edot_m = None
        if p["visibility"]:
            out = outside_rectangle(self.cur, self.tgt, self.W, self.H, p["margin"])
            self.h_m.set(t, 1.0 if self.refresh.visibility_allowed(t, out) else 0.0)
            e_m, J_m = visibility_task(self.cur, self.K, p["visibility_depth_m"],
                                       self.cam_from_body)
            edot_m = -p["lambda_m"] * e_m
            # its authority bounded (issue 28): the velocity it asks for on its own
            v_m = G.pinv(J_m) @ edot_m
            scale = min(1.0, p["vis_v_max_mps"] / max(float(np.linalg.norm(v_m[:3])), 1e-9),
                        math.radians(p["vis_wz_max_dps"]) / max(abs(float(v_m[3])), 1e-9))
            edot_m = scale * edot_m
        h_m = self.h_m.value(t)
        nu, _, _ = G.hierarchy(nu_v, J_a, edot_a, h_a, J_m, edot_m, h_m)
        h_t = self.h_t.value(t) if p["smoothing"] else 1.0
        self._command(t, h_t * nu)
        self._ha_log.append((t, h_a))
        self._hm_log.append((t, h_m))
        self.frame_log.append((t, float(self.k), eps, float(len(self.cur)), H_CODE[used],
                               *map(float, e), lam, h_a, h_m, h_t, *map(float, self._cmd),
                               *map(float, ff), ob_px))
        self._switch(t, eps, gray)

    def _avoidance(self, t: float, ob: Obstacle | None, v_fwd: float
                   ) -> tuple[Any, Any, float]:
        """Sec. 3.1: (J_a, desired rate, apparent width px) and the activation's target; `ob`
        the column this frame shows (`frame_work`).

        Corridor task (ours, the default): wanted while the column, estimated `avoid_range_m`
        or closer, stands in the corridor the vehicle sweeps and the servo moves forward
        (towards it). Each sighting is remembered in the vehicle's own local frame
        (vs/memory.py, from LOCAL_POSITION_NED and ATTITUDE); once the column has left the
        view the task goes on from that memory until the column is passed: pushing out while
        it is in the corridor, holding the side otherwise (issue 28: the paper ramps down as
        soon as the column leaves the view, and a sideways hold for a fixed time froze the
        offset reached so far, short of clear when the column left the view early)."""
        p = self.p
        corridor = p["avoidance_task"] == "corridor"
        if ob is None:
            if corridor:
                return self._remembered(t, v_fwd)
            self.h_a.set(t, 0.0)
            return self._last_J_a, 0.0, 0.0
        ob_w = ob.x_right_px - ob.x_left_px
        sigma = self.sigmas[min(self.k, len(self.sigmas) - 1)]
        e_a, J_a = avoidance_task(ob, self.K, sigma, p["obstacle_width_m"], self.cam_from_body)
        edot_a = -p["lambda_a"] * e_a
        want = e_a > 0.0
        if corridor:
            e_c, J_a = corridor_task(ob, self.K, p["obstacle_width_m"], p["clearance_m"],
                                     self.cam_from_body)
            edot_a = -p["lambda_c"] * e_c
            Z = p["obstacle_width_m"] * self.K[0, 0] / max(ob_w, 1.0)
            pos, yaw = self.client.position, self.client.attitude[2]
            seen = self.memory.see(ob, self.K, p["obstacle_width_m"], pos, yaw,
                                   self.path.mount_B[0])
            near = self.memory.task(pos, yaw, p["clearance_m"], p["obstacle_width_m"])
            # a nearer column out of view comes first while the vehicle is in, or within half
            # the clearance of, its corridor
            if seen is not None and near is not None and near[0] > -0.5 * p["clearance_m"] \
                    and near[2] < self.memory.body(seen, pos, yaw)[0] - self.memory.same_m:
                return self._remembered(t, v_fwd)
            # only while the servo closes on it: a key that stands near a column (E2's second
            # key is 0.75 m in front of the bar) is reached, not held off by the corridor
            want = e_c > 0.0 and Z < p["avoid_range_m"] and v_fwd > 0.02
        self._last_J_a = J_a if want or self.h_a.target > 0.0 else None
        self.h_a.set(t, 1.0 if want else 0.0)
        return J_a, edot_a, ob_w

    def _remembered(self, t: float, v_fwd: float) -> tuple[Any, Any, float]:
        """The corridor task from the obstacle memory while the column is out of view."""
        p = self.p
        yaw = self.client.attitude[2]
        r = self.memory.task(self.client.position, yaw, p["clearance_m"],
                             p["obstacle_width_m"])
        if r is None:                       # nothing remembered, or passed: ramp down
            self.h_a.set(t, 0.0)
            J = self._last_J_a
            return (lateral_hold(J), np.zeros(1), 0.0) if J is not None else (None, 0.0, 0.0)
        e_c, J, x = r
        if e_c > 0.0 and x < p["avoid_range_m"] and (self.h_a.target > 0.0 or v_fwd > 0.02):
            self.h_a.set(t, 1.0)
            self._last_J_a = J
            return J, np.array([-p["lambda_c"] * e_c]), 0.0
        if self.h_a.target > 0.0:           # clear of the corridor, not passed: hold the side
            return J, np.zeros(1), 0.0
        return None, 0.0, 0.0

    def _verified(self, t: float, gray: np.ndarray) -> bool:
        """At the last key: eps from tracked points can drift low while the pose is still off
        (LK drift, a thinned point set), so the goal is confirmed by matching the frame with
        the key afresh (ours). When the fresh matches disagree, servoing goes on with them."""
        tgt, cur, ratio = self._match_key(gray, self.seed + 7 * self.k)
        if len(tgt) < self.p["min_tracked"]:
            return False
        eps = float(np.mean(np.linalg.norm(cur - tgt, axis=1)))
        if eps < self.p["t_eps_final_px"] * self.px:
            return True
        self._use_points(t, tgt, cur, ratio)
        self._rematches += 1
        return False

    def _switch(self, t: float, eps: float, gray: np.ndarray | None = None) -> None:
        """Eq. 7 and imgChVerif: next key on eps < T_eps (or, with feed-forward, eps rising
        over the last `rising_n` cycles; with `rising_max_px` > 0 only below it, ours, an
        option); at the last key eps < the final threshold, confirmed by a fresh match
        (_verified)."""
        p = self.p
        last = self.k == len(self.path.keys) - 1
        self._eps_hist.append(eps)
        hist = self._eps_hist[-(p["rising_n"] + 1):]
        rising = (p["feedforward"] and not last and len(hist) == p["rising_n"] + 1
                  and (p["rising_max_px"] <= 0.0 or eps < p["rising_max_px"] * self.px)
                  and all(b > a for a, b in zip(hist[:-1], hist[1:], strict=False)))
        near = eps < p["t_eps_px"] * self.px
        turn = self.turn_key[self.k] and p["turn_t_ev"] > 0.0
        rising = rising and not turn     # a turn key is not left half-turned (issue 28)
        if near and turn:
            # a turn key is reached when its translation is too (issue 28, ours): eps is
            # mostly the rotation's, and small once the heading is right while the vehicle
            # is still inside the corner; e_v is the translation over the plane's depth.
            # After turn_wait_s with eps below T_eps it is taken as it is.
            if math.isnan(self._t_eps_ok):
                self._t_eps_ok = t
            near = (float(np.linalg.norm(self._e[:3])) < p["turn_t_ev"]
                    or t - self._t_eps_ok >= p["turn_wait_s"])
        final = eps < p["t_eps_final_px"] * self.px
        if last and final and (gray is None or self._verified(t, gray)):
            self._switches.append((t, self.k, "eps"))
            self._t_goal = t
            self.phase = "final"
            self.events.append((t, "goal_reached"))
            self._command(t, np.zeros(4))
        elif not last and (near or rising):
            self._switches.append((t, self.k, "rising" if rising and not near else "eps"))
            self.k += 1
            self._t_eps_ok = NAN
            self.phase = "matching"
            self._t_target = t
            if p["smoothing"]:
                self.h_t.restart(t, p["h0"])
        elif math.isnan(self._t_target):
            self._t_target = t
        elif t - self._t_target >= p["target_timeout_s"]:
            self._finish(t, f"aborted: key {self.k + 1} not reached in "
                            f"{p['target_timeout_s']:g} s (eps {eps:.1f} px)")

    def _command(self, t: float, nu: np.ndarray) -> None:
        p = self.p
        nu = np.array(nu, dtype=float)
        vh = math.hypot(nu[0], nu[1])
        if vh > p["v_max_mps"]:
            nu[:2] *= p["v_max_mps"] / vh
        nu[2] = min(max(nu[2], -p["v_max_mps"]), p["v_max_mps"])
        wz = math.radians(p["wz_max_dps"])
        nu[3] = min(max(nu[3], -wz), wz)
        self._dnu_max = max(self._dnu_max, float(np.max(np.abs(nu - self._cmd))))
        self._cmd = nu
        self._new_cmd = True

    def _finish(self, t: float, outcome: str) -> None:
        self.outcome = outcome
        self.phase = "landing"
        self.events.append((t, "goal" if outcome == "goal_reached" else "abort"))
        self.seq.land(t, self.client)

    # ---------------------------------------------------------------- per tick
    def on_tick(self, t: float) -> None:
        c = self.client
        c.poll(t)
        seq = self.seq
        if self.phase == "prelude":
            if seq.step(t, c, self._hold):
                self.phase = "matching"
                self.outcome = "flying"
                self.events.append((t, "repeat"))
            return
        if self.phase in ("matching", "servo", "final"):
            if self.low.send(c, t, self._cmd, self._new_cmd):   # vs/lowlevel.py
                self._new_cmd = False
            return
        seq.step(t, c, self._hold)
        if seq.state == "landed":
            self.phase = "done"
            self.done = True

    @property
    def goal_reached(self) -> bool:
        return self.outcome == "goal_reached"

    def metrics(self) -> dict[str, Any]:
        switch_t = [s[0] for s in self._switches]
        return {
            "outcome": self.outcome,
            "goal_reached": self.goal_reached,
            "goal_time_s": self._t_goal if not math.isnan(self._t_goal) else None,
            "keys": len(self.path.keys) if self.path else 0,
            "keys_reached": len(self._switches),
            "switch_times_s": switch_t,
            "switches_by_rising": sum(1 for s in self._switches if s[2] == "rising"),
            "rematches": self._rematches,
            "avoidance_active_s": active_intervals(self._ha_log),
            "visibility_active_s": active_intervals(self._hm_log),
            "command_step_max": self._dnu_max,
            "vision_cycles": len(self.frame_log),
            "homography_changes": self.hchoice.changes if self.path else 0,
            "homography_holds": self.hchoice.holds if self.path else 0,
            "refreshes": dict(self.refresh.count) if self.path else {},
        }
