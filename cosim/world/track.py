"""The pieces of a flat world: arena, track parts, end marker, distractors (world NED, m)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

RED = (255, 0, 0)
PLAIN_FLOOR_RGB = (180, 180, 180)       # light grey, stands in for the template's floor
COMPETITION_FLOOR_RGB = (176, 164, 148)  # light grey-brown base of the competition floor
COMPETITION_TILE_RGB = (122, 104, 86)    # darker brown tiles
TILE_PITCH_M = 0.25                      # m, competition floor grid
TILE_SIZE_M = (0.15, 0.05)               # m, (long, short) side of a competition tile


RGB = tuple[int, int, int]
NE = tuple[float, float]


class Arena(NamedTuple):
    """Flyable area, world NED metres. Also indexable: ``arena[0..3]``."""

    n_min: float
    n_max: float
    e_min: float
    e_max: float

    def contains(self, n: float, e: float) -> bool:
        return self.n_min <= n <= self.n_max and self.e_min <= e <= self.e_max


@dataclass(frozen=True)
class RectPart:
    """A straight track piece: a rectangle on the floor."""

    center: NE            # m, (N, E)
    length: float         # m, along the axis
    width: float          # m
    heading: float        # rad, axis direction from North towards East
    rgb: RGB = RED

    def axis_ends(self) -> np.ndarray:
        """(2, 2) the two ends of the axis, (N, E) m: centre -/+ length/2 along the heading."""
        h = 0.5 * self.length
        u = np.array([math.cos(self.heading), math.sin(self.heading)])
        c = np.array(self.center, dtype=float)
        return np.stack([c - h * u, c + h * u])


@dataclass(frozen=True)
class PolylinePart:
    """A track piece following a polyline (points in track order) with round joins."""

    points: tuple[NE, ...]   # m, (N, E)
    width: float             # m
    rgb: RGB = RED


TrackPart = RectPart | PolylinePart


@dataclass(frozen=True)
class Marker:
    """The end-marker disc."""

    center: NE     # m, (N, E)
    radius: float  # m
    rgb: RGB = RED


@dataclass(frozen=True)
class Distractor:
    """A shape on the floor that is not the track (competition: yellow/blue squares)."""

    shape: str         # "square" (size = side) or "disc" (size = diameter)
    center: NE         # m, (N, E)
    size: float        # m
    rgb: RGB
    heading: float = 0.0  # rad, squares only
