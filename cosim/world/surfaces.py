"""A world as textured planar surfaces, for the front camera's renderers.

A ``Surface`` is a flat convex polygon on a plane ``X = O + s U + t V`` (world NED, m), with
``U`` the viewer's right and ``V`` the viewer's down as seen from its visible side, so its
texture (row 0 at t = 0, column 0 at s = 0, ``ppm`` texels per metre, texel centres at
``(s, t) = ((col + 0.5) / ppm, (row + 0.5) / ppm)``) appears unmirrored. Its visible side
faces ``normal = V x U``; seen from behind it is culled (every solid is closed and the room is
seen from inside). ``group`` orders drawing for the painter's renderer: 0 the room (convex,
seen from inside: its surfaces never overlap on screen), 1 what hangs on the walls (posters
and frames, drawn over their wall), 2 + i the i-th solid (box or column, convex).

``world_surfaces(world)`` builds them once per world and resolution (cached on the world).
A world without a room gets its flat floor (``World.floor_image``: track, marker,
distractors) as one surface; above the horizon it has no walls (the renderer's background).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from cosim.world.room import POSTER_OFFSET_M, Box, Column, Poster, Scene
from cosim.world.textures import TextureSpec, cached_texture

DOWN = np.array([0.0, 0.0, 1.0])


@dataclass
class Surface:
    name: str
    O: np.ndarray            # (3,) m, world NED of the (s, t) = (0, 0) corner
    U: np.ndarray            # (3,) unit, viewer's right
    V: np.ndarray            # (3,) unit, viewer's down
    w: float                 # m along U
    h: float                 # m along V
    image: np.ndarray        # RGB uint8, rows along V, cols along U
    ppm: float               # texels per metre
    group: int
    poly: np.ndarray | None = None   # (k, 2) convex outline in (s, t) m; None: the rectangle
    solid: int = -1          # index of the solid it belongs to (groups >= 2)

    @functools.cached_property
    def normal(self) -> np.ndarray:
        """(3,) unit, towards the viewer (made once: U and V are not changed after)."""
        n = np.cross(self.V, self.U)
        n.flags.writeable = False
        return n

    def outline(self) -> np.ndarray:
        """(k, 2) convex outline in (s, t) metres, counter-clockwise as seen (s right, t down:
        clockwise in the usual y-up sense, consistent for every surface)."""
        if self.poly is not None:
            return self.poly
        return np.array([[0.0, 0.0], [self.w, 0.0], [self.w, self.h], [0.0, self.h]])

    def corners_W(self) -> np.ndarray:
        st = self.outline()
        return self.O[None, :] + st[:, :1] * self.U[None, :] + st[:, 1:] * self.V[None, :]


def _plain(rgb, w: float, h: float) -> tuple[np.ndarray, float]:
    # a few texels are enough for one colour; ppm so that the image spans the surface
    cols, rows = 4, 4
    return np.full((rows, cols, 3), rgb, np.uint8), min(cols / max(w, 1e-6), rows / max(h, 1e-6))


def _vertical(name: str, a, b, top_d: float, bottom_d: float, image_fn, group: int,
              inside_point, solid: int = -1) -> Surface:
    """A vertical rectangle from NE point a to b, D from top_d (up) to bottom_d, facing
    away from ``inside_point`` (solids) or towards it (room walls: pass the room centre with
    a negative sign convention via ``towards``)."""
    a = np.array([a[0], a[1], 0.0])
    b = np.array([b[0], b[1], 0.0])
    width = float(np.linalg.norm(b - a))
    U = (b - a) / width
    n = np.cross(DOWN, U)
    mid = 0.5 * (a + b)
    towards, p = inside_point
    to_p = np.array([p[0], p[1], 0.0]) - mid
    if (float(n @ to_p) > 0.0) != towards:   # wrong side: walk the edge the other way
        a, b, U = b, a, -U
    O = np.array([a[0], a[1], top_d])
    hgt = bottom_d - top_d
    img, ppm = image_fn(width, hgt)
    return Surface(name, O, U, DOWN.copy(), width, hgt, img, ppm, group, solid=solid)


def _horizontal(name: str, n_max: float, e_min: float, w_e: float, h_n: float, d: float,
                up: bool, image_fn, group: int, poly_ne=None, solid: int = -1) -> Surface:
    """A horizontal rectangle N in [n_max - h_n, n_max], E in [e_min, e_min + w_e] at depth d,
    visible from above (``up``: floor, tops) or from below (ceiling)."""
    if up:   # image up = north, right = east
        O = np.array([n_max, e_min, d])
        U = np.array([0.0, 1.0, 0.0])
    else:    # seen from below with image up = north: right = west
        O = np.array([n_max, e_min + w_e, d])
        U = np.array([0.0, -1.0, 0.0])
    V = np.array([-1.0, 0.0, 0.0])
    img, ppm = image_fn(w_e, h_n)
    poly = None
    if poly_ne is not None:
        poly = np.array([[float((np.array([pn, pe, d]) - O) @ U),
                          float((np.array([pn, pe, d]) - O) @ V)] for pn, pe in poly_ne])
    return Surface(name, O, U, V, w_e, h_n, img, ppm, group, poly=poly, solid=solid)


def _tex(spec: TextureSpec, ppm: float, salt: int):
    return lambda w, h: cached_texture(spec, w, h, ppm, salt=salt)


def footprint(center, size, heading: float, shape: str, sides: int) -> list[tuple[float, float]]:
    cn, ce = center
    cu, su = math.cos(heading), math.sin(heading)
    if shape == "cylinder":
        r = 0.5 * size[0] / math.cos(math.pi / sides)    # circumscribed: the prism holds the
        pts = [(r * math.cos(2 * math.pi * (k + 0.5) / sides),   # cylinder the clearance uses
                r * math.sin(2 * math.pi * (k + 0.5) / sides)) for k in range(sides)]
    else:
        hl, hw = 0.5 * size[0], 0.5 * size[1]
        pts = [(hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw)]
    return [(cn + x * cu - y * su, ce + x * su + y * cu) for x, y in pts]


def _solid(name: str, foot: list, top_d: float, ceiling_d: float, side_fn, top_fn,
           group: int, solid: int) -> list[Surface]:
    cn = sum(p[0] for p in foot) / len(foot)
    ce = sum(p[1] for p in foot) / len(foot)
    out = []
    for k in range(len(foot)):
        a, b = foot[k], foot[(k + 1) % len(foot)]
        out.append(_vertical(f"{name} side {k}", a, b, top_d, 0.0, side_fn(k), group,
                             (False, (cn, ce)), solid))
    if top_d > ceiling_d + 1e-6:      # below the ceiling: the top is visible
        ns = [p[0] for p in foot]
        es = [p[1] for p in foot]
        out.append(_horizontal(f"{name} top", max(ns), min(es), max(es) - min(es),
                               max(ns) - min(ns), top_d, True, top_fn, group, poly_ne=foot,
                               solid=solid))
    return out


def _poster(p: Poster, arena, ppm: float, salt: int) -> list[Surface]:
    n0, n1, e0, e1 = arena
    off = POSTER_OFFSET_M
    w, h = p.size
    # the wall line, seen from inside: (point at 'at' on the wall, offset into the room)
    if p.wall == "north":
        a, b, inside = (n1 - off, p.at - w / 2), (n1 - off, p.at + w / 2), (n0, p.at)
    elif p.wall == "south":
        a, b, inside = (n0 + off, p.at + w / 2), (n0 + off, p.at - w / 2), (n1, p.at)
    elif p.wall == "east":
        a, b, inside = (p.at + w / 2, e1 - off), (p.at - w / 2, e1 - off), (p.at, e0)
    else:
        a, b, inside = (p.at - w / 2, e0 + off), (p.at + w / 2, e0 + off), (p.at, e1)
    top = -(p.z + h / 2)
    frame = _vertical(f"poster '{p.name}' frame", a, b, top, top + h,
                      lambda ww, hh: _plain(p.frame_rgb, ww, hh), 1, (True, inside))
    fm = p.frame_m
    out = [frame]
    if fm * 2 < min(w, h):
        # the picture: inset by the frame width, 1 mm further into the room
        U, nrm = frame.U, frame.normal
        O = frame.O + fm * U + fm * DOWN + 0.001 * nrm
        pw, ph = w - 2 * fm, h - 2 * fm
        img, pp = cached_texture(p.texture, pw, ph, ppm, salt=salt)
        out.append(Surface(f"poster '{p.name}'", O, U.copy(), DOWN.copy(), pw, ph, img, pp, 1))
    return out


def scene_surfaces(scene: Scene, floor=None) -> list[Surface]:
    """Surfaces of a scene. ``floor``: (image, T_tex_W) of the flat floor, used when the
    scene has no room."""
    out: list[Surface] = []
    room = scene.room
    n0, n1, e0, e1 = scene.arena
    if room is not None:
        H, ppm = room.height, room.px_per_m
        out.append(_horizontal("floor", n1, e0, e1 - e0, n1 - n0, 0.0, True,
                               _tex(room.floor, ppm, 1), 0))
        out.append(_horizontal("ceiling", n1, e0, e1 - e0, n1 - n0, -H, False,
                               _tex(room.ceiling, ppm, 2), 0))
        centre = (0.5 * (n0 + n1), 0.5 * (e0 + e1))
        for k, (nm, a, b) in enumerate((("north wall", (n1, e0), (n1, e1)),
                                        ("east wall", (n1, e1), (n0, e1)),
                                        ("south wall", (n0, e1), (n0, e0)),
                                        ("west wall", (n0, e0), (n1, e0)))):
            out.append(_vertical(nm, a, b, -H, 0.0, _tex(room.walls, ppm, 10 + k), 0,
                                 (True, centre)))
        for i, p in enumerate(scene.posters):
            out += _poster(p, scene.arena, ppm, 100 + i)
    elif floor is not None:
        img, T = floor
        s = float(T[0, 1])                        # texels per metre (col = s * E + ...)
        corner = np.linalg.solve(T, np.array([-0.5, -0.5, 1.0]))   # (N, E) of texel corner
        rows, cols = img.shape[:2]
        out.append(Surface("floor", np.array([corner[0], corner[1], 0.0]),
                           np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0]),
                           cols / s, rows / s, img, s, 0))
    ceiling_d = scene.ceiling_d
    ppm = room.px_per_m if room is not None else 200.0
    solids: list[Box | Column] = [*scene.boxes, *scene.columns]
    for i, sd in enumerate(solids):
        group = 2 + i
        if isinstance(sd, Box):
            foot = footprint(sd.center, sd.size[:2], sd.heading, "bar", 4)
            out += _solid(f"box '{sd.name}'", foot, -sd.size[2], ceiling_d,
                          lambda k, sd=sd, i=i: _tex(sd.texture, ppm, 1000 * (i + 1) + k),
                          _tex(sd.texture, ppm, 1000 * (i + 1) + 99), group, i)
        else:
            foot = footprint(sd.center, sd.size, sd.heading, sd.shape, sd.sides)
            rgb = sd.rgb
            out += _solid(f"column '{sd.name}'", foot, -sd.height, ceiling_d,
                          lambda k, rgb=rgb: (lambda w, h: _plain(rgb, w, h)),
                          lambda w, h, rgb=rgb: _plain(rgb, w, h), group, i)
    return out


def solid_centres(scene: Scene) -> list[tuple[float, float, float]]:
    """(N, E, radius) of each solid's footprint, in group order (for drawing order)."""
    out = []
    for sd in (*scene.boxes, *scene.columns):
        r = 0.5 * math.hypot(sd.size[0], sd.size[1])
        out.append((sd.center[0], sd.center[1], r))
    return out
