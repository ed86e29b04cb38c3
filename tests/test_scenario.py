"""Scenario loading: every shipped file validates; malformed input names the field."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, parse_scenario, with_set

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = sorted((ROOT / "scenarios").glob("*.toml"))


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_shipped_scenarios_validate(path):
    sc = load_scenario(path)
    assert sc.vehicle.name in ("mambo", "bebop2")
    assert sc.timing.tick_s == 0.005


def _raw():
    p = ROOT / "scenarios" / "scripted_square.toml"
    return tomllib.loads(p.read_text()), p.parent


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda r: r["vehicle"].__setitem__("preset", "crazyflie"), "vehicle.preset"),
        (lambda r: r["vehicle"]["start"].__setitem__("yaw_deg", "north"), "vehicle.start.yaw_deg"),
        (lambda r: r.setdefault("timing", {}).__setitem__("camera_every", 0),
         "timing.camera_every"),
        (lambda r: r.setdefault("timing", {}).__setitem__("tick_s", 0.01), "timing.tick_s"),
        (lambda r: r["timing"].__setitem__("t_final_s", -1.0), "timing.t_final_s"),
        (lambda r: r.__setitem__("colour", "red"), "colour"),
        (lambda r: r["app"].__setitem__("name", "nonexistent"), "app.name"),
        (lambda r: r.setdefault("criteria", {}).__setitem__("path_rms_max_m", 0),
         "criteria.path_rms_max_m"),
        (lambda r: r.setdefault("criteria", {}).__setitem__("must_complete", "yes"),
         "criteria.must_complete"),
        (lambda r: r.__setitem__("faults", {"motor_1": "dead"}), "faults.motor_1"),
        (lambda r: r.__setitem__("faults", {"link": [{"loss": 2.0}]}), "faults.link[0].loss"),
        (lambda r: r.__setitem__("faults", {"link": [{"link": "hil", "loss": 0.1}]}),
         "faults.link[0].link"),
        (lambda r: r.__setitem__("faults", {"link": [{"start_s": 5.0}]}), "faults.link[0]"),
        (lambda r: r.__setitem__("faults", {"odometry": [{"kind": "teleport"}]}),
         "faults.odometry[0].kind"),
        (lambda r: r.__setitem__("faults", {"odometry": [{"kind": "dropout", "start_s": 3}]}),
         "faults.odometry[0].end_s"),
        (lambda r: r.__setitem__("faults", {"camera": [{"kind": "black", "start_s": 3,
                                                        "end_s": 1}]}),
         "faults.camera[0].end_s"),
        (lambda r: r.__setitem__("faults", {"motor": [{"motor": 5, "thrust": 0.5}]}),
         "faults.motor[0].motor"),
        (lambda r: r.__setitem__("faults", {"link": "lossy"}), "faults.link"),
        (lambda r: r.__setitem__("faults", {"battery": [{"kind": "drain", "start_s": 9}]}),
         "faults.battery[0].remaining"),
        (lambda r: r.__setitem__("faults", {"battery": [{"kind": "sag", "r_factor": 0.5}]}),
         "faults.battery[0].r_factor"),
        (lambda r: r["vehicle"].__setitem__("overrides", {"mass": -0.1}),
         "vehicle.overrides.mass"),
        (lambda r: r.__setitem__("onboard", {"params": {"NO_SUCH_PARAM": 1}}),
         "onboard.params.NO_SUCH_PARAM"),
        (lambda r: r.__setitem__("onboard", {"params": {"COM_LOW_BAT_ACT": 7}}),
         "onboard.params.COM_LOW_BAT_ACT"),
        (lambda r: r.__setitem__("onboard", {"params": {"TPL_XY_CRUISE": "fast"}}),
         "onboard.params.TPL_XY_CRUISE"),
        (lambda r: r.__setitem__("onboard", {"parameters": {}}), "onboard.parameters"),
        (lambda r: r["vehicle"].__setitem__("overrides", {"mass_kg": 0.1}),
         "vehicle.overrides.mass_kg"),
        (lambda r: r.setdefault("sensors", {}).__setitem__(
            "odometry_noise", {"pos_std_m": float("nan")}), "sensors.odometry_noise.pos_std_m"),
        (lambda r: r["world"].__setitem__("file", "worlds/missing.toml"), "world.file"),
        (lambda r: r.pop("vehicle"), "vehicle"),
    ],
)
def test_bad_field_is_named(mutate, field):
    raw, base = _raw()
    raw = copy.deepcopy(raw)
    mutate(raw)
    with pytest.raises(ScenarioError) as ei:
        parse_scenario(raw, source=str(base / "x.toml"), base_dir=base)
    assert ei.value.field == field
    assert field in str(ei.value) and "allowed" in str(ei.value)


def test_with_set_overrides_and_revalidates():
    sc = load_scenario(ROOT / "scenarios" / "scripted_square.toml")
    sc2 = with_set(sc, {"seed": 7, "app.tolerance_m": 0.2})
    assert sc2.seed == 7 and sc2.app.params["tolerance_m"] == 0.2
    assert sc.seed == 0 and sc.app.params["tolerance_m"] == 0.10  # original untouched
    with pytest.raises(ScenarioError, match="timing.camera_every"):
        with_set(sc, {"timing.camera_every": -3})


def test_invalid_toml_is_reported(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("name = \n")
    with pytest.raises(ScenarioError, match="valid UTF-8 TOML"):
        load_scenario(p)


def test_non_utf8_file_is_reported(tmp_path):
    p = tmp_path / "latin1.toml"
    p.write_bytes('name = "caf\xe9"\n'.encode("latin-1"))
    with pytest.raises(ScenarioError, match="valid UTF-8 TOML"):
        load_scenario(p)
