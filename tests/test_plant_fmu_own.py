"""Your own plant FMU: the FMI 3.0 build of our plant and a PythonFMU-built quadrotor (another
toolchain, other names, ENU/FLU, Euler angles in degrees) fly the scripted square and the seed
mission through the scenario's map; the map's mistakes are errors naming the field."""

from __future__ import annotations

import copy
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from cosim.errors import ComponentError, ScenarioError
from cosim.load import load_scenario, parse_scenario
from cosim.outputs.report import summarize
from cosim.plant.fmu import Plant
from cosim.plant.mapped import (
    MappedPlant,
    attitude_to_ned_frd,
    body_swap,
    world_swap,
)
from cosim.plant.mapping import PlantSpec
from cosim.scenario.vehicles import MAMBO
from cosim.sim.master import RunOptions, run_scenario
from fmus import build as fb
from mav.rotations import quat_from_euler, rotate_world_to_body

ROOT = Path(__file__).resolve().parent.parent
SCEN = ROOT / "scenarios"
PLANTS = Path(__file__).parent / "plants"


@pytest.fixture(scope="module")
def enu_fmu(tmp_path_factory) -> Path:
    """The PythonFMU test plant, exported into a temporary folder (never committed)."""
    pytest.importorskip("pythonfmu")
    out = tmp_path_factory.mktemp("pythonfmu")
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                    str(PLANTS / "EnuQuad.py"), "-d", str(out)], check=True, cwd=out,
                   capture_output=True)
    return out / "EnuQuad.fmu"


def enu_map() -> dict:
    return tomllib.loads((PLANTS / "enu_quad_map.toml").read_text())["vehicle"]["fmu_map"]


def scenario_on(name: str, fmu: Path, fmu_map: dict, **vehicle):
    raw = tomllib.loads((SCEN / name).read_text())
    raw["vehicle"].update(fmu=str(fmu), fmu_map=fmu_map, **vehicle)
    return parse_scenario(raw, source=str(SCEN / name), base_dir=SCEN)


def fly(sc, mode: str = "mil"):
    res = run_scenario(sc, RunOptions(mode=mode))
    s = summarize(res)
    assert s["exit_reason"] == "mission_complete", s["message"]
    failed = {k: v for k, v in s["criteria"].items() if not v["passed"]}
    assert not failed, failed
    return res, s


# ---- the FMI 3.0 build of our plant ------------------------------------------------------------
def test_both_builds_validate_clean():
    assert validate_fmu(str(fb.fmu_path())) == []
    assert validate_fmu(str(fb.fmu_path(fmi=3))) == []


def test_fmi3_build_steps_like_the_fmi2_fast_path():
    u = MAMBO.u_hover
    with Plant(MAMBO, x0=3.0, y0=-2.0, yaw0=0.7) as a, \
            MappedPlant(MAMBO, PlantSpec(None, 3, None), x0=3.0, y0=-2.0, yaw0=0.7) as b:
        assert a.y == b.y
        for k in range(1500):
            us = (0.8 if k < 300 else u, u + 0.01, u, u - 0.005 * math.sin(0.01 * k))
            assert list(a.step(*us, 0.5, -0.2, 0.1)) == list(b.step(*us, 0.5, -0.2, 0.1)), k
        y_end = list(b.y)
        b.reset()
        assert b.k == 0 and b.y[:3] == [3.0, -2.0, b.y[2]]
        for k in range(1500):     # a fresh instance replays the same bits
            us = (0.8 if k < 300 else u, u + 0.01, u, u - 0.005 * math.sin(0.01 * k))
            b.step(*us, 0.5, -0.2, 0.1)
        assert list(b.y) == y_end


def test_fmi3_build_reports_the_fmus_message():
    with MappedPlant(MAMBO, PlantSpec(None, 3, None)) as p:
        with pytest.raises(ComponentError, match="input 'u3' must be a number"):
            p.step(0.5, 0.5, math.nan, 0.5)


def test_closed_mapped_plant_refuses_to_step():
    """As the default plant: no fmpy call into a freed instance after close."""
    p = MappedPlant(MAMBO, PlantSpec(None, 3, None))
    p.step(*(4 * [MAMBO.u_hover]))
    p.close()
    with pytest.raises(ComponentError, match="the plant is closed"):
        p.step(*(4 * [MAMBO.u_hover]))


@pytest.mark.flight
def test_fmi3_scenario_flies_the_square_as_the_fmi2_one():
    res3, s3 = fly(load_scenario(SCEN / "scripted_square_fmi3.toml"))
    res2, _ = fly(load_scenario(SCEN / "scripted_square.toml"))
    assert np.array_equal(res3.series, res2.series, equal_nan=True)   # setpoints: NaN at first
    assert s3["criteria"]["position_error_max_m"]["passed"]


# ---- frames ------------------------------------------------------------------------------------
def same_rotation(a, b) -> bool:
    return bool(np.allclose(a, b) or np.allclose(a, np.negative(b)))


def test_frame_conversions():
    # a body facing east, level: ENU yaw 0 with FLU axes is NED yaw +90 degrees with FRD axes
    q = attitude_to_ned_frd(quat_from_euler(0.0, 0.0, 0.0), "ENU", "FLU")
    assert same_rotation(q, quat_from_euler(0.0, 0.0, math.pi / 2))
    # nose up 10 degrees, facing north: ENU yaw 90, pitch -10 about FLU's y (left) is +10 NED
    q = attitude_to_ned_frd(quat_from_euler(0.0, math.radians(-10), math.pi / 2), "ENU", "FLU")
    assert same_rotation(q, quat_from_euler(0.0, math.radians(10), 0.0))
    # roll +20 about x forward turns y towards z: FLU's left wing up is FRD's right wing down,
    # the same motion, the same sign
    q = attitude_to_ned_frd(quat_from_euler(math.radians(20), 0.0, math.pi / 2), "ENU", "FLU")
    assert same_rotation(q, quat_from_euler(math.radians(20), 0.0, 0.0))
    assert world_swap((1.0, 2.0, 3.0), "ENU") == (2.0, 1.0, -3.0)
    assert world_swap(world_swap((1.0, 2.0, 3.0), "ENU"), "ENU") == (1.0, 2.0, 3.0)
    assert body_swap((1.0, 2.0, 3.0), "FLU") == (1.0, -2.0, -3.0)
    # gravity seen from a body rolled 90 degrees right lies along its +y (right) axis
    g_b = rotate_world_to_body(quat_from_euler(math.pi / 2, 0.0, 0.0), (0.0, 0.0, 9.81))
    assert np.allclose(g_b, (0.0, 9.81, 0.0))


# ---- a plant from another toolchain: PythonFMU -------------------------------------------------
@pytest.mark.flight
def test_pythonfmu_plant_flies_the_scripted_square(enu_fmu):
    _, s = fly(scenario_on("scripted_square.toml", enu_fmu, enu_map()))
    assert s["metrics"]["position_error_max_m"] <= 0.15


@pytest.mark.flight
def test_pythonfmu_plant_flies_the_bebop2_square_in_sil_as_in_mil(enu_fmu):
    sc = scenario_on("bebop2_scripted_square.toml", enu_fmu, enu_map())
    sil, _ = fly(sc, mode="sil")
    mil, _ = fly(sc, mode="mil")
    assert np.array_equal(sil.series, mil.series, equal_nan=True)


@pytest.mark.flight
def test_pythonfmu_plant_flies_the_seed_mission(enu_fmu):
    fly(scenario_on("mambo_seed_track.toml", enu_fmu, enu_map()))


@pytest.mark.flight
def test_pythonfmu_plant_takes_thrust_and_torques(enu_fmu):
    m = enu_map()
    m["command"] = "wrench"
    m["inputs"] = {"thrust": "thrust", "tau_x": "torque_x", "tau_y": "torque_y",
                   "tau_z": "torque_z"}
    m["parameters"]["wrench"] = True
    fly(scenario_on("scripted_square.toml", enu_fmu, m))


def test_pythonfmu_plant_is_deterministic_and_resets(enu_fmu):
    sc = scenario_on("scripted_square.toml", enu_fmu, enu_map())
    with MappedPlant(MAMBO, sc.plant, x0=57.0, y0=95.0, yaw0=0.4) as p:
        assert p.y[:3] == pytest.approx([57.0, 95.0, 0.0])
        assert p.y[6:10] == pytest.approx(quat_from_euler(0.0, 0.0, 0.4))
        assert p.y[20] == 1.0                          # on the floor (no on_ground output)
        for _ in range(400):
            p.step(0.8, 0.8, 0.8, 0.8, 0.0, 0.0, 0.0)
        first = list(p.y)
        assert first[2] < -0.2 and first[20] == 0.0    # climbed: NED z negative, airborne
        assert first[15] == pytest.approx(-(4 * MAMBO.k_thrust * (0.8 * MAMBO.omega_max) ** 2
                                            - MAMBO.drag_z * -first[5]) / MAMBO.mass, rel=0.05)
        assert math.isnan(first[16])                   # rotor speeds: not mapped, not made up
        p.reset()
        for _ in range(400):
            p.step(0.8, 0.8, 0.8, 0.8, 0.0, 0.0, 0.0)
        assert list(p.y)[:16] == first[:16]


def test_pythonfmu_plant_through_its_map_moves_like_our_plant(enu_fmu):
    """Same airframe, same inputs (a climb, then slightly uneven rotors, in a 3D wind, started
    turned 23 degrees): once converted, the ENU/FLU/Euler-in-degrees plant's state is our
    NED plant's. Only the floor models differ (take-off), so the tolerances are small."""
    sc = scenario_on("scripted_square.toml", enu_fmu, enu_map())
    h = MAMBO.u_hover
    with MappedPlant(MAMBO, sc.plant, x0=57.0, y0=95.0, yaw0=0.4) as p, \
            Plant(MAMBO, x0=57.0, y0=95.0, yaw0=0.4) as ref:
        for k in range(160):
            u = (0.75,) * 4 if k < 100 else (h + 0.002, h - 0.001, h + 0.0015, h - 0.002)
            a = p.step(*u, 2.0, -1.0, 0.3)
            b = ref.step(*u, 2.0, -1.0, 0.3)
        assert b[2] < -0.3 and abs(b[9]) > 0.1 and abs(b[11]) > 0.3    # up, turned, pitching
        assert a[0:6] == pytest.approx(b[0:6], abs=0.03)               # position, velocity
        assert a[6:13] == pytest.approx(b[6:13], abs=1e-3)             # attitude, body rates
        assert a[13:16] == pytest.approx(b[13:16], abs=0.05)           # specific force


@pytest.mark.flight
def test_the_map_matters(enu_fmu):
    """The same plant told it is NED/FRD does not fly: the map is what makes it work."""
    m = enu_map()
    m["world"], m["body"] = "NED", "FRD"
    res = run_scenario(with_time(scenario_on("scripted_square.toml", enu_fmu, m), 10.0))
    assert res.exit_reason.value == "crashed", res.message


def with_time(sc, t: float):
    from cosim.load import with_set

    return with_set(sc, {"timing.t_final_s": t})


# ---- mistakes in the map are errors naming the field ------------------------------------------
def bad(enu_fmu, change, **vehicle):
    m = copy.deepcopy(enu_map())
    change(m)
    with pytest.raises(ScenarioError) as ei:
        scenario_on("scripted_square.toml", enu_fmu, m, **vehicle)
    return str(ei.value)


def test_map_errors_name_the_variable(enu_fmu):
    msg = bad(enu_fmu, lambda m: m["outputs"].update(x="pos_east"))
    assert "vehicle.fmu_map.outputs.x" in msg and "pos_east" in msg and "pos_e" in msg
    msg = bad(enu_fmu, lambda m: m["outputs"].pop("vz"))
    assert "vehicle.fmu_map.outputs.vz" in msg
    msg = bad(enu_fmu, lambda m: m["inputs"].update(u1="pos_e"))          # an output
    assert "vehicle.fmu_map.inputs.u1" in msg and "causality input" in msg
    msg = bad(enu_fmu, lambda m: m["outputs"].update(x={"name": "pos_e", "unit": "deg"}))
    assert "vehicle.fmu_map.outputs.x" in msg and "length" in msg
    msg = bad(enu_fmu, lambda m: m["outputs"].update(x={"name": "pos_e", "unit": "furlong"}))
    assert "furlong" in msg
    msg = bad(enu_fmu, lambda m: m.update(world="NWU"))
    assert "vehicle.fmu_map.world" in msg
    msg = bad(enu_fmu, lambda m: m["parameters"].update(kf="k_thrst"))
    assert "vehicle.fmu_map.parameters.kf" in msg and "k_thrust" in msg
    msg = bad(enu_fmu, lambda m: m["parameters"].update(Jxy=1.0))           # not its name
    assert "vehicle.fmu_map.parameters.Jxy" in msg and "did you mean" in msg and "Jxx" in msg
    assert "pos_e" not in msg                                               # parameters only
    msg = bad(enu_fmu, lambda m: m["inputs"].pop("wind_x"))
    assert "wind_x, wind_y and wind_z" in msg                               # all or none
    raw = tomllib.loads((SCEN / "mambo_seed_wind.toml").read_text())
    mm = enu_map()
    del mm["inputs"]["wind_x"]
    raw["vehicle"].update(fmu=str(enu_fmu), fmu_map=mm)
    with pytest.raises(ScenarioError, match="wind_x"):     # wind in the scenario: mapped
        parse_scenario(raw, source=str(SCEN / "mambo_seed_wind.toml"), base_dir=SCEN)


def test_vehicle_table_errors(enu_fmu, tmp_path):
    with pytest.raises(ScenarioError, match="vehicle.fmu"):
        scenario_on("scripted_square.toml", tmp_path / "nope.fmu", enu_map())
    junk = tmp_path / "junk.fmu"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ScenarioError, match="vehicle.fmu"):
        scenario_on("scripted_square.toml", junk, enu_map())
    with pytest.raises(ScenarioError, match="vehicle.fmi"):
        scenario_on("scripted_square.toml", enu_fmu, enu_map(), fmi=3)
    raw = tomllib.loads((SCEN / "scripted_square.toml").read_text())
    raw["vehicle"]["fmi"] = 4
    with pytest.raises(ScenarioError, match="vehicle.fmi"):
        parse_scenario(raw, source="x.toml", base_dir=SCEN)
    raw["vehicle"]["fmi"] = 2
    raw["vehicle"]["fmu_map"] = enu_map()
    with pytest.raises(ScenarioError, match="vehicle.fmu_map"):
        parse_scenario(raw, source="x.toml", base_dir=SCEN)


def test_cli_exits_2_naming_the_variable(enu_fmu, tmp_path):
    text = (SCEN / "scripted_square.toml").read_text()
    text = text.replace('preset = "mambo"', f'preset = "mambo"\nfmu = "{enu_fmu}"')
    text = text.replace('"worlds/empty.toml"', f'"{SCEN / "worlds" / "empty.toml"}"')
    text += "\n" + (PLANTS / "enu_quad_map.toml").read_text().replace('"psi_deg"', '"psi"')
    path = tmp_path / "square_on_enu.toml"
    path.write_text(text)
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "run", str(path), "--out",
                        str(tmp_path / "run")], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert "vehicle.fmu_map.outputs.yaw" in r.stderr and "psi" in r.stderr
    assert not (tmp_path / "run").exists()
