"""The floor texture of a flat world (`cosim.world.floor.World`): the track, the marker,
distractors and floor tiles drawn with exact area coverage per texel (signed distances, a box
prefilter), so thin lines keep their area and do not break up. `World.floor_image` calls it
once per resolution."""

from __future__ import annotations

import math

import numpy as np

from cosim.world.track import (
    NE,
    RGB,
    TILE_PITCH_M,
    TILE_SIZE_M,
    RectPart,
    TrackPart,
)


class _Grid:
    """Texture pixel <-> world mapping: N = n0 - (row + 0.5)/s, E = e0 + (col + 0.5)/s."""

    def __init__(self, n0: float, e0: float, s: float, rows: int, cols: int) -> None:
        self.n0, self.e0, self.s, self.rows, self.cols = n0, e0, s, rows, cols

    def window(self, n_lo: float, n_hi: float, e_lo: float, e_hi: float
               ) -> tuple[slice, slice, np.ndarray, np.ndarray] | None:
        """Pixel slices covering a world box (plus 2 px), and their centre coordinates."""
        s = self.s
        r0 = max(0, int(math.floor((self.n0 - n_hi) * s)) - 2)
        r1 = min(self.rows, int(math.ceil((self.n0 - n_lo) * s)) + 2)
        c0 = max(0, int(math.floor((e_lo - self.e0) * s)) - 2)
        c1 = min(self.cols, int(math.ceil((e_hi - self.e0) * s)) + 2)
        if r0 >= r1 or c0 >= c1:
            return None
        n = self.n0 - (np.arange(r0, r1) + 0.5) / s
        e = self.e0 + (np.arange(c0, c1) + 0.5) / s
        return slice(r0, r1), slice(c0, c1), n[:, None], e[None, :]


def _sd_box(n: np.ndarray, e: np.ndarray, c: NE, half_len: float, half_wid: float,
            heading: float) -> np.ndarray:
    """Signed distance (m) to an oriented box (negative inside)."""
    cu, su = math.cos(heading), math.sin(heading)
    dn, de = n - c[0], e - c[1]
    x = np.abs(dn * cu + de * su) - half_len
    y = np.abs(-dn * su + de * cu) - half_wid
    outside = np.hypot(np.maximum(x, 0.0), np.maximum(y, 0.0))
    return outside + np.minimum(np.maximum(x, y), 0.0)


def _sd_disc(n: np.ndarray, e: np.ndarray, c: NE, r: float) -> np.ndarray:
    return np.hypot(n - c[0], e - c[1]) - r


def _coverage(sd: np.ndarray, s: float) -> np.ndarray:
    """Area fraction of a pixel (side 1/s m) inside a shape from the signed distance."""
    return np.clip(0.5 - sd * s, 0.0, 1.0).astype(np.float32)


def _blend(img: np.ndarray, rs: slice, cs: slice, alpha: np.ndarray, rgb: RGB) -> None:
    if not alpha.any():
        return
    reg = img[rs, cs].astype(np.float32)
    a = alpha[..., None]
    reg += a * (np.asarray(rgb, dtype=np.float32) - reg)
    img[rs, cs] = np.rint(reg).astype(np.uint8)


def _pieces(part: TrackPart) -> list[tuple[str, tuple]]:
    """A track part as boxes (centre, half_len, half_wid, heading) and join discs."""
    hw = 0.5 * part.width
    if isinstance(part, RectPart):
        return [("box", (part.center, 0.5 * part.length, hw, part.heading))]
    pts = part.points
    out: list[tuple[str, tuple]] = []
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        dn, de = b[0] - a[0], b[1] - a[1]
        out.append(("box", (((a[0] + b[0]) / 2, (a[1] + b[1]) / 2), 0.5 * math.hypot(dn, de),
                            hw, math.atan2(de, dn))))
    for q in pts[1:-1]:
        out.append(("disc", (q, hw)))
    return out


def _piece_bbox(kind: str, args: tuple) -> tuple[float, float, float, float]:
    if kind == "disc":
        (cn, ce), r = args
        return cn - r, cn + r, ce - r, ce + r
    (cn, ce), hl, hw, h = args
    ext_n = abs(hl * math.cos(h)) + abs(hw * math.sin(h))
    ext_e = abs(hl * math.sin(h)) + abs(hw * math.cos(h))
    return cn - ext_n, cn + ext_n, ce - ext_e, ce + ext_e


def _draw_union(img: np.ndarray, g: _Grid, pieces: list[tuple[str, tuple]], rgb: RGB) -> None:
    """Draw the union of pieces in one colour (coverage = max over pieces, no seams)."""
    boxes = [_piece_bbox(k, a) for k, a in pieces]
    win = g.window(min(b[0] for b in boxes), max(b[1] for b in boxes),
                   min(b[2] for b in boxes), max(b[3] for b in boxes))
    if win is None:
        return
    rs, cs, _, _ = win
    alpha = np.zeros((rs.stop - rs.start, cs.stop - cs.start), np.float32)
    for (kind, args), bb in zip(pieces, boxes, strict=True):
        w = g.window(*bb)
        if w is None:
            continue
        prs, pcs, n, e = w
        sd = _sd_disc(n, e, *args) if kind == "disc" else _sd_box(n, e, *args)
        sub = alpha[prs.start - rs.start:prs.stop - rs.start,
                    pcs.start - cs.start:pcs.stop - cs.start]
        np.maximum(sub, _coverage(sd, g.s), out=sub)
    _blend(img, rs, cs, alpha, rgb)


def _tile_coverage(x: np.ndarray, half: float, s: float) -> np.ndarray:
    """1-D coverage of pixels (centres x, side 1/s) by a centred interval in each grid cell."""
    c = (np.floor(x / TILE_PITCH_M) + 0.5) * TILE_PITCH_M
    d = 0.5 / s
    return np.clip(np.minimum(x + d, c + half) - np.maximum(x - d, c - half), 0.0, 2 * d) * s


def rasterise(world, s: float, margin: float) -> tuple[np.ndarray, np.ndarray]:
    a = world.arena
    n0, e0 = a.n_max + margin, a.e_min - margin
    rows = int(math.ceil((a.n_max - a.n_min + 2 * margin) * s))
    cols = int(math.ceil((a.e_max - a.e_min + 2 * margin) * s))
    g = _Grid(n0, e0, s, rows, cols)
    img = np.empty((rows, cols, 3), np.uint8)
    img[:] = world.floor_rgb
    if world.floor_texture == "competition":
        n = n0 - (np.arange(rows) + 0.5) / s
        e = e0 + (np.arange(cols) + 0.5) / s
        hl, hs = 0.5 * TILE_SIZE_M[0], 0.5 * TILE_SIZE_M[1]
        f32 = np.float32
        n_long, n_short = (_tile_coverage(n, hl, s).astype(f32)[:, None],
                           _tile_coverage(n, hs, s).astype(f32)[:, None])
        e_long, e_short = (_tile_coverage(e, hl, s).astype(f32)[None, :],
                           _tile_coverage(e, hs, s).astype(f32)[None, :])
        odd = np.not_equal((np.floor(n / TILE_PITCH_M).astype(np.int64) & 1)[:, None],
                           (np.floor(e / TILE_PITCH_M).astype(np.int64) & 1)[None, :])
        # even cells: long side along East; odd cells: long side along North
        alpha = np.where(odd, n_long * e_short, n_short * e_long)
        for ch in range(3):
            b, tl = float(world.floor_rgb[ch]), float(world.tile_rgb[ch])
            img[..., ch] = np.rint(b + alpha * f32(tl - b))
    for dsh in world.distractors:
        if dsh.shape == "disc":
            pieces = [("disc", (dsh.center, 0.5 * dsh.size))]
        else:
            h = 0.5 * dsh.size
            pieces = [("box", (dsh.center, h, h, dsh.heading))]
        _draw_union(img, g, pieces, dsh.rgb)
    for part in world.track:
        _draw_union(img, g, _pieces(part), part.rgb)
    if world.marker is not None:
        m = world.marker
        _draw_union(img, g, [("disc", (m.center, m.radius))], m.rgb)
    T = np.array([[0.0, s, -e0 * s - 0.5],
                  [-s, 0.0, n0 * s - 0.5],
                  [0.0, 0.0, 1.0]])
    return img, T
