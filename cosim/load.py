"""Scenario files into records: `load_scenario`, `parse_scenario`, `with_set`.

cosim/scenario/ reads the file and checks the tables it owns (name, seed, timing, start, app,
criteria, onboard parameters, the vehicle preset and its overrides); every other table is
parsed by the package that builds from it (world, camera, sensors, wind, faults, plant, app
plugins), handed to the scenario parser as `Parts`. This module puts the two together, so the
scenario package stays a leaf that no other cosim package needs to be imported first.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cosim.apps.registry import BUILTIN_APPS, check_app, check_inputs
from cosim.faults.core import parse_faults
from cosim.plant.mapping import parse_plant
from cosim.scenario import parse as _parse
from cosim.scenario.records import Scenario
from cosim.sensors.camera import parse_camera
from cosim.sensors.spec import TABLES as SENSOR_TABLES
from cosim.sensors.spec import parse_sensors
from cosim.world.floor import World
from cosim.world.wind import parse_wind

PARTS = _parse.Parts(
    world=World.from_dict, camera=parse_camera, sensors=parse_sensors,
    sensor_tables=tuple(SENSOR_TABLES), wind=parse_wind, faults=parse_faults,
    plant=parse_plant, apps=tuple(BUILTIN_APPS), check_app=check_app,
    check_inputs=check_inputs,
)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file (ScenarioError names the field)."""
    return _parse.load_scenario(path, PARTS)


def parse_scenario(raw: dict, *, source: str = "", base_dir: Path | None = None) -> Scenario:
    """Validate a scenario's TOML tables."""
    return _parse.parse_scenario(raw, PARTS, source=source, base_dir=base_dir)


def with_set(sc: Scenario, assignments: dict[str, Any]) -> Scenario:
    """A copy of `sc` with dotted-path overrides applied to its TOML and parsed again
    (`{"app.params.alpha": 0.005, "seed": 3}`; `app.X` is short for `app.params.X`)."""
    return _parse.with_set(sc, assignments, PARTS)
