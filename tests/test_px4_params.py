"""Every PX4-named parameter the vehicle serves has PX4's meaning, type, unit and a range within
PX4's, and PX4's default unless its spec says why not (issue 44, item 2). PX4's metadata is data
in the repository, mav/px4_params.json, each entry with its PX4 source file and commit; every
other parameter has a name of ours (TPL_, MB_) that PX4 does not use."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from mav.airframe import get_airframe
from mav.control import make_controller
from mav.params import ONBOARD_PARAMS, RENAMED, ParamError, ParamTable, UnknownParamError

M = mavlink2
PX4 = json.loads((Path(__file__).parents[1] / "mav" / "px4_params.json").read_text())
OURS = ("TPL_", "MB_")         # prefixes of this stack's own names (mav/params.py)


def _bound(v, inf):
    return inf if v is None else float(v)


def test_metadata_records_its_source():
    assert PX4["repository"] == "https://github.com/PX4/PX4-Autopilot"
    for name, m in PX4["params"].items():
        assert m["file"].startswith("src/") and len(m["commit"]) == 40, name
        assert m["type"] in ("FLOAT", "INT32"), name
        assert _bound(m["min"], -math.inf) <= m["default"] <= _bound(m["max"], math.inf), name


@pytest.mark.parametrize("spec", ONBOARD_PARAMS, ids=lambda s: s.name)
def test_px4_names_have_px4s_type_unit_range_and_default(spec):
    name = spec.name
    assert len(name) <= 16
    if name.startswith(OURS):
        assert name not in PX4["params"] and name not in PX4["not_in_px4"], name
        assert spec.ptype == "REAL32" and not spec.own_default, name
        return
    assert name in PX4["params"], (
        f"{name} is neither a PX4 parameter in mav/px4_params.json "
        f"({PX4['not_in_px4'].get(name, 'not recorded')}) nor a name of ours {OURS}")
    px4 = PX4["params"][name]
    assert spec.ptype == {"FLOAT": "REAL32", "INT32": "INT32"}[px4["type"]], (name, px4["type"])
    assert spec.unit == px4["unit"], (name, spec.unit, px4["unit"])
    lo, hi = _bound(px4["min"], -math.inf), _bound(px4["max"], math.inf)
    assert lo <= spec.min and spec.max <= hi, (name, (spec.min, spec.max), (lo, hi))
    if spec.own_default:          # an airframe's or the room's own value, said with its reason
        assert spec.default != px4["default"] and len(spec.own_default) > 10, name
    else:
        assert spec.default == px4["default"], (name, spec.default, px4["default"])
    if spec.ptype == "INT32":
        assert spec.default == int(spec.default) and spec.min == int(spec.min)
        assert all(v in px4.get("enum", [v]) for v in (spec.default,))


def test_the_px4_names_used_before_with_other_meanings_are_gone():
    names = {s.name for s in ONBOARD_PARAMS}
    for v in ("mambo", "bebop2"):
        names |= {s.name for s in make_controller(get_airframe(v)).param_table()}
    for old, new in RENAMED.items():
        assert old not in names and new in names, (old, new)
    # the ones the issue names: seconds vs microseconds, metres vs standard deviations, ...
    assert PX4["params"]["EKF2_NOAID_TOUT"]["unit"] == "us"
    assert {PX4["params"][n]["unit"] for n in ("EKF2_BARO_GATE", "EKF2_RNG_GATE",
                                               "EKF2_OF_GATE")} == {"SD"}
    for n in ("EKF2_TYPE", "EKF2_ACC_W", "EKF2_ACC_GATE", "EKF2_MAG_W", "EKF2_OF_Q",
              "EKF2_OF_R", "EKF2_GPS_W"):
        assert n in PX4["not_in_px4"] and RENAMED[n].startswith("TPL_")


def test_an_old_name_is_an_error_naming_the_new_one(tmp_path):
    t = ParamTable()
    t.add_store(ONBOARD_PARAMS, {})
    with pytest.raises(UnknownParamError, match="EKF2_BARO_GATE is now TPL_BARO_GATE"):
        t.set("EKF2_BARO_GATE", 0.5)
    with pytest.raises(ParamError, match="whole number"):
        t.set("COM_DL_LOSS_T", 10.5)


def test_param_value_carries_px4s_type_byte_wise():
    rig = Rig()
    rig.tick()
    rig.send("gcs", M.MAVLink_param_request_list_message(1, 1))
    rig.tick(40)
    pv = {m.param_id: m for m in rig.msgs("gcs", "PARAM_VALUE")}
    specs = {s.name: s for s in ONBOARD_PARAMS}
    assert pv["COM_DL_LOSS_T"].param_type == M.MAV_PARAM_TYPE_INT32
    assert pv["MIS_TAKEOFF_ALT"].param_type == M.MAV_PARAM_TYPE_REAL32
    for name, m in pv.items():
        if name in specs and specs[name].ptype == "INT32":
            assert m.param_type == M.MAV_PARAM_TYPE_INT32
            i = struct.unpack("<i", struct.pack("<f", m.param_value))[0]
            assert i == specs[name].default, name
    # a ground station sets an INT32 as PX4 expects it: byte-wise, typed INT32
    bits = struct.unpack("<f", struct.pack("<i", 20))[0]
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"COM_DL_LOSS_T", bits,
                                                M.MAV_PARAM_TYPE_INT32))
    rig.tick()
    assert rig.ob.params.get("COM_DL_LOSS_T") == 20.0
    echo = rig.msgs("gcs", "PARAM_VALUE")[-1]
    assert echo.param_id == "COM_DL_LOSS_T" and echo.param_value == bits


def test_a_scenario_with_an_old_name_names_the_new_one_a_px4_file_keeps_loading(tmp_path):
    from cosim.errors import ScenarioError
    from cosim.load import load_scenario, with_set

    sc = load_scenario(Path(__file__).parents[1] / "scenarios" / "scripted_square.toml")
    with pytest.raises(ScenarioError, match="TPL_BARO_GATE") as ei:
        with_set(sc, {"onboard.params.EKF2_BARO_GATE": 0.5})
    assert ei.value.field == "onboard.params.EKF2_BARO_GATE"
    rig = Rig()
    f = tmp_path / "old.params"
    f.write_text("MIS_TAKEOFF_ALT 1.2\nEKF2_NOAID_TOUT 5000000\n")   # as a PX4 file has it
    rig.ob.load_params(str(f))           # PX4's EKF2_NOAID_TOUT is not this vehicle's
    assert rig.ob.parameters.table.get("MIS_TAKEOFF_ALT") == pytest.approx(1.2)
    assert rig.ob.parameters.table.get("TPL_NOAID_TOUT") == pytest.approx(1.0)
    assert any("ignored EKF2_NOAID_TOUT" in w and "TPL_NOAID_TOUT" in w
               for w in rig.ob.parameters.warnings)
