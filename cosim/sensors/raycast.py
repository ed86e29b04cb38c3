"""The exact front-camera renderer: ray casting per pixel with an exact z-buffer (the test
oracle of the fast renderer, and `[camera] exact = true`). Slow: seconds per frame."""

from __future__ import annotations

import cv2
import numpy as np

from cosim.sensors.pinhole import (
    R_BC_FRONT,
    FrontCameraConfig,
    _View,
    rpy_matrix,
    world_surfaces,
)
from cosim.world.surfaces import Surface


class ReferenceRenderer:
    """Exact visibility by ray casting (the oracle; see the module docstring)."""

    def __init__(self, world, config: FrontCameraConfig | None = None,
                 surfaces: list[Surface] | None = None) -> None:
        self.config = cfg = config or FrontCameraConfig()
        self.surfaces = surfaces if surfaces is not None else world_surfaces(world)
        self.R_BC = rpy_matrix(*np.radians(cfg.mount_rpy_deg)) @ R_BC_FRONT

    def render(self, p_W, q_WB) -> np.ndarray:
        return self.render_with_depth(p_W, q_WB)[0]

    def render_with_depth(self, p_W, q_WB) -> tuple[np.ndarray, np.ndarray]:
        """(RGB uint8 image, depth float32 m along the optical axis, inf where nothing)."""
        cfg = self.config
        k = cfg.supersample
        W, H = cfg.width * k, cfg.height * k
        view = _View(cfg, self.R_BC, p_W, q_WB)
        # sub-pixel ray directions (camera frame, z = 1)
        u = (np.arange(W, dtype=np.float64) + 0.5) / k - 0.5
        v = (np.arange(H, dtype=np.float64) + 0.5) / k - 0.5
        rx = ((u - cfg.cx) / cfg.fx)[None, :].repeat(H, 0)
        ry = ((v - cfg.cy) / cfg.fy)[:, None].repeat(W, 1)
        R_WC = view.R_CW.T
        d = np.stack([rx, ry, np.ones_like(rx)], -1) @ R_WC.T      # world rays, (H, W, 3)
        zbuf = np.full((H, W), np.inf)
        rgb = np.empty((H, W, 3), np.float32)
        rgb[:] = cfg.background_rgb
        c = view.c
        for s in self.surfaces:
            nrm = s.normal
            if float(nrm @ (c - s.O)) <= 1e-9:
                continue
            denom = d @ nrm                                          # (H, W)
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = (nrm @ (s.O - c)) / denom                     # = z (rays have z_C = 1)
            hit = (lam >= cfg.near_m) & (lam < zbuf)
            if not hit.any():
                continue
            X = c + d[hit] * lam[hit][:, None] - s.O
            st = np.stack([X @ s.U, X @ s.V], -1)
            inside = _inside(st, s.outline())
            if not inside.any():
                continue
            idx = np.flatnonzero(hit)[inside]
            st = st[inside]
            zbuf.flat[idx] = lam.flat[idx]
            rgb.reshape(-1, 3)[idx] = _bilinear(s.image, st[:, 0] * s.ppm - 0.5,
                                                st[:, 1] * s.ppm - 0.5)
        img = np.clip(rgb + 0.5, 0, 255).astype(np.uint8)
        depth = zbuf.astype(np.float32)
        if k > 1:
            img = cv2.resize(np.clip(rgb, 0, 255), (cfg.width, cfg.height),
                             interpolation=cv2.INTER_AREA)
            img = np.clip(img + 0.5, 0, 255).astype(np.uint8)
            depth = depth[k // 2::k, k // 2::k] if k % 2 else _min_pool(depth, k)
        return img, depth


def _min_pool(a: np.ndarray, k: int) -> np.ndarray:
    h, w = a.shape[0] // k, a.shape[1] // k
    return a[:h * k, :w * k].reshape(h, k, w, k).min(axis=(1, 3))


def _inside(st: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Points (n, 2) inside the convex polygon poly (k, 2) (either winding)."""
    ok_pos = np.ones(len(st), bool)
    ok_neg = np.ones(len(st), bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        cr = (b[0] - a[0]) * (st[:, 1] - a[1]) - (b[1] - a[1]) * (st[:, 0] - a[0])
        ok_pos &= cr >= -1e-12
        ok_neg &= cr <= 1e-12
    return ok_pos | ok_neg


def _bilinear(img: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear samples (n, 3) float of an RGB image at (col, row), edges clamped."""
    rows, cols = img.shape[:2]
    col = np.clip(col, 0, cols - 1)
    row = np.clip(row, 0, rows - 1)
    c0 = np.floor(col).astype(np.int64)
    r0 = np.floor(row).astype(np.int64)
    c1 = np.minimum(c0 + 1, cols - 1)
    r1 = np.minimum(r0 + 1, rows - 1)
    fc = (col - c0)[:, None]
    fr = (row - r0)[:, None]
    f = img.astype(np.float32)
    top = f[r0, c0] * (1 - fc) + f[r0, c1] * fc
    bot = f[r1, c0] * (1 - fc) + f[r1, c1] * fc
    return top * (1 - fr) + bot * fr
