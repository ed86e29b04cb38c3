"""The one module of cosim/studies that names the modules outside it (scenario, master,
report, metrics, sweep), so a reorganisation of cosim/ changes the imports here only.

Imports are inside the functions: parsing a `--vary` or reading a table loads no simulator.
Besides these, the package reads fields of the records: Scenario .raw .world_table .start .seed
.source .name .app.name; RunResult .scenario .exit_reason .message .series .phases.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

# the command line's values (a leaf module: nothing of the simulator is loaded)
from cosim.scenario.sets import one_each, parse_sets, parse_value, split_values  # noqa: F401


# ---------------------------------------------------------------- command-line values
def strict_json(o: Any, **kw: Any) -> str:
    """JSON without NaN / Infinity (null for a missing number) and with real booleans."""
    from cosim.outputs.strict import dumps

    return dumps(o, **kw)


# ---------------------------------------------------------------- scenarios
def load_scenario(path: str | Path):
    from cosim.load import load_scenario as f

    return f(path)


def parse_scenario(raw: dict[str, Any], *, source: str, base_dir: Path):
    from cosim.load import parse_scenario as f

    return f(raw, source=source, base_dir=base_dir)


def with_set(sc, assignments: dict[str, Any]):
    """A copy of the scenario with dotted-path overrides, re-validated."""
    from cosim.load import with_set as f

    return f(sc, assignments)


# ---------------------------------------------------------------- one run
def run_mission(sc, *, mode: str, out_dir: Path, mcap: bool = False):
    from cosim.sim.master import RunOptions, run_scenario

    return run_scenario(sc, RunOptions(mode=mode, out_dir=out_dir, mcap=mcap))


def component_error(res) -> bool:
    """The run ended because a part of the co-simulation failed."""
    from cosim.sim.master import ExitReason

    return res.exit_reason is ExitReason.COMPONENT_ERROR


def interrupted(res) -> bool:
    """The run was cut by a signal (Ctrl-C, SIGTERM): not a result."""
    return res.exit_reason.value == cut_exit()


def cut_exit() -> str:
    """The exit reason of a run cut by a signal (a row an older cosim kept: run again)."""
    from cosim.scenario.records import ExitReason  # a leaf: loads no simulator

    return ExitReason.INTERRUPTED.value


def summarize(res) -> dict[str, Any]:
    from cosim.outputs.report import summarize as f

    return f(res)


def write_run(res, out: Path) -> dict[str, Any]:
    from cosim.outputs.report import write_run as f

    return f(res, out)


def phase_column() -> int:
    """Index of the app's phase in a run's recorded series."""
    from cosim.outputs.series import COL

    return COL["phase"]
