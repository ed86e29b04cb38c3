"""Parameter answers clients understand and the rule for changes while armed (issue 13, item 7;
issue 14, item 6): PARAM_ERROR before the echo, bounds from PX4's metadata, the flight
envelope of gains and thrust limit (refused in flight, arming refused outside it)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from cosim.plant.fmu import Y_Z
from mav.airframe import get_airframe
from mav.control import make_controller
from mav.onboard import IN_AIR
from mav.params import ONBOARD_PARAMS, THRUST_LIMIT, flight_envelope

M = mavlink2

# PX4's metadata for every PX4 name (type, unit, range, default) is checked against
# mav/px4_params.json in tests/test_px4_params.py; here the bounds and the flight envelope.


def _specs(vehicle: str) -> list:
    return list(make_controller(get_airframe(vehicle)).param_table()) + list(ONBOARD_PARAMS)


@pytest.mark.parametrize("vehicle", ["mambo", "bebop2"])
def test_every_parameter_has_bounds(vehicle):
    for spec in _specs(vehicle):
        assert math.isfinite(spec.min) and math.isfinite(spec.max) and spec.min < spec.max
        assert spec.min <= spec.default <= spec.max, spec.name


@pytest.mark.parametrize("vehicle, thrust_floor", [("mambo", 0.709), ("bebop2", 0.505)])
def test_flight_envelopes(vehicle, thrust_floor):
    a = get_airframe(vehicle)
    hover = a.weight / (4.0 * a.thrust_max)
    specs = {s.name: s for s in _specs(vehicle)}
    lo, hi = flight_envelope(specs[THRUST_LIMIT], hover)
    assert lo == pytest.approx(thrust_floor, abs=1e-3) and hi == 1.0
    assert lo > hover * 1.4                       # room to climb and to steer above hover
    gains = [n for n in specs if specs[n].flight_gain]
    assert len(gains) >= 8
    for n in gains:
        lo, hi = flight_envelope(specs[n], hover)
        assert 0.0 < lo < specs[n].default <= hi, n           # zero is never allowed in flight
    for n in ("TPL_TILTMAX_AIR", "CAS_TILTMAX_AIR", "MPC_XY_VEL_MAX", "MIS_TAKEOFF_ALT",
              "TPL_Z_I", "CAS_Z_VEL_I"):
        if n in specs:
            assert flight_envelope(specs[n], hover) is None   # limits and integrators: free


# ------------------------------------------------------------------ the protocol answers
def _set(rig: Rig, name: str, value: float, link: str = "gcs") -> None:
    rig.send(link, M.MAVLink_param_set_message(1, 1, name.encode(), value,
                                               M.MAV_PARAM_TYPE_REAL32))
    rig.tick()


def _order(rig: Rig, link: str, since: int) -> list[str]:
    return [m.get_type() for t, m in rig.rx[link] if t >= since
            and m.get_type() in ("PARAM_ERROR", "PARAM_VALUE")]


def test_unknown_name_gets_param_error_does_not_exist_and_no_value():
    rig = Rig()
    rig.tick()
    _set(rig, "NO_SUCH_PARAM", 1.0)
    (err,) = rig.msgs("gcs", "PARAM_ERROR")
    assert (err.param_id, err.param_index, err.error) == ("NO_SUCH_PARAM", -1,
                                                          M.MAV_PARAM_ERROR_DOES_NOT_EXIST)
    assert (err.target_system, err.target_component) == (255, 190)        # to the asker
    assert rig.msgs("gcs", "PARAM_VALUE") == [] and rig.msgs("api", "PARAM_ERROR") == []
    assert "Unknown parameter 'NO_SUCH_PARAM'" in rig.texts()
    rig.send("gcs", M.MAVLink_param_request_read_message(1, 1, b"NOPE", -1))
    rig.send("gcs", M.MAVLink_param_request_read_message(1, 1, b"", 9999))
    rig.tick()
    errs = [(e.param_id, e.param_index, e.error) for e in rig.msgs("gcs", "PARAM_ERROR")[1:]]
    assert errs == [("NOPE", -1, 1), ("", 9999, 1)]
    assert rig.ob.stats["param_rejected"] == 1


@pytest.mark.parametrize("value", [50.0, -1.0, math.nan, math.inf])
def test_bad_value_gets_param_error_out_of_range_then_the_old_value(value):
    rig = Rig()
    rig.tick()
    t0 = rig.t_us
    _set(rig, "TPL_LAND_SPEED", value)
    assert _order(rig, "gcs", t0) == ["PARAM_ERROR", "PARAM_VALUE"]     # error first (MAVSDK)
    assert _order(rig, "api", t0) == ["PARAM_VALUE"]                    # everyone: the echo
    err = rig.last("gcs", "PARAM_ERROR")
    assert (err.param_id, err.error) == ("TPL_LAND_SPEED", M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE)
    for link in ("api", "gcs"):
        assert rig.last(link, "PARAM_VALUE").param_value == pytest.approx(0.4)
    assert rig.texts()[-1].startswith("Param rejected: TPL_LAND_SPEED")


# ------------------------------------------------------------------ armed
def _hovering_mambo() -> Rig:
    rig = Rig(plant=True, client=True)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 2.0)
    c.arm()
    c.takeoff(1.0)
    rig.run_until(lambda r: r.ob.mode_name == "AUTO.LOITER" and r.ob.landed_state == IN_AIR,
                  10.0)
    rig.tick(200)
    return rig


def test_in_flight_a_thrust_limit_that_cannot_hold_the_vehicle_is_refused():
    rig = _hovering_mambo()
    z0 = rig.plant.y[Y_Z]
    t0 = rig.t_us
    _set(rig, "MPC_THR_MAX", 0.1)
    assert _order(rig, "gcs", t0) == ["PARAM_ERROR", "PARAM_VALUE"]
    err = rig.last("gcs", "PARAM_ERROR")
    assert (err.param_id, err.error) == ("MPC_THR_MAX", M.MAV_PARAM_ERROR_PERMISSION_DENIED)
    assert rig.last("gcs", "PARAM_VALUE").param_value == pytest.approx(0.92)
    assert "MPC_THR_MAX 0.1 refused while armed: in flight 0.709..1" in rig.texts()[-1]
    rig.tick(400)
    assert rig.plant.y[Y_Z] == pytest.approx(z0, abs=0.02)            # still flying there
    _set(rig, "MPC_THR_MAX", 0.8)                                       # inside: fine in flight
    assert rig.ob.params.get("MPC_THR_MAX") == pytest.approx(0.8)
    st = rig.ob.stats
    assert st["param_denied_armed"] == 1 and st["param_rejected"] == 1


def test_what_the_rule_prevents_a_thrust_limit_below_hover_brings_it_down():
    """The reason for the rule (issue 14): the same 0.1 forced past the protocol."""
    rig = _hovering_mambo()
    z0 = rig.plant.y[Y_Z]
    rig.ob.params.set("MPC_THR_MAX", 0.1)
    rig.tick(200)
    assert rig.plant.y[Y_Z] > z0 + 0.3                                # falling


def test_in_flight_gains_change_within_the_envelope_only():
    rig = _hovering_mambo()
    for name, bad, good in (("TPL_XY_P", 0.0, 0.3), ("TPL_PITCH_P", 0.0, 0.02),
                            ("TPL_Z_D", 5.0, 0.6)):
        _set(rig, name, bad)
        assert rig.last("gcs", "PARAM_ERROR").param_id == name
        assert rig.last("gcs", "PARAM_ERROR").error == M.MAV_PARAM_ERROR_PERMISSION_DENIED
        _set(rig, name, good)
        assert rig.ob.params.get(name) == pytest.approx(good)
    _set(rig, "TPL_TILTMAX_AIR", 5.0)                 # a limit: only slows it, allowed
    _set(rig, "TPL_Z_I", 0.0)                          # an integrator off: allowed
    assert rig.ob.params.get("TPL_TILTMAX_AIR") == 5.0 and rig.ob.params.get("TPL_Z_I") == 0.0
    assert rig.ob.stats["param_denied_armed"] == 3
    rig.tick(400)
    assert rig.ob.landed_state == IN_AIR


def test_disarmed_any_value_in_range_is_stored_but_arming_waits_for_the_envelope():
    rig = Rig()
    rig.tick()
    _set(rig, "MPC_THR_MAX", 0.1)
    assert rig.ob.params.get("MPC_THR_MAX") == pytest.approx(0.1)
    assert rig.msgs("gcs", "PARAM_ERROR") == []
    assert "arming refused until it is back" in rig.texts()[-1]
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick()
    assert rig.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_DENIED and not rig.ob.armed
    assert rig.texts()[-1] == "Arming denied: MPC_THR_MAX 0.1 outside its flight range 0.709..1"
    _set(rig, "MPC_THR_MAX", 0.92)
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick()
    assert rig.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_ACCEPTED and rig.ob.armed


def test_a_parameter_file_outside_the_envelope_also_blocks_arming(tmp_path):
    f = tmp_path / "zero_gain.params"
    f.write_text("TPL_PITCH_P 0\n")
    rig = Rig(param_file=str(f))
    rig.tick()
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick()
    assert rig.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_DENIED
    assert "TPL_PITCH_P 0 outside its flight range" in rig.texts()[-1]
