"""The onboard estimator's own checks (issue 43): the barometer's reference only from readings
it accepted, HIL_SENSOR's `fields_updated` honoured (MAVLink HIL_SENSOR_UPDATED_FLAGS, read as
PX4's simulator interface reads them), and a state that is not finite reset and reported."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from cosim.load import load_scenario, with_set
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from mav import hil_sensors as hs
from mav.estimator import Estimator
from mav.hil import SIM_SYSID
from mav.params import ONBOARD_PARAMS
from mav.wire import FlatEarth

ROOT = Path(__file__).resolve().parent.parent
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
P0_HPA = 1012.7095
RHO_G = 1.225 * 9.81
ALL = 0x1FFF
NO_BARO = ALL & ~0x1A00
SIM = M.MAVLink(None, SIM_SYSID, M.MAV_COMP_ID_SYSTEM_CONTROL)


def _estimator() -> tuple[Estimator, dict]:
    own = {p.name: p.default for p in ONBOARD_PARAMS}
    own["TPL_EST_TYPE"] = 1.0
    stats: dict[str, int] = {}
    return Estimator(own, stats, FlatEarth(42.3, -71.35, 71.0)), stats


def _sensor(k: int, hpa: float, fields: int = ALL, z: float = 0.0) -> bytes:
    """HIL_SENSOR at rest at height -z (m) with abs_pressure `hpa` (None: the true one)."""
    if hpa is None:
        hpa = P0_HPA + z * RHO_G / 100.0
    return hs.encode_hil_sensor(SIM, k * 5000, (0.0, 0.0, -9.81), (0.0, 0.0, 0.0),
                                (0.2, -0.05, 0.48), hpa, 0.0, 25.0, fields)


@pytest.mark.parametrize("first", [math.nan, 0.0, 5000.0, "absent"])
def test_a_bad_first_barometer_reading_never_becomes_the_reference(first):
    """Before, a NaN, out-of-range or absent (abs_pressure 0, bit 9 clear) first reading left
    the reference pressure NaN, and the altitude with it, for ever."""
    est, st = _estimator()
    if first == "absent":
        est.on_hil(_sensor(0, 0.0, NO_BARO))
    else:
        est.on_hil(_sensor(0, first))
    for k in range(1, 300):
        od = est.on_hil(_sensor(k, None))
    e = est.impl
    assert math.isfinite(e.p0_hpa) and abs(e.p0_hpa - P0_HPA) < 1e-3
    assert all(math.isfinite(v) for v in od[1:14]) and abs(e.z) < 1e-3
    assert st["est_baro_fused"] > 150


def test_no_barometer_at_rest_takes_the_reference_at_the_altitude_estimated_then():
    est, st = _estimator()
    for k in range(150):                       # the alignment without any pressure
        est.on_hil(_sensor(k, 0.0, NO_BARO))
    assert math.isnan(est.impl.p0_hpa) and st["est_rej_baro"] == 0
    for k in range(150, 400):
        est.on_hil(_sensor(k, None))
    assert abs(est.impl.p0_hpa - P0_HPA) < 1e-3 and st["est_baro_fused"] > 200


@pytest.mark.parametrize("kind", [1.0, 2.0], ids=["type1", "release"])
def test_a_reference_taken_in_the_air_is_the_floors(kind):
    """No barometer at rest, the first one 1 m up: the reference is the floor's pressure
    (p + rho g h), so the barometer's altitude is the height (it was 2 h off: the sign)."""
    est, st = _estimator()
    if kind == 2.0:
        from mav.estimator.release import ReleaseEstimator

        est.impl = ReleaseEstimator(est.own, st)
    for k in range(150):
        est.on_hil(_sensor(k, 0.0, NO_BARO))
    est.impl.z = -1.0                          # 1 m above the floor when the first comes
    est.on_hil(_sensor(150, None, z=-1.0))
    assert abs(est.impl.p0_hpa - P0_HPA) < 2e-3, est.impl.p0_hpa


def test_fields_updated_is_honoured():
    """A pressure 0.5 m off, carried without its bit: not read (not fused, not rejected);
    with its bit it moves the estimate. Accelerometer and gyro without theirs: no IMU step."""
    def run(fields: int) -> tuple[float, dict]:
        est, st = _estimator()
        for k in range(200):
            est.on_hil(_sensor(k, None))
        for k in range(200, 300):
            est.on_hil(_sensor(k, P0_HPA - 0.5 * RHO_G / 100.0, fields))
        return est.impl.z, st

    z_clear, st_clear = run(NO_BARO)
    z_set, _ = run(ALL)
    assert abs(z_clear) < 1e-4 and st_clear["est_baro_fused"] == 100
    assert z_set < -0.05                       # m: pulled up towards the reading
    est, st = _estimator()
    for k in range(200):
        est.on_hil(_sensor(k, None, ALL & ~0x3F))
    assert est.impl.n == 0 and est.impl.imu_us == -1


def test_a_state_that_is_not_finite_is_reset_and_reported():
    """No reading may make the state non-finite; should one ever, the part affected starts
    again (counted), and the vehicle says so."""
    est, st = _estimator()
    for k in range(200):
        est.on_hil(_sensor(k, None))
    est.impl.z = math.nan
    od = est.on_hil(_sensor(200, None))
    assert st["est_resets"] == 1 and all(math.isfinite(v) for v in od[1:14])


@pytest.mark.flight
def test_a_barometer_of_noise_flies_on_the_sonar():
    """`baro_noise_pa=1e6` (the issue: validation passed, then the altitude went NaN and the
    vehicle stopped answering, `component_error: onboard`): nearly every reading is out of
    range and rejected, the few accepted ones gated; the mission flies on the sonar."""
    sc = with_set(load_scenario(SQUARE), {"sensors.baro.baro_noise_pa": 1e6,
                                          "timing.t_final_s": 20.0})
    res = run_scenario(sc, RunOptions())
    assert res.exit_reason is not ExitReason.COMPONENT_ERROR, res.message
    st = res.onboard_stats
    assert st["est_rej_baro"] > 0.9 * res.ticks and st["est_resets"] == 0
    import numpy as np

    assert np.isfinite(res.estimate[:, :9]).all()
    assert abs(res.estimate[-1, 2] - res.series[-1, 3]) < 0.1


@pytest.mark.flight
def test_a_lost_position_is_regained_only_by_aiding_not_by_descending():
    """Over a plain floor (no usable flow from the start): before, below 0.5 m the estimator
    said "Position estimate regained" with nothing fused, the app's pending take-off was
    accepted, and the climb-lose cycle went on until the vehicle left the arena 4.5 m away.
    Now the failsafe's landing goes on to the floor, and the position stays lost."""
    from test_faults import _statustexts

    sc = with_set(load_scenario(ROOT / "scenarios" / "mambo_hover.toml"),
                  {"sensors.flow_floor": "plain", "timing.t_final_s": 15.0})
    res = run_scenario(sc, RunOptions())
    texts = _statustexts(res)[::2]
    assert "Position estimate regained" not in texts, texts
    assert texts.count("Failsafe: no position estimate, landing") == 1
    assert res.exit_reason is not ExitReason.LEFT_ARENA, res.message
    z = res.series[:, 3]
    t_land = res.series[z < -0.5, 0].max()
    assert (z[res.series[:, 0] > t_land + 3.0] > -0.05).all()     # down, and stays down


def _gps(mav, k: int, n_m: float, eph_cm: int = 50, nsat: int = 10) -> bytes:
    geo = FlatEarth(42.3, -71.35, 71.0)
    lat, lon, alt = geo.to_int(n_m, 0.0, 0.0)
    rest = hs._GPS_REST(lat, lon, alt, eph_cm, 2 * eph_cm, 0, 0, 0, 0, 65535, 3, nsat, 0, 0)
    return hs.stamped(mav, hs.HIL_GPS, k * 5000, rest)


def test_gps_fixes_pass_ekf2s_checks_and_gate_or_are_rejected():
    """Fixes 100 m off for 3 s moved the estimate 2.6 km before (no check at all). Now EKF2's
    quality checks (EKF2_REQ_EPH 3 m, EKF2_REQ_NSATS 6) and its innovation gate
    (EKF2_GPS_P_GATE 5 sd) reject them; another system's fix is not read."""
    est, st = _estimator()
    other = M.MAVLink(None, 77, M.MAV_COMP_ID_SYSTEM_CONTROL)
    k = 0

    def tick(gps: bytes = b"") -> None:
        nonlocal k
        est.on_hil(_sensor(k, None) + gps)
        k += 1

    for _ in range(200):
        tick(_gps(SIM, k, 0.0) if k % 40 == 0 else b"")
    assert st["est_gps_fused"] == 5 and st["est_rej_gps"] == 0
    for _ in range(600):                               # 3 s of fixes 100 m off, at 5 Hz
        tick(_gps(SIM, k, 100.0) if k % 40 == 0 else b"")
    assert st["est_rej_gps"] == 15 and st["est_gps_fused"] == 5
    assert abs(est.impl.x) < 0.1
    for eph, nsat in ((500, 10), (50, 4)):             # 5 m accuracy; 4 satellites
        tick(_gps(SIM, k, 1.0, eph, nsat))
    assert st["est_rej_gps"] == 17
    tick(_gps(other, k, 1.0))
    assert st["est_rej_gps"] == 17 and st["est_gps_fused"] == 5 and st["est_bad_frames"] == 0
    tick(_gps(SIM, k, 1.0))                            # a good fix: fused
    assert st["est_gps_fused"] == 6
