"""What the 3D view draws besides the truth: the vehicle's estimate and the app's setpoint, each
as where it is now and a trail of where it was (Foxglove messages, in the `world` frame).

- `/vehicle/estimate_pose` (foxglove.PoseInFrame): the estimated position; its attitude is the
  estimator's in a sensor-fed run, else the attitude the vehicle is given (the truth's: an
  odometry-fed run's ODOMETRY carries it). `POSE_DT` apart.
- `/app/setpoint_marker` (foxglove.SceneUpdate): a sphere at the position setpoint (entity
  "setpoint"), deleted while none is commanded (and at first if none is). `POSE_DT` apart.
- `/vehicle/estimate_path`, `/app/setpoint_path` (foxglove.PosesInFrame, drawn as a line): the
  last `TRAIL_S` of each, one point every `TRAIL_DT`, sent every `TRAIL_DT` (empty: none
  yet). So every topic is in every file, drawn or not.

Rates in simulation time, so the file stays the same run to run; the trail's points are
kept in a ring (memory stays flat over a day of sitl).
"""

from __future__ import annotations

import math
from collections import deque

from foxglove import Context
from foxglove.channels import PoseInFrameChannel, PosesInFrameChannel, SceneUpdateChannel
from foxglove.messages import (
    Color,
    Pose,
    PoseInFrame,
    PosesInFrame,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    Vector3,
)

from cosim.outputs import fox_scene as fs

POSE_DT_NS = 20_000_000          # 50 Hz: the estimate's pose and the setpoint's marker
TRAIL_DT_NS = 200_000_000        # 5 Hz: a trail point, and the trail sent
TRAIL_S = 10.0                   # s of trail
SETPOINT_RGBA = (0.1, 0.45, 1.0, 0.8)      # blue: the setpoint
SETPOINT_M = 0.08                          # its sphere's diameter
TOPICS = {"/vehicle/estimate_pose": "foxglove.PoseInFrame",
          "/app/setpoint_marker": "foxglove.SceneUpdate",
          "/vehicle/estimate_path": "foxglove.PosesInFrame",
          "/app/setpoint_path": "foxglove.PosesInFrame"}
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _pose(x: float, y: float, z: float, q=None) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z),
                orientation=_IDENTITY if q is None else fs.quaternion(q))


class Overlay:
    """The estimate and setpoint channels of one vehicle (`prefix` as its other topics')."""

    def __init__(self, ctx: Context, prefix: str = "") -> None:
        p = prefix
        self.est_pose = PoseInFrameChannel(p + "/vehicle/estimate_pose", context=ctx)
        self.sp_marker = SceneUpdateChannel(p + "/app/setpoint_marker", context=ctx)
        self.est_path = PosesInFrameChannel(p + "/vehicle/estimate_path", context=ctx)
        self.sp_path = PosesInFrameChannel(p + "/app/setpoint_path", context=ctx)
        n = int(round(TRAIL_S * 1e9 / TRAIL_DT_NS))
        self._est: deque[Pose] = deque(maxlen=n)
        self._sp: deque[Pose] = deque(maxlen=n)
        self._next_pose = self._next_trail = 0
        self._sp_shown = True        # the first marker message clears it if none is set
        self._sphere_color = Color(r=SETPOINT_RGBA[0], g=SETPOINT_RGBA[1], b=SETPOINT_RGBA[2],
                                   a=SETPOINT_RGBA[3])

    def channels(self) -> tuple:
        return self.est_pose, self.sp_marker, self.est_path, self.sp_path

    def add(self, t_ns: int, est, q_est, sp) -> None:
        """One tick: the estimated position `est` (x, y, z world NED, m) with attitude `q_est`
        (w, x, y, z), the setpoint `sp` (x, y, z; NaN: none commanded)."""
        if t_ns < self._next_pose:
            return
        self._next_pose = t_ns + POSE_DT_NS
        stamp = fs.ts(t_ns)
        est_ok = all(math.isfinite(v) for v in est)
        sp_ok = all(math.isfinite(v) for v in sp)
        if est_ok and self.est_pose.has_sinks():
            self.est_pose.log(PoseInFrame(timestamp=stamp, frame_id=fs.WORLD,
                                          pose=_pose(*est, q_est)), log_time=t_ns)
        if self.sp_marker.has_sinks() and (sp_ok or self._sp_shown):
            self._sp_shown = sp_ok
            if sp_ok:
                msg = SceneUpdate(entities=[SceneEntity(
                    timestamp=stamp, frame_id=fs.WORLD, id="setpoint", spheres=[SpherePrimitive(
                        pose=_pose(*sp), size=Vector3(x=SETPOINT_M, y=SETPOINT_M,
                                                      z=SETPOINT_M),
                        color=self._sphere_color)])])
            else:
                msg = SceneUpdate(deletions=[SceneEntityDeletion(
                    timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id="setpoint")])
            self.sp_marker.log(msg, log_time=t_ns)
        if t_ns < self._next_trail:
            return
        self._next_trail = t_ns + TRAIL_DT_NS
        for ok, ring, xyz, ch in ((est_ok, self._est, est, self.est_path),
                                  (sp_ok, self._sp, sp, self.sp_path)):
            if ok:
                ring.append(_pose(*xyz))
            if ch.has_sinks():              # empty while there is none
                ch.log(PosesInFrame(timestamp=stamp, frame_id=fs.WORLD, poses=list(ring)),
                       log_time=t_ns)
