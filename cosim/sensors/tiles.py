"""Surface tiles and the per-frame geometry of the fast front-camera renderer (``front.py``),
done for every visible tile at once in numpy.

A tile is a piece of a ``Surface`` at most ``tile_m`` on a side, with the surface's texture
pyramid (RGBA levels, ``cv2.pyrDown``, each with ``PAD`` replicated texels around it) and,
per level, the slice of that level covering the tile plus an ``APRON`` of neighbouring
texels (lazily cut). ``plan`` takes the camera-frame corners of the visible tiles and returns
what drawing needs: the polygon clipped to the near plane and the image borders
(Sutherland-Hodgman, ``clip_polygons``), its pixel bounding box, the pyramid level whose
texel best matches the projected pixel size, and the homography from ROI pixels to texels of
that level's slice. Floating-point operations are done in the same order as the per-tile
scalar code they replace, so the pixels are the same bit for bit.
"""

from __future__ import annotations

import math
from itertools import chain

import cv2
import numpy as np

from cosim.world.surfaces import Surface

APRON = 2          # texels of neighbouring texture around each tile's slice
PAD = 1            # replicated texels around each pyramid level (coverage reaches the edge)
MIN_LEVEL_PX = 4   # smallest pyramid level side


class Tile:
    """A piece of a surface (at most tile_m on a side) with lazily sliced pyramid levels.

    ``bounds[lv]`` = (c0, c1, r0, r1): the texel columns and rows of pyramid level ``lv``
    covering the tile plus its apron (clamped to the level). ``plain``: the RGBA colour of a
    one-colour surface (None for a texture)."""

    __slots__ = ("surface", "outline", "O", "U", "V", "normal", "n_dot_O", "corners",
                 "levels", "pyr", "bounds", "plain")

    def __init__(self, surface: Surface, pyr: list[np.ndarray], s_range, t_range,
                 outline: np.ndarray, plain: tuple[int, ...] | None = None) -> None:
        self.surface, self.pyr = surface, pyr
        self.outline = outline                          # (k, 2) (s, t) of the tile's polygon
        self.O, self.U, self.V = surface.O, surface.U, surface.V
        self.normal = surface.normal
        self.n_dot_O = float(self.normal @ self.O)
        self.levels: dict[int, np.ndarray] = {}
        st = outline
        self.corners = self.O[None, :] + st[:, :1] * self.U[None, :] + st[:, 1:] * self.V[None, :]
        self.bounds = []
        for lv, img in enumerate(pyr):
            ppm = surface.ppm / (1 << lv)
            rows, cols = img.shape[:2]
            c0 = max(0, int(math.floor(s_range[0] * ppm)) + PAD - APRON)
            c1 = min(cols, int(math.ceil(s_range[1] * ppm)) + PAD + APRON)
            r0 = max(0, int(math.floor(t_range[0] * ppm)) + PAD - APRON)
            r1 = min(rows, int(math.ceil(t_range[1] * ppm)) + PAD + APRON)
            self.bounds.append((c0, max(c1, c0 + 1), r0, max(r1, r0 + 1)))
        self.plain = plain

    def level(self, lv: int) -> np.ndarray:
        """RGBA slice of pyramid level lv with the apron (``bounds[lv]``)."""
        got = self.levels.get(lv)
        if got is None:
            c0, c1, r0, r1 = self.bounds[lv]
            got = self.levels[lv] = np.ascontiguousarray(self.pyr[lv][r0:r1, c0:c1])
        return got


def pyramid(img: np.ndarray) -> list[np.ndarray]:
    """RGBA levels (cv2.pyrDown), each with PAD replicated texels around it."""
    level = cv2.cvtColor(img, cv2.COLOR_RGB2RGBA)
    out = []
    while True:
        out.append(cv2.copyMakeBorder(level, PAD, PAD, PAD, PAD, cv2.BORDER_REPLICATE))
        if min(level.shape[:2]) < 2 * MIN_LEVEL_PX:
            return out
        level = cv2.pyrDown(level)


def tiles_of(s: Surface, pyr: list[np.ndarray], tile_m: float) -> list[Tile]:
    """A surface cut into tiles at most tile_m on a side (a polygon outline: one tile)."""
    img = s.image
    # one colour: drawn as a filled polygon (bilinear samples of a constant are exact)
    plain = (*(int(x) for x in img[0, 0]), 255) if (img == img[:1, :1]).all() else None
    if s.poly is not None:
        st = s.poly
        return [Tile(s, pyr, (st[:, 0].min(), st[:, 0].max()), (st[:, 1].min(), st[:, 1].max()),
                     st, plain)]
    ns, nt = max(1, math.ceil(s.w / tile_m - 1e-9)), max(1, math.ceil(s.h / tile_m - 1e-9))
    out = []
    for i in range(ns):
        for j in range(nt):
            sa, sb = s.w * i / ns, s.w * (i + 1) / ns
            ta, tb = s.h * j / nt, s.h * (j + 1) / nt
            out.append(Tile(s, pyr, (sa, sb), (ta, tb),
                            np.array([[sa, ta], [sb, ta], [sb, tb], [sa, tb]]), plain))
    return out


class TileSet:
    """Every tile of a world's surfaces in draw-group order (0 room, 1 posters, 2 + i solid
    i), with corner arrays padded to one shape (repeating the last corner) so that culling
    and the clipping, projection and level choice of the visible tiles are a few numpy
    passes per frame. Read-only once built: shared by the cameras of a world."""

    def __init__(self, surfaces: list[Surface], tile_m: float, solids) -> None:
        groups: dict[int, list[Tile]] = {}
        for s in surfaces:
            pyr = pyramid(s.image)
            for tile in tiles_of(s, pyr, tile_m):
                groups.setdefault(s.group, []).append(tile)
        self.solids = solids
        self.tiles = tiles = [t for g in sorted(groups) for t in groups[g]]
        kmax = max((len(t.corners) for t in tiles), default=4)
        self.corners = np.array([np.vstack([t.corners] + [t.corners[-1:]] *
                                           (kmax - len(t.corners))) for t in tiles]
                                ).reshape(-1, kmax, 3)
        self.count = np.array([len(t.corners) for t in tiles], dtype=np.int64)
        self.normals = np.array([t.normal for t in tiles]).reshape(-1, 3)
        # [U V O] per tile (columns), and each level's slice bounds (c0, c1, r0, r1)
        self.UVO = np.array([np.stack([t.U, t.V, t.O], axis=1) for t in tiles]).reshape(-1, 3, 3)
        nl = max((len(t.pyr) for t in tiles), default=1)
        self.bounds = np.array([t.bounds + t.bounds[-1:] * (nl - len(t.bounds))
                                for t in tiles], dtype=float).reshape(-1, nl, 4)
        self.n_dot_O = np.array([t.n_dot_O for t in tiles])
        self.group = np.array([t.surface.group for t in tiles], dtype=np.int64)
        self.ppm = np.array([t.surface.ppm for t in tiles])
        self.n_levels = [len(t.pyr) for t in tiles]


def tile_set(world, surfaces: list[Surface], tile_m: float) -> TileSet:
    """The world's tiles, built once per world object and, for a room world, once per scene
    in this process (``cosim/cache.py``: every run of a study shares them)."""
    from cosim import cache
    from cosim.sensors.pinhole import scene_key
    from cosim.world.surfaces import solid_centres

    def make() -> TileSet:
        return TileSet(surfaces, tile_m, solid_centres(world.scene))

    mine = world._cache
    k = ("tiles", float(tile_m))
    if k not in mine:
        sk = scene_key(world)
        mine[k] = make() if sk is None else cache.memo("tiles", cache.key(sk, tile_m), make)
    return mine[k]


def clip(poly: list, planes) -> list:
    """Sutherland-Hodgman: keep the part of a convex polygon (list of (x, y, z)) with
    a x + b y + c z >= e for every plane (a, b, c, e) in ``planes``, in that order."""
    for a, b, c, e in planes:
        n = len(poly)
        if not n:
            return poly
        d = [a * p[0] + b * p[1] + c * p[2] - e for p in poly]
        out = []
        for i in range(n):
            j = i + 1 if i + 1 < n else 0
            dp, dq = d[i], d[j]
            p = poly[i]
            if dp >= 0.0:
                out.append(p)
                if dq >= 0.0:
                    continue
            elif dq < 0.0:
                continue
            q = poly[j]
            t = dp / (dp - dq)
            out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]),
                        p[2] + t * (q[2] - p[2])))
        poly = out
    return poly


class Planner:
    """Clips, projects and measures the visible tiles' polygons for one camera (pinhole
    ``cfg``, clip ``planes`` (a, b, c, e): keep a x + b y + c z >= e, camera frame)."""

    def __init__(self, cfg, planes) -> None:
        self.planes = planes
        # the planes a polygon crosses, by bit mask (bit j: plane j)
        self.subsets = [[pl for j, pl in enumerate(planes) if code >> j & 1]
                        for code in range(1 << len(planes))]
        self.bits = 1 << np.arange(len(planes), dtype=np.int64)
        self.f = np.array([cfg.fx, cfg.fy])
        self.c = np.array([cfg.cx, cfg.cy])
        self.size = np.array([float(cfg.width), float(cfg.height)])
        self.prev: dict[int, np.ndarray] = {}   # k -> index of each vertex's predecessor

    def __call__(self, P: np.ndarray, count: np.ndarray, D: np.ndarray) -> dict:
        """``P`` (n, k, 3): the tiles' corners in the camera frame (m), each row padded to k
        by repeating its last corner; ``count`` (n,): corner counts; ``D`` (n, k, planes):
        the corners' signed distances to the clip planes (>= 0 inside). A polygon is clipped
        against the planes some corner of it is outside of (it is convex: the others cannot
        cut it).

        Returns, over the tiles in input order: ``ok`` (something left to draw), ``near``
        (clipped by the near plane, plane 0), ``count`` (vertices left), ``uv`` (n, k', 2)
        projected vertices (px, padded the same way), ``lo``, ``hi`` (n, 2) the ROI's first
        and one-past-last column and row, clamped to the image, ``area_m2`` and ``area_px``
        (the clipped polygon's area on its plane, m^2, and on the image, px^2, at least
        1e-9). Operations and sums run in the order of the scalar code (``cumsum`` is
        sequential): the same bits."""
        crossed = (D < 0.0).any(axis=1)                     # (n, planes)
        code = crossed.dot(self.bits)
        cut = np.flatnonzero(code).tolist()
        if cut:
            count = count.copy()
            cnt = count.tolist()
            k = P.shape[1]
            subsets = self.subsets
            polys = []
            for i, row, cd in zip(cut, P[cut].tolist(), code[cut].tolist(), strict=True):
                poly = clip(row[:cnt[i]], subsets[cd])
                count[i] = n = len(poly)
                polys.append(poly if n >= 3 else [(1.0, 1.0, 1.0)])   # (nothing left: dummy)
            kk = max(len(p) for p in polys)
            if kk > k:
                P = np.concatenate([P, np.repeat(P[:, -1:], kk - k, axis=1)], axis=1)
                k = kk
            flat = chain.from_iterable(chain.from_iterable(p + p[-1:] * (k - len(p))
                                                           for p in polys))
            P[cut] = np.fromiter(flat, float, 3 * k * len(cut)).reshape(-1, k, 3)
        k = P.shape[1]
        uv = self.c + self.f * P[..., :2] / P[..., 2:]      # (n, k, 2): cx + fx x / z, ...
        lo = np.floor(uv.min(axis=1))
        hi = np.ceil(uv.max(axis=1)) + 1
        np.maximum(lo, 0.0, out=lo)
        np.minimum(hi, self.size, out=hi)
        # shoelace on the image, and the 3D polygon's area (half the norm of the sum of the
        # edge crosses); the predecessor of vertex 0 is the (repeated) last one
        prev = self.prev.get(k)
        if prev is None:
            prev = self.prev[k] = np.roll(np.arange(k), 1)
        P5 = np.concatenate([P, P[..., :2]], axis=2)        # x y z x y: rotations are views
        a5 = P5[:, prev]
        nrm = a5[..., 1:4] * P5[..., 2:5] - a5[..., 2:5] * P5[..., 1:4]
        s = nrm.cumsum(axis=1)[:, -1]                       # (n, 3)
        s *= s
        area_m2 = 0.5 * np.sqrt(s[:, 0] + s[:, 1] + s[:, 2])
        up = uv[:, prev]
        area_px = 0.5 * np.abs((up[..., 0] * uv[..., 1] - uv[..., 0] * up[..., 1])
                               .cumsum(axis=1)[:, -1])
        ok = (count >= 3) & (hi > lo).all(axis=1)
        return {"ok": ok, "near": crossed[:, 0], "count": count, "uv": uv, "lo": lo, "hi": hi,
                "area_m2": area_m2, "area_px": np.maximum(area_px, 1e-9)}
