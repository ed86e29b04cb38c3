"""The flat indoor world the minidrone flies over: floor, track, end marker, distractors.

Everything lies on the floor plane z = 0 (world NED, so "up" is -z). Positions are (N, E) in
metres, angles in radians inside (``heading``), degrees only in the TOML (``heading_deg``).
A heading is the direction of an axis measured from North towards East (0 = N-S axis,
90 deg = E-W axis), as in reference/minidrone.md §5.

World TOML schema (the ``[world]`` table of a scenario or of ``scenarios/worlds/*.toml``;
every key is checked, unknown keys are errors; see scenarios/README.md "World")::

    [world]
    name = "seed"                     # optional label
    floor_texture = "plain"           # "plain" (default) or "competition" (0.15 x 0.05 m tiles
                                      #   on a 0.25 m grid, alternating orientation)
    floor_rgb = [180, 180, 180]       # 0-255; plain floor colour / competition base colour
    tile_rgb = [122, 104, 86]         # competition tiles only
    arena = { n_min = 51.5, n_max = 58.0, e_min = 91.5, e_max = 96.5 }   # m, NED
    start = { n = 57.0, e = 95.0, yaw_deg = 0.0 }   # optional: where the drone should start

    [[world.track]]                   # a rectangle part (the seed world's form)
    center = [56.30, 95.0]            # m, (N, E)
    length = 1.45                     # m, along the axis
    width = 0.10                      # m
    heading_deg = 0.0                 # axis direction, deg from North towards East
    rgb = [255, 0, 0]                 # optional, default red

    [[world.track]]                   # or a polyline part, points in track order
    points = [[55.0, 95.0], [55.0, 96.0], [54.0, 96.5]]   # m, (N, E)
    width = 0.10                      # m; round joins, flat ends
    rgb = [255, 0, 0]

    [world.marker]                    # optional end marker disc
    center = [52.93, 93.325]          # m, (N, E)
    radius = 0.10                     # m
    rgb = [255, 0, 0]

    [[world.distractor]]              # optional shapes that are not the track
    shape = "square"                  # "square" (size = side) or "disc" (size = diameter)
    center = [56.0, 96.0]             # m, (N, E)
    size = 0.20                       # m
    rgb = [220, 220, 60]
    heading_deg = 0.0                 # squares only

Track parts are listed in track order. A rectangle's centreline runs along its axis; its
direction is chosen so that consecutive parts connect (first part: towards the second).

Rasterisation (``World.floor_image``): the floor is drawn into an RGB texture covering the
arena plus a margin, with exact-coverage anti-aliasing from signed distances (a pixel on an
edge gets the area fraction of the shape). Order: floor, distractors, track, marker.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.scenario.validate import no_unknown, number, rgb
from cosim.world.room import Scene, parse_scene
from cosim.world.track import (
    COMPETITION_FLOOR_RGB,
    COMPETITION_TILE_RGB,
    NE,
    PLAIN_FLOOR_RGB,
    RED,
    RGB,
    Arena,
    Distractor,
    Marker,
    PolylinePart,
    RectPart,
    TrackPart,
)

__all__ = [
    "Arena",
    "RectPart",
    "PolylinePart",
    "Marker",
    "Distractor",
    "World",
    "WORLDS_DIR",
    "builtin_worlds",
    "load_world",
]

WORLDS_DIR = Path(__file__).resolve().parents[2] / "scenarios" / "worlds"


@dataclass(frozen=True)
class World:
    """A flat world. Build with ``World.from_dict`` / ``load_world``; immutable."""

    arena: Arena
    track: tuple[TrackPart, ...] = ()
    marker: Marker | None = None
    distractors: tuple[Distractor, ...] = ()
    floor_rgb: RGB = PLAIN_FLOOR_RGB
    floor_texture: str = "plain"          # "plain" or "competition"
    tile_rgb: RGB = COMPETITION_TILE_RGB  # competition tiles
    name: str = ""
    start: tuple[float, float, float] | None = None  # (n m, e m, yaw rad), informational
    scene: Scene = field(default_factory=Scene)  # room, boxes, columns, posters (3D worlds)
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False,
                         hash=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "world") -> World:
        """Validate the ``[world]`` table (schema in the module docstring).

        Raises ScenarioError(field, value, allowed) naming the dotted field, e.g.
        ``world.track[2].width``.
        """
        if not isinstance(d, Mapping):
            raise ScenarioError(where, d, "a table")
        no_unknown(d, {"name", "floor_texture", "floor_rgb", "tile_rgb", "arena", "start",
                        "track", "marker", "distractor", "room", "box", "column", "poster"},
                   where)
        name = d.get("name", "")
        if not isinstance(name, str):
            raise ScenarioError(f"{where}.name", name, "a string")
        texture = d.get("floor_texture", "plain")
        if texture not in ("plain", "competition"):
            raise ScenarioError(f"{where}.floor_texture", texture, "'plain' or 'competition'")
        floor_default = PLAIN_FLOOR_RGB if texture == "plain" else COMPETITION_FLOOR_RGB
        floor_rgb = rgb(d, "floor_rgb", where, floor_default)
        tile_rgb = rgb(d, "tile_rgb", where, COMPETITION_TILE_RGB)
        if "tile_rgb" in d and texture != "competition":
            raise ScenarioError(f"{where}.tile_rgb", d["tile_rgb"],
                                "only with floor_texture = 'competition'")

        if "arena" not in d:
            raise ScenarioError(f"{where}.arena", None,
                                "a table {n_min, n_max, e_min, e_max} in metres (required)")
        a = d["arena"]
        wa = f"{where}.arena"
        if not isinstance(a, Mapping):
            raise ScenarioError(wa, a, "a table {n_min, n_max, e_min, e_max} in metres")
        no_unknown(a, {"n_min", "n_max", "e_min", "e_max"}, wa)
        arena = Arena(*(number(a, k, wa, lo=-1e5, hi=1e5)
                        for k in ("n_min", "n_max", "e_min", "e_max")))
        if not arena.n_max - arena.n_min >= 0.5:
            raise ScenarioError(f"{wa}.n_max", arena.n_max, f"at least n_min + 0.5 = "
                                f"{arena.n_min + 0.5} (m)")
        if not arena.e_max - arena.e_min >= 0.5:
            raise ScenarioError(f"{wa}.e_max", arena.e_max, f"at least e_min + 0.5 = "
                                f"{arena.e_min + 0.5} (m)")
        if arena.n_max - arena.n_min > 200.0 or arena.e_max - arena.e_min > 200.0:
            raise ScenarioError(wa, dict(a), "at most 200 m on each side")

        start = None
        if "start" in d:
            s, ws = d["start"], f"{where}.start"
            if not isinstance(s, Mapping):
                raise ScenarioError(ws, s, "a table {n, e, yaw_deg}")
            no_unknown(s, {"n", "e", "yaw_deg"}, ws)
            n0, e0 = number(s, "n", ws, lo=-1e5, hi=1e5), number(s, "e", ws, lo=-1e5, hi=1e5)
            if not arena.contains(n0, e0):
                raise ScenarioError(ws, dict(s), "a point inside the arena")
            yaw0 = math.radians(number(s, "yaw_deg", ws, 0.0, lo=-360.0, hi=360.0))
            start = (n0, e0, yaw0)

        raw_track = d.get("track", [])
        if not isinstance(raw_track, list):
            raise ScenarioError(f"{where}.track", raw_track, "an array of tables ([[world.track]])")
        track = tuple(_track_part(p, f"{where}.track[{i}]", arena)
                      for i, p in enumerate(raw_track))

        marker = None
        if "marker" in d:
            m, wm = d["marker"], f"{where}.marker"
            if not isinstance(m, Mapping):
                raise ScenarioError(wm, m, "a table {center, radius, rgb}")
            no_unknown(m, {"center", "radius", "rgb"}, wm)
            marker = Marker(center=_point(m, "center", wm, arena),
                            radius=number(m, "radius", wm, lo=0.005, hi=2.0),
                            rgb=rgb(m, "rgb", wm, RED))

        raw_dis = d.get("distractor", [])
        if not isinstance(raw_dis, list):
            raise ScenarioError(f"{where}.distractor", raw_dis,
                                "an array of tables ([[world.distractor]])")
        distractors = tuple(_distractor(x, f"{where}.distractor[{i}]", arena)
                            for i, x in enumerate(raw_dis))
        scene = parse_scene(d, tuple(arena), where)
        return cls(arena=arena, track=track, marker=marker, distractors=distractors,
                   floor_rgb=floor_rgb, floor_texture=texture, tile_rgb=tile_rgb, name=name,
                   start=start, scene=scene)

    @classmethod
    def from_toml(cls, path: str | Path) -> World:
        """Load a TOML file holding a ``[world]`` table (or the world keys at top level)."""
        p = Path(path)
        try:
            raw = tomllib.loads(p.read_text())
        except FileNotFoundError:
            raise ScenarioError("world.file", str(p), "an existing world TOML file") from None
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError("world.file", str(p), f"valid TOML ({exc})") from None
        return cls.from_dict(raw.get("world", raw), "world")

    # ------------------------------------------------------------------ geometry
    def centreline(self) -> list[np.ndarray]:
        """Track centrelines, one (K, 2) float array of (N, E) points per part, track order.

        The list index is the part index used by ``distance_to_track``.
        """
        if "centreline" not in self._cache:
            self._cache["centreline"] = _orient_parts(self.track)
        return [c.copy() for c in self._cache["centreline"]]

    def distance_to_track(self, p_NE: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal distance (m) from points to the nearest centreline point, and the part.

        p_NE: (M, 2) (N, E) m. Returns (dist (M,) float, part_idx (M,) int). Without a track:
        dist = inf and part_idx = -1.
        """
        p = np.asarray(p_NE, dtype=float).reshape(-1, 2)
        if "segments" not in self._cache:
            a, b, part = [], [], []
            for i, c in enumerate(_orient_parts(self.track)):
                a.append(c[:-1])
                b.append(c[1:])
                part.append(np.full(len(c) - 1, i))
            if a:
                A, B = np.concatenate(a), np.concatenate(b)
                self._cache["segments"] = (A, B - A, np.concatenate(part))
            else:
                self._cache["segments"] = None
        seg = self._cache["segments"]
        m = len(p)
        if seg is None:
            return np.full(m, np.inf), np.full(m, -1, dtype=int)
        A, AB, part = seg
        ab2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-18)
        dist = np.empty(m)
        idx = np.empty(m, dtype=int)
        for lo in range(0, m, 4096):
            q = p[lo:lo + 4096, None, :] - A[None, :, :]                  # (m, S, 2)
            t = np.clip(np.einsum("msk,sk->ms", q, AB) / ab2, 0.0, 1.0)
            r = q - t[..., None] * AB[None, :, :]
            d2 = np.einsum("msk,msk->ms", r, r)
            j = np.argmin(d2, axis=1)
            dist[lo:lo + 4096] = np.sqrt(d2[np.arange(len(j)), j])
            idx[lo:lo + 4096] = part[j]
        return dist, idx

    def track_length(self) -> float:
        """Total centreline length, m."""
        return float(sum(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()
                         for c in self.centreline()))

    # ------------------------------------------------------------------ rendering
    def floor_image(self, px_per_m: float = 300.0, margin_m: float = 1.5
                    ) -> tuple[np.ndarray, np.ndarray]:
        """The floor as an RGB texture and its transform (cached per arguments).

        Returns (image (H, W, 3) uint8 RGB, T_tex_W (3, 3) float): ``T_tex_W @ [N, E, 1]``
        gives the texture pixel ``[col, row, 1]`` (integer values at pixel centres, as cv2
        expects). Rows run southward, columns eastward; the texture covers the arena plus
        ``margin_m`` on every side. The returned array is shared: do not modify it.
        """
        if not (10.0 <= px_per_m <= 2000.0):
            raise ValueError(f"px_per_m must be in [10, 2000], got {px_per_m}")
        key = ("floor", float(px_per_m), float(margin_m))
        if key not in self._cache:
            from cosim.world.raster import rasterise

            img, T = rasterise(self, float(px_per_m), float(margin_m))
            img.setflags(write=False)
            self._cache[key] = (img, T)
        return self._cache[key]


# ====================================================================== validation helpers
def _pair(v: Any, f: str) -> NE:
    if (not isinstance(v, list) or len(v) != 2
            or any(isinstance(c, bool) or not isinstance(c, (int, float))
                   or not math.isfinite(c) for c in v)):
        raise ScenarioError(f, v, "[north, east] in metres (two finite numbers)")
    return (float(v[0]), float(v[1]))


def _point(d: Mapping, key: str, where: str, arena: Arena) -> NE:
    f = f"{where}.{key}"
    if key not in d:
        raise ScenarioError(f, None, "[north, east] in metres (required)")
    p = _pair(d[key], f)
    if not arena.contains(*p):
        raise ScenarioError(f, d[key], f"a point inside the arena {tuple(arena)}")
    return p


def _track_part(p: Any, where: str, arena: Arena) -> TrackPart:
    if not isinstance(p, Mapping):
        raise ScenarioError(where, p, "a table (rectangle or polyline part)")
    width = number(p, "width", where, lo=0.005, hi=2.0)
    colour = rgb(p, "rgb", where, RED)
    if "points" in p:
        no_unknown(p, {"points", "width", "rgb"}, where)
        raw = p["points"]
        f = f"{where}.points"
        if not isinstance(raw, list) or len(raw) < 2:
            raise ScenarioError(f, raw, "at least two [north, east] points")
        pts = tuple(_pair(q, f"{f}[{i}]") for i, q in enumerate(raw))
        for i, q in enumerate(pts):
            if not arena.contains(*q):
                raise ScenarioError(f"{f}[{i}]", list(q), f"a point inside the arena "
                                    f"{tuple(arena)}")
            if i and math.dist(q, pts[i - 1]) < 1e-3:
                raise ScenarioError(f"{f}[{i}]", list(q),
                                    "a point at least 1 mm from the previous one")
        return PolylinePart(points=pts, width=width, rgb=colour)
    no_unknown(p, {"center", "length", "width", "heading_deg", "rgb"}, where)
    if "center" not in p:
        raise ScenarioError(where, dict(p), "a rectangle (center, length, width, heading_deg) "
                            "or a polyline (points, width)")
    part = RectPart(center=_point(p, "center", where, arena),
                    length=number(p, "length", where, lo=0.0, hi=200.0, lo_open=True),
                    width=width,
                    heading=math.radians(number(p, "heading_deg", where, lo=-360.0, hi=360.0)),
                    rgb=colour)
    for q in part.axis_ends():
        if not arena.contains(*q):
            raise ScenarioError(f"{where}.length", part.length,
                                f"a length that keeps both ends inside the arena {tuple(arena)}")
    return part


def _distractor(x: Any, where: str, arena: Arena) -> Distractor:
    if not isinstance(x, Mapping):
        raise ScenarioError(where, x, "a table {shape, center, size, rgb, heading_deg}")
    no_unknown(x, {"shape", "center", "size", "rgb", "heading_deg"}, where)
    shape = x.get("shape")
    if shape not in ("square", "disc"):
        raise ScenarioError(f"{where}.shape", shape, "'square' or 'disc'")
    if shape == "disc" and "heading_deg" in x:
        raise ScenarioError(f"{where}.heading_deg", x["heading_deg"], "only for squares")
    if "rgb" not in x:
        raise ScenarioError(f"{where}.rgb", None, "[r, g, b] with integers 0-255 (required)")
    return Distractor(shape=shape, center=_point(x, "center", where, arena),
                      size=number(x, "size", where, lo=0.0, hi=10.0, lo_open=True),
                      rgb=rgb(x, "rgb", where, (0, 0, 0)),
                      heading=math.radians(number(x, "heading_deg", where, 0.0,
                                                lo=-360.0, hi=360.0)))


# ====================================================================== geometry helpers
def _orient_parts(track: Sequence[TrackPart]) -> list[np.ndarray]:
    """Centrelines in track order; rectangles flipped so consecutive parts connect."""
    out: list[np.ndarray] = []
    for i, part in enumerate(track):
        if isinstance(part, PolylinePart):
            out.append(np.array(part.points, dtype=float))
            continue
        ends = part.axis_ends()
        if i == 0:
            if len(track) == 1:
                out.append(ends)
                continue
            nxt = track[1]
            cand = (nxt.axis_ends() if isinstance(nxt, RectPart)
                    else np.array(nxt.points[:1], dtype=float))
            d_fwd = np.min(np.linalg.norm(cand - ends[1], axis=1))
            d_rev = np.min(np.linalg.norm(cand - ends[0], axis=1))
            out.append(ends if d_fwd <= d_rev else ends[::-1].copy())
        else:
            prev_end = out[-1][-1]
            if np.linalg.norm(ends[1] - prev_end) < np.linalg.norm(ends[0] - prev_end):
                ends = ends[::-1].copy()
            out.append(ends)
    return out


# ====================================================================== built-in worlds
def builtin_worlds() -> list[str]:
    """Names of the worlds shipped in scenarios/worlds/."""
    return sorted(p.stem for p in WORLDS_DIR.glob("*.toml"))


def load_world(spec: str | Path | Mapping[str, Any], where: str = "world") -> World:
    """A world from a built-in name ('seed', 'turns', ...), a TOML path, or a ``[world]`` dict."""
    if isinstance(spec, Mapping):
        return World.from_dict(spec, where)
    p = Path(spec)
    if p.suffix != ".toml":
        p = WORLDS_DIR / f"{spec}.toml"
        if not p.is_file():
            raise ScenarioError(where, str(spec),
                                f"a world TOML path or one of {', '.join(builtin_worlds())}")
    return World.from_toml(p)
