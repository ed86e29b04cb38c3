"""Issue 31, defect 8: MAVLink values a PX4 vehicle would not act on. DO_CHANGE_SPEED below
the speed parameter's minimum (1e-30 m/s froze every later go-to) is denied and above its
maximum clamped; DO_REPOSITION's ground speed is clamped the same way (below the minimum: the
default cruise speed); a subnormal PARAM_SET value is refused with PARAM_ERROR."""

from __future__ import annotations

import math

import pytest
from test_onboard_auto import M, flying_rig, goto
from test_onboard_params_rules import _order, _set
from test_onboard_rig import Rig


def test_reposition_ground_speed_is_clamped_to_the_cruise_range():
    rig = flying_rig()
    nav = rig.ob.navigator
    for asked, want in ((1e-30, 1.0), (-5.0, 1.0), (math.nan, 1.0), (0.5, 0.5), (1e30, 20.0),
                        (math.inf, 1.0)):
        goto(rig, 3.0, 0.0, 1.0, speed_mps=asked)
        assert nav.leg.vmax == pytest.approx(want, rel=1e-3), asked


def test_change_speed_below_the_minimum_is_denied_and_above_the_maximum_clamped():
    rig = flying_rig()
    nav = rig.ob.navigator
    for kind, bad in ((1, 1e-30), (1, 0.0), (2, 1e-38), (3, 0.05)):
        rig.cmd(M.MAV_CMD_DO_CHANGE_SPEED, kind, bad, -1)
        rig.tick(2)
        assert rig.ack(M.MAV_CMD_DO_CHANGE_SPEED) == M.MAV_RESULT_DENIED, (kind, bad)
    assert math.isnan(nav.speed_xy) and math.isnan(nav.speed_up)
    rig.cmd(M.MAV_CMD_DO_CHANGE_SPEED, 1, 1e30, -1)
    rig.tick(2)
    assert rig.ack(M.MAV_CMD_DO_CHANGE_SPEED) == M.MAV_RESULT_ACCEPTED and nav.speed_xy == 20.0
    rig.cmd(M.MAV_CMD_DO_CHANGE_SPEED, 2, 100.0, -1)
    rig.tick(2)
    assert nav.speed_up == 8.0                            # MPC_Z_V_AUTO_UP's maximum
    goto(rig, 2.0, 0.0, 1.0)                              # and a go-to still flies
    rig.run_until(lambda r: nav.leg.done, 10.0)
    assert nav.leg.done


@pytest.mark.parametrize("name", ["BAT1_CAPACITY", "COM_RC_LOSS_T", "TPL_HOLD_DZ",
                                  "MPC_MAN_Y_MAX"])
@pytest.mark.parametrize("value", [1e-40, -1e-42, 1.4e-45])
def test_a_subnormal_param_value_is_refused_with_param_error(name, value):
    rig = Rig()
    rig.tick()
    before = rig.ob.params.get(name)
    t0 = rig.t_us
    _set(rig, name, value)
    assert _order(rig, "gcs", t0) == ["PARAM_ERROR", "PARAM_VALUE"]
    err = rig.last("gcs", "PARAM_ERROR")
    assert (err.param_id, err.error) == (name, M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE)
    assert rig.ob.params.get(name) == before                 # the value in effect stays
    assert rig.last("gcs", "PARAM_VALUE").param_value == pytest.approx(before)
    assert "subnormal" in rig.texts()[-1]
