"""The Mambo's downward camera over a flat world (`[camera] kind = "down"`, the default).

Downward camera model (reference/minidrone.md §3):

- Pinhole, square pixels, ``f = (H/2) / tan(vfov/2)`` px (45 deg across 120 px: f = 144.85 px),
  principal point at the exact image centre ``((W-1)/2, (H-1)/2) = (79.5, 59.5)`` in 0-based
  (col, row) pixel-centre coordinates, the same centre the IPS uses (row 59.5, col 79.5).
- Mounted at ``mount_B`` in body FRD (Mambo: 0.1 m below the CoG), rigidly: it tilts with roll
  and pitch. Looking straight down (optical axis = body +z); image up = body +x (forward),
  image right = body +y (right). Camera axes: x_C (col) = body y, y_C (row) = -body x,
  z_C = body z.
- The floor plane z = 0 is rendered through the plane-induced homography: output pixel ->
  world (N, E) on the floor -> floor texture pixel, one ``cv2.warpPerspective``, sampled
  bilinearly. The texture is rasterised once with exact area coverage per texel (a box
  prefilter), so thin lines keep their area and do not break up. Defaults: 150 px/m texture
  (6.7 mm texels), rendered at 1x: at the 1.1 m hover height one output pixel covers 7.6 mm,
  about one texel, so the texture is already filtered to the pixel footprint (mipmap-like).
  ``supersample = k`` renders at k x resolution and box-filters down with
  ``cv2.resize(INTER_AREA)`` (pair it with a k x finer texture: 300 px/m and k = 2 was the
  earlier default; it gives the same mission metrics at ~3.5x the cost, 0.43 vs 0.12 ms per
  160 x 120 frame, single-threaded, on the development machine). The warp reads an RGBA copy
  of the texture (OpenCV's 4-channel warp is ~1.8x faster than its 3-channel one and gives
  the same bytes). ``interpolation = "nearest"`` is faster still and keeps points within
  0.5 px, but biases the width of axis-aligned lines by up to ~0.5 px. OpenCV runs
  single-threaded (one run uses one core).
- No floor in view: pixels whose ray does not hit the floor in front of the camera (at or
  above the horizon, |tilt| > ~55 deg) are black (0, 0, 0); with the camera at or below the
  floor (e.g. on the ground, camera 0.1 m below the CoG) the whole frame is black. Beyond the
  rasterised texture (arena + margin) the floor continues in ``world.floor_rgb``.
- Noise: ``cosim.sensors.noise.FrameNoise`` (exposure gain and pixel noise, seeded).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from cosim.errors import ScenarioError
from cosim.scenario.validate import integer, no_unknown, number, string
from cosim.sensors.noise import FrameNoise
from cosim.sensors.stream import StreamSpec
from cosim.world.floor import World
from mav.rotations import R_from_quat

# Camera axes in body FRD: columns are x_C (image right), y_C (image down), z_C (optical axis).
R_BC_DOWN = np.array([[0.0, -1.0, 0.0],
                      [1.0, 0.0, 0.0],
                      [0.0, 0.0, 1.0]])

NO_FLOOR_RGB = (0, 0, 0)


@dataclass(frozen=True)
class CameraConfig:
    """Downward camera parameters (TOML ``[camera]`` table, same keys)."""

    width: int = 160                                # px
    height: int = 120                               # px
    vfov_deg: float = 45.0                          # deg across the height (VRML default 0.785)
    mount_B: tuple[float, float, float] = (0.0, 0.0, 0.1)  # m, body FRD offset from the CoG
    noise_std: float = 0.0                          # 0-255 units, per-pixel Gaussian noise
    lighting_noise: float = 0.0                     # 1, std of the per-frame gain around 1
    supersample: int = 1                            # render at k x resolution, box-filter down
    texture_px_per_m: float = 150.0                 # px/m, floor texture resolution
    interpolation: str = "linear"                   # texture sampling: "linear" or "nearest"
    stream: StreamSpec = StreamSpec()               # latency and jitter of its frames

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels)."""
        return 0.5 * self.height / math.tan(0.5 * math.radians(self.vfov_deg))

    @property
    def center_rc(self) -> tuple[float, float]:
        """Principal point (row, col), 0-based pixel-centre coordinates."""
        return 0.5 * (self.height - 1), 0.5 * (self.width - 1)

    def K(self) -> np.ndarray:
        """Intrinsic matrix mapping camera-frame rays to (col, row, 1)."""
        f = self.focal_px
        r0, c0 = self.center_rc
        return np.array([[f, 0.0, c0], [0.0, f, r0], [0.0, 0.0, 1.0]])

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "camera") -> CameraConfig:
        """Validate a ``[camera]`` table; unknown keys and bad values raise ScenarioError."""
        if not isinstance(d, Mapping):
            raise ScenarioError(where, d, "a table")
        no_unknown(d, {"width", "height", "vfov_deg", "mount_B", "noise_std", "lighting_noise",
                       "supersample", "texture_px_per_m", "interpolation"}, where)
        kw: dict[str, Any] = {}
        for k, lo, hi in (("width", 8, 4096), ("height", 8, 4096), ("supersample", 1, 8)):
            if k in d:
                kw[k] = integer(d, k, where, lo=lo, hi=hi)
        for k, lo, hi, lo_open in (("vfov_deg", 0.0, 170.0, True), ("noise_std", 0.0, 100.0, False),
                                   ("lighting_noise", 0.0, 0.5, False),
                                   ("texture_px_per_m", 50.0, 2000.0, False)):
            if k in d:
                kw[k] = number(d, k, where, lo=lo, hi=hi, lo_open=lo_open)
        if "mount_B" in d:
            v = d["mount_B"]
            if (not isinstance(v, list) or len(v) != 3
                    or any(isinstance(c, bool) or not isinstance(c, (int, float))
                           or not math.isfinite(c) or abs(c) > 1.0 for c in v)):
                raise ScenarioError(f"{where}.mount_B", v,
                                    "[x, y, z] body FRD offset in metres, each |.| <= 1")
            kw["mount_B"] = (float(v[0]), float(v[1]), float(v[2]))
        if "interpolation" in d:
            kw["interpolation"] = string(d, "interpolation", where, choices=("linear", "nearest"))
        return cls(**kw)


def _camera_pose(cfg: CameraConfig, p_W: Sequence[float], q_WB: Sequence[float]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(R_WC (3, 3), c_W (3,)) of the camera for a body pose."""
    R_WB = R_from_quat(q_WB)
    c_W = np.asarray(p_W, dtype=float).reshape(3) + R_WB @ np.asarray(cfg.mount_B)
    return R_WB @ R_BC_DOWN, c_W


def project_floor_point(p_floor_W: Sequence[float], p_W: Sequence[float],
                        q_WB: Sequence[float], config: CameraConfig | None = None
                        ) -> tuple[float, float]:
    """Exact pinhole projection (row, col) of a floor point (N, E) or (N, E, D) m.

    Returns (nan, nan) when the point is not in front of the camera.
    """
    cfg = config or CameraConfig()
    R_WC, c_W = _camera_pose(cfg, p_W, q_WB)
    p = np.zeros(3)
    p[: len(p_floor_W)] = p_floor_W
    x, y, z = R_WC.T @ (p - c_W)
    if not z > 1e-9:
        return math.nan, math.nan
    f = cfg.focal_px
    r0, c0 = cfg.center_rc
    return r0 + f * y / z, c0 + f * x / z


class DownwardCamera:
    """Renders the downward camera over a ``World`` (see the module docstring for the model).

    Per frame: pose -> 3x3 homography (a few numpy products) -> warpPerspective at
    ``supersample`` x resolution -> resize(INTER_AREA) -> optional noise.
    """

    def __init__(self, world: World, config: CameraConfig | None = None, seed: int = 0) -> None:
        # One run uses one core (ARCHITECTURE.md, Scale): OpenCV's worker threads would take
        # the second core from the SIL onboard process or from the other runs of a sweep.
        cv2.setNumThreads(1)
        self.world = world
        self.config = cfg = config or CameraConfig()
        self.rng = np.random.default_rng(seed)
        texture, self.T_tex_W = world.floor_image(cfg.texture_px_per_m)
        # Sampled as RGBA: OpenCV's 4-channel warp is ~1.8x faster than its 3-channel one and
        # gives the same R, G, B bytes (each channel is interpolated on its own; tested).
        self._texture4 = cv2.cvtColor(texture, cv2.COLOR_RGB2RGBA)
        k = cfg.supersample
        self._size_hi = (cfg.width * k, cfg.height * k)        # cv2 (width, height)
        self._size = (cfg.width, cfg.height)
        # hi-res pixel coords u_hi = k * u + (k - 1)/2 (pixel centres line up under INTER_AREA)
        A = np.array([[k, 0.0, 0.5 * (k - 1)], [0.0, k, 0.5 * (k - 1)], [0.0, 0.0, 1.0]])
        self._Kinv_hi = np.linalg.inv(A @ cfg.K())
        w_hi, h_hi = self._size_hi
        self._corners_hi = np.array([[-0.5, -0.5, 1.0], [w_hi - 0.5, -0.5, 1.0],
                                     [-0.5, h_hi - 0.5, 1.0], [w_hi - 0.5, h_hi - 0.5, 1.0]]).T
        self._border = (*(float(c) for c in world.floor_rgb), 255.0)
        self._mount_B = np.asarray(cfg.mount_B, dtype=float)
        interp = cv2.INTER_NEAREST if cfg.interpolation == "nearest" else cv2.INTER_LINEAR
        self._warp_flags = interp | cv2.WARP_INVERSE_MAP
        self._G = np.zeros((3, 3))
        self._G[2, 2] = 1.0
        self._grid_hi: tuple[np.ndarray, np.ndarray] | None = None
        self._noise = FrameNoise(self.rng, cfg.noise_std, cfg.lighting_noise,
                                 cfg.height * cfg.width * 3)

    def project(self, p_floor_W: Sequence[float], p_W: Sequence[float],
                q_WB: Sequence[float]) -> tuple[float, float]:
        """(row, col) of a floor point for this camera; see ``project_floor_point``."""
        return project_floor_point(p_floor_W, p_W, q_WB, self.config)

    def homography(self, p_W: Sequence[float], q_WB: Sequence[float]
                   ) -> tuple[np.ndarray, np.ndarray, float]:
        """(M, dz_row, c_z): M maps hi-res output pixels to texture pixels (cv2 inverse map);
        dz_row @ [u, v, 1] is the down component of each pixel's ray (> 0: sees the floor);
        c_z the camera's NED z (m)."""
        R_WB = R_from_quat(q_WB)
        c_W = np.asarray(p_W, dtype=float).reshape(3) + R_WB @ self._mount_B
        D = (R_WB @ R_BC_DOWN) @ self._Kinv_hi      # pixel -> ray in world
        # ray hits z = 0 at c + lam d, lam = -c_z / d_z  =>  [N, E, 1] ~ G d
        G = self._G
        G[0, 0] = G[1, 1] = -c_W[2]
        G[0, 2], G[1, 2] = c_W[0], c_W[1]
        return self.T_tex_W @ G @ D, D[2], float(c_W[2])

    def render(self, p_W: Sequence[float], q_WB: Sequence[float]) -> np.ndarray:
        """The camera image (H x W x 3 uint8 RGB) for the body pose (p_W m NED, q_WB)."""
        cfg = self.config
        M, dz, c_z = self.homography(p_W, q_WB)
        dz_corners = dz @ self._corners_hi
        if c_z >= -1e-6 or dz_corners.max() <= 0.0:
            out = np.zeros((cfg.height, cfg.width, 3), np.uint8)   # no floor in view
        else:
            hi = cv2.warpPerspective(self._texture4, M, self._size_hi, flags=self._warp_flags,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=self._border)
            if dz_corners.min() <= 1e-9:            # horizon in view: black above it
                if self._grid_hi is None:
                    w_hi, h_hi = self._size_hi
                    self._grid_hi = (np.arange(w_hi, dtype=float)[None, :],
                                     np.arange(h_hi, dtype=float)[:, None])
                u, v = self._grid_hi
                hi[dz[0] * u + dz[1] * v + dz[2] <= 1e-9] = (*NO_FLOOR_RGB, 255)
            if cfg.supersample > 1:
                hi = cv2.resize(hi, self._size, interpolation=cv2.INTER_AREA)
            out = cv2.cvtColor(hi, cv2.COLOR_RGBA2RGB)
        return self._add_noise(out)

    @property
    def texture(self) -> np.ndarray:
        """The floor texture (rows x cols x 3 uint8 RGB view); `T_tex_W` maps world to it."""
        return self._texture4[:, :, :3]

    def _add_noise(self, img: np.ndarray) -> np.ndarray:
        return self._noise.apply(img)
