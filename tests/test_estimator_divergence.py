"""Issue 43, item 7: a diverging estimate is flagged, a failsafe lands the vehicle and the run
says why; an implausible IMU refuses arming (PX4's preflight checks) and the run ends there.

The faults of the issue, on a short scripted square over a textured floor: before, a gyro bias
step in the air, strong flow noise or an accelerometer bias step left the estimate metres off
with `lost` false and nothing said (the runs ended left_arena, flipped or with the time limit),
and a saturated accelerometer passed the alignment: the vehicle armed and climbed through the
ceiling in 2.3 s."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cosim.load import load_scenario, with_set
from cosim.outputs.series import COL
from cosim.sensors.spec import SensorParams, SensorsSpec
from cosim.sensors.suite import SensorSuite
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from mav.estimator import Estimator
from mav.params import ONBOARD_PARAMS
from mav.wire import FlatEarth

ROOT = Path(__file__).resolve().parent.parent
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
HIL = {"sensors.feed": "hil", "sensors.flow_floor": "textured"}


def _square(t_final: float, **sets):
    return with_set(load_scenario(SQUARE), {**HIL, "timing.t_final_s": t_final, **sets})


def _texts(res) -> list[str]:
    from test_faults import _statustexts

    return _statustexts(res)


def _at_rest(kind: float = 1.0, **params) -> str | None:
    """The estimator's preflight answer after 1 s at rest on the floor with these sensors
    (estimator `kind`: TPL_EST_TYPE)."""
    own = {p.name: p.default for p in ONBOARD_PARAMS}
    own["TPL_EST_TYPE"] = kind
    est = Estimator(own, {}, FlatEarth(42.3, -71.35, 71.0))
    su = SensorSuite(SensorsSpec(feed="hil", params=replace(SensorParams(), **params)), 0,
                     0.005, (0.0, 0.0), True)
    y = [0.0] * 21
    y[6], y[15] = 1.0, -9.81           # qw, the specific force at rest
    for k in range(200):
        est.on_hil(su.encode(k * 5000, y))
    return est.preflight()


@pytest.mark.parametrize("params, why", [
    ({}, None),
    ({"acc_max": 2.0}, "Preflight Fail: Accel 0 reads 2.0 m/s^2 at rest"),     # saturated
    ({"acc_scale": (1.0, 1.0, 0.5)}, "Preflight Fail: Accel 0 reads 4.8 m/s^2 at rest"),
    ({"gyro_noise": (0.5, 0.5, 0.5)}, "Preflight Fail: Gyro 0 inconsistent at rest"),
    ({"gyro_bias": (0.2, 0.0, 0.0)}, "Preflight Fail: High Gyro Bias"),
])
@pytest.mark.parametrize("kind", [1.0, 2.0], ids=["type1", "release"])
def test_an_implausible_imu_at_rest_fails_the_preflight_checks(params, why, kind):
    assert _at_rest(kind, **params) == why


@pytest.mark.flight
def test_a_saturated_accelerometer_refuses_arming_and_the_run_ends_saying_so():
    """Before: alignment passed on 2 m/s^2 of 'gravity', the vehicle armed and left through
    the ceiling 2.3 s later. Now: 'Preflight Fail', the arm COMMAND_ACK denied, the app stops
    asking and the run ends at once, the motors never spun."""
    res = run_scenario(_square(6.0, **{"sensors.imu.acc_max": 2.0}), RunOptions())
    assert res.exit_reason is ExitReason.APP_ABORTED
    assert res.message == "arming refused: Preflight Fail: Accel 0 reads 2.0 m/s^2 at rest"
    assert res.t_end_s < 1.5 and [name for _, name in res.events] == ["arming_refused"]
    texts = _texts(res)
    assert "Preflight Fail: Accel 0 reads 2.0 m/s^2 at rest" in texts and "Armed" not in texts
    u = [COL[k] for k in ("u1", "u2", "u3", "u4")]
    assert not res.series[:, u].any()


def _fails(res, kind: str) -> None:
    st = res.onboard_stats
    assert st[f"failsafe_est_{kind}"] == 1, st
    what = "attitude" if kind == "tilt" else "velocity"
    assert f"Failsafe: estimator failure ({what}), landing" in _texts(res)
    assert res.message.endswith(f"; failsafe: estimator failure ({what})")
    assert res.estimate[-1, -1] == 1.0          # the position is lost for good


@pytest.mark.flight
def test_an_accelerometer_bias_step_in_the_air_is_flagged_and_the_vehicle_lands():
    """3 m/s^2 on x at 6 s: the tilt innovation (the accelerometer's gravity against the
    estimated roll and pitch) stays outside its gate; before, the flight went on 12 deg off
    in attitude to the time limit and nothing was said."""
    res = run_scenario(_square(14.0, **{"faults.sensor": [
        {"kind": "imu_bias", "start_s": 6.0, "value": [3.0, 0.0, 0.0]}]}), RunOptions())
    _fails(res, "tilt")
    assert res.exit_reason is ExitReason.LANDED, res.message
    assert res.series[-1, 3] > -0.05


@pytest.mark.flight
def test_strong_flow_noise_is_flagged_and_the_vehicle_lands():
    """3 rad/s of flow noise from the start: before, the estimate wandered up to 2.9 m off
    with `lost` false to the time limit."""
    res = run_scenario(_square(12.0, **{"sensors.flow.flow_noise_rad_s": 3.0}), RunOptions())
    _fails(res, "tilt")
    assert res.exit_reason is ExitReason.LANDED, res.message


@pytest.mark.flight
def test_a_gyro_bias_step_in_the_air_is_flagged_within_two_seconds():
    """0.3 rad/s on x at 6 s (the estimate drifts 45 deg in attitude: this estimator cannot
    fly on it, and before it left the arena 3 s later without a word): the failsafe fires and
    the summary's message names it, whatever the end."""
    res = run_scenario(_square(9.0, **{"faults.sensor": [
        {"kind": "imu_bias", "start_s": 6.0, "gyro": [0.3, 0.0, 0.0]}]}), RunOptions())
    _fails(res, "tilt")
    t = res.series[:, 0]
    lost = res.estimate[:, -1] > 0
    assert 6.0 < t[np.argmax(lost)] < 8.0        # measured 7.8
