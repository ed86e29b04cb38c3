"""The topics of a run for Foxglove-protocol viewers (Foxglove, Lichtblick, PlotJuggler), one
set of channels on a Foxglove SDK `Context`: the MCAP file (`mcap.py`) and the live view
(`live.py`) log through the same `Topics`, so both carry the same topics and schemas.

Every topic has a schema: Foxglove's well-known schemas (protobuf) for frames, poses, the
scene, images and the camera calibration; a JSON Schema for each JSON topic (`JSON_SCHEMAS`,
and one per MAVLink message type, `mavlink_schema`), so a viewer knows each field's type and
can plot it (`/vehicle/truth.z`). A value that is not a number (NaN: a setpoint not commanded)
is left out of its message rather than sent as null: the schema says "number", and the
viewers' JSON Schema readers take one type per field.

Camera frames are `foxglove.CompressedImage` by default: JPEG (`JPEG_QUALITY`) or PNG
(lossless) by the `images` setting (`cosim run --images`), `foxglove.RawImage` (rgb8) on
request ("raw"): an E1 frame (856 x 480) is 1.2 MB raw, ~48 kB as JPEG.

Frames and the 3D scene: `fox_scene.py`. Times are simulation time (ns since t = 0).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
from foxglove import Channel, Context, Schema
from foxglove.channels import (
    CameraCalibrationChannel,
    CompressedImageChannel,
    FrameTransformsChannel,
    PoseInFrameChannel,
    RawImageChannel,
    SceneUpdateChannel,
)
from foxglove.messages import (
    CameraCalibration,
    CompressedImage,
    FrameTransforms,
    Pose,
    PoseInFrame,
    RawImage,
    Vector3,
)

from cosim.outputs import fox_overlay
from cosim.outputs import fox_scene as fs
from cosim.outputs.series import COL, ESTIMATE_COLUMNS
from mav.rotations import R_from_quat, euler_from_quat, quat_from_euler

IMAGES = ("jpeg", "png", "raw")        # how camera frames are stored and sent; the first: default
# JPEG quality 65, Huffman tables optimized (lossless, ~2 % smaller): an E1 frame (856 x 480,
# textured walls) ~48 kB, mean error ~4 of 255 per channel; quality 90 was ~95 kB and put an
# E1 run's file at 56 MB (issue 42 asks <= 30 MB)
JPEG_QUALITY = 65
NUM, INT, STR = "number", "integer", "string"
# the JSON topics' fields; a number may be missing (not finite), the fields in REQUIRED not
JSON_SCHEMAS: dict[str, tuple[str, dict[str, str]]] = {
    "/vehicle/truth": ("cosim.VehicleTruth", {
        "t": NUM, "x": NUM, "y": NUM, "z": NUM, "vx": NUM, "vy": NUM, "vz": NUM,
        "roll_deg": NUM, "pitch_deg": NUM, "yaw_deg": NUM, "p": NUM, "q": NUM, "r": NUM,
        "alt": NUM}),
    # x, y, z from the series; a sensor-fed run's the rest of its estimate (ESTIMATE_COLUMNS)
    "/vehicle/estimate": ("cosim.VehicleEstimate", dict.fromkeys(
        (n[4:] for n in ESTIMATE_COLUMNS), NUM)),
    "/app/setpoint": ("cosim.Setpoint", {"x": NUM, "y": NUM, "z": NUM, "alt": NUM, "vx": NUM,
                                         "vy": NUM, "vz": NUM, "yaw": NUM, "yaw_rate": NUM,
                                         "dx": NUM, "dy": NUM, "dz": NUM, "dyaw": NUM,
                                         "frame": INT}),
    "/vehicle/motors": ("cosim.Motors", {"u1": NUM, "u2": NUM, "u3": NUM, "u4": NUM}),
    "/app/phase": ("cosim.AppPhase", {"phase": STR, "index": INT}),
    "/app/vision": ("cosim.AppVision", {}),     # the app's frame columns (`Topics.vision`)
}
REQUIRED = {"/vehicle/truth": ("t",), "/app/phase": ("phase", "index")}
# each JSON field's meaning and unit (the schemas' `description`, which a viewer shows): the
# simulator's angles in degrees, MAVLink's in radians (their unit from pymavlink's fields)
_NED = "world NED (x north, y east, z down), m"
DESCRIPTIONS: dict[str, dict[str, str]] = {
    "/vehicle/truth": {
        "t": "simulation time, s", "x": f"north, {_NED}", "y": f"east, {_NED}",
        "z": f"down, {_NED}", "vx": "velocity north, m/s", "vy": "velocity east, m/s",
        "vz": "velocity down, m/s", "roll_deg": "roll, deg", "pitch_deg": "pitch, deg",
        "yaw_deg": "yaw (heading from north), deg", "p": "body roll rate, rad/s",
        "q": "body pitch rate, rad/s", "r": "body yaw rate, rad/s",
        "alt": "altitude above the floor (-z), m"},
    "/vehicle/estimate": {
        "x": f"estimated north, {_NED}", "y": f"estimated east, {_NED}",
        "z": f"estimated down, {_NED}", "vx": "estimated velocity north, m/s",
        "vy": "estimated velocity east, m/s", "vz": "estimated velocity down, m/s",
        "roll": "estimated roll, rad", "pitch": "estimated pitch, rad",
        "yaw": "estimated yaw, rad", "lost": "1 while the estimate is lost, else 0"},
    "/app/setpoint": {
        "x": f"position setpoint north, {_NED}", "y": f"position setpoint east, {_NED}",
        "z": f"position setpoint down, {_NED}",
        "alt": "position setpoint altitude above the floor (-z), m",
        # the app's SET_POSITION_TARGET_LOCAL_NED in force (run.mcap only: from the tlog)
        "vx": "velocity setpoint x (in `frame`), m/s", "vy": "velocity setpoint y, m/s",
        "vz": "velocity setpoint z (down), m/s", "yaw": "yaw setpoint, rad",
        "yaw_rate": "yaw rate setpoint, rad/s",
        "dx": "relative move forward (in `frame`), m", "dy": "relative move right, m",
        "dz": "relative move down, m", "dyaw": "relative heading change, rad",
        "frame": "the command's MAV_FRAME: 1 local NED (world axes), 8 body NED (x forward, "
                 "y right, z down, turned by the heading only), 9 body offset NED (a relative "
                 "move), enum"},
    "/vehicle/motors": {f"u{i}": f"motor {i} command, 0..1" for i in range(1, 5)},
    "/app/phase": {"phase": "the app's phase name", "index": "the app's phase index"},
}
TOPICS: dict[str, str] = {
    "/tf_static": "foxglove.FrameTransforms",
    "/tf": "foxglove.FrameTransforms",
    "/vehicle/pose": "foxglove.PoseInFrame",
    "/vehicle/model": "foxglove.SceneUpdate",
    "/world/scene": "foxglove.SceneUpdate",
    "/camera/image": "foxglove.CompressedImage",      # foxglove.RawImage with images="raw"
    "/camera/calibration": "foxglove.CameraCalibration",
    **{topic: name for topic, (name, _) in JSON_SCHEMAS.items()},
    **fox_overlay.TOPICS,       # the estimate and the setpoint in the 3D view
}
MAVLINK = "/mavlink/"                     # + message name: one topic per MAVLink message type
VISION_FIELDS = ("flag_track", "flag_marker", "e_x_px", "e_y_px")   # line follower's frames


def json_schema(title: str, fields: dict[str, Any], required=(),
                descriptions: dict[str, str] | None = None) -> dict[str, Any]:
    """An object schema: each field of one JSON type (or a full schema) with its description
    (meaning and unit), no other fields."""
    props = {k: dict(v) if isinstance(v, dict) else {"type": v} for k, v in fields.items()}
    for k, d in (descriptions or {}).items():
        props[k]["description"] = d
    return {"title": title, "type": "object", "properties": props, "required": list(required),
            "additionalProperties": False}


def _channel(ctx: Context, topic: str, schema: dict[str, Any]) -> Channel:
    return Channel(topic, message_encoding="json", context=ctx, schema=Schema(
        name=schema["title"], encoding="jsonschema",
        data=json.dumps(schema).encode()))


def _finite(d: dict[str, float]) -> dict[str, float]:
    return {k: v for k, v in d.items() if math.isfinite(v)}


def encode_image(img: np.ndarray, images: str) -> bytes:
    """An H x W x 3 RGB frame as JPEG or PNG bytes (OpenCV's codecs: the same bytes for the
    same frame)."""
    import cv2

    ext, params = ((".jpg", [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY, cv2.IMWRITE_JPEG_OPTIMIZE, 1])
                   if images == "jpeg" else (".png", [cv2.IMWRITE_PNG_COMPRESSION, 3]))
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(img[..., ::-1]), params)
    if not ok:
        raise ValueError(f"cannot encode a {img.shape} frame as {images}")
    return buf.tobytes()


class Topics:
    """The channels of one vehicle's run on `ctx`; `prefix` namespaces them (a fleet's
    vehicles: "/v1"), `body` names its body frame, `images` how camera frames are stored
    (IMAGES)."""

    def __init__(self, ctx: Context, scenario, *, prefix: str = "", body: str = fs.BODY,
                 images: str = IMAGES[0]) -> None:
        if images not in IMAGES:
            raise ValueError(f"images: one of {', '.join(IMAGES)}, not {images!r}")
        self.ctx, self.sc, self.prefix, self.body = ctx, scenario, prefix, body
        self.images = images
        self.camera_frame = fs.CAMERA if body == fs.BODY else f"{body}_{fs.CAMERA}"
        p = prefix
        self.tf_static = FrameTransformsChannel(p + "/tf_static", context=ctx)
        self.tf = FrameTransformsChannel(p + "/tf", context=ctx)
        self.pose = PoseInFrameChannel(p + "/vehicle/pose", context=ctx)
        self.model = SceneUpdateChannel(p + "/vehicle/model", context=ctx)
        self.scene = SceneUpdateChannel(p + "/world/scene", context=ctx)
        # the camera's topics only for a vehicle with a camera (cosim sitl's have none)
        cam = scenario.camera is not None
        kind = RawImageChannel if images == "raw" else CompressedImageChannel
        self.image = kind(p + "/camera/image", context=ctx) if cam else None
        self.calibration = CameraCalibrationChannel(p + "/camera/calibration",
                                                    context=ctx) if cam else None
        self.json = {topic: _channel(ctx, p + topic, json_schema(title, fields, REQUIRED.get(
            topic, ()), DESCRIPTIONS[topic])) for topic, (title, fields) in JSON_SCHEMAS.items()
            if fields}
        self.overlay = fox_overlay.Overlay(ctx, p)
        self.vision_fields: tuple[str, ...] = ()
        self._mav: dict[str, Channel] = {}
        self._static: tuple | None = None

    # ------------------------------------------------------------------ once
    def static(self, t_ns: int = 0) -> None:
        """The frames' static transform, the world and the vehicle model (a live view sends
        them again now and then, for clients that connect later; built once)."""
        if self._static is None:
            w = self.sc.world
            self._static = ((self.tf_static, FrameTransforms(transforms=[
                fs.map_to_world(w), fs.flu_in_body(self.body)])),
                            (self.scene, fs.world_scene(w)),
                            (self.model, fs.vehicle_model(self.sc.vehicle, self.body)))
        for ch, msg in self._static:
            ch.log(msg, log_time=t_ns)

    # ------------------------------------------------------------------ per tick
    def watched(self) -> bool:
        """Whether any per-tick or per-frame topic has a taker (a live view's client)."""
        return any(ch is not None and ch.has_sinks() for ch in (
            self.tf, self.pose, self.image, self.calibration, *self.json.values(),
            *self.overlay.channels()))

    def row(self, r, phases: list[str], pose: bool = True, est=None,
            command: dict[str, float] | None = None) -> None:
        """One recorded tick (a row of the series, `recorder.SERIES_COLUMNS`); `pose`: also
        the body frame and the pose (a fleet's live view sends those more often); `est`: a
        sensor-fed run's estimate of that tick (ESTIMATE_COLUMNS), the rest of
        `/vehicle/estimate`; `command`: the app's setpoint command in force (velocities, yaw:
        `mcap.commands`), the rest of `/app/setpoint`. A message nobody takes (a live view
        without a client on its topic) is not even built."""
        c = COL
        t = float(r[c["t"]])
        t_ns = int(round(t * 1e9))
        x, y, z = float(r[c["x"]]), float(r[c["y"]]), float(r[c["z"]])
        q = (float(r[c["qw"]]), float(r[c["qx"]]), float(r[c["qy"]]), float(r[c["qz"]]))
        if pose:
            self.state(t_ns, x, y, z, q)
        j = self.json
        ch = j["/vehicle/truth"]
        if ch.has_sinks():
            roll, pitch, yaw = (math.degrees(a) for a in euler_from_quat(*q))
            ch.log(_finite({"t": t, "x": x, "y": y, "z": z, "vx": float(r[c["vx"]]),
                            "vy": float(r[c["vy"]]), "vz": float(r[c["vz"]]),
                            "roll_deg": roll, "pitch_deg": pitch, "yaw_deg": yaw,
                            "p": float(r[c["p"]]), "q": float(r[c["q"]]),
                            "r": float(r[c["r"]]), "alt": -z}), log_time=t_ns)
        for topic, prefix, keys in (("/vehicle/estimate", "est_", ("x", "y", "z")),
                                    ("/app/setpoint", "sp_", ("x", "y", "z")),
                                    ("/vehicle/motors", "", ("u1", "u2", "u3", "u4"))):
            ch = j[topic]
            if ch.has_sinks():
                d = {k: float(r[c[prefix + k]]) for k in keys}
                if prefix == "sp_":
                    d["alt"] = -d["z"]
                    if command:
                        d.update(command)
                if est is not None and prefix == "est_":
                    d.update({n[4:]: float(v) for n, v in zip(
                        ESTIMATE_COLUMNS[3:], est[3:], strict=True)})
                ch.log(_finite(d), log_time=t_ns)
        # the 3D view's estimate (its attitude: a sensor-fed run's estimate, else the truth's,
        # as the odometry gives it) and setpoint
        q_est = q if est is None else quat_from_euler(*(float(v) for v in est[6:9]))
        self.overlay.add(t_ns, (float(r[c["est_x"]]), float(r[c["est_y"]]),
                                float(r[c["est_z"]])), q_est,
                         (float(r[c["sp_x"]]), float(r[c["sp_y"]]), float(r[c["sp_z"]])))
        ch = j["/app/phase"]
        if ch.has_sinks():
            pi = int(r[c["phase"]])
            ch.log({"phase": phases[pi] if 0 <= pi < len(phases) else "none", "index": pi},
                   log_time=t_ns)

    def state(self, t_ns: int, x: float, y: float, z: float, q) -> None:
        """The body frame and the pose at one instant."""
        if self.tf.has_sinks():
            self.tf.log(FrameTransforms(transforms=[fs.body_in_world(
                t_ns, x, y, z, q, self.body)]), log_time=t_ns)
        if self.pose.has_sinks():
            self.pose.log(PoseInFrame(timestamp=fs.ts(t_ns), frame_id=fs.WORLD, pose=Pose(
                position=Vector3(x=x, y=y, z=z), orientation=fs.quaternion(q))),
                log_time=t_ns)

    # ------------------------------------------------------------------ per frame
    def frame(self, t: float, img: np.ndarray, p_W, q_WB) -> None:
        """A camera frame (H x W x 3 RGB) taken at body pose (p_W, q_WB): the image, the
        camera's calibration and its frame's transform from the body."""
        from cosim.sensors.camera import camera_pose_W

        t_ns = int(round(t * 1e9))
        cfg = self.sc.camera
        h, w = img.shape[:2]
        stamp = fs.ts(t_ns)
        if self.tf.has_sinks():
            R_WC, _ = camera_pose_W(cfg, p_W, q_WB)
            R_BC = R_from_quat(q_WB).T @ R_WC
            self.tf.log(FrameTransforms(transforms=[fs.camera_in_body(
                t_ns, cfg.mount_B, R_BC, self.body, self.camera_frame)]), log_time=t_ns)
        if self.calibration.has_sinks():
            K = [float(v) for v in cfg.K().ravel()]
            self.calibration.log(CameraCalibration(
                timestamp=stamp, frame_id=self.camera_frame, width=w, height=h,
                distortion_model="plumb_bob", D=[0.0] * 5, K=K,
                R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                P=K[0:3] + [0.0] + K[3:6] + [0.0] + K[6:9] + [0.0]), log_time=t_ns)
        if self.image.has_sinks():
            if self.images == "raw":
                msg = RawImage(timestamp=stamp, frame_id=self.camera_frame, width=w, height=h,
                               encoding="rgb8", step=3 * w, data=img.tobytes())
            else:
                msg = CompressedImage(timestamp=stamp, frame_id=self.camera_frame,
                                      data=encode_image(img, self.images), format=self.images)
            self.image.log(msg, log_time=t_ns)

    def vision(self, record, columns=None) -> None:
        """One record of the app's frame log: (t, value per field...); `columns` (the app's
        `frame_columns`, "t" first; default: the line follower's) name the fields, and the
        channel's schema is made from them on the first record."""
        if "/app/vision" not in self.json:
            self.vision_fields = tuple(columns)[1:] if columns else VISION_FIELDS
            title, _ = JSON_SCHEMAS["/app/vision"]
            self.json["/app/vision"] = _channel(self.ctx, self.prefix + "/app/vision", json_schema(
                title, dict.fromkeys(self.vision_fields, NUM), (), {
                    k: vision_description(k) for k in self.vision_fields}))
        t_ns = int(round(float(record[0]) * 1e9))
        self.json["/app/vision"].log(_finite({k: float(v) for k, v in zip(
            self.vision_fields, record[1:], strict=False)}), log_time=t_ns)

    # ------------------------------------------------------------------ MAVLink
    def mavlink(self, msg, t_ns: int) -> None:
        """A decoded pymavlink message on its type's topic (channel made on first use)."""
        name = msg.get_type()
        ch = self._mav.get(name)
        if ch is None:
            ch = self._mav[name] = _channel(self.ctx, self.prefix + MAVLINK + name,
                                            mavlink_schema(msg))
        d: dict[str, Any] = {"mavpackettype": name, "sysid": msg.get_srcSystem(),
                             "compid": msg.get_srcComponent()}
        for k in msg.get_fieldnames():
            v = getattr(msg, k)
            if isinstance(v, float):
                if math.isfinite(v):
                    d[k] = v
            elif isinstance(v, list):
                if all(not isinstance(e, float) or math.isfinite(e) for e in v):
                    d[k] = v
            elif isinstance(v, bytes):
                d[k] = v.decode("utf-8", "replace")
            else:
                d[k] = v
        ch.log(d, log_time=t_ns)


def vision_description(name: str) -> str:
    """An app's per-frame output, its unit read from its name's suffix (`e_x_px`: px)."""
    units = {"_px": "px", "_mps": "m/s", "_m": "m", "_deg": "deg", "_rad": "rad", "_s": "s",
             "_radps": "rad/s"}
    unit = next((u for suffix, u in units.items() if name.endswith(suffix)), None)
    if name.startswith("flag_"):
        return f"the app's per-frame flag {name[5:]}: 1 or 0"
    return f"the app's per-frame output {name}" + (f", {unit}" if unit else "")


_MAV_TYPES = {"float": NUM, "double": NUM, "char": STR}


def mavlink_schema(msg) -> dict[str, Any]:
    """The JSON Schema of one MAVLink message type, from pymavlink's field definitions: C
    integers -> integer, float/double -> number, char[N] -> string, other arrays -> arrays.
    Floats (NaN is left out) and arrays holding NaN are optional."""
    name = msg.get_type()
    fields: dict[str, Any] = {"mavpackettype": STR, "sysid": INT, "compid": INT}
    docs = {"mavpackettype": "the MAVLink message name", "sysid": "the sender's system id",
            "compid": "the sender's component id"}
    units = getattr(msg, "fieldunits_by_name", {}) or {}
    enums = getattr(msg, "fieldenums_by_name", {}) or {}
    optional = set()
    lengths = dict(zip(msg.ordered_fieldnames, msg.array_lengths, strict=True))  # wire order
    for k, ctype in zip(msg.fieldnames, msg.fieldtypes, strict=True):
        base = _MAV_TYPES.get(ctype, INT)
        if base == NUM:
            optional.add(k)
        fields[k] = ({"type": "array", "items": {"type": base}} if lengths[k] and base != STR
                     else base)
        docs[k] = f"MAVLink {name}.{k}" + (f", {units[k]}" if k in units else "") + (
            f" ({enums[k]})" if k in enums else "")
    return json_schema(f"mavlink.{name}", fields, [k for k in fields if k not in optional],
                       docs)
