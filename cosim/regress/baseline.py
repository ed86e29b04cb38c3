"""Baselines: small files in the user's repository, readable and diff-able.

`<baselines>/<case>.json` holds how the baseline was made (scenario, seed, assignments, mode,
numerics, versions), its exit, its metrics and the SHA-256 of its whole series;
`<case>.csv` its trajectory at `rate_hz` (t, n, e, alt, yaw and any signal a tolerance names),
each number written in full (shortest round-trip form), so a portable baseline is compared bit
for bit on any machine and a change reads as a diff.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.regress.cases import Case
from cosim.regress.flight import Flight

FORMAT = 1


@dataclass
class Baseline:
    path: Path
    meta: dict[str, Any]
    trajectory: dict[str, np.ndarray]

    @property
    def metrics(self) -> dict[str, Any]:
        return self.meta.get("metrics", {})

    @property
    def numerics(self) -> str:
        return self.meta.get("numerics", "")


def read(case: Case) -> Baseline | None:
    """The case's baseline, None when it has none (a new case)."""
    path = case.baseline
    if not path.exists():
        return None
    try:
        meta = json.loads(path.read_text())
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ValueError(f"format {meta.get('format') if isinstance(meta, dict) else '?'}"
                             f", this cosim reads format {FORMAT}")
        csv = path.with_suffix(".csv")
        names = csv.open().readline().strip().split(",")
        data = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
        if data.shape[1] != len(names) or names[0] != "t":
            raise ValueError(f"{csv.name}: a header t,... and {len(names)} columns a row")
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"baseline {path}", "(file)", f"a baseline cosim test wrote "
                            f"({exc}); write it again with cosim test --update") from None
    return Baseline(path, meta, dict(zip(names, data.T, strict=True)))


def write(case: Case, flight: Flight) -> Baseline:
    """The case's baseline from `flight` (the JSON and CSV files, written whole)."""
    s = flight.summary or {}
    meta = {
        "format": FORMAT,
        "case": case.id,
        "scenario": _relative(case.scenario, case.baselines),
        "seed": s.get("seed", case.seed),
        "set": list(case.sets),
        "mode": s.get("mode", case.mode),
        "numerics": flight.numerics,
        "versions": flight.versions,
        "exit_reason": s.get("exit_reason"),
        "passed": s.get("passed"),
        "sim_time_s": s.get("sim_time_s"),
        "metrics": {k: _json_number(v) for k, v in sorted(flight.metrics.items())},
        "series_sha256": flight.series_sha256,
        "rate_hz": case.tolerance.rate_hz,
        "trajectory": f"{case.id}.csv",
    }
    case.baselines.mkdir(parents=True, exist_ok=True)
    _atomic_write(case.baseline.with_suffix(".csv"), trajectory_csv(flight.trajectory))
    _atomic_write(case.baseline, json.dumps(meta, indent=1) + "\n")
    return Baseline(case.baseline, meta, dict(flight.trajectory))


def trajectory_csv(traj: dict[str, np.ndarray]) -> str:
    names = list(traj)
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    for row in zip(*(traj[n].tolist() for n in names), strict=True):
        buf.write(",".join(repr(v) for v in row) + "\n")
    return buf.getvalue()


def changes(old: Baseline | None, new: Baseline) -> list[str]:
    """What an update changed, a line each (for the screen; the files' diff says the rest)."""
    if old is None:
        return ["new baseline"]
    out = []
    for k in ("exit_reason", "passed", "numerics", "series_sha256"):
        if old.meta.get(k) != new.meta.get(k):
            out.append(f"{k}: {_short(old.meta.get(k))} -> {_short(new.meta.get(k))}")
    om, nm = old.metrics, new.metrics
    for k in sorted(set(om) | set(nm)):
        if om.get(k) != nm.get(k):
            out.append(f"metric {k}: {_short(om.get(k))} -> {_short(nm.get(k))}")
    for k, v in new.trajectory.items():
        if k == "t" or k not in old.trajectory:
            continue
        n = min(len(v), len(old.trajectory[k]))
        d = float(np.max(np.abs(v[:n] - old.trajectory[k][:n]))) if n else 0.0
        if d > 0 or len(v) != len(old.trajectory[k]):
            out.append(f"signal {k}: max change {d:.4g}, {len(old.trajectory[k])} -> {len(v)} "
                       f"samples")
    return out or ["unchanged"]


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    text = str(v)
    return text[:12] + "..." if isinstance(v, str) and len(text) == 64 else text


def _json_number(v: Any) -> Any:
    """JSON has no NaN or infinity: those are written as strings ('nan', 'inf')."""
    if isinstance(v, float) and not math.isfinite(v):
        return repr(v)
    return v


def _relative(path: Path, start: Path) -> str:
    import os

    try:
        return os.path.relpath(path.resolve(), start.resolve())
    except ValueError:                 # another drive
        return str(path)


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
