"""A run as an MCAP file with Foxglove's well-known schemas, written through the Foxglove SDK
(`foxglove-sdk`), for Foxglove and PlotJuggler. Every log time is simulation time (ns since
t = 0), so the file of a run is as deterministic as the run.

Topics (`TOPICS`): the vehicle pose (`foxglove.PoseInFrame`, frame `world`, world NED as the
simulator uses it) and the world as a 3D scene (`foxglove.SceneUpdate`: track centreline,
end marker, arena); camera frames (`foxglove.RawImage`, rgb8, at camera ticks); JSON topics
for plots: truth, estimate, setpoint, motor commands, the app's phase, the app's per-frame
vision outputs; every MAVLink message of the API and GCS links decoded to its fields.
The per-tick topics are written from the recorded series, block by block, after the run;
frames are added while the run goes (`McapFrames`).
"""

from __future__ import annotations

import math
from pathlib import Path

import foxglove
from foxglove import Channel, Context
from foxglove.channels import PoseInFrameChannel, RawImageChannel, SceneUpdateChannel
from foxglove.messages import (
    Color,
    CylinderPrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    Vector3,
)

from cosim.sim.estimate import ESTIMATE_COLUMNS
from cosim.sim.recorder import COL

TOPICS = {
    "/vehicle/pose": "foxglove.PoseInFrame",
    "/world/scene": "foxglove.SceneUpdate",
    "/camera/image": "foxglove.RawImage",
    "/vehicle/truth": "json",
    "/vehicle/estimate": "json",
    "/app/setpoint": "json",
    "/vehicle/motors": "json",
    "/app/phase": "json",
    "/app/vision": "json",
    "/mavlink": "json",
}
_VISION_FIELDS = ("flag_track", "flag_marker", "e_x_px", "e_y_px")


def _ts(t_ns: int) -> Timestamp:
    return Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


class McapRun:
    """An open MCAP file for one run; `frame(t, img)` during the run, `finish(res)` after."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.ctx = Context()
        self._writer = foxglove.open_mcap(str(self.path), allow_overwrite=True, context=self.ctx)
        self._image = RawImageChannel("/camera/image", context=self.ctx)
        self.frames = 0

    def frame(self, t: float, img) -> None:
        """A camera frame (H x W x 3 uint8 RGB) at simulation time t (s)."""
        t_ns = int(round(t * 1e9))
        h, w = img.shape[:2]
        self._image.log(RawImage(timestamp=_ts(t_ns), frame_id="camera", width=w, height=h,
                                 encoding="rgb8", step=3 * w, data=img.tobytes()),
                        log_time=t_ns)
        self.frames += 1

    def finish(self, res) -> Path:
        """Write the recorded series, the scene, the app's outputs and the MAVLink traffic."""
        ctx = self.ctx
        pose = PoseInFrameChannel("/vehicle/pose", context=ctx)
        json_ch = {name: Channel(name, context=ctx) for name, kind in TOPICS.items()
                   if kind == "json"}
        self._scene(SceneUpdateChannel("/world/scene", context=ctx), res.scenario.world)
        phases = res.phases
        c = COL
        est = res.estimate          # sensor-fed: the rest of the vehicle's estimate
        k = -1
        for block in res.recorded.blocks():
            for row in block:
                k += 1
                t_ns = int(round(row[c["t"]] * 1e9))
                x, y, z = row[c["x"]], row[c["y"]], row[c["z"]]
                pose.log(PoseInFrame(
                    timestamp=_ts(t_ns), frame_id="world",
                    pose=Pose(position=Vector3(x=x, y=y, z=z),
                              orientation=Quaternion(x=row[c["qx"]], y=row[c["qy"]],
                                                     z=row[c["qz"]], w=row[c["qw"]]))),
                    log_time=t_ns)
                json_ch["/vehicle/truth"].log(
                    {"t": row[c["t"]], "x": x, "y": y, "z": z, "vx": row[c["vx"]],
                     "vy": row[c["vy"]], "vz": row[c["vz"]]}, log_time=t_ns)
                e = {"x": row[c["est_x"]], "y": row[c["est_y"]], "z": row[c["est_z"]]}
                if est is not None and k < len(est):
                    e.update({n[4:]: _num(float(v)) for n, v in
                              zip(ESTIMATE_COLUMNS[3:], est[k, 3:], strict=True)})
                json_ch["/vehicle/estimate"].log(e, log_time=t_ns)
                json_ch["/app/setpoint"].log(
                    {k: _num(row[c["sp_" + k]]) for k in ("x", "y", "z")}, log_time=t_ns)
                json_ch["/vehicle/motors"].log(
                    {f"u{i}": row[c[f"u{i}"]] for i in range(1, 5)}, log_time=t_ns)
                json_ch["/app/phase"].log({"phase": phases[int(row[c["phase"]])],
                                           "index": int(row[c["phase"]])}, log_time=t_ns)
        fields = (res.frame_columns or ("t",) + _VISION_FIELDS)[1:]
        for r in res.frame_log:
            t_ns = int(round(float(r[0]) * 1e9))
            json_ch["/app/vision"].log({k: _num(float(v)) for k, v in
                                        zip(fields, r[1:], strict=False)}, log_time=t_ns)
        self._mavlink(json_ch["/mavlink"], res.tlog.path)
        self._writer.close()
        return self.path

    def close(self) -> None:
        """Close without the series (a run that could not finish writing)."""
        self._writer.close()

    @staticmethod
    def _scene(ch, world) -> None:
        red = Color(r=0.9, g=0.1, b=0.1, a=1.0)
        lines = [LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.02,
                               points=[Point3(x=float(p[0]), y=float(p[1]), z=0.0) for p in line],
                               color=red)
                 for line in world.centreline()]
        a = world.arena
        lines.append(LinePrimitive(
            type=LinePrimitiveLineType.LineLoop, thickness=0.02, color=Color(r=0.5, g=0.5, b=0.5,
                                                                             a=1.0),
            points=[Point3(x=a[0], y=a[2]), Point3(x=a[1], y=a[2]), Point3(x=a[1], y=a[3]),
                    Point3(x=a[0], y=a[3])]))
        cylinders = []
        marker = getattr(world, "marker", None)
        if marker is not None:
            d = 2.0 * marker.radius
            cylinders.append(CylinderPrimitive(
                pose=Pose(position=Vector3(x=marker.center[0], y=marker.center[1], z=0.0),
                          orientation=Quaternion(w=1.0)),
                size=Vector3(x=d, y=d, z=0.005), bottom_scale=1.0, top_scale=1.0, color=red))
        ch.log(SceneUpdate(entities=[SceneEntity(timestamp=_ts(0), frame_id="world", id="world",
                                                 lines=lines, cylinders=cylinders)]),
               log_time=0)

    @staticmethod
    def _mavlink(ch, tlog_path: Path) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        from cosim.outputs.tlog import read_tlog

        mav = mavlink2.MAVLink(None)
        mav.robust_parsing = True
        for t_us, data in read_tlog(tlog_path):
            try:
                msg = mav.decode(bytearray(data))
            except Exception:
                continue
            if msg is None:
                continue
            d = {k: _num(v) if isinstance(v, float) else v for k, v in msg.to_dict().items()
                 if isinstance(v, int | float | str)}
            d["sysid"], d["compid"] = msg.get_srcSystem(), msg.get_srcComponent()
            ch.log(d, log_time=t_us * 1000)


def _num(v: float) -> float | None:
    """JSON has no NaN: a value that is not commanded is null."""
    return v if math.isfinite(v) else None
