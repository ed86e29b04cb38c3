"""The command line's assignments to a scenario: `--set KEY=VALUE` (one value, every command)
and `--set KEY=V1,V2,...` (a sweep's values), and the values of `--vary` distributions.

A value is TOML (number, bool, string, list, inline table); a bare word is a string. Nested at
most MAX_DEPTH deep (a deeper one would exhaust the recursion of the parser and the checks).
"""

from __future__ import annotations

import tomllib
from typing import Any

from cosim.errors import ScenarioError

MAX_DEPTH = 32


def parse_value(text: str) -> Any:
    """A TOML value; a bare word is a string."""
    depth = deepest = 0
    for ch in text:
        depth += ch in "[{"
        depth -= ch in "]}"
        deepest = max(deepest, depth)
    if deepest > MAX_DEPTH:
        raise ScenarioError("value", text, f"a TOML value nested at most {MAX_DEPTH} deep")
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def split_values(text: str) -> list[str]:
    """Split 'a,b,[1,2]' at top-level commas."""
    out, depth, cur = [], 0, ""
    for ch in text:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    out.append(cur)
    return [s.strip() for s in out if s.strip()]


def parse_sets(sets: list[str], *, multi: bool) -> dict[str, list[Any]]:
    """`KEY=VALUE` assignments -> {dotted key: its values} (`multi`: comma-separated values
    each, a sweep's grid; else the whole text after `=` is one value)."""
    out: dict[str, list[Any]] = {}
    for s in sets:
        key, eq, vals = s.partition("=")
        if not eq or not key.strip():
            raise ScenarioError("--set", s, "KEY=VALUE[,VALUE...] with a dotted key")
        values = [parse_value(v) for v in (split_values(vals) if multi else [vals])]
        if not values:
            raise ScenarioError(f"--set {key}", vals, "at least one value")
        out[key.strip()] = values
    return out


def one_each(sets: list[str]) -> dict[str, Any]:
    """`--set KEY=VALUE` assignments of a single run: {dotted key: its value}."""
    return {k: v[0] for k, v in parse_sets(sets, multi=False).items()}
