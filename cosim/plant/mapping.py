"""Your own plant FMU: the scenario's map from an FMU's variables, frames and units to the
master's, parsed and checked once when the scenario loads.

A scenario names any FMI 2.0 or 3.0 Co-Simulation FMU as the plant and says how it talks::

    [vehicle]
    preset = "mambo"                 # the airframe the flight stack flies (and the parameters)
    fmu = "plants/EnuQuad.fmu"       # relative to the scenario file
    fmu_timeout_s = 10.0             # the longest one call into it may take (default 10 s):
                                     # it runs in a process of its own (cosim/plant/isolated.py)

    [vehicle.fmu_map]
    world = "ENU"          # its world frame: NED (default) or ENU
    body = "FLU"           # its body frame: FRD (default) or FLU
    attitude = "euler"     # quaternion (qw qx qy qz, body -> world; default) or euler (roll,
                           # pitch, yaw: z-y-x, body axes relative to its world frame)
    acceleration = "world" # body (default: specific force in body axes, an accelerometer) or
                           # world (kinematic acceleration in its world frame)
    command = "rotors"     # rotors (default: u1..u4, PX4 quad-X numbering) or wrench
                           # (thrust along body up, N; tau_x, tau_y, tau_z in its body axes, N m)

    [vehicle.fmu_map.inputs]            # the master's quantity = the FMU's variable
    u1 = "w_front_right"                # or { name = "...", unit = "rpm" }
    wind_x = "wind_e"                   # optional: wind in its world frame (m/s)

    [vehicle.fmu_map.outputs]
    x = "pos_x"                         # position, velocity, attitude, body rates and
    roll = { name = "phi", unit = "deg" }   # acceleration in ITS frames; optional: omega1..4,
                                            # on_ground
    [vehicle.fmu_map.parameters]
    m = "mass"        # a string: the preset's field of that name; a number: as it is

    [vehicle.fmu_map.start]             # optional: its parameters that take the start pose
    x = "x0"                            # (else the master puts its origin at [vehicle.start]
    y = "y0"                            # and turns its x axis, the heading it starts with,
    yaw = "psi0"                        # to the start's yaw)

Units: a variable's unit is the one given in the map, else the one the FMU declares (its
UnitDefinitions give the factor to SI), else SI. A rotor input with the unit of an angular
velocity takes the rotor speed command u * omega_max; a dimensionless one takes u (0..1).
Every name is checked against the FMU's model description here: a missing variable, a
variable of the wrong causality or type, or a unit of the wrong dimension raises
`ScenarioError` naming the field (the CLI exits with status 2).

`[vehicle] fmi = 3` flies the project's own plant built as FMI 3.0 (`OWN_MAP`).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.errors import ScenarioError
from cosim.plant import fmufile
from cosim.scenario.validate import no_unknown, number, string, table

# dimensions as (kg, m, s) exponents (radians count as dimensionless)
LENGTH, VELOCITY, ACCEL = (0, 1, 0), (0, 1, -1), (0, 1, -2)
ANGLE, RATE, ONE = (0, 0, 0), (0, 0, -1), (0, 0, 0)
FORCE, TORQUE = (1, 1, -2), (1, 2, -2)

#: units the map may name when the FMU does not define them: name -> (dimension, factor to
#: SI, offset)
UNITS: dict[str, tuple[tuple[int, int, int], float, float]] = {
    "1": (ONE, 1.0, 0.0), "%": (ONE, 0.01, 0.0),
    "rad": (ANGLE, 1.0, 0.0), "deg": (ANGLE, math.pi / 180.0, 0.0),
    "m": (LENGTH, 1.0, 0.0), "cm": (LENGTH, 0.01, 0.0), "mm": (LENGTH, 0.001, 0.0),
    "m/s": (VELOCITY, 1.0, 0.0), "km/h": (VELOCITY, 1.0 / 3.6, 0.0),
    "rad/s": (RATE, 1.0, 0.0), "deg/s": (RATE, math.pi / 180.0, 0.0),
    "rpm": (RATE, math.pi / 30.0, 0.0), "1/s": (RATE, 1.0, 0.0),
    "m/s2": (ACCEL, 1.0, 0.0), "g": (ACCEL, 9.80665, 0.0),
    "N": (FORCE, 1.0, 0.0), "N.m": (TORQUE, 1.0, 0.0),
}

WORLDS, BODIES = ("NED", "ENU"), ("FRD", "FLU")
ATTITUDES, ACCELERATIONS, COMMANDS = ("quaternion", "euler"), ("body", "world"), \
    ("rotors", "wrench")

_POS = {"x": LENGTH, "y": LENGTH, "z": LENGTH, "vx": VELOCITY, "vy": VELOCITY,
        "vz": VELOCITY, "p": RATE, "q": RATE, "r": RATE, "ax": ACCEL, "ay": ACCEL,
        "az": ACCEL}
_QUAT = {"qw": ONE, "qx": ONE, "qy": ONE, "qz": ONE}
_EULER = {"roll": ANGLE, "pitch": ANGLE, "yaw": ANGLE}
_OPTIONAL_OUT = {"omega1": RATE, "omega2": RATE, "omega3": RATE, "omega4": RATE,
                 "on_ground": None}
_ROTORS = {"u1": None, "u2": None, "u3": None, "u4": None}   # ONE or RATE
_WRENCH = {"thrust": FORCE, "tau_x": TORQUE, "tau_y": TORQUE, "tau_z": TORQUE}
_WIND = {"wind_x": VELOCITY, "wind_y": VELOCITY, "wind_z": VELOCITY}
_START = {"x": LENGTH, "y": LENGTH, "yaw": ANGLE}
_INTEGER_TYPES = ("Integer", "Enumeration", "Int8", "UInt8", "Int16", "UInt16", "Int32",
                  "UInt32", "Int64", "UInt64")


@dataclass(frozen=True)
class Var:
    """One mapped variable: SI value = factor * FMU value + offset."""

    name: str
    vr: int
    factor: float = 1.0
    offset: float = 0.0
    dim: tuple[int, int, int] = ONE

    @property
    def identity(self) -> bool:
        return self.factor == 1.0 and self.offset == 0.0


@dataclass(frozen=True)
class PlantMap:
    """How an FMU talks to the master (module docstring); `inputs`/`outputs` keyed by the
    master's quantities in the FMU's own frames."""

    world: str = "NED"
    body: str = "FRD"
    attitude: str = "quaternion"
    acceleration: str = "body"
    command: str = "rotors"
    inputs: dict[str, Var] = field(default_factory=dict)
    outputs: dict[str, Var] = field(default_factory=dict)
    parameters: tuple[tuple[str, int, Any], ...] = ()   # (FMU name, vr, number or preset field)
    start: dict[str, Var] = field(default_factory=dict)


TIMEOUT_S = 10.0         # s: the default of [vehicle] fmu_timeout_s
TIMEOUT_MAX_S = 3600.0


@dataclass(frozen=True)
class PlantSpec:
    """The scenario's plant when it is not the default: an FMU and its map."""

    fmu: Path | None          # None: the project's own plant, built as FMI `fmi`
    fmi: int                  # 2 or 3 (read from the FMU for a user's FMU)
    map: PlantMap | None      # None: OWN_MAP (built when the FMU is, its value references)
    timeout_s: float = TIMEOUT_S   # s: a user's FMU (its own process) answers within this


def _own_names() -> tuple[dict[str, str], dict[str, str]]:
    from cosim.plant.fmu import OUTPUT_NAMES

    outs = {n: n for n in OUTPUT_NAMES}
    ins = {"u1": "u1", "u2": "u2", "u3": "u3", "u4": "u4",
           "wind_x": "wind_n", "wind_y": "wind_e", "wind_z": "wind_d"}
    return ins, outs


def own_map(md, vehicle) -> PlantMap:
    """The map of the project's own plant (NED, FRD, quaternion, accelerometer, rotors; the
    preset's parameters and the start pose set as its parameters): checked like a user's."""
    ins, outs = _own_names()
    raw = {"inputs": ins, "outputs": outs,
           "parameters": {k: k for k in vehicle.fmu_parameters()},
           "start": {"x": "x0", "y": "y0", "yaw": "yaw0"}}
    return check_map(raw, md, vehicle, "vehicle.fmi")


# ------------------------------------------------------------------ parsing and checks
def parse_plant(v: dict, vehicle, base_dir: Path, has_wind: bool) -> PlantSpec | None:
    """`[vehicle] fmu`, `fmi` and `[vehicle.fmu_map]` -> a PlantSpec (None: the default
    plant). The FMU's model description is read and every name checked against it."""
    if "fmu" not in v:
        for k in ("fmu_map", "fmu_timeout_s"):
            if k in v:
                raise ScenarioError(f"vehicle.{k}", v[k], "only with vehicle.fmu (a user's FMU)")
        fmi = v.get("fmi", 2)
        if isinstance(fmi, bool) or fmi not in (2, 3):
            raise ScenarioError("vehicle.fmi", fmi, "2 or 3 (the FMI version of the "
                                                    "project's own plant)")
        return None if fmi == 2 else PlantSpec(fmu=None, fmi=3, map=None)
    if "fmi" in v:
        raise ScenarioError("vehicle.fmi", v["fmi"], "no fmi with vehicle.fmu (the FMU says "
                                                     "its version)")
    f = v["fmu"]
    if not isinstance(f, str) or not f:
        raise ScenarioError("vehicle.fmu", f, "a path to an .fmu file")
    path = Path(f) if Path(f).is_absolute() else base_dir / f
    md = read_description(path, "vehicle.fmu", f)
    m = table(v, "fmu_map", "vehicle", required=True)
    pmap = check_map(m, md, vehicle, "vehicle.fmu_map")
    if has_wind and not {"wind_x", "wind_y", "wind_z"} <= set(pmap.inputs):
        raise ScenarioError("vehicle.fmu_map.inputs", sorted(pmap.inputs),
                            "wind_x, wind_y and wind_z mapped: the scenario has [wind]")
    timeout = number(v, "fmu_timeout_s", "vehicle", TIMEOUT_S, lo=0.0, hi=TIMEOUT_MAX_S,
                     lo_open=True)
    return PlantSpec(fmu=path.resolve(), fmi=int(md.fmiVersion[0]), map=pmap,
                     timeout_s=timeout)


def read_description(path: Path, where: str, given: Any):
    """The model description of a Co-Simulation FMU (ScenarioError if it is none)."""
    if not path.is_file():
        raise ScenarioError(where, given, f"an existing .fmu file (looked for {path})")
    try:
        md = fmufile.model_description(path, validate=False)
    except Exception as exc:         # not a zip, no or a malformed modelDescription.xml
        raise ScenarioError(where, given, f"an FMU with a readable modelDescription.xml "
                                          f"({type(exc).__name__}: {exc})") from None
    if md.fmiVersion not in ("2.0", "3.0") or md.coSimulation is None:
        raise ScenarioError(where, given, f"an FMI 2.0 or 3.0 Co-Simulation FMU (it is FMI "
                                          f"{md.fmiVersion}, Co-Simulation: "
                                          f"{md.coSimulation is not None})")
    try:               # its binary for this platform, what a run extracts within the limits
        fmufile.check(path, int(md.fmiVersion[0]), md.coSimulation.modelIdentifier)
    except fmufile.FmuFileError as exc:
        raise ScenarioError(where, given, str(exc)) from None
    return md


def check_map(m: dict, md, vehicle, where: str) -> PlantMap:
    """The `[vehicle.fmu_map]` table checked against the model description `md`."""
    no_unknown(m, {"world", "body", "attitude", "acceleration", "command", "inputs",
                   "outputs", "parameters", "start"}, where)
    world = string(m, "world", where, "NED", WORLDS)
    body = string(m, "body", where, "FRD", BODIES)
    attitude = string(m, "attitude", where, "quaternion", ATTITUDES)
    acceleration = string(m, "acceleration", where, "body", ACCELERATIONS)
    command = string(m, "command", where, "rotors", COMMANDS)
    variables = {v.name: v for v in md.modelVariables}
    units = {u.name: u for u in (md.unitDefinitions or [])}

    def var(tbl: dict, key: str, w: str, dim, causalities: tuple[str, ...],
            boolean: bool = False) -> Var:
        spec = tbl[key]
        f = f"{w}.{key}"
        unit = None
        if isinstance(spec, dict):
            no_unknown(spec, {"name", "unit"}, f)
            name = string(spec, "name", f)
            unit = string(spec, "unit", f, None)
        elif isinstance(spec, str):
            name = spec
        else:
            raise ScenarioError(f, spec, "the FMU's variable name, or { name = ..., unit = ... }")
        mv = variables.get(name)
        if mv is None:
            raise ScenarioError(f, name, f"a variable of the FMU ({_some(variables, name)})")
        if mv.causality not in causalities:
            raise ScenarioError(f, name, f"a variable with causality {' or '.join(causalities)}"
                                         f" (it is {mv.causality})")
        types = ("Boolean",) if boolean else ("Real", "Float64")
        if mv.type not in types:
            raise ScenarioError(f, name, f"a {' or '.join(types)} variable (it is {mv.type})")
        if boolean:
            return Var(name, mv.valueReference)
        if unit is None:
            unit = mv.unit or (mv.declaredType.unit if mv.declaredType is not None else None)
        d, factor, offset = _unit(unit, units, f, name)
        if dim is None:          # rotor commands: normalised or a rotor speed
            dim = RATE if d == RATE else ONE
        if d is not None and d != dim:    # no unit at all: SI
            raise ScenarioError(f, name, f"a variable in a unit of {_dim_name(dim)} (its unit "
                                         f"{unit!r} is {_dim_name(d)})")
        return Var(name, mv.valueReference, factor, offset, dim)

    def group(w_key: str, wanted: dict, required: set[str], causalities: tuple[str, ...]):
        w = f"{where}.{w_key}"
        tbl = table(m, w_key, where, required=bool(required))
        no_unknown(tbl, set(wanted), w)
        missing = sorted(required - set(tbl))
        if missing:
            raise ScenarioError(f"{w}.{missing[0]}", None,
                                f"the FMU's variable for {missing[0]} (required: "
                                f"{', '.join(sorted(required))})")
        return {k: var(tbl, k, w, wanted[k], causalities, boolean=k == "on_ground")
                for k in tbl}

    cmd = _ROTORS if command == "rotors" else _WRENCH
    inputs = group("inputs", {**cmd, **_WIND}, set(cmd), ("input",))
    wind = sorted(set(inputs) & set(_WIND))
    if wind and len(wind) != len(_WIND):
        raise ScenarioError(f"{where}.inputs", wind, "all of wind_x, wind_y and wind_z, or none")
    att = _QUAT if attitude == "quaternion" else _EULER
    outputs = group("outputs", {**_POS, **att, **_OPTIONAL_OUT}, set(_POS) | set(att),
                    ("output",))
    start = group("start", _START, set(), ("parameter",))
    if start and set(start) != set(_START):
        raise ScenarioError(f"{where}.start", sorted(start), "all of x, y and yaw, or none")

    p = table(m, "parameters", where)
    fields = set(vehicle.fmu_parameters()) | {"body_radius"}
    params = []
    for k, val in p.items():
        f = f"{where}.parameters.{k}"
        mv = variables.get(k)
        if mv is None or mv.causality != "parameter":
            params_of = {n: mv for n, mv in variables.items() if mv.causality == "parameter"}
            raise ScenarioError(f, val, f"a parameter of the FMU ({_some(params_of, k)})")
        if isinstance(val, str):
            if val not in fields:
                raise ScenarioError(f, val, f"a number, or a field of the preset "
                                            f"({', '.join(sorted(fields))})")
        elif mv.type == "Boolean":
            if not isinstance(val, bool):
                raise ScenarioError(f, val, "true or false (a Boolean parameter)")
        elif mv.type in ("Real", "Float64"):
            val = number(p, k, f"{where}.parameters")
        elif mv.type not in _INTEGER_TYPES:
            raise ScenarioError(f, val, f"a Real, Boolean or integer parameter (it is "
                                        f"{mv.type})")
        elif isinstance(val, bool) or not isinstance(val, int):
            raise ScenarioError(f, val, f"an integer (a {mv.type} parameter)")
        params.append((k, mv.valueReference, val))
    return PlantMap(world=world, body=body, attitude=attitude, acceleration=acceleration,
                    command=command, inputs=inputs, outputs=outputs,
                    parameters=tuple(params), start=start)


def _unit(unit: str | None, defined: dict, f: str, name: str):
    if unit is None:
        return None, 1.0, 0.0
    u = defined.get(unit)
    if u is not None and u.baseUnit is not None:
        b = u.baseUnit
        if b.A or b.K or b.mol or b.cd:
            raise ScenarioError(f, name, f"a mechanical unit (its unit {unit!r} is not)")
        return (b.kg, b.m, b.s), float(b.factor), float(b.offset)
    if unit in UNITS:
        return UNITS[unit]
    raise ScenarioError(f, name, f"a variable whose unit is known: the FMU does not define "
                                 f"{unit!r}; name one in the map ({', '.join(UNITS)})")


def _dim_name(d) -> str:
    names = {LENGTH: "length (m)", VELOCITY: "velocity (m/s)", ACCEL: "acceleration (m/s2)",
             ONE: "angle or 1", RATE: "angular velocity (rad/s)", FORCE: "force (N)",
             TORQUE: "torque (N.m)", None: "no unit (SI assumed)"}
    return names.get(d, f"kg^{d[0]} m^{d[1]} s^{d[2]}")


def _some(variables: dict, name: str) -> str:
    """What the FMU has: the names closest to `name` first."""
    close = difflib.get_close_matches(name, list(variables), n=3, cutoff=0.5)
    names = close + [n for n in sorted(variables) if n not in close]
    more = f", ... {len(names) - 12} more" if len(names) > 12 else ""
    return ("did you mean " + " or ".join(close) + "? " if close else "") + "it has " + \
        ", ".join(names[:12]) + more
