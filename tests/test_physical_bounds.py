"""Issue 31, defect 4: physical parameters have physical bounds. A value no airframe, app or
camera can have is refused when the scenario loads (exit 2 naming the field), not found out
in flight by a ZeroDivisionError, an OverflowError or an 8 GiB frame."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.cli import main
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set
from cosim.scenario.vehicles import PHYSICAL_RANGES, PRESETS

ROOT = Path(__file__).resolve().parents[1]
HOVER = ROOT / "scenarios" / "mambo_hover.toml"
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
E1 = ROOT / "scenarios" / "bebop2_vs_e1.toml"


def _refused(path: Path, sets: dict, field: str) -> ScenarioError:
    with pytest.raises(ScenarioError) as ei:
        with_set(load_scenario(path), sets)
    assert ei.value.field == field, str(ei.value)
    return ei.value


@pytest.mark.parametrize("key,value", [
    ("mass", 1e-300), ("mass", 1e300), ("omega_max", 1e300), ("k_thrust", 1e-300),
    ("k_thrust", 1e300), ("g", 1e300), ("g", 1e-300), ("motor_tau", 1e-300),
    ("arm_length", 1e-300), ("Ixx", 1e-300), ("k_torque", 1e300), ("drag_xy", 1e300)])
def test_overrides_outside_their_physical_range_are_refused(key, value):
    _refused(HOVER, {f"vehicle.overrides.{key}": value}, f"vehicle.overrides.{key}")


def test_every_preset_is_inside_the_ranges_it_is_checked_against():
    for v in PRESETS.values():
        for k, (lo, hi) in PHYSICAL_RANGES.items():
            assert lo <= getattr(v, k) <= hi, (v.name, k)
        assert v.physical_problem() is None


def test_a_vehicle_that_cannot_lift_itself_is_refused():
    e = _refused(HOVER, {"vehicle.overrides.mass": 50.0}, "vehicle.overrides")
    assert "thrust/weight" in str(e)
    e = _refused(HOVER, {"vehicle.overrides.k_torque": 1e-3}, "vehicle.overrides")
    assert "moment constant" in str(e)


def test_the_run_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "r"
    rc = main(["run", str(HOVER), "--set", "vehicle.overrides.mass=1e-300", "--out", str(out),
               "--quiet", "--no-plots"])
    assert rc == 2 and "vehicle.overrides.mass" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("value", [-1e308, 1e308, 0.0, 121.0])
def test_takeoff_altitude_is_a_height_an_app_can_fly(value):
    _refused(HOVER, {"app.takeoff_alt_m": value}, "app.params.takeoff_alt_m")


def test_app_numbers_are_bounded():
    _refused(HOVER, {"app.tolerance_m": 1e300}, "app.params.tolerance_m")
    _refused(E1, {"app.target_timeout_s": 1e300}, "app.params.target_timeout_s")


def test_a_camera_that_needs_gigabytes_per_frame_is_refused():
    e = _refused(E1, {"camera.width": 4096, "camera.height": 4096, "camera.hfov_deg": 90,
                      "camera.exact": True, "camera.supersample": 8}, "camera.supersample")
    assert "GiB" in str(e)
    with_set(load_scenario(E1), {"camera.exact": True})      # the default exact camera is fine


def test_sigma_has_one_value_per_key():
    _refused(E1, {"app.sigma": [0.05, 0.06]}, "app.params.sigma")
    sc = with_set(load_scenario(E1), {"app.sigma": [0.05]})   # one for all keys
    assert sc.app.params["sigma"] == [0.05]


def test_waypoints_and_keys_outside_the_arena_or_below_the_floor_are_refused():
    sc = load_scenario(SQUARE)
    wps = sc.raw["app"]["params"]["waypoints"]
    below = [list(w) for w in wps]
    below[1][2] = 0.5                                          # 0.5 m under the floor
    _refused(SQUARE, {"app.waypoints": below}, "app.params.waypoints[1]")
    far = [list(w) for w in wps]
    far[0][0] = 1e5
    _refused(SQUARE, {"app.waypoints": far}, "app.params.waypoints[0]")
    _refused(E1, {"app.keys": [[1.5, 0.0, 0.3, 0.0]]}, "app.params.keys[0]")
    _refused(E1, {"app.keys": [[500.0, 0.0, -1.0, 0.0]]}, "app.params.keys[0]")
