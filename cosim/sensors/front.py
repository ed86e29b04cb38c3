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
  is just a clipped polygon), a mask of the projected polygon, and one
  ``cv2.warpPerspective`` of the ROI from the tile's texture through the plane-induced
  homography, copied through the mask. Visibility by the painter's order: the room (convex,
  seen from inside: no overlaps), then posters, then the solids far to near (each is convex
  and culled, so its faces do not overlap). Anti-aliasing: each surface has a texture pyramid
  (``cv2.pyrDown``) and each tile (at most ``tile_m`` on a side) samples, bilinearly, the
  level whose texel best matches its projected pixel size (texels per pixel from the areas of
  the clipped polygon in the texture and on the image).
- ``ReferenceRenderer`` (``raycast.py``; ``exact = true``, and the tests' oracle): ray
  casting per pixel (``supersample`` x ``supersample`` rays, box-filtered), the nearest hit
  over every surface (an exact z-buffer), bilinear samples of the full-resolution textures.
  Slow (seconds).

``depth = true`` makes the camera keep ``last_depth``: the z (m along the optical axis) of each
pixel's surface, inf where nothing is hit (the fast renderer writes 1/z, affine on each plane,
through the same masks). Noise: ``cosim.sensors.noise.FrameNoise`` (seeded). Pixels that see
nothing (no room, above the horizon) are ``background_rgb``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

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
from cosim.world.surfaces import Surface, solid_centres

__all__ = ["R_BC_FRONT", "FrontCamera", "FrontCameraConfig", "ReferenceRenderer", "camera_pose",
           "project", "rpy_matrix", "world_surfaces", "yaw_of"]

APRON = 2          # texels of neighbouring texture around each tile's slice
PAD = 1            # replicated texels around each pyramid level (coverage reaches the edge)
MIN_LEVEL_PX = 4   # smallest pyramid level side


def _clip(poly: list[tuple[float, float, float]], planes) -> list:
    """Sutherland-Hodgman: keep the part of a convex polygon with a x + b y + c z >= e."""
    for a, b, c, e in planes:
        if not poly:
            return poly
        out = []
        n = len(poly)
        for i in range(n):
            p, q = poly[i], poly[(i + 1) % n]
            dp = a * p[0] + b * p[1] + c * p[2] - e
            dq = a * q[0] + b * q[1] + c * q[2] - e
            if dp >= 0.0:
                out.append(p)
            if (dp >= 0.0) != (dq >= 0.0):
                t = dp / (dp - dq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]),
                            p[2] + t * (q[2] - p[2])))
        poly = out
    return poly


class _Tile:
    """A piece of a surface (at most tile_m on a side) with lazily sliced pyramid levels."""

    __slots__ = ("surface", "outline", "O", "U", "V", "normal", "n_dot_O", "corners",
                 "levels", "pyr", "s_range", "t_range")

    def __init__(self, surface: Surface, pyr: list[np.ndarray], s_range, t_range,
                 outline: np.ndarray) -> None:
        self.surface, self.pyr = surface, pyr
        self.s_range, self.t_range = s_range, t_range
        self.outline = outline                          # (k, 2) (s, t) of the tile's polygon
        self.O, self.U, self.V = surface.O, surface.U, surface.V
        self.normal = surface.normal
        self.n_dot_O = float(self.normal @ self.O)
        self.levels: dict[int, tuple[np.ndarray, float, float]] = {}
        st = outline
        self.corners = self.O[None, :] + st[:, :1] * self.U[None, :] + st[:, 1:] * self.V[None, :]

    def level(self, lv: int) -> tuple[np.ndarray, float, float]:
        """(RGBA slice of pyramid level lv with an apron, col offset, row offset)."""
        got = self.levels.get(lv)
        if got is None:
            img = self.pyr[lv]
            ppm = self.surface.ppm / (1 << lv)
            rows, cols = img.shape[:2]
            c0 = max(0, int(math.floor(self.s_range[0] * ppm)) + PAD - APRON)
            c1 = min(cols, int(math.ceil(self.s_range[1] * ppm)) + PAD + APRON)
            r0 = max(0, int(math.floor(self.t_range[0] * ppm)) + PAD - APRON)
            r1 = min(rows, int(math.ceil(self.t_range[1] * ppm)) + PAD + APRON)
            c1, r1 = max(c1, c0 + 1), max(r1, r0 + 1)
            got = (np.ascontiguousarray(img[r0:r1, c0:c1]), float(c0), float(r0))
            self.levels[lv] = got
        return got


def _pyramid(img: np.ndarray) -> list[np.ndarray]:
    """RGBA levels (cv2.pyrDown), each with PAD replicated texels around it."""
    level = cv2.cvtColor(img, cv2.COLOR_RGB2RGBA)
    out = []
    while True:
        out.append(cv2.copyMakeBorder(level, PAD, PAD, PAD, PAD, cv2.BORDER_REPLICATE))
        if min(level.shape[:2]) < 2 * MIN_LEVEL_PX:
            return out
        level = cv2.pyrDown(level)


class FrontCamera:
    """Fast renderer (see the module docstring). ``render`` -> H x W x 3 uint8 RGB."""

    def __init__(self, world, config: FrontCameraConfig | None = None, seed: int = 0) -> None:
        cv2.setNumThreads(1)
        self.world = world
        self.config = cfg = config or FrontCameraConfig()
        self.rng = np.random.default_rng(seed)
        self._noise = FrameNoise(self.rng, cfg.noise_std, cfg.lighting_noise,
                                 cfg.width * cfg.height * 3)
        self.R_BC = rpy_matrix(*np.radians(cfg.mount_rpy_deg)) @ R_BC_FRONT
        self.surfaces = world_surfaces(world)
        self.last_depth: np.ndarray | None = None
        self._ref: ReferenceRenderer | None = None
        if cfg.exact:
            self._ref = ReferenceRenderer(world, cfg, surfaces=self.surfaces)
            return
        # tiles per draw group: 0 room, 1 posters, 2 + i solid i
        self._groups: dict[int, list[_Tile]] = {}
        for s in self.surfaces:
            pyr = _pyramid(s.image)
            for tile in _tiles(s, pyr, cfg.tile_m):
                self._groups.setdefault(s.group, []).append(tile)
        self._solids = solid_centres(world.scene)
        # every tile in draw-group order, with corner arrays padded to one shape so that
        # culling (back faces, outside the view) is one numpy pass per frame
        self._tiles = [t for g in sorted(self._groups) for t in self._groups[g]]
        kmax = max((len(t.corners) for t in self._tiles), default=4)
        self._corners = np.array([np.vstack([t.corners] + [t.corners[-1:]] *
                                            (kmax - len(t.corners))) for t in self._tiles]
                                 ).reshape(-1, kmax, 3)
        self._normals = np.array([t.normal for t in self._tiles]).reshape(-1, 3)
        self._U = np.array([t.U for t in self._tiles]).reshape(-1, 3)
        self._V = np.array([t.V for t in self._tiles]).reshape(-1, 3)
        self._O = np.array([t.O for t in self._tiles]).reshape(-1, 3)
        self._n_dot_O = np.array([t.n_dot_O for t in self._tiles])
        self._tile_group = np.array([t.surface.group for t in self._tiles], dtype=np.int64)
        W, H = cfg.width, cfg.height
        fx, fy, cx, cy = cfg.fx, cfg.fy, cfg.cx, cfg.cy
        m = 1.0   # px of margin around the image
        self._planes = ((0.0, 0.0, 1.0, cfg.near_m),
                        (fx, 0.0, cx + 0.5 + m, 0.0), (-fx, 0.0, W - 0.5 + m - cx, 0.0),
                        (0.0, fy, cy + 0.5 + m, 0.0), (0.0, -fy, H - 0.5 + m - cy, 0.0))
        self._plane_n = np.array([p[:3] for p in self._planes]).T      # (3, 5)
        self._plane_e = np.array([p[3] for p in self._planes])
        self._K = cfg.K()
        self._background = np.empty((cfg.height, cfg.width, 4), np.uint8)
        self._background[:] = (*cfg.background_rgb, 255)

    # ------------------------------------------------------------------ rendering
    def render(self, p_W: Sequence[float], q_WB: Sequence[float]) -> np.ndarray:
        cfg = self.config
        if self._ref is not None:
            img, depth = self._ref.render_with_depth(p_W, q_WB)
            self.last_depth = depth if cfg.depth else None
            return self._noise.apply(img)
        view = _View(cfg, self.R_BC, p_W, q_WB)
        frame = self._background.copy()
        inv_z = np.zeros((cfg.height, cfg.width), np.float32) if cfg.depth else None
        tiles = self._tiles
        idx, D, P, Minv, all_in = self._visible(view)
        Minv = Minv.tolist()
        for j, i in enumerate(idx):
            self._draw(frame, inv_z, tiles[i], view, D[j], P[j], Minv[j], all_in[j])
        if inv_z is not None:
            with np.errstate(divide="ignore"):
                self.last_depth = np.where(inv_z > 0, 1.0 / inv_z, np.inf).astype(np.float32)
        return self._noise.apply(cv2.cvtColor(frame, cv2.COLOR_RGBA2RGB))

    def _visible(self, view: _View):
        """(tile index, plane distances (k, 5), camera-frame corners (k, 3), pixel -> (s, t)
        map (3, 3)) of the tiles facing the camera and not wholly outside the view, in the
        painter's order: room, posters, solids far to near."""
        c, R = view.c, view.R_CW
        front = self._normals @ c - self._n_dot_O > 1e-9
        P = (self._corners - c) @ R.T                            # (N, k, 3) camera frame
        D = P @ self._plane_n - self._plane_e                    # (N, k, 5): >= 0 inside
        vis = front & ~(D < 0.0).all(axis=1).any(axis=1)
        idx = np.flatnonzero(vis)
        if len(self._solids):
            dist = np.array([math.hypot(n - c[0], e - c[1]) - r for n, e, r in self._solids])
            idx = idx[_painter_order(self._tile_group[idx], dist)]
        # pixel -> (s, t) for every visible tile at once: inverse of K R_CW [U V O-c]
        cols = np.stack([self._U[idx], self._V[idx], self._O[idx] - c], axis=2)   # (n, 3, 3)
        Minv = np.linalg.inv(self._K @ R @ cols)
        all_in = (D[idx] >= 0.0).all(axis=(1, 2))
        return idx.tolist(), D[idx], P[idx], Minv, all_in.tolist()

    def _draw(self, frame: np.ndarray, inv_z, tile: _Tile, view: _View, D, P, Minv,
              all_in: bool) -> None:
        cfg = self.config
        k = len(tile.corners)
        if all_in:
            poly = P[:k].tolist()
            near_clipped = False
        else:
            near_clipped = bool((D[:k, 0] < 0.0).any())
            poly = _clip(P[:k].tolist(), self._planes)
            if len(poly) < 3:
                return
        fx, fy, cx, cy = cfg.fx, cfg.fy, cfg.cx, cfg.cy
        us = [cx + fx * x / z for x, _, z in poly]
        vs = [cy + fy * y / z for _, y, z in poly]
        x0 = max(0, math.floor(min(us)))
        x1 = min(cfg.width, math.ceil(max(us)) + 1)
        y0 = max(0, math.floor(min(vs)))
        y1 = min(cfg.height, math.ceil(max(vs)) + 1)
        if x1 <= x0 or y1 <= y0:
            return
        surf = tile.surface
        # texels per pixel: the polygon's area in the texture over its area on the image
        area_px = 0.5 * abs(_shoelace(us, vs))
        nx = ny = nz = 0.0
        for i in range(len(poly)):
            a, b = poly[i - 1], poly[i]
            nx += a[1] * b[2] - a[2] * b[1]
            ny += a[2] * b[0] - a[0] * b[2]
            nz += a[0] * b[1] - a[1] * b[0]
        area_m2 = 0.5 * math.sqrt(nx * nx + ny * ny + nz * nz)
        ratio = area_m2 * surf.ppm * surf.ppm / max(area_px, 1e-9)
        lv = 0 if ratio <= 1.0 else min(len(tile.pyr) - 1, int(0.5 * math.log2(ratio) + 0.5))
        tex, c_off, r_off = tile.level(lv)
        # ROI pixel -> texel of the slice: scale/offset (s, t) after Minv after the ROI shift
        sc = surf.ppm / (1 << lv)
        oc = PAD - 0.5 / (1 << lv) - c_off
        orow = PAD - 0.5 / (1 << lv) - r_off
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = Minv
        a2 += a0 * x0 + a1 * y0
        b2 += b0 * x0 + b1 * y0
        c2 += c0 * x0 + c1 * y0
        M = np.array(((sc * a0 + oc * c0, sc * a1 + oc * c1, sc * a2 + oc * c2),
                      (sc * b0 + orow * c0, sc * b1 + orow * c1, sc * b2 + orow * c2),
                      (c0, c1, c2)))
        w, h = x1 - x0, y1 - y0
        roi = frame[y0:y1, x0:x1]
        exact_edges = near_clipped or surf.group >= 2
        mask = None
        if exact_edges or inv_z is not None:
            mask = np.zeros((h, w), np.uint8)
            pts = np.array([[round((u - x0) * 16.0), round((v - y0) * 16.0)]
                            for u, v in zip(us, vs, strict=True)], np.int32)
            cv2.fillConvexPoly(mask, pts, 255, cv2.LINE_8, 4)
        if exact_edges:
            warped = cv2.warpPerspective(tex, M, (w, h),
                                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_REPLICATE)
            cv2.copyTo(warped, mask, roi)
        else:   # the slice's extent is the tile's extent (plus its apron): no mask needed
            cv2.warpPerspective(tex, M, (w, h), dst=roi,
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_TRANSPARENT)
        if inv_z is not None:
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


def _shoelace(xs: list, ys: list) -> float:
    n = len(xs)
    return sum(xs[i - 1] * ys[i] - xs[i] * ys[i - 1] for i in range(n))


def _tiles(s: Surface, pyr: list[np.ndarray], tile_m: float) -> list[_Tile]:
    if s.poly is not None:
        st = s.poly
        return [_Tile(s, pyr, (st[:, 0].min(), st[:, 0].max()), (st[:, 1].min(), st[:, 1].max()),
                      st)]
    ns, nt = max(1, math.ceil(s.w / tile_m - 1e-9)), max(1, math.ceil(s.h / tile_m - 1e-9))
    out = []
    for i in range(ns):
        for j in range(nt):
            sa, sb = s.w * i / ns, s.w * (i + 1) / ns
            ta, tb = s.h * j / nt, s.h * (j + 1) / nt
            out.append(_Tile(s, pyr, (sa, sb), (ta, tb),
                             np.array([[sa, ta], [sb, ta], [sb, tb], [sa, tb]])))
    return out


