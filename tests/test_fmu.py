"""The Quadrotor FMU through fmpy: model description, CS and ME, errors, build, golden output."""

from __future__ import annotations

import csv
import ctypes
import math
import re
import shutil
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Model,
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.logging import addLoggerProxy
from fmpy.validation import validate_fmu

from cosim.plant.fmu import OUTPUT_NAMES
from cosim.scenario.vehicles import BEBOP2, MAMBO, PRESETS
from fmus import build as fb

SRC = Path(fb.SOURCE_DIR)


@pytest.fixture(scope="module")
def fmu() -> Path:
    return fb.fmu_path()


@pytest.fixture(scope="module")
def md(fmu):
    return read_model_description(str(fmu))


@pytest.fixture(scope="module")
def unzipdir(fmu):
    d = extract(str(fmu))
    yield d
    shutil.rmtree(d, ignore_errors=True)


class Instance:
    """An fmpy FMU2Slave/FMU2Model with a logger that collects the FMU's messages."""

    def __init__(self, md, unzipdir, kind="cs"):
        cls = FMU2Slave if kind == "cs" else FMU2Model
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.messages: list[str] = []
        self.fmu = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier="Quadrotor",
                       instanceName="test")
        self._logger = fmi2CallbackLoggerTYPE(
            lambda env, name, status, cat, msg: self.messages.append(msg.decode())
        )
        cb = fmi2CallbackFunctions()
        cb.logger = self._logger
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        addLoggerProxy(ctypes.byref(cb))
        self._cb = cb
        self.fmu.instantiate(callbacks=cb)

    def set(self, **values):
        self.fmu.setReal([self.vr[k] for k in values], [float(v) for v in values.values()])

    def get(self, *names):
        return self.fmu.getReal([self.vr[n] for n in names])

    def init(self, **values):
        if values:
            self.set(**values)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def close(self):
        self.fmu.freeInstance()


@pytest.fixture
def make(md, unzipdir):
    made = []

    def _make(kind="cs"):
        inst = Instance(md, unzipdir, kind)
        made.append(inst)
        return inst

    yield _make
    for inst in made:
        inst.close()


# ---- model description -------------------------------------------------------------------


def test_validate_fmu_finds_no_problem(fmu):
    assert validate_fmu(str(fmu)) == []


def test_both_interfaces_in_one_binary(md):
    assert md.coSimulation.modelIdentifier == "Quadrotor"
    assert md.modelExchange.modelIdentifier == "Quadrotor"
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert md.numberOfContinuousStates == 17
    assert md.numberOfEventIndicators == 1


def test_value_references_match_the_c_sources(md):
    """modelDescription.xml and config.h/model.c must agree on every value reference."""
    text = (SRC / "model.c").read_text()
    names_block = text[text.index("NAMES[N_VR] = {"):text.index("};", text.index("NAMES[N_VR]"))]
    c_names = re.findall(r'"([^"]+)"', names_block)
    xml = {v.valueReference: v.name for v in md.modelVariables}
    assert len(c_names) == len(xml) == len(md.modelVariables)
    assert [xml[i] for i in range(len(c_names))] == c_names


def test_interface_names_units_and_causality(md):
    var = {v.name: v for v in md.modelVariables}
    for n in ("u1", "u2", "u3", "u4", "wind_n", "wind_e", "wind_d"):
        assert var[n].causality == "input" and var[n].variability == "continuous"
        assert var[n].start in ("0", 0.0, 0)
    for n in OUTPUT_NAMES:
        assert var[n].causality == "output", n
    assert var["on_ground"].type == "Boolean"
    params = {v.name for v in md.modelVariables if v.causality == "parameter"}
    for v in PRESETS.values():
        assert set(v.fmu_parameters()) <= params
    assert {"x0", "y0", "z0", "yaw0", "omega0", "substep", "contact_omega", "contact_zeta",
            "contact_friction", "contact_omega_att"} <= params
    units = {u.name for u in md.unitDefinitions}
    for v in md.modelVariables:
        if v.type == "Real" and v.causality != "independent":
            unit = v.unit or (v.declaredType.unit if v.declaredType else None)
            assert unit in units, f"{v.name} has no declared unit"
    assert var["mass"].declaredType.unit == "kg"
    assert var["k_thrust"].declaredType.unit == "N.s2/rad2"


def test_fmu_start_values_are_the_mambo_preset(md):
    var = {v.name: v for v in md.modelVariables}
    for name, value in MAMBO.fmu_parameters().items():
        assert float(var[name].start) == pytest.approx(value, rel=1e-12), name


def test_no_direct_feedthrough_from_motor_commands(md):
    u_vars = {v for v in md.modelVariables if v.name in ("u1", "u2", "u3", "u4")}
    for out in md.outputs:
        assert out.dependencies is not None, f"{out.variable.name}: dependencies not declared"
        assert not (set(out.dependencies) & u_vars), out.variable.name
    # u_i only drives its own rotor: der(omega_i) depends on u_i and omega_i
    for der in md.derivatives:
        name = der.variable.name
        deps = {v.name for v in der.dependencies}
        if name.startswith("der(omega"):
            i = name[-2]
            assert deps == {f"u{i}", f"omega{i}"}
        else:
            assert not deps & {"u1", "u2", "u3", "u4"}, name


# ---- simulation through fmpy ---------------------------------------------------------------


@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
def test_simulate_fmu_rests_on_the_floor(fmu, fmi_type):
    r = fmpy.simulate_fmu(str(fmu), fmi_type=fmi_type, stop_time=2.0, output_interval=0.01,
                          output=["z", "az", "on_ground"])
    assert np.all(np.abs(r["z"]) < 1e-3)
    assert np.allclose(r["az"], -9.81, atol=1e-9)
    assert np.all(r["on_ground"])


def _schedule(v):
    """10 s manoeuvre: take off from the floor, roll/pitch doublets, yaw step, descend, land."""
    uh, d = v.u_hover, 0.01
    roll, pitch, yaw = (-1, 1, 1, -1), (1, -1, 1, -1), (1, 1, -1, -1)

    def doublet(t0, s):
        return [(t0, tuple(uh + d * x for x in s)), (t0 + 0.05, tuple(uh - d * x for x in s)),
                (t0 + 0.15, tuple(uh + d * x for x in s)), (t0 + 0.2, (uh,) * 4)]

    return ([(0.0, (0.0,) * 4), (0.5, (0.72,) * 4), (1.5, (uh,) * 4)] + doublet(2.0, roll)
            + doublet(3.0, pitch) + [(4.0, tuple(uh + d * x for x in yaw)), (4.5, (uh,) * 4),
                                     (6.0, (0.66,) * 4), (9.0, (0.0,) * 4)])


def test_model_exchange_cvode_agrees_with_cosimulation_rk4(fmu):
    """Same 10 s manoeuvre two ways. In flight (t < 8.9 s): position within 1 mm, velocity
    1 mm/s, quaternion 1e-5, body rates 1e-3 rad/s, rotor speeds 1e-3 rad/s. After landing
    (t >= 9.5 s, at rest): position within 1 mm, both on the ground."""
    from cosim.plant.fmu import Plant

    h, T = 0.005, 10.0
    sched = _schedule(MAMBO)

    def u_at(t):
        return [u for ts, u in sched if t >= ts][-1]

    with Plant(MAMBO, step_size=h, fmu_path=fmu) as plant:
        cs = [list(plant.y)]
        for k in range(round(T / h)):
            cs.append(list(plant.step(*u_at((k + 0.5) * h))))
    cs = np.array(cs)

    rows = []
    for i, (ts, u) in enumerate(sched):
        if i:
            rows.append((ts, *sched[i - 1][1], 0.0, 0.0, 0.0))
        rows.append((ts, *u, 0.0, 0.0, 0.0))
    rows.append((T, *sched[-1][1], 0.0, 0.0, 0.0))
    sig = np.array(rows, dtype=[(n, float) for n in
                                ("time", "u1", "u2", "u3", "u4", "wind_n", "wind_e", "wind_d")])
    r = fmpy.simulate_fmu(str(fmu), fmi_type="ModelExchange", solver="CVode", stop_time=T,
                          output_interval=h, input=sig, relative_tolerance=1e-8,
                          record_events=False, output=list(OUTPUT_NAMES),
                          start_values=MAMBO.fmu_parameters())
    me = np.column_stack([r[n].astype(float) for n in OUTPUT_NAMES])
    assert me.shape == cs.shape
    assert cs[:, 2].min() < -1.0  # it did fly

    t = np.arange(cs.shape[0]) * h
    fly = t < 8.9
    tol = {"x": 1e-3, "y": 1e-3, "z": 1e-3, "vx": 1e-3, "vy": 1e-3, "vz": 1e-3,
           "qw": 1e-5, "qx": 1e-5, "qy": 1e-5, "qz": 1e-5, "p": 1e-3, "q": 1e-3, "r": 1e-3,
           "omega1": 1e-3, "omega2": 1e-3, "omega3": 1e-3, "omega4": 1e-3}
    for name, atol in tol.items():
        i = OUTPUT_NAMES.index(name)
        err = np.abs(me[fly, i] - cs[fly, i]).max()
        assert err < atol, f"{name}: max |ME - CS| = {err:g} >= {atol:g} in flight"
    rest = t >= 9.5
    for name in ("x", "y", "z"):
        i = OUTPUT_NAMES.index(name)
        assert np.abs(me[rest, i] - cs[rest, i]).max() < 1e-3, name
    assert cs[rest, OUTPUT_NAMES.index("on_ground")].all()
    assert me[rest, OUTPUT_NAMES.index("on_ground")].all()


# ---- Co-Simulation details ------------------------------------------------------------------


def test_dostep_is_made_of_substeps(make):
    """doStep(5 ms) = five 1 ms RK4 substeps; doStep(2.5 ms) = 1 + 1 + 0.5 ms (bit for bit)."""
    names = ["x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r",
             "omega1", "omega2", "omega3", "omega4"]
    cmd = dict(u1=0.8, u2=0.7, u3=0.75, u4=0.72)

    def run(steps):
        inst = make("cs")
        inst.init()
        inst.set(**cmd)
        t = 0.0
        for h in steps:
            inst.fmu.doStep(t, h)
            t += h
        return inst.get(*names)

    assert run([0.005] * 20) == run([0.001] * 100)
    assert run([0.0025] * 4) == run([0.001, 0.001, 0.0005] * 4)
    assert run([0.0025] * 4) != run([0.005] * 2)  # a different grid is a different result


def test_fmu_state_serialisation_round_trip(make):
    inst = make("cs")
    inst.init(z0=-1.0, omega0=MAMBO.omega_hover)
    inst.set(u1=0.7, u2=0.69, u3=0.68, u4=0.71)
    for k in range(50):
        inst.fmu.doStep(k * 0.005, 0.005)
    state = inst.fmu.getFMUstate()
    blob = inst.fmu.serializeFMUstate(state)
    inst.fmu.freeFMUstate(state)
    for k in range(50, 150):
        inst.fmu.doStep(k * 0.005, 0.005)
    ref = inst.get(*OUTPUT_NAMES[:-1])
    state = inst.fmu.deSerializeFMUstate(blob)
    inst.fmu.setFMUstate(state)
    inst.fmu.freeFMUstate(state)
    for k in range(50, 150):
        inst.fmu.doStep(k * 0.005, 0.005)
    assert inst.get(*OUTPUT_NAMES[:-1]) == ref


# ---- errors -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("mass", -1.0, "fmi2SetReal: parameter 'mass' must be > 0, got -1"),
        ("Ixx", 0.0, "fmi2SetReal: parameter 'Ixx' must be > 0, got 0"),
        ("Izz", 0.0, "fmi2SetReal: parameter 'Izz' must be > 0, got 0"),
        ("motor_tau", 0.0, "fmi2SetReal: parameter 'motor_tau' must be > 0, got 0"),
        ("drag_xy", -0.1, "fmi2SetReal: parameter 'drag_xy' must be >= 0, got -0.1"),
        ("substep", 0.002, "parameter 'substep' must be in [1e-06, 0.001] s, got 0.002"),
        # issue 14 item 8: a tiny substep (a hang per doStep), wind of 1e300 (positions of
        # 4e297), start positions beyond the planet
        ("substep", 1e-9, "parameter 'substep' must be in [1e-06, 0.001] s, got 1e-09"),
        ("wind_n", 1e300, "input 'wind_n' must be within +-100 m/s, got 1e+300"),
        ("wind_d", -101.0, "input 'wind_d' must be within +-100 m/s, got -101"),
        ("x0", 1e9, "parameter 'x0' must be within +-1e+06 m, got 1e+09"),
        ("mass", math.inf, "parameter 'mass' must be finite, got inf"),
    ],
)
def test_bad_parameter_values_are_refused_with_a_message(make, name, value, message):
    inst = make("cs")
    with pytest.raises(FMICallException):
        inst.set(**{name: value})
    assert any(message in m for m in inst.messages), inst.messages


def test_a_huge_step_is_an_error_not_a_hang(make):
    """Issue 14 item 8: doStep(h=1e6) ran 1e9 substeps; now the work per step is bounded."""
    inst = make("cs")
    inst.init()
    with pytest.raises(FMICallException):
        inst.fmu.doStep(0.0, 1e6)
    assert any("needs more than 10000 substeps" in m for m in inst.messages), inst.messages


def test_nan_input_is_an_error(make):
    inst = make("cs")
    inst.init()
    with pytest.raises(FMICallException):
        inst.set(u3=math.nan)
    assert any("fmi2SetReal: input 'u3' must be a number, got NaN" in m for m in inst.messages)


def test_calls_in_the_wrong_state_are_errors(make):
    inst = make("cs")
    with pytest.raises(FMICallException):
        inst.fmu.doStep(0.0, 0.005)
    assert any("fmi2DoStep: not allowed in state Instantiated" in m for m in inst.messages)
    inst.init()
    with pytest.raises(FMICallException):
        inst.set(mass=0.1)
    assert any("parameter 'mass' is fixed and cannot be set in state StepComplete" in m
               for m in inst.messages)


def test_time_mismatch_and_omega0_limit_are_errors(make):
    inst = make("cs")
    inst.init()
    with pytest.raises(FMICallException):
        inst.fmu.doStep(1.0, 0.005)
    assert any("does not match the FMU time" in m for m in inst.messages)
    inst = make("cs")
    inst.set(omega0=3000.0)
    inst.fmu.setupExperiment(startTime=0.0)
    inst.fmu.enterInitializationMode()
    with pytest.raises(FMICallException):
        inst.fmu.exitInitializationMode()
    assert any("'omega0' (3000 rad/s) must not exceed 'omega_max'" in m for m in inst.messages)


def test_interface_functions_check_the_instance_kind(make):
    me = make("me")
    me.init()
    do_step = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                               ctypes.c_int)(("fmi2DoStep", me.fmu.dll))
    assert do_step(me.fmu.component, 0.0, 0.005, 1) == 3  # fmi2Error
    assert any("fmi2DoStep: only for Co-Simulation instances" in m for m in me.messages)
    cs = make("cs")
    cs.init()
    set_time = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double)(
        ("fmi2SetTime", cs.fmu.dll))
    assert set_time(cs.fmu.component, 0.0) == 3
    assert any("not allowed in state StepComplete" in m for m in cs.messages)


# ---- build ----------------------------------------------------------------------------------


def test_build_is_deterministic(tmp_path):
    a = fb.build(force=True, out_dir=tmp_path / "a").read_bytes()
    b = fb.build(force=True, out_dir=tmp_path / "b").read_bytes()
    assert a == b
    assert a == fb.fmu_path().read_bytes()


def test_build_is_skipped_when_nothing_changed(tmp_path):
    p = fb.build(out_dir=tmp_path)
    mtime = p.stat().st_mtime_ns
    assert fb.build(out_dir=tmp_path) == p
    assert p.stat().st_mtime_ns == mtime
    (tmp_path / "Quadrotor.fmu.sha256").write_text("stale\n")
    fb.build(out_dir=tmp_path)
    assert (tmp_path / "Quadrotor.fmu.sha256").read_text().split()[0] == fb.source_hash()


def test_missing_gcc_gives_a_clear_message(monkeypatch, tmp_path):
    monkeypatch.setattr(fb.shutil, "which", lambda name: None)
    msg = r"gcc not found: install it with `apt-get install gcc`"
    with pytest.raises(fb.BuildError, match=msg):
        fb.build(force=True, out_dir=tmp_path)


def test_fmu_path_is_under_the_repo_build_dir():
    assert fb.fmu_path(build_if_needed=False) == Path(fb.REPO_ROOT) / "build" / "Quadrotor.fmu"
    assert (Path(fb.REPO_ROOT) / "fmus" / "build.py").is_file()


# ---- golden output ------------------------------------------------------------------------


def test_golden_output(fmu):
    """Regression against fmus/quadrotor/Quadrotor_out.csv: |y - y_ref| <= 1e-6 + 1e-6 |y_ref|
    for every output at every 50 Hz sample. Regenerate with `python -m fmus.build --golden`."""
    with open(fb.GOLDEN_CSV) as f:
        reader = csv.reader(f)
        header = next(reader)
        ref = np.array([[float(x) for x in row] for row in reader])
    assert header == ["time", *fb.GOLDEN_OUTPUTS]
    got = np.array(fb.golden_run(fmu))
    assert got.shape == ref.shape == (251, 22)
    bad = ~np.isclose(got, ref, rtol=1e-6, atol=1e-6)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        pytest.fail(f"{header[j]} at t = {ref[i, 0]} s: {got[i, j]!r} vs golden {ref[i, j]!r}")
    # the trace exercises what it claims: take-off, flight above 2 m, a landing, rest
    z = ref[:, header.index("z")]
    on = ref[:, header.index("on_ground")]
    assert on[0] == 1 and on[-1] == 1 and z.min() < -2.0 and not on[100]


def test_bebop2_parameters_run_in_the_fmu(make):
    inst = make("cs")
    inst.init(**BEBOP2.fmu_parameters(), z0=-1.0, omega0=BEBOP2.omega_hover)
    u = BEBOP2.u_hover
    inst.set(u1=u, u2=u, u3=u, u4=u)
    for k in range(200):
        inst.fmu.doStep(k * 0.005, 0.005)
    x, y, z = inst.get("x", "y", "z")
    assert abs(z + 1.0) < 1e-6 and abs(x) < 1e-9 and abs(y) < 1e-9


def test_builds_go_where_cosim_build_dir_says(monkeypatch, tmp_path):
    from onesource import switch as compiled
    assert compiled.CHECKOUT and compiled.build_root() == Path(fb.REPO_ROOT) / "build"
    monkeypatch.setenv("COSIM_BUILD_DIR", str(tmp_path))
    assert compiled.build_root() == tmp_path
