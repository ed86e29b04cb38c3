"""Monte Carlo draws: the `--vary KEY=DIST(ARGS)` syntax and seeded, reproducible sampling.

Distributions (numbers are TOML numbers; `choice` takes any TOML values):
    uniform(a,b)            a <= x < b
    normal(mu,sigma)        sigma >= 0
    truncnormal(mu,sigma,lo,hi)  normal restricted to [lo, hi] (inverse CDF, one draw each)
    loguniform(a,b)         0 < a < b, log(x) uniform
    choice(v1,v2,...)       each value with the same probability

Seeds: run i of a study with seed S draws from `SeedSequence(S, spawn_key=(i,))` (the i-th child
of `SeedSequence(S).spawn`), so a run's draws depend only on (S, i): the first 200 runs of a
1000-run study are the 200-run study. Each run's child is split again: one stream gives the
run's scenario seed, and each varied key draws from its own stream (keyed by the key's CRC-32),
so adding a `--vary` does not change the other keys' draws.

A draw outside the field's allowed range is not clipped: the study stops before it starts with
an error naming the `--vary` and the field (use truncnormal or narrower bounds).
"""

from __future__ import annotations

import math
import re
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.studies.deps import parse_value, split_values

SEED_MAX = 2**31 - 1          # scenario seeds stay short enough to type in a replay command
_SPEC = re.compile(r"^\s*([a-z]+)\s*\((.*)\)\s*$", re.S)
_ARITY = {"uniform": 2, "normal": 2, "loguniform": 2, "truncnormal": 4}
NAMES = (*_ARITY, "choice")


@dataclass(frozen=True)
class Dist:
    key: str                    # dotted scenario field, e.g. wind.n_mps
    kind: str                   # uniform | normal | truncnormal | loguniform | choice
    args: tuple[Any, ...]

    @property
    def text(self) -> str:
        return f"{self.key}={self.kind}({','.join(map(str, self.args))})"

    def draw(self, rng: np.random.Generator) -> Any:
        a = self.args
        if self.kind == "uniform":
            return float(rng.uniform(a[0], a[1]))
        if self.kind == "normal":
            return float(rng.normal(a[0], a[1]))
        if self.kind == "loguniform":
            return float(math.exp(rng.uniform(math.log(a[0]), math.log(a[1]))))
        if self.kind == "truncnormal":
            from scipy.special import ndtr, ndtri

            mu, sigma, lo, hi = a
            if sigma == 0:
                return float(min(max(mu, lo), hi))
            c_lo, c_hi = ndtr((lo - mu) / sigma), ndtr((hi - mu) / sigma)
            x = mu + sigma * float(ndtri(c_lo + rng.uniform() * (c_hi - c_lo)))
            return float(min(max(x, lo), hi))      # guard the last ulp of the inverse CDF
        return a[int(rng.integers(len(a)))]        # choice


def parse_vary(text: str) -> Dist:
    """`KEY=DIST(ARGS)` -> Dist; a bad one raises ScenarioError naming the `--vary`."""
    key, eq, spec = text.partition("=")
    key = key.strip()
    where = f"--vary {text}"
    if not eq or not key or " " in key:
        raise ScenarioError(where, text, "KEY=DIST(ARGS) with a dotted scenario key, e.g. "
                            "wind.n_mps=uniform(0,1.5)")
    m = _SPEC.match(spec)
    if not m or m.group(1) not in NAMES:
        raise ScenarioError(where, spec, f"one of {', '.join(n + '(...)' for n in NAMES)}")
    kind = m.group(1)
    args = tuple(parse_value(v) for v in split_values(m.group(2)))
    if kind == "choice":
        if not args:
            raise ScenarioError(where, spec, "choice(v1,v2,...) with at least one value")
        return Dist(key, kind, args)
    if len(args) != _ARITY[kind] or not all(_is_number(v) for v in args):
        names = {"uniform": "a,b", "normal": "mu,sigma", "loguniform": "a,b",
                 "truncnormal": "mu,sigma,lo,hi"}[kind]
        raise ScenarioError(where, spec, f"{kind}({names}) with {_ARITY[kind]} finite numbers")
    args = tuple(float(v) for v in args)
    if kind == "uniform" and not args[0] < args[1]:
        raise ScenarioError(where, spec, "uniform(a,b) with a < b")
    if kind in ("uniform", "truncnormal") and not math.isfinite(args[-1] - args[-2]):
        raise ScenarioError(where, spec, f"{kind}(...) whose range b - a is a finite number")
    if kind in ("normal", "truncnormal") and args[1] < 0:
        raise ScenarioError(where, spec, f"{kind}(...) with sigma >= 0")
    if kind == "truncnormal" and not args[2] < args[3]:
        raise ScenarioError(where, spec, "truncnormal(mu,sigma,lo,hi) with lo < hi")
    if kind == "loguniform" and not 0 < args[0] < args[1]:
        raise ScenarioError(where, spec, "loguniform(a,b) with 0 < a < b")
    return Dist(key, kind, args)


def parse_varies(texts: list[str]) -> list[Dist]:
    dists = [parse_vary(t) for t in texts]
    seen: set[str] = set()
    for d in dists:
        if d.key in seen:
            raise ScenarioError(f"--vary {d.text}", d.key, "each key varied once")
        seen.add(d.key)
    return dists


def run_draws(study_seed: int, run: int, dists: list[Dist]) -> tuple[int, dict[str, Any]]:
    """(scenario seed, {key: value}) of run `run`: a function of (study_seed, run) only."""
    seed_ss = np.random.SeedSequence(study_seed, spawn_key=(run, 0))
    seed = int(seed_ss.generate_state(1, np.uint32)[0]) & SEED_MAX
    values = {}
    for d in dists:
        ss = np.random.SeedSequence(study_seed, spawn_key=(run, 1, zlib.crc32(d.key.encode())))
        values[d.key] = d.draw(np.random.default_rng(ss))
    return seed, values


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
