"""Seeded procedural textures for indoor scenes (walls, floor, ceiling, posters, boxes).

A texture is named in TOML by a table ``{ kind = ..., seed = ..., ... }`` (validated by
``parse_texture``) and drawn by ``make_texture(spec, width_m, height_m, px_per_m)`` into an
RGB image covering a surface of that size. Nothing is read from disk or downloaded; the same
spec and size give the same bytes.

Kinds (reference/paper2-visual-servoing.md §7):

- ``"posters"`` (default): dense, non-repeating, multi-scale: fractal value noise (six octaves
  of upsampled uniform noise) tinted with two palette colours, then random filled rectangles,
  circles and triangles from 1/60 to 1/8 of the surface's smaller side, and short random text.
  Corners and blobs at every scale from a few texels to a quarter metre: what ORB, SIFT and
  GFTT need, with no repetition for the ratio test to confuse.
- ``"noise"``: the fractal noise alone (low-contrast natural-feature surface: floors,
  ceilings).
- ``"plain"``: one colour (``rgb``).
- ``"checker"`` and ``"bricks"``: regular patterns, for negative tests only (repetition gives
  wrong matches and the aperture problem), with ``cell_m`` the pattern pitch.

Palettes exclude obstacle hues: every colour drawn by ``posters`` and ``noise`` has an HSV
hue outside ``EXCLUDED_HUES_DEG`` (green, the colour of the paper's columns) or a saturation
below ``MAX_GREY_SAT`` (greys). ``palette_ok`` is the test the tests use.
"""

from __future__ import annotations

import colorsys
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from cosim.errors import ScenarioError
from cosim.scenario.validate import integer, no_unknown, number, rgb, string

KINDS = ("posters", "noise", "plain", "checker", "bricks")
EXCLUDED_HUES_DEG = (70.0, 170.0)   # green to cyan-green: reserved for obstacles
MAX_GREY_SAT = 0.25                 # below this saturation a colour counts as grey
MAX_TEXTURE_PX = 4096               # per side; larger surfaces get fewer texels per metre


@dataclass(frozen=True)
class TextureSpec:
    kind: str = "posters"
    seed: int = 0
    rgb: tuple[int, int, int] = (200, 200, 200)   # plain colour / base tint
    cell_m: float = 0.25                          # checker / bricks pitch (m)
    contrast: float = 1.0                         # 0-1, scales the noise / shapes contrast

    @classmethod
    def from_value(cls, v: Any, where: str, default_seed: int = 0) -> TextureSpec:
        """A texture from TOML: a table, or a kind name as a string."""
        if isinstance(v, str):
            v = {"kind": v}
        if not isinstance(v, Mapping):
            raise ScenarioError(where, v, "a texture table {kind = ..., seed = ...} or a kind")
        no_unknown(v, {"kind", "seed", "rgb", "cell_m", "contrast"}, where)
        kind = string(v, "kind", where, "posters", choices=KINDS)
        seed = integer(v, "seed", where, default_seed, lo=0, hi=2**31 - 1)
        colour = rgb(v, "rgb", where, cls.rgb)
        cell = number(v, "cell_m", where, 0.25, lo=0.01, hi=5.0)
        contrast = number(v, "contrast", where, 1.0, lo=0.0, hi=1.0)
        return cls(kind=kind, seed=seed, rgb=colour, cell_m=cell, contrast=contrast)


def palette_ok(rgb) -> bool:
    """True if a colour may appear on walls: not an obstacle hue (see module docstring)."""
    r, g, b = (float(c) / 255.0 for c in rgb[:3])
    h, s, v = colorsys.rgb_to_hsv(r, g, b)
    lo, hi = EXCLUDED_HUES_DEG
    return s < MAX_GREY_SAT or v < 0.15 or not (lo <= h * 360.0 <= hi)


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    """n colours (uint8 RGB) with hues outside the excluded band."""
    lo, hi = EXCLUDED_HUES_DEG
    span = 360.0 - (hi - lo)
    out = np.empty((n, 3), np.uint8)
    for i in range(n):
        h = (hi + rng.uniform(0.0, span)) % 360.0          # skips [lo, hi]
        s = rng.uniform(0.0, 1.0) ** 0.7
        v = rng.uniform(0.15, 1.0)
        out[i] = [int(round(c * 255)) for c in colorsys.hsv_to_rgb(h / 360.0, s, v)]
    return out


def texture_size(width_m: float, height_m: float, px_per_m: float) -> tuple[int, int, float]:
    """(cols, rows, px_per_m actually used): at most MAX_TEXTURE_PX per side."""
    s = min(px_per_m, MAX_TEXTURE_PX / max(width_m, 1e-6), MAX_TEXTURE_PX / max(height_m, 1e-6))
    return max(2, int(math.ceil(width_m * s))), max(2, int(math.ceil(height_m * s))), s


def _fractal(rng: np.random.Generator, rows: int, cols: int, px_per_m: float) -> np.ndarray:
    """Fractal value noise in [0, 1], octaves from ~1 m down to ~2 texels (float32)."""
    acc = np.zeros((rows, cols), np.float32)
    total = 0.0
    cell_px = px_per_m * 1.0
    amp = 1.0
    while cell_px >= 2.0:
        gr = max(2, int(math.ceil(rows / cell_px)) + 2)
        gc = max(2, int(math.ceil(cols / cell_px)) + 2)
        g = rng.random((gr, gc), dtype=np.float32)
        up = cv2.resize(g, (int(gc * cell_px), int(gr * cell_px)), interpolation=cv2.INTER_CUBIC)
        r0 = int(rng.integers(0, max(1, up.shape[0] - rows)))
        c0 = int(rng.integers(0, max(1, up.shape[1] - cols)))
        acc += amp * up[r0:r0 + rows, c0:c0 + cols]
        total += amp
        amp *= 0.6
        cell_px /= 2.0
    acc /= total
    lo, hi = float(acc.min()), float(acc.max())
    return (acc - lo) / max(hi - lo, 1e-6)


def _shapes(img: np.ndarray, rng: np.random.Generator, pal: np.ndarray, contrast: float,
            px_per_m: float) -> None:
    rows, cols = img.shape[:2]
    side = min(rows, cols)
    area_m2 = rows * cols / (px_per_m * px_per_m)
    n = int(np.clip(area_m2 * 25, 40, 1500))     # ~25 shapes per square metre
    for _ in range(n):
        size = side * math.exp(rng.uniform(math.log(1 / 60), math.log(1 / 8)))
        cx, cy = rng.uniform(0, cols), rng.uniform(0, rows)
        col = pal[int(rng.integers(0, len(pal)))].astype(float)
        if contrast < 1.0:
            col = 128 + contrast * (col - 128)
        colour = tuple(int(c) for c in col)
        shape = int(rng.integers(0, 3))
        if shape == 0:
            w, h = size * rng.uniform(0.4, 1.6), size * rng.uniform(0.4, 1.6)
            ang = rng.uniform(0, 180)
            box = cv2.boxPoints(((cx, cy), (w, h), ang))
            cv2.fillConvexPoly(img, np.round(box * 16).astype(np.int32), colour, cv2.LINE_AA, 4)
        elif shape == 1:
            cv2.circle(img, (int(cx * 16), int(cy * 16)), int(size * 8), colour, -1,
                       cv2.LINE_AA, 4)
        else:
            pts = np.array([[cx + size * math.cos(a), cy + size * math.sin(a)]
                            for a in rng.uniform(0, 2 * math.pi, 3)])
            cv2.fillConvexPoly(img, np.round(pts * 16).astype(np.int32), colour, cv2.LINE_AA, 4)
    letters = "ABCDEFGHJKLMNPQRSTUVWXYZ0123456789"
    for _ in range(max(5, n // 6)):
        txt = "".join(letters[int(i)] for i in rng.integers(0, len(letters), rng.integers(2, 7)))
        scale = side / 400 * rng.uniform(0.6, 2.5)
        col = tuple(int(c) for c in pal[int(rng.integers(0, len(pal)))])
        cv2.putText(img, txt, (int(rng.uniform(0, cols)), int(rng.uniform(0, rows))),
                    int(rng.integers(0, 8)), scale, col, max(1, int(scale * 2)), cv2.LINE_AA)


def make_texture(spec: TextureSpec, width_m: float, height_m: float, px_per_m: float,
                 salt: int = 0) -> tuple[np.ndarray, float]:
    """(RGB uint8 image rows x cols, px_per_m used) for a surface of width x height metres.

    Column 0 is the surface's u = 0 edge, row 0 its v = 0 edge. ``salt`` separates surfaces
    that share a spec (the walls of a room) so they do not show the same picture.
    """
    cols, rows, s = texture_size(width_m, height_m, px_per_m)
    rng = np.random.default_rng([spec.seed, salt, 0x7E7])
    if spec.kind == "plain":
        return np.full((rows, cols, 3), spec.rgb, np.uint8), s
    if spec.kind in ("checker", "bricks"):
        u = (np.arange(cols) + 0.5) / s
        v = (np.arange(rows) + 0.5) / s
        cu = np.floor(u / spec.cell_m).astype(int)[None, :]
        cv_ = np.floor(v / (spec.cell_m if spec.kind == "checker" else spec.cell_m / 2))
        cv_ = cv_.astype(int)[:, None]
        if spec.kind == "checker":
            dark = (cu + cv_) % 2 == 1
        else:  # running bond: rows of bricks offset by half a brick, thin mortar lines
            off = (cv_ % 2) * 0.5 * spec.cell_m
            uu = (u[None, :] + off) % spec.cell_m
            vv = v[:, None] % (spec.cell_m / 2)
            mortar = 0.02 * spec.cell_m
            dark = (uu < mortar) | (vv < mortar)
        a = np.array(spec.rgb, np.float32)
        b = 0.35 * a
        img = np.where(dark[:, :, None], b, a).astype(np.uint8)
        return img, s
    base = np.array(spec.rgb, np.float32) / 255.0
    pal = _palette(rng, 24)
    noise = _fractal(rng, rows, cols, s)
    c1 = pal[int(rng.integers(0, len(pal)))].astype(np.float32) / 255.0
    c2 = base
    k = spec.contrast if spec.kind == "posters" else 0.6 * spec.contrast
    mix = 0.5 + k * (noise - 0.5)
    img = (c1[None, None, :] * mix[:, :, None] + c2[None, None, :] * (1 - mix[:, :, None]))
    img = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if spec.kind == "posters":
        _shapes(img, rng, pal, spec.contrast, s)
    return exclude_obstacle_hues(img), s


def cached_texture(spec: TextureSpec, width_m: float, height_m: float, px_per_m: float,
                   salt: int = 0) -> tuple[np.ndarray, float]:
    """``make_texture``, made once per spec and size in a process (and kept on disk in a
    study: ``cosim/cache.py``). The image is read-only: it is shared by every run."""
    from cosim import cache

    def make() -> dict[str, np.ndarray]:
        img, s = make_texture(spec, width_m, height_m, px_per_m, salt)
        return {"image": img, "px_per_m": np.array(s)}

    got = cache.arrays("texture", cache.key(spec, width_m, height_m, px_per_m, salt), make)
    img = got["image"]
    img.setflags(write=False)
    return img, float(got["px_per_m"])


def exclude_obstacle_hues(img: np.ndarray) -> np.ndarray:
    """The image with every pixel of an obstacle hue turned grey enough to pass ``palette_ok``
    (blends of two allowed colours at anti-aliased edges can land in the excluded band)."""
    hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV_FULL)
    h = hsv[:, :, 0].astype(np.float32) * (360.0 / 256.0)
    lo, hi = EXCLUDED_HUES_DEG
    bad = (h >= lo - 2.0) & (h <= hi + 2.0) & (hsv[:, :, 1] >= int(MAX_GREY_SAT * 255) - 8)
    bad &= hsv[:, :, 2] >= int(0.15 * 255) - 4
    if not bad.any():
        return np.ascontiguousarray(img)
    grey = img.mean(axis=2, keepdims=True).astype(np.uint8)
    out = img.copy()
    np.copyto(out, np.repeat(grey, 3, axis=2), where=bad[:, :, None])
    return out
