"""Scenario files: typed records, loaded from TOML and validated field by field.

A malformed file raises `ScenarioError(field, value, allowed)`; `cosim` turns it into a
one-line message and exit status 2. Unknown keys are errors too (a typo must not be ignored).
The schema is documented in scenarios/README.md.
"""

from __future__ import annotations

import copy
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cosim.errors import ScenarioError
from cosim.numerics import MODES as NUMERICS_MODES
from cosim.scenario.records import (
    AppSpec,
    Criteria,
    ExitReason,
    Scenario,
    SensorNoise,
    Start,
    Timing,
)
from cosim.scenario.validate import boolean, integer, no_unknown, number, string, table
from cosim.scenario.vehicles import PHYSICAL_RANGES, PRESETS, get_vehicle
from mav.params import EST_OURS, EST_RELEASE


@dataclass(frozen=True)
class Parts:
    """The parsers of the tables other packages own, each building that package's record and
    naming the field it refuses: handed in by cosim/load.py (which imports them all), so this
    package imports none of the packages that build from it."""

    world: Callable[[dict, str], Any]             # [world] -> cosim.world.floor.World
    camera: Callable[[dict, str], Any]            # [camera] -> a camera config
    sensors: Callable[[dict, str], Any]           # [sensors], vehicle -> SensorsSpec
    sensor_tables: tuple[str, ...]                # the sub-tables [sensors] may have
    wind: Callable[[dict], Any]                   # [wind] -> WindSpec
    faults: Callable[[dict], Any]                 # [faults] -> FaultSpec
    plant: Callable[..., Any]                     # [vehicle] fmu/fmu_map/fmi -> PlantSpec | None
    apps: tuple[str, ...]                         # the built-in apps' names
    check_app: Callable[[AppSpec], None]          # the app's class and parameters
    check_inputs: Callable[..., None]             # the app's inputs against camera and world


# --------------------------------------------------------------------------- parsing
NAME_OK = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,79}")
TOP_KEYS = {"name", "description", "seed", "vehicle", "timing", "world", "camera", "app",
            "sensors", "wind", "faults", "onboard", "criteria", "run"}


def load_scenario(path: str | Path, parts: Parts) -> Scenario:
    """Read and validate a scenario TOML file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8") if p.is_file() else None
    except OSError as exc:          # a name too long, a folder we may not read, ...
        raise ScenarioError("scenario", str(p), f"a readable .toml file ({exc.strerror})"
                            ) from None
    except UnicodeDecodeError as exc:
        raise ScenarioError("scenario", str(p), f"valid UTF-8 TOML ({exc})") from None
    if text is None:
        raise ScenarioError("scenario", str(p), "an existing .toml file")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError("scenario", str(p), f"valid UTF-8 TOML ({exc})") from None
    except RecursionError:   # thousands of nested tables or arrays
        raise ScenarioError("scenario", str(p), "TOML nested less deeply") from None
    return parse_scenario(raw, parts, source=str(p), base_dir=p.parent)


def _load_world(raw: dict, base_dir: Path) -> dict:
    w = table(raw, "world", "", required=True)
    w = dict(w)
    if "file" in w:
        f = w.pop("file")
        if not isinstance(f, str):
            raise ScenarioError("world.file", f, "a path to a world TOML file")
        fp = (base_dir / f) if not Path(f).is_absolute() else Path(f)
        try:
            found = fp.is_file()
        except OSError:                 # e.g. a name too long
            found = False
        if not found:
            raise ScenarioError("world.file", f, f"an existing file (looked for {fp})")
        try:
            base = tomllib.loads(fp.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ScenarioError("world.file", f, f"valid UTF-8 TOML ({exc})") from None
        except RecursionError:   # thousands of nested tables or arrays
            raise ScenarioError("world.file", f, "TOML nested less deeply") from None
        base = base.get("world", base)
        if not isinstance(base, dict):
            raise ScenarioError("world.file", f, "a world file whose `world` is a table")
        base.update(w)  # keys given in the scenario override the file's
        w = base
    return w


def parse_scenario(raw: dict, parts: Parts, *, source: str = "",
                   base_dir: Path | None = None) -> Scenario:
    base_dir = base_dir or Path(".")
    no_unknown(raw, TOP_KEYS, "")
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", Path(source).stem).lstrip("._-")[:80]
    name = string(raw, "name", "", stem or "scenario")
    if not NAME_OK.fullmatch(name):   # it names run folders: no path, no control characters
        raise ScenarioError("name", name, "1-80 characters of letters, digits, '.', '_', '-', "
                            "starting with a letter or digit")
    description = string(raw, "description", "", "")
    seed = integer(raw, "seed", "", 0, lo=0, hi=2**63 - 1)

    # vehicle
    v = table(raw, "vehicle", "", required=True)
    no_unknown(v, {"preset", "overrides", "start", "fmu", "fmu_map", "fmu_timeout_s", "fmi"},
               "vehicle")
    preset = string(v, "preset", "vehicle", choices=tuple(sorted(PRESETS)))
    vehicle = get_vehicle(preset)
    ov = table(v, "overrides", "vehicle")
    fields = set(vehicle.fmu_parameters()) | {"body_radius"}
    no_unknown(ov, fields, "vehicle.overrides")
    if ov:
        vehicle = vehicle.with_overrides(
            **{k: number(ov, k, "vehicle.overrides", lo=PHYSICAL_RANGES[k][0],
                         hi=PHYSICAL_RANGES[k][1]) for k in ov})
        problem = vehicle.physical_problem()
        if problem is not None:
            raise ScenarioError("vehicle.overrides", ov, f"a vehicle that can fly: {problem}")
    world_table = _load_world(raw, base_dir)
    st = table(v, "start", "vehicle")
    no_unknown(st, {"n", "e", "yaw_deg"}, "vehicle.start")
    ws = world_table.get("start")     # the world's suggested start: fills what st leaves out
    ws = ws if isinstance(ws, dict) else {}
    start = Start(**{
        k: number(st, k, "vehicle.start", lo=lo, hi=hi) if k in st
        else number(ws, k, "world.start", 0.0, lo=lo, hi=hi)
        for k, lo, hi in (("n", -1e4, 1e4), ("e", -1e4, 1e4), ("yaw_deg", -180.0, 360.0))})

    # timing
    tm = table(raw, "timing", "")
    no_unknown(tm, {"tick_s", "camera_every", "t_final_s"}, "timing")
    tick = number(tm, "tick_s", "timing", 0.005, lo=0.005, hi=0.005)
    timing = Timing(
        tick_s=tick,
        camera_every=integer(tm, "camera_every", "timing", 40, lo=1, hi=10_000),
        t_final_s=number(tm, "t_final_s", "timing", 100.0, lo=0.0, hi=86_400.0, lo_open=True),
    )

    camera_table = table(raw, "camera", "") if "camera" in raw else None

    # how the run computes: the numerics it needs of its process (cosim/numerics.py)
    rn = table(raw, "run", "")
    no_unknown(rn, {"numerics"}, "run")
    numerics = string(rn, "numerics", "run", "native", NUMERICS_MODES)

    # app
    a = table(raw, "app", "")
    no_unknown(a, {"name", "params"}, "app")
    app_name = string(a, "name", "app", "none")
    if app_name not in parts.apps and ":" not in app_name:
        raise ScenarioError(
            "app.name", app_name, f"one of {', '.join(parts.apps)} or 'package.module:Class'"
        )
    app = AppSpec(name=app_name, params=dict(table(a, "params", "app")))

    # sensors / wind / faults
    s = table(raw, "sensors", "")
    no_unknown(s, {"odometry_noise", "feed", "flow_floor", *parts.sensor_tables}, "sensors")
    n = table(s, "odometry_noise", "sensors")
    no_unknown(n, {"pos_std_m", "vel_std_mps", "att_std_rad", "rate_std_radps"},
                "sensors.odometry_noise")
    w = "sensors.odometry_noise"
    noise = SensorNoise(
        pos_std_m=number(n, "pos_std_m", w, 0.0, lo=0.0, hi=10.0),
        vel_std_mps=number(n, "vel_std_mps", w, 0.0, lo=0.0, hi=10.0),
        att_std_rad=number(n, "att_std_rad", w, 0.0, lo=0.0, hi=1.0),
        rate_std_radps=number(n, "rate_std_radps", w, 0.0, lo=0.0, hi=10.0),
    )
    wind_spec = parts.wind(table(raw, "wind", ""))
    wind = wind_spec.mean
    faults = parts.faults(table(raw, "faults", ""))
    # your own plant FMU ([vehicle] fmu, fmu_map) or the FMI 3.0 build (fmi = 3); None: ours
    plant = parts.plant(v, vehicle, base_dir, has_wind=any(wind) or not wind_spec.steady)

    # the flight stack's parameters at start (PX4-style names, mav/README.md "Parameters")
    ob = table(raw, "onboard", "")
    no_unknown(ob, {"params"}, "onboard")
    onboard_params = _onboard_params(table(ob, "params", "onboard"), preset)
    sensors = parts.sensors(s, preset)
    if sensors.hil and "odometry_noise" in s:
        raise ScenarioError("sensors.odometry_noise", dict(n),
                            "feed = 'truth' (it is the noise of the truth ODOMETRY; on the "
                            "default feed 'hil' each sensor has its own noise: [sensors.imu] ...)")
    if sensors.hil and faults.odometry:
        raise ScenarioError("faults.odometry", len(faults.odometry),
                            "feed = 'truth' in [sensors] (these are faults of the truth "
                            "ODOMETRY; on the default feed 'hil' use [[faults.sensor]], e.g. "
                            "kind = 'flow_loss')")
    if not sensors.hil and faults.sensors:
        raise ScenarioError("faults.sensor", len(faults.sensors),
                            "feed = 'hil' in [sensors] (these are faults of the sensor "
                            "messages, which the truth feed does not send; on feed = 'truth' "
                            "use [[faults.odometry]], e.g. kind = 'dropout')")
    if sensors.hil:             # the vehicle must run its estimator on the sensor messages
        ekf = dict(onboard_params).get("TPL_EST_TYPE")
        if ekf is None:         # the Mambo: paper 1's own (2); it has no GPS: with one, or on
            # the Bebop 2 (not the release's airframe), the template's with ours (1)
            ekf = EST_RELEASE if preset == "mambo" and not sensors.gps else EST_OURS
            onboard_params += (("TPL_EST_TYPE", ekf),)
        elif ekf < 1.0:
            raise ScenarioError("onboard.params.TPL_EST_TYPE", ekf,
                                "1 or 2 with [sensors] feed = 'hil' (the vehicle gets no "
                                "ODOMETRY)")
        if ekf == EST_RELEASE and sensors.gps:
            raise ScenarioError("onboard.params.TPL_EST_TYPE", ekf,
                                "1 with [sensors.gps] enabled (paper 1's release, 2, fuses no "
                                "GPS)")

    # criteria
    c = table(raw, "criteria", "")
    known = {"must_complete", "landing_error_max_m", "path_rms_max_m", "path_max_m",
             "mission_time_max_s", "position_error_max_m", "final_pose_error_max_m",
             "final_yaw_error_max_deg", "min_clearance_min_m", "coverage_min", "expect_exit",
             "fault_displacement_max_m"}
    no_unknown(c, known, "criteria")

    def opt(key: str) -> float | None:
        return number(c, key, "criteria", lo=0.0, lo_open=True) if key in c else None

    criteria = Criteria(
        must_complete=boolean(c, "must_complete", "criteria", True),
        landing_error_max_m=opt("landing_error_max_m"),
        path_rms_max_m=opt("path_rms_max_m"),
        path_max_m=opt("path_max_m"),
        mission_time_max_s=opt("mission_time_max_s"),
        position_error_max_m=opt("position_error_max_m"),
        final_pose_error_max_m=opt("final_pose_error_max_m"),
        final_yaw_error_max_deg=opt("final_yaw_error_max_deg"),
        min_clearance_min_m=opt("min_clearance_min_m"),
        coverage_min=number(c, "coverage_min", "criteria", lo=0.0, hi=1.0)
        if "coverage_min" in c else None,
        expect_exit=string(c, "expect_exit", "criteria", None,
                           tuple(r.value for r in ExitReason)),
        fault_displacement_max_m=opt("fault_displacement_max_m"),
    )

    # the parts owned by other modules, parsed here once into their records
    world = parts.world(world_table, "world")
    a = world.arena
    if not (a.n_min <= start.n <= a.n_max and a.e_min <= start.e <= a.e_max):
        where = "vehicle.start" if st else "world.start"
        raise ScenarioError(where, {"n": start.n, "e": start.e},
                            f"a start inside the world's arena (N {a.n_min:g} to {a.n_max:g}, "
                            f"E {a.e_min:g} to {a.e_max:g})")
    camera = parts.camera(camera_table, "camera") if camera_table is not None else None
    parts.check_app(app)
    parts.check_inputs(app, camera, source, world.arena, world.scene, vehicle.body_radius)
    return Scenario(
        name=name, description=description, seed=seed, vehicle=vehicle, start=start,
        timing=timing, world=world, camera=camera, app=app, noise=noise,
        wind_ned_mps=wind, criteria=criteria, source=source, raw=raw, world_table=world_table,
        wind=wind_spec,
        faults=faults, onboard_params=onboard_params, plant=plant, sensors=sensors,
        numerics=numerics,
    )


def _onboard_params(p: dict, vehicle: str) -> tuple[tuple[str, float], ...]:
    """`[onboard.params]` NAME = value: each name known to the vehicle's flight stack, each
    value a finite number within the parameter's bounds (a fault names the field)."""
    from mav.params import ParamError, UnknownParamError, check_values, renamed_to, vehicle_table

    pairs = [(k, number(p, k, "onboard.params")) for k in p]
    for k, v in pairs:
        try:
            check_values(vehicle, [(k, v)])
        except UnknownParamError:
            new = renamed_to(k, vehicle_table(vehicle).names())
            want = (f"{new} (the new name of this stack's {k}, whose meaning is not PX4's)"
                    if new else f"a parameter of the {vehicle} flight stack")
            raise ScenarioError(f"onboard.params.{k}", v, want) from None
        except ParamError as exc:
            raise ScenarioError(f"onboard.params.{k}", v,
                                str(exc).split("; ", 1)[-1]) from None
    return tuple(pairs)


def with_set(sc: Scenario, assignments: dict[str, Any], parts: Parts) -> Scenario:
    """A copy of `sc` with dotted-path overrides applied to its TOML and parsed again.

    `{"app.params.alpha": 0.005, "seed": 3}`: the path names keys of the file; for the app's
    parameters `app.X` is accepted as a short form of `app.params.X`.
    """
    raw = copy.deepcopy(sc.raw)
    for path, value in assignments.items():
        keys = path.split(".")
        if keys[0] == "app" and len(keys) == 2 and keys[1] not in ("name", "params"):
            keys = ["app", "params", keys[1]]
        node = raw
        for k in keys[:-1]:
            node = node.setdefault(k, {})
            if not isinstance(node, dict):
                raise ScenarioError(path, value, "a path through tables of the scenario")
        node[keys[-1]] = value
    return parse_scenario(raw, parts, source=sc.source, base_dir=Path(sc.source).parent)
