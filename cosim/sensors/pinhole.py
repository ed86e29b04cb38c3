"""The front camera's model: its config record (`[camera] kind = "front"`), mount and
stabilization, and the pinhole projection shared by its renderers (`cosim/sensors/front.py`
fast, `cosim/sensors/raycast.py` exact). See front.py's docstring for the model."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.scenario.validate import boolean, integer, no_unknown, number, rgb
from cosim.sensors.stream import StreamSpec
from cosim.world.surfaces import Surface, scene_surfaces
from mav.rotations import R_from_quat

# Camera axes in the rig frame (= body FRD for a zero mount rotation): columns are x_C (image
# right) = rig y, y_C (image down) = rig z, z_C (optical axis) = rig x.
R_BC_FRONT = np.array([[0.0, 0.0, 1.0],
                       [1.0, 0.0, 0.0],
                       [0.0, 1.0, 0.0]])

def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """ZYX (yaw, pitch, roll) rotation, rig -> body (rad)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def yaw_of(q_WB: Sequence[float]) -> float:
    w, x, y, z = (float(c) for c in q_WB)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@dataclass(frozen=True)
class FrontCameraConfig:
    """Front camera parameters (TOML ``[camera]`` with ``kind = "front"``, same keys)."""

    width: int = 856
    height: int = 480
    fx: float = 537.3
    fy: float = 527.0
    cx: float = 428.0
    cy: float = 240.0
    mount_B: tuple[float, float, float] = (0.09, 0.0, 0.0)
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stabilized: bool = True
    near_m: float = 0.05
    tile_m: float = 2.0
    noise_std: float = 0.0
    lighting_noise: float = 0.0   # 1, std of the per-frame exposure gain around 1
    offset_noise: float = 0.0     # 0-255 units, std of the per-frame exposure offset
    exposure_s: float = 0.0       # s, shutter time of the motion blur (0: no blur)
    brightness: float = 1.0       # the scene's lighting at repeat: every frame's values x this
    background_rgb: tuple[int, int, int] = (0, 0, 0)
    exact: bool = False           # render with the reference ray caster (slow)
    supersample: int = 2          # reference renderer: rays per pixel side
    depth: bool = False           # keep the depth image of each frame (last_depth)
    kind: str = "front"
    stream: StreamSpec = StreamSpec()   # latency and jitter of its frames (stream.py)

    @property
    def noisy(self) -> bool:
        """Frames differ with the camera's seed (pixel or exposure noise)."""
        return self.noise_std > 0.0 or self.lighting_noise > 0.0 or self.offset_noise > 0.0

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "camera") -> FrontCameraConfig:
        if not isinstance(d, Mapping):
            raise ScenarioError(where, d, "a table")
        no_unknown(d, {"width", "height", "fx", "fy", "cx", "cy", "hfov_deg", "mount_B",
                       "mount_rpy_deg", "stabilized", "near_m", "tile_m", "noise_std",
                       "lighting_noise", "offset_noise", "exposure_s", "brightness",
                       "background_rgb", "exact", "supersample", "depth"},
                   where)
        kw: dict[str, Any] = {}
        w = kw["width"] = integer(d, "width", where, cls.width, lo=16, hi=4096)
        h = kw["height"] = integer(d, "height", where, cls.height, lo=16, hi=4096)
        if "hfov_deg" in d:
            for k in ("fx", "fy"):
                if k in d:
                    raise ScenarioError(f"{where}.{k}", d[k], "either hfov_deg or fx/fy")
            hfov = number(d, "hfov_deg", where, lo=1.0, hi=170.0)
            kw["fx"] = kw["fy"] = 0.5 * w / math.tan(math.radians(0.5 * hfov))
        else:
            scale = w / cls.width     # defaults follow the resolution (428 x 240: half)
            aspect = (w / h) / (cls.width / cls.height)
            if ("fx" not in d or "fy" not in d) and abs(aspect - 1.0) > 0.01:
                raise ScenarioError(
                    f"{where}.height", h, f"{round(w * cls.height / cls.width)} for a width of "
                    f"{w} (the {cls.width} x {cls.height} stream's shape, whose lens the "
                    f"defaults scale), or the lens for this shape: fx and fy, or hfov_deg")
            kw["fx"] = number(d, "fx", where, cls.fx * scale, lo=1.0, hi=1e5, lo_open=False)
            kw["fy"] = number(d, "fy", where, cls.fy * h / cls.height, lo=1.0, hi=1e5)
        kw["cx"] = number(d, "cx", where, 0.5 * w, lo=-0.5, hi=w - 0.5)
        kw["cy"] = number(d, "cy", where, 0.5 * h, lo=-0.5, hi=h - 0.5)
        for key, lim, what in (("mount_B", 1.0, "[x, y, z] body FRD offset in metres"),
                               ("mount_rpy_deg", 90.0, "[roll, pitch, yaw] in degrees")):
            if key in d:
                v = d[key]
                if (not isinstance(v, list) or len(v) != 3
                        or any(isinstance(c, bool) or not isinstance(c, (int, float))
                               or not math.isfinite(c) or abs(c) > lim for c in v)):
                    raise ScenarioError(f"{where}.{key}", v, f"{what}, each |.| <= {lim:g}")
                kw[key] = (float(v[0]), float(v[1]), float(v[2]))
        kw["stabilized"] = boolean(d, "stabilized", where, True)
        kw["exact"] = boolean(d, "exact", where, False)
        kw["depth"] = boolean(d, "depth", where, False)
        kw["near_m"] = number(d, "near_m", where, 0.05, lo=0.001, hi=1.0)
        kw["tile_m"] = number(d, "tile_m", where, 2.0, lo=0.1, hi=100.0)
        kw["noise_std"] = number(d, "noise_std", where, 0.0, lo=0.0, hi=100.0)
        kw["lighting_noise"] = number(d, "lighting_noise", where, 0.0, lo=0.0, hi=0.5)
        kw["offset_noise"] = number(d, "offset_noise", where, 0.0, lo=0.0, hi=50.0)
        kw["exposure_s"] = number(d, "exposure_s", where, 0.0, lo=0.0, hi=0.2)
        kw["brightness"] = number(d, "brightness", where, 1.0, lo=0.1, hi=4.0)
        kw["supersample"] = integer(d, "supersample", where, 2, lo=1, hi=8)
        kw["background_rgb"] = rgb(d, "background_rgb", where, cls.background_rgb)
        return cls(**kw)


# ====================================================================== geometry
class _View:
    """Camera pose for one frame: R_CW (world -> camera), centre c (world NED)."""

    def __init__(self, cfg: FrontCameraConfig, R_BC: np.ndarray, p_W, q_WB) -> None:
        R_WB = R_from_quat(q_WB)
        self.c = np.asarray(p_W, dtype=float).reshape(3) + R_WB @ np.asarray(cfg.mount_B)
        if cfg.stabilized:
            yaw = yaw_of(q_WB)
            cy, sy = math.cos(yaw), math.sin(yaw)
            R_WBs = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
            R_WC = R_WBs @ R_BC
        else:
            R_WC = R_WB @ R_BC
        self.R_CW = R_WC.T


def camera_pose(cfg: FrontCameraConfig, p_W, q_WB) -> tuple[np.ndarray, np.ndarray]:
    """(R_WC, c_W) of the front camera for a body pose."""
    v = _View(cfg, rpy_matrix(*np.radians(cfg.mount_rpy_deg)) @ R_BC_FRONT, p_W, q_WB)
    return v.R_CW.T, v.c


def project(cfg: FrontCameraConfig, X_W, p_W, q_WB) -> tuple[float, float]:
    """(col, row) pixel of a world point, (nan, nan) behind the camera."""
    R_WC, c = camera_pose(cfg, p_W, q_WB)
    x, y, z = R_WC.T @ (np.asarray(X_W, float) - c)
    if z <= 1e-9:
        return math.nan, math.nan
    return cfg.cx + cfg.fx * x / z, cfg.cy + cfg.fy * y / z


def scene_key(world) -> str | None:
    """A hash of what a room world's surfaces are made of (None for a flat world: its floor
    is drawn from the track, not the scene)."""
    if world.scene.room is None:
        return None
    mine = world._cache
    if "scene_key" not in mine:
        from cosim import cache
        mine["scene_key"] = cache.key("scene", world.scene)
    return mine["scene_key"]


def world_surfaces(world) -> list[Surface]:
    """The world's surfaces: built once per world object and, for a room world, once per
    scene in this process (``cosim/cache.py``)."""
    from cosim import cache

    mine = world._cache
    if "surfaces" not in mine:
        sk = scene_key(world)
        if sk is None:
            mine["surfaces"] = scene_surfaces(world.scene, world.floor_image(200.0))
        else:
            mine["surfaces"] = cache.memo("surfaces", sk,
                                          lambda: scene_surfaces(world.scene, None))
    return mine["surfaces"]


