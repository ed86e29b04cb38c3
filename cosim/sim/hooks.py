"""The seam where fault injection plugs into the tick loop (the `[faults]` table builds one).

Faults sit between the parts, not inside them (ARCHITECTURE.md): a `Hooks` object may wrap the
MAVLink links when the run is built, and may change what passes at three points of each tick:
the ODOMETRY measurement before it is sent, the camera frame before the app sees it, and the
motor commands before they reach the plant. A run without faults has no hooks (`None`), and the
loop then calls nothing extra per tick.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Hooks(Protocol):
    odometry_lost: bool   # after on_odometry: send this tick's ODOMETRY with quality -1

    def wrap_link(self, name: str, link):
        """`name` in ('api', 'gcs', 'hil'): return the link to use (the same, or a wrapper)."""
        ...

    def on_odometry(self, t_us: int, meas: tuple[float, ...]) -> tuple[float, ...]:
        """The measurement sent at t_us (a dropout sets `odometry_lost` and repeats the old
        position: the HIL lockstep needs one ODOMETRY per tick)."""
        ...

    def on_frame(self, t_us: int, img: np.ndarray) -> np.ndarray | None:
        """The frame the app gets at t_us; None: the frame is dropped."""
        ...

    def on_actuators(self, t_us: int, u: tuple[float, float, float, float]
                     ) -> tuple[float, float, float, float]:
        """The motor commands applied to the plant from t_us (normalised, 0..1)."""
        ...

    def fired(self) -> list[tuple[float, str]]:
        """(t s, description) of every fault that took effect, for the summary and plots."""
        ...
