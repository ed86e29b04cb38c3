"""What every `cosim bench` figure shares: the seed scenario, the per-call timer, the
median / spread summary."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"
# the bench's seed-mission figures are truth-fed (ODOMETRY, the figures' history and targets)
# unless a figure says otherwise: the default feed is the sensors (feed = "hil")
TRUTH_FEED = {"sensors.feed": "truth"}


def seed_scenario(sets: dict[str, Any] | None = None):
    """The seed mission, truth-fed unless `sets` says otherwise (e.g. {"sensors.feed": "hil"})."""
    from cosim.load import load_scenario, with_set

    return with_set(load_scenario(SEED), {**TRUTH_FEED, **(sets or {})})


def _per_call_us(fn: Callable[[], Any], n: int, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        out.append((time.perf_counter() - t0) / n * 1e6)
    return out


def _stat(samples: list[float], unit: str, target: float | None = None,
          higher_is_better: bool = False) -> dict[str, Any]:
    d = {"median": statistics.median(samples), "min": min(samples), "max": max(samples),
         "n": len(samples), "unit": unit}
    if target is not None:
        d["target"] = target
        d["meets_target"] = (d["median"] >= target) if higher_is_better else (
            d["median"] <= target)
    return d
