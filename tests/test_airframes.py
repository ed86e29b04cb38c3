"""One source per value: the flight stack's nominal airframes (mav/airframe.py) are the plant's
presets (cosim/scenario/vehicles.py) field for field, and the FMU's built-in defaults (model.c) and
start values (modelDescription.xml, tested in test_fmu.py) are the Mambo preset."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cosim.scenario.vehicles import PRESETS
from mav.airframe import AIRFRAMES, FIELDS, get_airframe

MODEL_C = Path(__file__).resolve().parents[1] / "fmus" / "quadrotor" / "model.c"


def test_same_airframes_on_both_sides():
    assert set(AIRFRAMES) == set(PRESETS)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_nominal_airframe_is_the_plant_preset(name):
    assert get_airframe(name).values() == PRESETS[name].fmu_parameters()
    assert set(FIELDS) == set(PRESETS[name].fmu_parameters())


def test_model_c_defaults_are_the_mambo_preset():
    defaults = {k: float(v) for k, v in
                re.findall(r"P\(m, (\w+)\)\s*=\s*([-+0-9.eE]+);", MODEL_C.read_text())}
    mambo = PRESETS["mambo"].fmu_parameters()
    missing = set(mambo) - set(defaults)
    assert not missing, f"model.c sets no default for {missing}"
    for k, v in mambo.items():
        assert defaults[k] == v, k


def test_unknown_airframe_names_the_choices():
    with pytest.raises(ValueError, match="bebop2, mambo"):
        get_airframe("crazyflie")
