"""Indoor scenes: a room (floor, walls, ceiling), boxes, framed posters and columns.

World TOML (all optional; a world without them is the flat line-following world)::

    [world.room]                      # walls on the arena bounds, floor at D = 0
    height = 2.6                      # m, floor to ceiling
    walls = { kind = "posters", seed = 3 }     # textures: see cosim/world/textures.py
    floor = { kind = "noise", seed = 4, rgb = [150, 130, 110] }
    ceiling = { kind = "noise", seed = 5, rgb = [235, 235, 235] }
    px_per_m = 200                    # texture resolution (texels per metre)

    [[world.box]]                     # a box standing on the floor
    name = "crate"
    center = [1.0, 2.0]               # m, (N, E)
    size = [0.6, 0.4, 0.5]            # m, length (along heading), width, height
    heading_deg = 0.0
    texture = { kind = "posters", seed = 9 }

    [[world.column]]                  # an obstacle: uniform saturated colour, floor upwards
    name = "bar"
    shape = "bar"                     # "bar" (size = [length, width]) or "cylinder" (diameter)
    center = [1.5, 0.0]
    size = [0.05, 0.02]               # bar; a cylinder has diameter = 0.11
    heading_deg = 0.0
    height = 2.6                      # m, default: the room height (or 2.5 m without a room)
    rgb = [0, 170, 0]                 # default green
    sides = 16                        # cylinder: prism sides

    [[world.poster]]                  # a framed picture on a wall
    wall = "north"                    # north / south / east / west wall of the room
    at = 0.5                          # m, E of the centre (N/S walls) or N (E/W walls)
    z = 1.3                           # m above the floor (centre)
    size = [0.8, 0.6]                 # m, width, height
    texture = { kind = "posters", seed = 11 }
    frame_rgb = [40, 30, 20]          # frame colour, frame_m wide
    frame_m = 0.03

Geometry the loop uses (``Scene.clearance``): the distance from the vehicle's body sphere to
the nearest wall, ceiling, box or column (the floor is where it lands, so it is not an
obstacle), and what that nearest thing is. Negative clearance is a collision.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from cosim.errors import ScenarioError
from cosim.scenario.validate import integer, no_unknown, number, rgb, string
from cosim.world.clearance import sphere_clearance
from cosim.world.textures import TextureSpec, palette_ok

GREEN = (0, 170, 0)
DEFAULT_COLUMN_HEIGHT_M = 2.5
POSTER_OFFSET_M = 0.004        # posters stand this far off their wall (visible, no z-fight)
WALLS = ("north", "south", "east", "west")


@dataclass(frozen=True)
class Room:
    height: float = 2.6
    walls: TextureSpec = TextureSpec("posters", 1)
    floor: TextureSpec = TextureSpec("noise", 2, (150, 130, 110))
    ceiling: TextureSpec = TextureSpec("noise", 3, (235, 235, 235), contrast=0.3)
    px_per_m: float = 200.0


@dataclass(frozen=True)
class Box:
    name: str
    center: tuple[float, float]
    size: tuple[float, float, float]      # length (along heading), width, height
    heading: float                        # rad
    texture: TextureSpec


@dataclass(frozen=True)
class Column:
    name: str
    shape: str                            # "bar" or "cylinder"
    center: tuple[float, float]
    size: tuple[float, float]             # bar: (length, width); cylinder: (diameter, diameter)
    heading: float
    height: float
    rgb: tuple[int, int, int]
    sides: int = 16


@dataclass(frozen=True)
class Poster:
    name: str
    wall: str
    at: float
    z: float
    size: tuple[float, float]
    texture: TextureSpec
    frame_rgb: tuple[int, int, int]
    frame_m: float


@dataclass(frozen=True)
class Scene:
    """The 3D content of a world (empty for a flat world)."""

    room: Room | None = None
    boxes: tuple[Box, ...] = ()
    columns: tuple[Column, ...] = ()
    posters: tuple[Poster, ...] = ()
    arena: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)   # n_min n_max e_min e_max
    _solids: list = field(default_factory=list, init=False, repr=False, compare=False,
                          hash=False)

    @property
    def empty(self) -> bool:
        return self.room is None and not self.boxes and not self.columns

    @property
    def ceiling_d(self) -> float:
        """NED D of the ceiling (m; -inf without a room)."""
        return -self.room.height if self.room is not None else -math.inf

    # ------------------------------------------------------------------ geometry
    def solids(self) -> list[tuple]:
        """Obstacles as (True, name, cn, ce, cos, sin, half_l, half_w, top_d) (boxes, square
        columns) or (False, name, cn, ce, r, top_d) (cylinders) records, for clearance."""
        if not self._solids:
            out = []
            for b in self.boxes:
                out.append((True, f"box '{b.name}'", b.center[0], b.center[1],
                            math.cos(b.heading), math.sin(b.heading), 0.5 * b.size[0],
                            0.5 * b.size[1], -b.size[2]))
            for c in self.columns:
                if c.shape == "cylinder":
                    out.append((False, f"column '{c.name}'", c.center[0], c.center[1],
                                0.5 * c.size[0], -c.height))
                else:
                    out.append((True, f"column '{c.name}'", c.center[0], c.center[1],
                                math.cos(c.heading), math.sin(c.heading), 0.5 * c.size[0],
                                0.5 * c.size[1], -c.height))
            self._solids.extend(out)
        return self._solids

    def clearance(self, n: float, e: float, d: float, radius: float) -> tuple[float, str]:
        """(distance from a sphere of ``radius`` at (n, e, d) to the nearest obstacle surface,
        m, negative when they overlap; the obstacle's name). Floor excluded. Computed by
        cosim/world/clearance.py (compiled: it runs on every tick)."""
        return sphere_clearance(self.walls(), self.solids(), float(n), float(e), float(d),
                                float(radius))

    def walls(self) -> tuple[float, float, float, float, float] | None:
        """(N min, N max, E min, E max, height) of the room's walls and ceiling, for
        clearance; None without a room."""
        return None if self.room is None else (*self.arena, self.room.height)


# ====================================================================== parsing
def _floats(v: Any, f: str, n: int, what: str, lo: float, hi: float) -> tuple[float, ...]:
    if (not isinstance(v, list) or len(v) != n
            or any(isinstance(c, bool) or not isinstance(c, (int, float))
                   or not math.isfinite(c) for c in v)):
        raise ScenarioError(f, v, f"{what} ({n} finite numbers)")
    if any(not lo <= c <= hi for c in v):
        raise ScenarioError(f, v, f"{what}, each in [{lo:g}, {hi:g}] m")
    return tuple(float(c) for c in v)


def _inside(f: str, v: Any, arena, n: float, e: float, reach: float) -> None:
    n0, n1, e0, e1 = arena
    if not (n0 + reach <= n <= n1 - reach and e0 + reach <= e <= e1 - reach):
        raise ScenarioError(f, v, f"a footprint inside the room/arena N [{n0:g}, {n1:g}] "
                                  f"E [{e0:g}, {e1:g}] m")


def _texture(d: Mapping, key: str, where: str, default: TextureSpec, *, wall: bool
             ) -> TextureSpec:
    if key not in d:
        return default
    t = TextureSpec.from_value(d[key], f"{where}.{key}", default.seed)
    if wall and t.kind in ("posters", "noise", "plain") and not palette_ok(t.rgb):
        raise ScenarioError(f"{where}.{key}.rgb", list(t.rgb),
                            "a colour outside the obstacle hues (no green on walls)")
    return t


def _names(items: list[Mapping], where: str, prefix: str) -> list[str]:
    names = []
    for i, it in enumerate(items):
        nm = it.get("name", f"{prefix}{i + 1}")
        if not isinstance(nm, str) or not nm or len(nm) > 60:
            raise ScenarioError(f"{where}[{i}].name", nm, "a non-empty string up to 60 chars")
        if nm in names:
            raise ScenarioError(f"{where}[{i}].name", nm, "a name not used twice")
        names.append(nm)
    return names


def _array(d: Mapping, key: str, where: str) -> list:
    v = d.get(key, [])
    if not isinstance(v, list) or any(not isinstance(x, Mapping) for x in v):
        raise ScenarioError(f"{where}.{key}", v, f"an array of tables ([[{where}.{key}]])")
    return v


def parse_scene(d: Mapping[str, Any], arena, where: str = "world") -> Scene:
    """The room, boxes, columns and posters of a ``[world]`` table (validated)."""
    arena = tuple(arena)
    room = None
    if "room" in d:
        r = d["room"]
        w = f"{where}.room"
        if not isinstance(r, Mapping):
            raise ScenarioError(w, r, "a table")
        no_unknown(r, {"height", "walls", "floor", "ceiling", "px_per_m"}, w)
        dflt = Room()
        room = Room(height=number(r, "height", w, dflt.height, lo=0.5, hi=20.0),
                    walls=_texture(r, "walls", w, dflt.walls, wall=True),
                    floor=_texture(r, "floor", w, dflt.floor, wall=True),
                    ceiling=_texture(r, "ceiling", w, dflt.ceiling, wall=True),
                    px_per_m=number(r, "px_per_m", w, dflt.px_per_m, lo=20.0, hi=1000.0))
    top = room.height if room is not None else None

    boxes = []
    raw = _array(d, "box", where)
    for i, (b, nm) in enumerate(zip(raw, _names(raw, f"{where}.box", "box"), strict=True)):
        w = f"{where}.box[{i}]"
        no_unknown(b, {"name", "center", "size", "heading_deg", "texture"}, w)
        if "center" not in b:
            raise ScenarioError(f"{w}.center", None, "[north, east] in metres (required)")
        c = _floats(b["center"], f"{w}.center", 2, "[north, east]", -1e6, 1e6)
        if "size" not in b:
            raise ScenarioError(f"{w}.size", None, "[length, width, height] m (required)")
        size = _floats(b["size"], f"{w}.size", 3, "[length, width, height] in metres",
                       0.01, 100.0)
        if top is not None and size[2] > top:
            raise ScenarioError(f"{w}.size", b["size"], f"a height up to the room's {top:g} m")
        _inside(f"{w}.center", b["center"], arena, c[0], c[1], 0.0)
        hd = math.radians(number(b, "heading_deg", w, 0.0, lo=-360.0, hi=360.0))
        boxes.append(Box(nm, (c[0], c[1]), size, hd,
                         _texture(b, "texture", w, TextureSpec("posters", 1000 + i), wall=True)))

    columns = []
    raw = _array(d, "column", where)
    for i, (cd, nm) in enumerate(zip(raw, _names(raw, f"{where}.column", "column"),
                                     strict=True)):
        w = f"{where}.column[{i}]"
        no_unknown(cd, {"name", "shape", "center", "size", "diameter", "heading_deg", "height",
                        "rgb", "sides"}, w)
        shape = string(cd, "shape", w, "bar", choices=("bar", "cylinder"))
        if "center" not in cd:
            raise ScenarioError(f"{w}.center", None, "[north, east] in metres (required)")
        c = _floats(cd["center"], f"{w}.center", 2, "[north, east]", -1e6, 1e6)
        if shape == "bar":
            if "diameter" in cd:
                raise ScenarioError(f"{w}.diameter", cd["diameter"], "size = [l, w] for a bar")
            if "size" not in cd:
                raise ScenarioError(f"{w}.size", None, "[length, width] m (required for a bar)")
            size = _floats(cd["size"], f"{w}.size", 2, "[length, width] in metres", 0.005, 20.0)
        else:
            if "size" in cd:
                raise ScenarioError(f"{w}.size", cd["size"], "diameter = m for a cylinder")
            dia = number(cd, "diameter", w, lo=0.005, hi=20.0)
            size = (dia, dia)
        h = number(cd, "height", w, top if top is not None else DEFAULT_COLUMN_HEIGHT_M,
                   lo=0.05, hi=top if top is not None else 100.0)
        _inside(f"{w}.center", cd["center"], arena, c[0], c[1], 0.0)
        columns.append(Column(nm, shape, (c[0], c[1]), size,
                              math.radians(number(cd, "heading_deg", w, 0.0, lo=-360.0,
                                                  hi=360.0)),
                              h, rgb(cd, "rgb", w, GREEN),
                              integer(cd, "sides", w, 16, lo=6, hi=64)))

    posters = []
    raw = _array(d, "poster", where)
    if raw and room is None:
        raise ScenarioError(f"{where}.poster", raw, "posters on the walls of a [world.room]")
    for i, (p, nm) in enumerate(zip(raw, _names(raw, f"{where}.poster", "poster"),
                                    strict=True)):
        w = f"{where}.poster[{i}]"
        no_unknown(p, {"name", "wall", "at", "z", "size", "texture", "frame_rgb", "frame_m"}, w)
        wall = string(p, "wall", w, choices=WALLS)
        if "size" not in p:
            raise ScenarioError(f"{w}.size", None, "[width, height] m (required)")
        size = _floats(p["size"], f"{w}.size", 2, "[width, height] in metres", 0.05, 20.0)
        at = number(p, "at", w)
        z = number(p, "z", w, 0.5 * room.height, lo=0.0, hi=room.height)
        lo_, hi_ = (arena[2], arena[3]) if wall in ("north", "south") else (arena[0], arena[1])
        if not (lo_ + 0.5 * size[0] <= at <= hi_ - 0.5 * size[0]):
            raise ScenarioError(f"{w}.at", at, f"a position keeping the poster on the {wall} "
                                               f"wall [{lo_:g}, {hi_:g}] m")
        if not (0.5 * size[1] <= z <= room.height - 0.5 * size[1]):
            raise ScenarioError(f"{w}.z", z, "a centre height keeping the poster on the wall")
        fm = number(p, "frame_m", w, 0.03, lo=0.0, hi=0.5)
        posters.append(Poster(nm, wall, at, z, size,
                              _texture(p, "texture", w, TextureSpec("posters", 2000 + i),
                                       wall=True),
                              rgb(p, "frame_rgb", w, (40, 30, 20)), fm))
    return Scene(room=room, boxes=tuple(boxes), columns=tuple(columns),
                 posters=tuple(posters), arena=arena)
