"""The front camera (`[camera] kind = "front"`): a pinhole view of a 3D world, rendered on the
CPU with OpenCV, deterministic to the byte.

Model (reference/paper2-visual-servoing.md §2): pinhole with intrinsics ``fx, fy, cx, cy`` in
0-based pixel-centre coordinates (Bebop 2 rectified stream: 856 x 480, fx 537.3, fy 527.0,
centre (428, 240)), or a horizontal field of view ``hfov_deg`` with square pixels and the
principal point at the image centre. Mounted ``mount_B`` m from the CoG in body FRD (Bebop 2:
0.09 m ahead, paper Eq. 5) and turned by ``mount_rpy_deg`` (roll, pitch, yaw of the camera rig
in the body frame; pitch < 0 looks down). Optical axis = the rig's x (forward), image right =
its y, image down = its z. ``stabilized = true`` (default, as the Bebop 2 streams) removes the
body's roll and pitch from the view (heading kept); ``false`` is a rigid camera.

Renderers (``cosim/world/surfaces.py`` gives the scene as textured convex planar surfaces):

- ``FrontCamera`` (default): per surface tile, back-face culling, clipping of the polygon
  against the near plane (``near_m``) and the image borders in camera space (a wall 5 cm away
  is just a clipped polygon), and one ``cv2.warpPerspective`` of the polygon's bounding box
  (ROI) from the tile's texture slice through the plane-induced homography: straight into
  the frame for the room and the posters' pictures (ROI pixels that map outside the slice,
  i.e. the tile plus a 2-texel apron, are left alone), through a mask of the projected
  polygon where the edges must be exact (solids, near-clipped tiles). A one-colour surface
  (a column, a poster frame, a plain wall) is that polygon filled with its colour (the same
  pixels as warping a constant through the mask; its few texels span more than the surface,
  so a warp through the ROI would paint past its edges). Visibility by the
  painter's order: the room (convex, seen from inside: no overlaps), then posters, then the
  solids far to near (each is convex and culled, so its faces do not overlap).
  Anti-aliasing: each surface has a texture pyramid (``cv2.pyrDown``) and each tile (at most
  ``tile_m`` on a side) samples, bilinearly, the level whose texel best matches its projected
  pixel size (texels per pixel from the areas of the clipped polygon in the texture and on
  the image). The per-frame geometry of the tiles
  (culling, clipping, projection, level, homography) is done for all of them at once
  (``cosim/sensors/tiles.py``); what is left per tile is the warp.
- ``ReferenceRenderer`` (``raycast.py``; ``exact = true``, and the tests' oracle): ray
  casting per pixel (``supersample`` x ``supersample`` rays, box-filtered), the nearest hit
  over every surface (an exact z-buffer), bilinear samples of the full-resolution textures.
  Slow (seconds).

``depth = true`` makes the camera keep ``last_depth``: the z (m along the optical axis) of each
pixel's surface, inf where nothing is hit (the fast renderer writes 1/z, affine on each plane,
through the same masks). Motion blur (``exposure_s > 0``, when the stream passes the vehicle's
motion): ``cosim/sensors/blur.py``, before the noise. Noise: ``cosim.sensors.noise.FrameNoise``
(seeded). Pixels that see nothing (no room, above the horizon) are ``background_rgb``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from cosim import cvthreads
from cosim.sensors import blur
from cosim.sensors.noise import FrameNoise
from cosim.sensors.pinhole import (
    R_BC_FRONT,
    FrontCameraConfig,
    _View,
    camera_pose,
    project,
    rpy_matrix,
    world_surfaces,
    yaw_of,
)
from cosim.sensors.raycast import ReferenceRenderer
from cosim.sensors.tiles import PAD, Planner, Tile, tile_set
from mav.rotations import R_from_quat

__all__ = ["R_BC_FRONT", "FrontCamera", "FrontCameraConfig", "ReferenceRenderer", "camera_pose",
           "project", "rpy_matrix", "world_surfaces", "yaw_of"]

_WARP = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP


class FrontCamera:
    """Fast renderer (see the module docstring). ``render`` -> H x W x 3 uint8 RGB."""

    def __init__(self, world, config: FrontCameraConfig | None = None, seed: int = 0) -> None:
        cvthreads.apply()     # every core for a run, one in a study worker
        self.world = world
        self.config = cfg = config or FrontCameraConfig()
        self.rng = np.random.default_rng(seed)
        self._noise = FrameNoise(self.rng, cfg.noise_std, cfg.lighting_noise,
                                 cfg.width * cfg.height * 3, cfg.brightness,
                                 cfg.offset_noise)
        self.wants_motion = cfg.exposure_s > 0.0   # render(..., motion=) blurs the frame
        self.last_blur_px = 0.0                    # px, the streak of the last frame
        self.R_BC = rpy_matrix(*np.radians(cfg.mount_rpy_deg)) @ R_BC_FRONT
        self.surfaces = world_surfaces(world)
        self.last_depth: np.ndarray | None = None
        self._ref: ReferenceRenderer | None = None
        if cfg.exact:
            self._ref = ReferenceRenderer(world, cfg, surfaces=self.surfaces)
            return
        ts = tile_set(world, self.surfaces, cfg.tile_m)
        self._solids = ts.solids
        self._tiles, self._corners, self._count = ts.tiles, ts.corners, ts.count
        self._normals, self._UVO, self._bounds = ts.normals, ts.UVO, ts.bounds
        self._n_dot_O, self._tile_group, self._ppm = ts.n_dot_O, ts.group, ts.ppm
        self._n_levels = ts.n_levels
        W, H = cfg.width, cfg.height
        fx, fy, cx, cy = cfg.fx, cfg.fy, cfg.cx, cfg.cy
        m = 1.0   # px of margin around the image
        self._planes = ((0.0, 0.0, 1.0, cfg.near_m),
                        (fx, 0.0, cx + 0.5 + m, 0.0), (-fx, 0.0, W - 0.5 + m - cx, 0.0),
                        (0.0, fy, cy + 0.5 + m, 0.0), (0.0, -fy, H - 0.5 + m - cy, 0.0))
        self._plane_n = np.array([p[:3] for p in self._planes]).T      # (3, 5)
        self._plane_e = np.array([p[3] for p in self._planes])
        self._K = cfg.K()
        self._planner = Planner(cfg, self._planes)
        self._background = np.empty((cfg.height, cfg.width, 4), np.uint8)
        self._background[:] = (*cfg.background_rgb, 255)

    # ------------------------------------------------------------------ rendering
    def render(self, p_W: Sequence[float], q_WB: Sequence[float], motion=None,
               drawn: tuple | None = None) -> np.ndarray:
        """The frame at a body pose; ``motion = (v_W m/s world NED, w_B rad/s body FRD)``
        blurs it over ``exposure_s`` (the stream passes it when ``wants_motion``). With
        ``drawn`` (from ``skip``): that skipped frame, made now, the same to the byte."""
        cfg = self.config
        if self._ref is not None:
            img, depth = self._ref.render_with_depth(p_W, q_WB)
            self.last_depth = depth if cfg.depth else None
            if motion is not None and cfg.exposure_s > 0.0:
                img = self._blur(img, _View(cfg, self.R_BC, p_W, q_WB), q_WB, motion)
            return self._noise.apply(img, drawn)
        view = _View(cfg, self.R_BC, p_W, q_WB)
        frame = self._background.copy()
        inv_z = np.zeros((cfg.height, cfg.width), np.float32) if cfg.depth else None
        tiles = self._tiles
        idx, lv, box, M, near_clipped, count, uv = self._visible(view)
        for j, i in enumerate(idx):
            self._draw(frame, inv_z, tiles[i], view, lv[j], box[j], M[j], near_clipped[j],
                       (count[j], uv[j]))
        if inv_z is not None:
            with np.errstate(divide="ignore"):
                self.last_depth = np.where(inv_z > 0, 1.0 / inv_z, np.inf).astype(np.float32)
        img = cv2.cvtColor(frame, cv2.COLOR_RGBA2RGB)
        if motion is not None and cfg.exposure_s > 0.0:
            img = self._blur(img, view, q_WB, motion)
        return self._noise.apply(img, drawn)

    def skip(self, p_W: Sequence[float], q_WB: Sequence[float], motion=None) -> tuple:
        """A frame nobody looks at: what it takes from the camera's state (its noise draws;
        its blur streak, in ``last_blur_px``) without its image, so the frames after it are
        the same. Returns the draws: ``render(..., drawn=)`` makes the frame if it is wanted
        after all. A camera that keeps ``last_depth`` is always rendered (not skipped)."""
        if motion is not None and self.config.exposure_s > 0.0:
            self._streak(_View(self.config, self.R_BC, p_W, q_WB), q_WB, motion)
        return self._noise.draw()

    def _blur(self, img: np.ndarray, view: _View, q_WB, motion) -> np.ndarray:
        """The frame blurred along the image centre's motion over the exposure."""
        k = self._streak(view, q_WB, motion)
        return img if k is None else blur.apply(img, k)

    def _streak(self, view: _View, q_WB, motion) -> np.ndarray | None:
        """The blur kernel of the image centre's motion over the exposure (None: none);
        sets ``last_blur_px``."""
        cfg = self.config
        v_W, w_B = (np.asarray(m, dtype=float) for m in motion)
        R_WB = R_from_quat(q_WB)
        w_W = R_WB @ w_B
        v_cam = v_W + np.cross(w_W, R_WB @ np.asarray(cfg.mount_B))   # the camera centre's
        R = view.R_CW
        depth = blur.centre_depth(self.surfaces, view.c, R[2], cfg.near_m)
        du, dv = blur.streak_px(cfg.fx, cfg.fy, R @ v_cam, R @ w_W, depth, cfg.exposure_s)
        self.last_blur_px = math.hypot(du, dv)
        return blur.kernel(du, dv)

    def _visible(self, view: _View):
        """What to draw, in the painter's order (room, posters, solids far to near): the tiles
        facing the camera, not wholly outside the view and not clipped away. Returns lists
        over them of: tile index, pyramid level, ROI (x0, y0, x1, y1), ROI pixel -> texel
        homography of the level's slice (3, 3), near-plane clipped?, and the clipped polygon
        (vertex count, its vertices' image columns and rows in px (k, 2), padded by
        repeating the last). The level is the one whose texel best matches the tile's
        projected pixel size (texels per pixel from the areas of the clipped polygon in the
        texture and on the image)."""
        c, R = view.c, view.R_CW
        front = self._normals @ c - self._n_dot_O > 1e-9
        nt, kt = self._corners.shape[:2]
        P = (self._corners.reshape(-1, 3) - c) @ R.T             # (N k, 3) camera frame
        D = (P @ self._plane_n - self._plane_e).reshape(nt, kt, -1)  # (N, k, 5): >= 0 inside
        P = P.reshape(nt, kt, 3)
        vis = front & ~(D < 0.0).all(axis=1).any(axis=1)
        idx = np.flatnonzero(vis)
        grp = self._tile_group[idx]
        solid = grp >= 2
        if solid.any():     # the room and posters stay in order (tiles are in group order)
            dist = np.array([math.hypot(n - c[0], e - c[1]) - r for n, e, r in self._solids])
            idx = np.concatenate([idx[~solid], idx[solid][_painter_order(grp[solid], dist)]])
        g = self._planner(P[idx], self._count[idx], D[idx])
        ok = g["ok"]
        sel = slice(None) if ok.all() else np.flatnonzero(ok)
        idx = idx[sel]
        lo, hi = g["lo"][sel], g["hi"][sel]
        ppm = self._ppm[idx]
        ratio = g["area_m2"][sel] * ppm * ppm / g["area_px"][sel]
        nlev = self._n_levels
        il = idx.tolist()
        lv = [0 if r <= 1.0 else min(nlev[i] - 1, int(0.5 * math.log2(r) + 0.5))
              for i, r in zip(il, ratio.tolist(), strict=True)]
        lva = np.array(lv, dtype=np.int64)
        off = self._bounds[idx, lva]                             # (n, 4) c0 c1 r0 r1
        # ROI pixel -> (s, t) m: inverse of K R_CW [U V O-c], shifted to the ROI origin,
        # then -> texel of the slice: scale and offset of its level
        cols = self._UVO[idx]
        cols[:, :, 2] -= c
        Minv = np.linalg.inv((self._K @ R) @ cols)
        step = np.left_shift(1, lva)
        sc = ppm / step
        half = PAD - 0.5 / step
        oc = half - off[:, 0]
        orow = half - off[:, 2]
        x0, y0 = lo[:, 0], lo[:, 1]
        A, B, C = Minv[:, 0], Minv[:, 1], Minv[:, 2]
        A[:, 2] += A[:, 0] * x0 + A[:, 1] * y0
        B[:, 2] += B[:, 0] * x0 + B[:, 1] * y0
        C[:, 2] += C[:, 0] * x0 + C[:, 1] * y0
        M = np.empty_like(Minv)
        M[:, 0] = sc[:, None] * A + oc[:, None] * C
        M[:, 1] = sc[:, None] * B + orow[:, None] * C
        M[:, 2] = C
        box = np.concatenate([lo, hi], axis=1).astype(np.int64).tolist()
        return il, lv, box, M, g["near"][sel].tolist(), g["count"][sel].tolist(), g["uv"][sel]

    def _draw(self, frame: np.ndarray, inv_z, tile: Tile, view: _View, lv: int, box, M,
              near_clipped: bool, poly) -> None:
        x0, y0, x1, y1 = box
        w, h = x1 - x0, y1 - y0
        roi = frame[y0:y1, x0:x1]
        # masked or filled: solids, near-clipped tiles and one-colour surfaces (a poster
        # frame's 4x4-texel slice reaches far past it: warped through the ROI, its colour
        # would cover the wall in the ROI's corners)
        exact_edges = near_clipped or tile.surface.group >= 2 or tile.plain is not None
        mask = pts = None
        if exact_edges or inv_z is not None:
            k, uv = poly
            pts = np.rint((uv[:k] - (x0, y0)) * 16.0).astype(np.int32)
            if inv_z is not None or tile.plain is None:
                mask = np.zeros((h, w), np.uint8)
                cv2.fillConvexPoly(mask, pts, 255, cv2.LINE_8, 4)
        if not exact_edges:     # the slice's extent is the tile's extent (plus its apron)
            cv2.warpPerspective(tile.level(lv), M, (w, h), dst=roi, flags=_WARP,
                                borderMode=cv2.BORDER_TRANSPARENT)
        elif tile.plain is not None:      # = a warp of the constant through the mask
            cv2.fillConvexPoly(roi, pts, tile.plain, cv2.LINE_8, 4)
        else:
            warped = cv2.warpPerspective(tile.level(lv), M, (w, h), flags=_WARP,
                                         borderMode=cv2.BORDER_REPLICATE)
            cv2.copyTo(warped, mask, roi)
        if inv_z is not None:
            self._depth(inv_z, tile, view, box, mask)

    def _depth(self, inv_z: np.ndarray, tile: Tile, view: _View, box, mask) -> None:
        """Write 1/z of the tile's plane through the mask into ``inv_z``."""
        cfg = self.config
        fx, fy, cx, cy = cfg.fx, cfg.fy, cfg.cx, cfg.cy
        x0, y0, x1, y1 = box
        # plane n_C . X = d_C in camera coordinates; 1/z = n_C . K^-1 [u v 1] / d_C
        c, R = view.c, view.R_CW
        n_C = R @ tile.normal
        d_C = float(n_C @ (R @ (tile.O - c)))
        a = n_C[0] / fx / d_C
        b = n_C[1] / fy / d_C
        k0 = (n_C[2] - n_C[0] * cx / fx - n_C[1] * cy / fy) / d_C
        uu = np.arange(x0, x1, dtype=np.float32)[None, :]
        vv = np.arange(y0, y1, dtype=np.float32)[:, None]
        iz = (a * uu + b * vv + k0).astype(np.float32)
        cv2.copyTo(iz, mask, inv_z[y0:y1, x0:x1])


def _painter_order(grp: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Order of tiles with draw groups ``grp``: room (0), posters (1), then the solids
    (group 2 + i) by decreasing footprint distance ``dist[i]`` from the camera (far first),
    stable within a group."""
    solid = grp >= 2
    rank = grp.astype(float)
    i = grp[solid] - 2
    rank[solid] = 2.0 + (dist.max() - dist[i]) + 1e-9 * i
    return np.argsort(rank, kind="stable")
