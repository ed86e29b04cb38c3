"""What `cosim test` flies: cases from scenario files, folders of them and suite files, each
with its seed, `--set` assignments, mode and tolerances.

A suite file is a TOML file with `[[case]]` entries (docs/regression.md):

    [suite]
    name = "my-app"                 # the JUnit suite name (default: the file's stem)
    baselines = "baselines"         # where baselines live, relative to this file
    numerics = "portable"           # the runs' numerics (default: the baseline's, else native)

    [tolerance]                     # every case; a case's own [case.tolerance] refines it
    position_m = 0.10               # n, e: m
    time_s = 0.2                    # a signal may lead or lag its baseline by this much

    [[case]]
    scenario = "../scenarios/mambo_seed_track.toml"
    seeds = [0, 1, 2]               # or seed = 0; one case per seed
    set = ["app.alpha=0.005"]       # or a table: set = { "app.alpha" = 0.005 }

Tolerances are Simulink Test's baseline criteria: a signal passes where it stays within
max(abs, rel x |baseline|) of the baseline at some time within +-time_s (its "leading /
lagging" tolerance); a metric passes within max(abs, rel x |baseline|).
"""

from __future__ import annotations

import hashlib
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.scenario.sets import parse_value

MODES = ("mil", "sil")
NUMERICS = ("native", "portable")
# the signals every baseline keeps: name -> (unit, default absolute tolerance)
DEFAULT_SIGNALS: dict[str, tuple[str, float]] = {
    "n": ("m", 0.10), "e": ("m", 0.10), "alt": ("m", 0.10), "yaw": ("deg", 5.0)}
SHORTCUTS = {"position_m": ("n", "e"), "altitude_m": ("alt",), "yaw_deg": ("yaw",)}
RATE_HZ = 10.0          # the baseline trajectory's samples per second


@dataclass(frozen=True)
class Tol:
    """max(abs, rel x |baseline|), and for a signal the time it may lead or lag by."""
    abs: float
    rel: float = 0.0
    time_s: float = 0.0

    def of(self, ref):
        """The band's half-width around `ref` (a number or an array)."""
        return np.maximum(self.abs, self.rel * np.abs(ref))


@dataclass(frozen=True)
class Tolerances:
    signals: dict[str, Tol] = field(default_factory=lambda: {
        k: Tol(v) for k, (_, v) in DEFAULT_SIGNALS.items()})
    metrics: dict[str, Tol] = field(default_factory=dict)
    metric: Tol = Tol(1e-6, 0.02)          # any metric not named in `metrics`
    ignore_metrics: tuple[str, ...] = ()
    exact: str = "auto"      # "true": a portable baseline must be met bit for bit (same
                             # versions); "auto": bits reported, the tubes decide (and the
                             # MIL/SIL, interpreted/compiled equivalences are exact);
                             # "false": never exact
    rate_hz: float = RATE_HZ

    def for_metric(self, name: str) -> Tol:
        return self.metrics.get(name, self.metric)

    def refined(self, table: dict[str, Any], where: str) -> Tolerances:
        """These tolerances with a `[tolerance]` table's entries over them."""
        if not isinstance(table, dict):
            raise ScenarioError(where, table, "a table of tolerances")
        t = self
        signals, metrics = dict(t.signals), dict(t.metrics)
        for key, v in table.items():
            name = f"{where}.{key}"
            if key in SHORTCUTS:
                for s in SHORTCUTS[key]:
                    signals[s] = replace(signals[s], abs=_number(v, name))
            elif key == "time_s":
                signals = {s: replace(tol, time_s=_number(v, name)) for s, tol in signals.items()}
            elif key in ("metric_abs", "metric_rel"):
                t = replace(t, metric=replace(t.metric, **{key[7:]: _number(v, name)}))
            elif key == "signals":      # a signal's own entry: what it does not say is 0
                for s, sub in _table(v, name).items():   # (time_s: the common one)
                    base = Tol(0.0, 0.0, signals["n"].time_s)
                    signals[s] = _tol(sub, f"{name}.{s}", base, ("abs", "rel", "time_s"))
            elif key == "metrics":
                for m, sub in _table(v, name).items():
                    metrics[m] = _tol(sub, f"{name}.{m}", Tol(0.0), ("abs", "rel"))
            elif key == "ignore_metrics":
                if not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
                    raise ScenarioError(name, v, "a list of metric names")
                t = replace(t, ignore_metrics=tuple(v))
            elif key == "exact":
                if v not in (True, False, "auto"):
                    raise ScenarioError(name, v, 'true, false or "auto"')
                t = replace(t, exact={True: "true", False: "false"}.get(v, v))
            elif key == "rate_hz":
                t = replace(t, rate_hz=_number(v, name, low=0.1, high=1000.0))
            else:
                raise ScenarioError(name, v, "one of " + ", ".join(
                    (*SHORTCUTS, "time_s", "metric_abs", "metric_rel", "signals", "metrics",
                     "ignore_metrics", "exact", "rate_hz")))
        return replace(t, signals=signals, metrics=metrics)


def _number(v: Any, name: str, low: float = 0.0, high: float = 1e12) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not low <= v <= high:
        raise ScenarioError(name, v, f"a number in [{low:g}, {high:g}]")
    return float(v)


def _table(v: Any, name: str) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise ScenarioError(name, v, "a table")
    return v


def _tol(sub: Any, name: str, base: Tol, keys: tuple[str, ...]) -> Tol:
    if isinstance(sub, int | float) and not isinstance(sub, bool):
        return replace(base, abs=_number(sub, name))
    for k, x in _table(sub, name).items():
        if k not in keys:
            raise ScenarioError(f"{name}.{k}", x, "one of " + ", ".join(keys))
        base = replace(base, **{k: _number(x, f"{name}.{k}")})
    return base


@dataclass(frozen=True)
class Case:
    id: str                                   # unique in the run; the baseline's file name
    scenario: Path
    seed: int | None = None
    sets: tuple[str, ...] = ()                # KEY=VALUE, as `cosim run --set`
    mode: str = "mil"
    numerics: str | None = None               # None: the baseline's, else the scenario's
    tolerance: Tolerances = field(default_factory=Tolerances)
    baselines: Path = Path("baselines")       # the folder of this case's baseline
    suite: str = "cosim"                      # JUnit suite name

    @property
    def baseline(self) -> Path:
        return self.baselines / f"{self.id}.json"


def case_id(scenario: Path, seed: int | None, sets: tuple[str, ...]) -> str:
    """The scenario's stem, `-seed<N>`, and a short hash of the assignments when there are
    any: stable, readable, and the same wherever the suite is run from."""
    out = scenario.stem + ("" if seed is None else f"-seed{seed}")
    if sets:
        out += "-" + hashlib.sha256("\n".join(sets).encode()).hexdigest()[:8]
    return out


def read_toml(path: Path, what: str) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ScenarioError(what, str(path), "an existing file") from None
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(str(path), "(file)", f"a readable TOML file ({exc})") from None


def kind_of(raw: dict[str, Any]) -> str | None:
    """'suite', 'scenario', or None (a world file or another TOML file)."""
    if "case" in raw:
        return "suite"
    if "vehicle" in raw or "app" in raw:
        return "scenario"
    return None


def collect(paths: list[str | Path], *, baselines: Path | None = None,
            sets: tuple[str, ...] = (), seed: int | None = None, mode: str | None = None,
            numerics: str | None = None, tolerance: Tolerances | None = None) -> list[Case]:
    """Cases from scenario files, folders of them (recursively; world files, `baselines/` and
    `worlds/` folders left out) and suite files. A scenario file is one case with its own seed;
    the keyword arguments (the command line's) apply to every case."""
    out: list[Case] = []
    for p in map(Path, paths):
        files = [p] if not p.is_dir() else sorted(
            f for f in p.rglob("*.toml")
            if not {"baselines", "worlds"} & set(f.relative_to(p).parts[:-1]))
        for f in files:
            raw = read_toml(f, "path")
            kind = kind_of(raw)
            if kind is None and not p.is_dir():
                raise ScenarioError(str(f), "(file)", "a scenario (with [vehicle]) or a suite "
                                    "(with [[case]])")
            if kind == "suite":
                out += suite_cases(f, raw, baselines=baselines, tolerance=tolerance)
            elif kind == "scenario":
                out.append(Case(id=f.stem, scenario=f, tolerance=tolerance or Tolerances(),
                                baselines=baselines or f.parent / "baselines",
                                suite=p.stem if p.is_dir() else "cosim"))
    out = [_cli(c, sets, seed, mode, numerics) for c in out]
    seen: dict[str, Case] = {}
    for c in out:
        if c.id in seen and seen[c.id].baselines == c.baselines:
            raise ScenarioError("case", c.id, f"one case of that id per baselines folder "
                                f"({seen[c.id].scenario} and {c.scenario}); name them")
        seen[c.id] = c
    return out


def _cli(c: Case, sets: tuple[str, ...], seed: int | None, mode: str | None,
         numerics: str | None) -> Case:
    """The command line's assignments over a case: the change under test. The case keeps its
    id, so it is checked against the baseline of the case as the suite defines it."""
    return replace(c, sets=c.sets + tuple(sets), seed=c.seed if seed is None else seed,
                   mode=mode or c.mode, numerics=numerics or c.numerics)


def suite_cases(path: Path, raw: dict[str, Any], *, baselines: Path | None = None,
                tolerance: Tolerances | None = None) -> list[Case]:
    head = _table(raw.get("suite", {}), "suite")
    for k in head:
        if k not in ("name", "baselines", "numerics", "mode"):
            raise ScenarioError(f"suite.{k}", head[k], "one of name, baselines, numerics, mode")
    for k in raw:
        if k not in ("suite", "tolerance", "case"):
            raise ScenarioError(k, raw[k], "a suite file holds [suite], [tolerance], [[case]]")
    name = str(head.get("name", path.stem))
    folder = baselines or path.parent / str(head.get("baselines", "baselines"))
    tol = (tolerance or Tolerances()).refined(raw.get("tolerance", {}), "tolerance")
    cases = raw["case"]
    if not isinstance(cases, list) or not cases:
        raise ScenarioError("case", cases, "one or more [[case]] tables")
    out = []
    for i, entry in enumerate(cases):
        where = f"case[{i}]"
        entry = _table(entry, where)
        unknown = set(entry) - {"scenario", "name", "seed", "seeds", "set", "mode",
                                "numerics", "tolerance"}
        if unknown:
            k = sorted(unknown)[0]
            raise ScenarioError(f"{where}.{k}", entry[k], "one of scenario, name, seed, seeds, "
                                "set, mode, numerics, tolerance")
        if not isinstance(entry.get("scenario"), str):
            raise ScenarioError(f"{where}.scenario", entry.get("scenario"),
                                "a scenario file, relative to the suite file")
        scenario = path.parent / entry["scenario"]
        if not scenario.is_file():
            raise ScenarioError(f"{where}.scenario", entry["scenario"], "an existing file")
        seeds = _seeds(entry, where)
        sets = _sets(entry.get("set", []), f"{where}.set")
        mode = _choice(entry.get("mode", head.get("mode", "mil")), MODES, f"{where}.mode")
        num = entry.get("numerics", head.get("numerics"))
        if num is not None:
            _choice(num, NUMERICS, f"{where}.numerics")
        ctol = tol.refined(entry.get("tolerance", {}), f"{where}.tolerance")
        for seed in seeds:
            cid = entry.get("name")
            if cid is not None and (not isinstance(cid, str) or not _safe(cid)):
                raise ScenarioError(f"{where}.name", cid, "letters, digits, '-', '_', '.'")
            if cid is None:
                cid = case_id(scenario, seed, sets)
            elif len(seeds) > 1:
                cid = f"{cid}-seed{seed}"
            out.append(Case(id=cid, scenario=scenario, seed=seed, sets=sets, mode=mode,
                            numerics=num, tolerance=ctol, baselines=folder, suite=name))
    return out


def _safe(name: str) -> bool:
    return bool(name) and all(ch.isalnum() or ch in "-_." for ch in name) and name[0] != "."


def _choice(v: Any, allowed: tuple[str, ...], name: str) -> str:
    if v not in allowed:
        raise ScenarioError(name, v, "one of " + ", ".join(allowed))
    return v


def _seeds(entry: dict[str, Any], where: str) -> list[int | None]:
    if "seed" in entry and "seeds" in entry:
        raise ScenarioError(f"{where}.seeds", entry["seeds"], "seed or seeds, not both")
    seeds = entry.get("seeds", [entry["seed"]] if "seed" in entry else [None])
    if not isinstance(seeds, list) or not seeds or not all(
            s is None or (isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32)
            for s in seeds):
        raise ScenarioError(f"{where}.seeds", seeds, "integers in [0, 2**32)")
    return seeds


def _sets(v: Any, name: str) -> tuple[str, ...]:
    """`set` as a list of "KEY=VALUE" strings or a table {KEY: VALUE}, as `--set` texts."""
    if isinstance(v, dict):
        return tuple(f"{k}={_toml(x)}" for k, x in v.items())
    if isinstance(v, list) and all(isinstance(s, str) and "=" in s for s in v):
        for s in v:
            parse_value(s.partition("=")[2])
        return tuple(v)
    raise ScenarioError(name, v, 'a list of "KEY=VALUE" or a table {KEY = VALUE}')


def _toml(x: Any) -> str:
    """A value as TOML text (what `--set` parses back)."""
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, str):
        return '"' + x.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(x, list):
        return "[" + ", ".join(_toml(i) for i in x) + "]"
    if isinstance(x, dict):
        return "{" + ", ".join(f'"{k}" = {_toml(i)}' for k, i in x.items()) + "}"
    return repr(x)
