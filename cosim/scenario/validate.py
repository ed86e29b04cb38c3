"""Field checks for the TOML tables of scenarios, worlds and cameras: one set, one wording.

Each check takes the table `d`, the `key` and the dotted path `where` of the table, and
raises `ScenarioError(path, value, allowed)` naming the field. A missing key returns the
default, or is an error when the default is REQUIRED.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from cosim.errors import ScenarioError

REQUIRED: Any = object()


def field(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def no_unknown(d: Mapping, known: set[str], where: str) -> None:
    for k in d:
        if k not in known:
            raise ScenarioError(field(where, k), d[k],
                                f"one of the keys {', '.join(sorted(known))}")


def table(d: Mapping, key: str, where: str, required: bool = False) -> dict:
    if key not in d:
        if required:
            raise ScenarioError(field(where, key), None, "a table (section) is required")
        return {}
    v = d[key]
    if not isinstance(v, Mapping):
        raise ScenarioError(field(where, key), v, "a table")
    return dict(v)


def number(d: Mapping, key: str, where: str, default: Any = REQUIRED, *,
           lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False) -> float:
    f = field(where, key)
    rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
    if key not in d:
        if default is REQUIRED:
            raise ScenarioError(f, None, f"a number in {rng} (required)")
        return default if default is None else float(default)
    v = d[key]
    if (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
            or v < lo or v > hi or (lo_open and v == lo)):
        raise ScenarioError(f, v, f"a finite number in {rng}")
    return float(v)


def integer(d: Mapping, key: str, where: str, default: Any = REQUIRED, *, lo: int,
            hi: int) -> int:
    f = field(where, key)
    if key not in d:
        if default is REQUIRED:
            raise ScenarioError(f, None, f"an integer in [{lo}, {hi}] (required)")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ScenarioError(f, v, f"an integer in [{lo}, {hi}]")
    return v


def string(d: Mapping, key: str, where: str, default: Any = REQUIRED,
           choices: tuple[str, ...] = ()) -> str:
    f = field(where, key)
    allowed = f"one of {', '.join(choices)}" if choices else "a string"
    if key not in d:
        if default is REQUIRED:
            raise ScenarioError(f, None, f"{allowed} (required)")
        return default
    v = d[key]
    if not isinstance(v, str) or (choices and v not in choices):
        raise ScenarioError(f, v, allowed)
    return v


def rgb(d: Mapping, key: str, where: str, default: Any = REQUIRED) -> tuple[int, int, int]:
    """A colour: [r, g, b] with integers 0-255."""
    f = field(where, key)
    if key not in d:
        if default is REQUIRED:
            raise ScenarioError(f, None, "[r, g, b] with integers 0-255 (required)")
        return default
    v = d[key]
    if (not isinstance(v, list) or len(v) != 3
            or any(isinstance(c, bool) or not isinstance(c, int) or not 0 <= c <= 255
                   for c in v)):
        raise ScenarioError(f, v, "[r, g, b] with integers 0-255")
    return (int(v[0]), int(v[1]), int(v[2]))


def boolean(d: Mapping, key: str, where: str, default: bool) -> bool:
    v = d.get(key, default)
    if not isinstance(v, bool):
        raise ScenarioError(field(where, key), v, "true or false")
    return v
