"""Mission metrics and pass criteria, computed from a run's recorded series.

Definitions (also in docs/outputs.md, Metrics):
- mission_time_s: from the app's take-off command to the final touchdown (s).
- path error while following: horizontal distance from the vehicle to the part of the track
  centreline it should be on (cosim/outputs/coverage.py: a cursor that follows the vehicle
  along the route, so a leg that crosses or comes near does not count), over the following
  span (first to last tick of the app's 'following' phase): RMS, max, per track part.
- track_coverage: the fraction of the route (the centreline parts joined in track order)
  flown in order, within COVERAGE_TOL_M, from the start of following to the end of the run.
- landing_error_m: horizontal distance from the touchdown point to the end-marker centre.
- line_in_view_s: camera frames in which the app saw the line, times the frame period.
- speed_mean_mps / speed_max_mps: horizontal speed over the following span.
- fault_displacement_m ([faults]): horizontal distance from where the vehicle was when the
  first fault took effect to its final touchdown (a vehicle that holds and lands: small).
- min_clearance_m (3D worlds): the smallest distance between the vehicle's body sphere
  (``body_radius`` of the airframe) and a wall, the ceiling, a box or a column over the run,
  with its time (min_clearance_t_s) and what it was (min_clearance_to); negative ends the run
  as ``collision``.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from cosim.outputs.coverage import track_progress
from cosim.outputs.result import RunResult
from cosim.outputs.series import COL
from cosim.scenario.records import Criteria, ExitReason

__all__ = ["COL", "compute_metrics", "evaluate"]

COVERAGE_TOL_M = 0.15    # m: a centreline point is passed when the vehicle comes this close


def compute_metrics(res: RunResult, world) -> dict[str, Any]:
    m: dict[str, Any] = {}
    ev = {}
    for t, name in res.events:
        ev.setdefault(name, t)
    t_takeoff = ev.get("takeoff_command")
    if res.touchdown is not None and t_takeoff is not None:
        m["mission_time_s"] = res.touchdown[0] - t_takeoff
    if "following" in res.phases and res.ticks and world.centreline():
        phase, x, y, vx, vy = res.recorded.columns("phase", "x", "y", "vx", "vy")
        mask = phase == res.phases.index("following")
        fol = np.flatnonzero(mask)
        if fol.size:
            # the following span: first to last tick of 'following' (a search or a lost
            # line inside it counts); coverage goes on to the end of the run
            i0, i1 = int(fol[0]), int(fol[-1]) + 1
            xy = np.column_stack((x[i0:], y[i0:]))
            cov, err = track_progress(world.centreline(), xy, COVERAGE_TOL_M)
            d = err[: i1 - i0]
            _, part = world.distance_to_track(xy[: i1 - i0])
            m["track_coverage"] = cov
            m["path_error_rms_m"] = float(np.sqrt(np.mean(d**2)))
            m["path_error_max_m"] = float(d.max())
            m["path_error_rms_by_part_m"] = {
                str(int(p)): float(np.sqrt(np.mean(d[part == p] ** 2))) for p in np.unique(part)
            }
            vh = np.hypot(vx[i0:i1], vy[i0:i1])
            m["speed_mean_mps"] = float(vh.mean())
            m["speed_max_mps"] = float(vh.max())
            m["following_time_s"] = float(mask.sum() * res.scenario.timing.tick_s)
            m["following_span_s"] = [float(i0 * res.scenario.timing.tick_s),
                                     float(i1 * res.scenario.timing.tick_s)]
    marker = getattr(world, "marker", None)
    if res.touchdown is not None and marker is not None:
        cn, ce = marker.center
        m["landing_error_m"] = math.hypot(res.touchdown[1] - cn, res.touchdown[2] - ce)
    if res.frame_log and res.frame_columns is None:    # the line follower's frame records
        period = res.scenario.timing.camera_every * res.scenario.timing.tick_s
        m["line_in_view_s"] = sum(1 for r in res.frame_log if r[1]) * period
    if res.faults and res.touchdown is not None and res.ticks:
        t0 = min(t for t, _ in res.faults)
        t, x, y = res.recorded.columns("t", "x", "y")
        k = min(int(np.searchsorted(t, t0)), len(t) - 1)
        m["fault_displacement_m"] = math.hypot(res.touchdown[1] - x[k], res.touchdown[2] - y[k])
    if res.min_clearance is not None:     # 3D worlds: body sphere to walls, boxes, columns
        gap, t, what = res.min_clearance
        m["min_clearance_m"] = gap
        m["min_clearance_t_s"] = t
        m["min_clearance_to"] = what
    if res.reference_poses:               # an app taught a path (teach-and-repeat)
        from cosim.outputs.taught import taught_metrics

        m.update(taught_metrics(res, res.app_metrics))
    if getattr(res, "estimate", None) is not None:    # sensor-fed: the vehicle's estimate
        from cosim.outputs.estimation import estimation_metrics

        m.update(estimation_metrics(res))
    for k, v in res.app_metrics.items():
        m.setdefault(k, v)
    return m


def evaluate(criteria: Criteria, metrics: dict[str, Any], exit_reason: ExitReason
             ) -> dict[str, dict[str, Any]]:
    """Each criterion: {'value', 'limit', 'passed'}; a metric that is missing fails."""
    out: dict[str, dict[str, Any]] = {}
    if criteria.must_complete:
        outcome = metrics.get("outcome")
        out["must_complete"] = {
            "value": exit_reason.value + (f" (app: {outcome})" if outcome is not None
                                          and metrics.get("goal_reached") is False else ""),
            "limit": ExitReason.MISSION_COMPLETE.value,
            # an app that says whether it reached its goal must have reached it
            "passed": exit_reason is ExitReason.MISSION_COMPLETE
            and metrics.get("goal_reached", True) is True,
        }
    if criteria.expect_exit is not None:
        out["expect_exit"] = {"value": exit_reason.value, "limit": criteria.expect_exit,
                              "passed": exit_reason.value == criteria.expect_exit}
    limits = {
        "landing_error_max_m": "landing_error_m",
        "path_rms_max_m": "path_error_rms_m",
        "path_max_m": "path_error_max_m",
        "mission_time_max_s": "mission_time_s",
        "position_error_max_m": "position_error_max_m",
        "final_pose_error_max_m": "final_pose_error_m",
        "final_yaw_error_max_deg": "final_yaw_error_deg",
        "fault_displacement_max_m": "fault_displacement_m",
    }
    for crit, metric in limits.items():
        limit = getattr(criteria, crit)
        if limit is None:
            continue
        v = metrics.get(metric)
        out[crit] = {"value": v, "limit": limit,
                     "passed": v is not None and math.isfinite(v) and v <= limit}
    for crit, metric in (("min_clearance_min_m", "min_clearance_m"),      # floors
                         ("coverage_min", "track_coverage")):
        limit = getattr(criteria, crit)
        if limit is None:
            continue
        v = metrics.get(metric)
        out[crit] = {"value": v, "limit": limit,
                     "passed": v is not None and math.isfinite(v) and v >= limit}
    return out


def flat_metrics(metrics: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Scalar metrics as columns; nested tables as `name.key`; a list of numbers (e.g. a key's
    switch times) as its JSON text; other lists stay in the run folder."""
    out: dict[str, Any] = {}
    for k, v in metrics.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flat_metrics(v, name + "."))
        elif isinstance(v, bool | str) or v is None:
            out[name] = v
        elif isinstance(v, int | float):
            out[name] = v
        elif hasattr(v, "item") and not hasattr(v, "__len__"):  # numpy scalar
            out[name] = v.item()
        elif isinstance(v, list | tuple) and all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            out[name] = json.dumps([float(x) for x in v])
    return out
