"""Every PX4-named parameter the vehicle serves has PX4's meaning, type, unit and a range within
PX4's, and PX4's default unless its spec says why not (issue 44, item 2). PX4's metadata is data
in the repository, mav/px4_params.json, each entry with its PX4 source file and commit; every
other parameter has a name of ours (TPL_, CAS_, MB_) that PX4 does not use. The onboard stack's
table and both controllers' (mav/control.py) are checked."""

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
from mav.params import (
    ONBOARD_PARAMS,
    RENAMED,
    RENAMED_CTL,
    ParamError,
    ParamTable,
    UnknownParamError,
    vehicle_table,
)

M = mavlink2
PX4 = json.loads((Path(__file__).parents[1] / "mav" / "px4_params.json").read_text())
OURS = ("TPL_", "CAS_", "MB_")  # prefixes of this stack's own names (mav/params.py)
VEHICLES = ("mambo", "bebop2")
CTL_SPECS = [(v, s) for v in VEHICLES for s in make_controller(get_airframe(v)).param_table()]


def _bound(v, inf):
    return inf if v is None else float(v)


def test_metadata_records_its_source():
    assert PX4["repository"] == "https://github.com/PX4/PX4-Autopilot"
    for name, m in PX4["params"].items():
        assert m["file"].startswith("src/") and len(m["commit"]) == 40, name
        assert m["type"] in ("FLOAT", "INT32"), name
        assert _bound(m["min"], -math.inf) <= m["default"] <= _bound(m["max"], math.inf), name


@pytest.mark.parametrize("owner, spec", [("onboard", s) for s in ONBOARD_PARAMS] + CTL_SPECS,
                         ids=lambda x: x if isinstance(x, str) else x.name)
def test_px4_names_have_px4s_type_unit_range_and_default(owner, spec):
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
    names = {v: vehicle_table(v).names() for v in VEHICLES}
    for old, new in RENAMED.items():
        for v in VEHICLES:
            assert old not in names[v] and new in names[v], (v, old, new)
    for v, renamed in RENAMED_CTL.items():
        for old, new in renamed.items():
            assert old not in names[v] and new in names[v], (v, old, new)
    # each old name is recorded: PX4's metadata (another meaning, unit or range) or not PX4's
    for old in [*RENAMED, *(n for m in RENAMED_CTL.values() for n in m)]:
        assert (old in PX4["params"]) != (old in PX4["not_in_px4"]), old
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


def test_the_controllers_px4_names_the_issue_names():
    """MC_PITCH_P was a torque per radian (PX4's: a rate per radian), MC_THR_MAX not PX4's,
    MPC_XY_VEL_P / MPC_Z_VEL_P / MPC_Z_VEL_I since renamed by PX4 (*_ACC, narrower ranges)."""
    assert PX4["params"]["MC_PITCH_P"]["unit"] == "" and PX4["params"]["MC_PITCH_P"]["max"] == 12
    assert RENAMED_CTL["mambo"]["MC_PITCH_P"] == "TPL_PITCH_P"
    for v in VEHICLES:
        assert RENAMED_CTL[v]["MC_THR_MAX"] == "MPC_THR_MAX"
        assert RENAMED_CTL[v]["MPC_Z_VEL_MAX"].startswith(("TPL_", "CAS_"))
    for n in ("MPC_XY_VEL_P", "MPC_Z_VEL_P", "MPC_Z_VEL_I"):
        assert n in PX4["not_in_px4"] and n + "_ACC" in PX4["params"]
        assert RENAMED_CTL["bebop2"][n].startswith("CAS_")


@pytest.mark.parametrize("vehicle, old, new", [("mambo", "MC_RP_I", "TPL_RP_I"),
                                               ("bebop2", "MC_RP_I", "CAS_RP_I"),
                                               ("mambo", "MC_THR_MAX", "MPC_THR_MAX")])
def test_an_old_controller_name_names_this_vehicles_new_one(vehicle, old, new, tmp_path):
    from cosim.errors import ScenarioError
    from cosim.load import load_scenario, with_set

    t = vehicle_table(vehicle)
    with pytest.raises(UnknownParamError, match=f"{old} is now {new} "):
        t.set(old, 0.5)
    name = {"mambo": "scripted_square", "bebop2": "bebop2_room_e1"}[vehicle]
    sc = load_scenario(Path(__file__).parents[1] / "scenarios" / f"{name}.toml")
    with pytest.raises(ScenarioError, match=new) as ei:
        with_set(sc, {f"onboard.params.{old}": 0.5})
    assert ei.value.field == f"onboard.params.{old}"


def test_a_px4_file_keeps_loading_on_either_vehicle(tmp_path):
    """A PX4 export: MC_YAW_P is PX4's on the Bebop 2 (set) and not the Mambo's TPL_YAW_P."""
    f = tmp_path / "px4.params"
    f.write_text("MC_YAW_P 2.5\nMC_PITCH_P 6.5\n")
    rig = Rig()
    rig.ob.load_params(str(f))
    assert rig.ob.parameters.table.get("TPL_PITCH_P") == pytest.approx(0.013)
    assert any("ignored MC_PITCH_P" in w and "TPL_PITCH_P" in w
               for w in rig.ob.parameters.warnings)
    rig = Rig(vehicle="bebop2")
    rig.ob.load_params(str(f))
    assert rig.ob.parameters.table.get("MC_YAW_P") == pytest.approx(2.5)
    assert any("unknown parameter(s): MC_PITCH_P" in w for w in rig.ob.parameters.warnings)
