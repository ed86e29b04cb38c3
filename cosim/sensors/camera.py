"""Cameras: the renderer contract, the choice of a camera by kind, saving frames.

Contract (``Renderer``): ``render(p_W, q_WB) -> image`` where ``p_W`` (3,) is the position of
the body (centre of gravity) in world NED (m) and ``q_WB`` (4,) the attitude quaternion
``[w, x, y, z]`` body->world; the result is a ``H x W x 3`` uint8 RGB image.

A scenario's ``[camera]`` table names its ``kind`` (default ``"down"``); ``parse_camera`` turns
the table into that kind's config record and ``make_camera`` builds the renderer from it, so the
master never names a concrete camera. To add a camera: write its config record (with
``from_dict`` and a ``kind`` field) and its renderer in a module of this folder, and add both
to ``KINDS``.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np

from cosim.errors import ScenarioError
from cosim.sensors.down import CameraConfig, DownwardCamera, _camera_pose
from cosim.sensors.front import FrontCamera, FrontCameraConfig, camera_pose
from cosim.sensors.stream import split_stream

# kind -> (config record, renderer class); the renderer takes (world, config, seed=...)
KINDS: dict[str, tuple[type, type]] = {
    "down": (CameraConfig, DownwardCamera),
    "front": (FrontCameraConfig, FrontCamera),
}
CameraConfigAny = CameraConfig | FrontCameraConfig   # the config records in KINDS


@runtime_checkable
class Renderer(Protocol):
    """Anything that turns a body pose into a camera image."""

    def render(self, p_W: np.ndarray, q_WB: np.ndarray) -> np.ndarray:
        """p_W (3,) m world NED of the body CoG, q_WB (4,) [w,x,y,z] -> H x W x 3 uint8 RGB."""
        ...


def parse_camera(d: Mapping[str, Any], where: str = "camera") -> CameraConfigAny:
    """Validate a ``[camera]`` table into the config record of its ``kind`` (its stream keys,
    any kind: ``cosim/sensors/stream.py``)."""
    if not isinstance(d, Mapping):
        raise ScenarioError(where, d, "a table")
    kind = d.get("kind", "down")
    if not isinstance(kind, str) or kind not in KINDS:
        raise ScenarioError(f"{where}.kind", kind, f"one of {', '.join(sorted(KINDS))}")
    rest, stream = split_stream(d, where, kind)
    cfg = KINDS[kind][0].from_dict({k: v for k, v in rest.items() if k != "kind"}, where)
    cfg = replace(cfg, stream=stream)
    need = frame_bytes(cfg)
    if need > FRAME_BYTES_MAX:
        raise ScenarioError(f"{where}.supersample", cfg.supersample,
                            f"a camera whose frame needs at most {FRAME_BYTES_MAX / 2**30:g} GiB "
                            f"to render (this one ~{need / 2**30:.1f} GiB: {cfg.width} x "
                            f"{cfg.height} px x {cfg.supersample}^2 samples); a smaller size or "
                            "supersample")
    return cfg


# Memory to render one frame (issue 31), measured as the peak resident growth of a render
# (ru_maxrss; 428 x 240 and 856 x 480, supersample 2 to 8): the exact front renderer (the ray
# caster) ~180 B per ray (width x height x supersample^2), the fast front renderer ~175 B per
# pixel (it does not supersample), the downward camera ~5 B per sample. A frame needing more
# than FRAME_BYTES_MAX is refused when the scenario loads instead of exhausting memory.
FRAME_BYTES_MAX = 2 * 2**30


def frame_bytes(cfg: CameraConfigAny) -> float:
    """An upper estimate of the memory (bytes) one frame of this camera takes to render."""
    px = cfg.width * cfg.height
    if isinstance(cfg, FrontCameraConfig):
        return px * 200.0 * (cfg.supersample ** 2 if cfg.exact else 1)
    return px * cfg.supersample ** 2 * 8.0


def make_camera(config: CameraConfigAny, world, seed: int) -> Renderer:
    """The renderer for a parsed camera config (chosen by the config's kind)."""
    for cfg_type, renderer in KINDS.values():
        if isinstance(config, cfg_type):
            return renderer(world, config, seed=seed)
    raise TypeError(f"no camera for config {type(config).__name__}")


def camera_pose_W(config: CameraConfigAny, p_W, q_WB) -> tuple[np.ndarray, np.ndarray]:
    """(R_WC, c_W): the camera's optical axes (columns: image right, image down, optical
    axis) and its centre, world NED, at a body pose (a stabilized camera's turn with it)."""
    pose = camera_pose if isinstance(config, FrontCameraConfig) else _camera_pose
    return pose(config, p_W, q_WB)


# ====================================================================== saving
def save_png(frame: np.ndarray, path: str | Path) -> Path:
    """Write one RGB frame as PNG (converted to cv2's BGR order)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(p), cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write PNG {p}")
    return p


class VideoSink:
    """RGB frames streamed into a video file as they come (no frame kept in memory).

    ``.mp4`` uses the 'mp4v' codec; if this OpenCV build cannot open it, falls back to Motion
    JPEG in an ``.avi`` next to it (with a warning). Other suffixes: ``.avi`` -> MJPG.
    ``path`` is the file actually written once a frame came (None before).
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        self.asked = Path(path)
        self.fps = float(fps)
        self.path: Path | None = None
        self.count = 0
        self._vw = None

    def _open(self, w: int, h: int) -> None:
        p = self.asked
        p.parent.mkdir(parents=True, exist_ok=True)
        attempts = [(p, "mp4v")] if p.suffix.lower() == ".mp4" else []
        attempts.append((p if p.suffix.lower() == ".avi" else p.with_suffix(".avi"), "MJPG"))
        for out, codec in attempts:
            vw = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*codec), self.fps, (w, h))
            if vw.isOpened():
                if out != p:
                    warnings.warn(f"save_video: codec for {p.name} unavailable; wrote "
                                  f"{out.name} (MJPG)", RuntimeWarning, stacklevel=3)
                self._vw, self.path = vw, out
                return
            vw.release()
        raise OSError(f"save_video: no usable video writer for {p} (tried mp4v, MJPG)")

    def add(self, frame: np.ndarray) -> None:
        if self._vw is None:
            self._open(frame.shape[1], frame.shape[0])
        self._vw.write(cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2BGR))
        self.count += 1

    def close(self) -> Path | None:
        if self._vw is not None:
            self._vw.release()
            self._vw = None
        return self.path


class PngSink:
    """Frames written as ``folder/frame_TTTT.TTT.png`` (t in s) as they come."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.count = 0

    def add(self, t: float, frame: np.ndarray) -> None:
        save_png(frame, self.folder / f"frame_{t:08.3f}.png")
        self.count += 1


def save_video(frames: Iterable[np.ndarray], path: str | Path, fps: float) -> Path:
    """Write RGB frames as a video; returns the path actually written (see VideoSink).

    Raises ValueError for no frames, OSError if no writer can be opened.
    """
    sink = VideoSink(path, fps)
    try:
        for f in frames:
            sink.add(f)
    finally:
        out = sink.close()
    if out is None:
        raise ValueError("save_video: no frames")
    return out
