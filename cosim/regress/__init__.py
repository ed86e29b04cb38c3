"""Regression tests of flights: `cosim test`, its baselines and tolerance tubes, equivalence
of two modes, JUnit and Markdown reports, a pytest plugin (docs/regression.md).

The Python API for users' own tests:

    from cosim.regress import fly, check_baseline
    flight = fly("scenarios/my_mission.toml", seed=3, sets=["app.alpha=0.005"])
    assert flight.metrics["mission_time_s"] < 80
    verdict = check_baseline("scenarios/my_mission.toml", flight)   # its baselines/ file
    assert verdict["status"] != "failed", verdict["failures"]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cosim.regress.cases import Case, Tol, Tolerances, collect
from cosim.regress.flight import Flight, fly

__all__ = ["Case", "Flight", "Tol", "Tolerances", "check_baseline", "collect", "fly"]


def check_baseline(scenario: str | Path, flight: Flight, *, case_id: str | None = None,
                   baselines: str | Path | None = None,
                   tolerance: Tolerances | None = None, update: bool = False) -> dict[str, Any]:
    """The verdict of `flight` against the baseline of `scenario` (`baselines/<case_id>.json`
    beside it, or in `baselines`); `update=True` writes the baseline from the flight first."""
    from cosim.regress import baseline
    from cosim.regress.compare import check

    p = Path(scenario)
    case = Case(id=case_id or p.stem, scenario=p, tolerance=tolerance or Tolerances(),
                baselines=Path(baselines) if baselines is not None else p.parent / "baselines")
    if update:
        baseline.write(case, flight)
    return check(case, {"run": flight}, baseline.read(case))
