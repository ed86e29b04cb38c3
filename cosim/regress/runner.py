"""Fly cases and check them: one job per case (its flights and its checks), on the study engine
(a local Dask cluster by default, `serial` on request), verdicts as they finish."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cosim.executors import map_jobs
from cosim.regress import baseline as baselines
from cosim.regress.cases import Case
from cosim.regress.compare import check
from cosim.regress.flight import SIDES, Flight, fly, read_run


@dataclass(frozen=True)
class CaseJob:
    run_id: int
    case: Case
    out: Path                                   # this case's folder: one run folder a side
    equivalence: tuple[str, str] | None = None
    timeout_s: float | None = None


def sides_of(job: CaseJob, base_numerics: str | None) -> dict[str, dict[str, Any]]:
    """side name -> what it flies with: mode, numerics, environment. The numerics are the
    case's, else its baseline's (a portable baseline is flown portable), else the scenario's."""
    c = job.case
    common = {"mode": c.mode, "numerics": c.numerics or base_numerics or None, "env": {}}
    if job.equivalence is None:
        return {"run": common}
    return {s: {**common, **SIDES[s]} for s in job.equivalence}


def run_case(job: CaseJob) -> dict[str, Any]:
    """Fly one case (each side in a process of its own) and check it. Never raises for a
    failed flight; a bad baseline file is a verdict with status 'error'."""
    c = job.case
    try:
        base = baselines.read(c)
    except ValueError as exc:                 # ScenarioError: names the file and the cure
        return {"id": c.id, "suite": c.suite, "scenario": str(c.scenario), "status": "error",
                "failures": [str(exc)], "notes": [], "tubes": [], "runs": {}, "wall_s": 0.0,
                "run_id": job.run_id}
    flights: dict[str, Flight] = {}
    for side, how in sides_of(job, base.numerics if base else None).items():
        flights[side] = fly(c.scenario, seed=c.seed, sets=c.sets, mode=how["mode"],
                            numerics=how["numerics"], env=how["env"], out=job.out / side,
                            signals=tuple(c.tolerance.signals), rate_hz=c.tolerance.rate_hz,
                            timeout_s=job.timeout_s)
    v = check(c, flights, base, job.equivalence)
    v["run_id"] = job.run_id
    return v


def lost_case(job: CaseJob, exc: BaseException) -> dict[str, Any]:
    return {"id": job.case.id, "suite": job.case.suite, "scenario": str(job.case.scenario),
            "status": "error", "failures": [f"the worker running it was lost: "
                                            f"{type(exc).__name__}: {exc}"],
            "notes": [], "tubes": [], "runs": {}, "wall_s": 0.0, "run_id": job.run_id}


def jobs_for(cases: list[Case], out: Path, *, equivalence: tuple[str, str] | None = None,
             timeout_s: float | None = None) -> list[CaseJob]:
    """One job a case, the longest first (the last run's wall time in `out`, else the
    baseline's simulated time): a suite on n workers then ends near the time of its runs
    spread over them, not with one long run alone at the end."""
    last = _last_walls(out / "verdicts.json")
    jobs = [CaseJob(i, c, out / c.suite / c.id, equivalence, timeout_s)
            for i, c in enumerate(cases)]
    return sorted(jobs, key=lambda j: -last.get((j.case.suite, j.case.id),
                                                _sim_time(j.case)))


def _last_walls(path: Path) -> dict[tuple[str, str], float]:
    try:
        return {(v["suite"], v["id"]): float(v["wall_s"]) for v in json.loads(path.read_text())
                if v.get("wall_s")}
    except (OSError, ValueError, TypeError, KeyError):
        return {}


def _sim_time(case: Case) -> float:
    """A case's cost in wall seconds, estimated from its baseline's simulated seconds at 10x
    real time (a shipped mission runs 10-100x); 0 without a baseline."""
    try:
        return float(json.loads(case.baseline.read_text()).get("sim_time_s") or 0.0) / 10.0
    except (OSError, ValueError, TypeError, AttributeError):
        return 0.0


def run_cases(jobs: list[CaseJob], *, executor: str = "dask", workers: int | None = None,
              scheduler: str | None = None) -> Iterator[dict[str, Any]]:
    yield from map_jobs(jobs, run_case, executor=executor, workers=workers,
                        scheduler=scheduler, lost=lost_case)


def update(job: CaseJob, verdict: dict[str, Any]) -> list[str]:
    """Write the case's baseline from its flight (the first side's); the lines say what
    changed. A flight that failed its own criteria or gave no result is not a baseline."""
    first = next(iter(verdict.get("runs", {}).values()), None)
    if verdict["status"] == "error" or first is None:
        return ["not updated: the flight gave no result"]
    c = job.case
    flight = read_run(Path(first), signals=tuple(c.tolerance.signals),
                      rate_hz=c.tolerance.rate_hz)
    if not flight.ok or not (flight.summary or {}).get("passed"):
        return ["not updated: the flight did not pass its own criteria "
                f"({(flight.summary or {}).get('exit_reason', flight.error)})"]
    try:
        old = baselines.read(c)
    except ValueError:
        old = None
    new = baselines.write(c, flight)
    return baselines.changes(old, new)
