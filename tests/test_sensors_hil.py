"""Sensor-fed HIL link (`[sensors] feed = "hil"`): the sensor models, PX4's simulator messages,
the onboard estimator (mav/estimator/), its outlier rules and faults, MIL == SIL."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set
from cosim.outputs.metrics import compute_metrics
from cosim.sensors.spec import SensorsSpec
from cosim.sensors.suite import SensorSuite
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from mav import hil_sensors as hs
from mav.estimator import Estimator
from mav.params import ONBOARD_PARAMS
from mav.wire import FlatEarth

ROOT = Path(__file__).resolve().parent.parent
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
HOVER = ROOT / "scenarios" / "mambo_hover.toml"
HIL = {"sensors.feed": "hil", "sensors.flow_floor": "textured"}


def _square(**sets):
    return with_set(load_scenario(SQUARE), {**HIL, "timing.t_final_s": 12.0, **sets})


def _y(z: float = 0.0) -> list[float]:
    y = [0.0] * 21
    y[2], y[6], y[15] = z, 1.0, -9.81      # z, qw, specific force z at rest
    return y


def _estimator() -> tuple[Estimator, dict]:
    own = {p.name: p.default for p in ONBOARD_PARAMS}
    own["TPL_EST_TYPE"] = 1.0
    stats: dict[str, int] = {}
    return Estimator(own, stats, FlatEarth(42.3, -71.35, 71.0)), stats


@pytest.mark.flight
def test_mil_and_sil_are_bit_identical_with_sensors_on():
    sc = _square()
    mil, sil = (run_scenario(sc, RunOptions(mode=m)) for m in ("mil", "sil"))
    assert mil.ticks == sil.ticks == 2400, (mil.message, sil.message)
    assert mil.series.tobytes() == sil.series.tobytes()
    assert mil.estimate.tobytes() == sil.estimate.tobytes()
    assert mil.tlog.read() == sil.tlog.read()
    assert sil.onboard_stats["est_flow_fused"] > 1000      # the SIL vehicle estimated too
    # it flew on its estimate, which is not the truth
    e = mil.estimate[-1]
    assert 0.0 < math.dist(e[:3], mil.series[-1, 1:4]) < 0.5


@pytest.mark.flight
def test_same_seed_same_flight_other_seed_other_noise():
    a, b = (run_scenario(_square(**{"timing.t_final_s": 4.0}), RunOptions()) for _ in range(2))
    c = run_scenario(_square(**{"timing.t_final_s": 4.0, "seed": 7}), RunOptions())
    assert a.series.tobytes() == b.series.tobytes()
    assert a.estimate.tobytes() == b.estimate.tobytes()
    assert a.estimate.tobytes() != c.estimate.tobytes()


@pytest.mark.flight
def test_the_sensors_are_the_default_feed_and_the_truth_an_option():
    sc = load_scenario(SQUARE)
    assert sc.sensors.hil and dict(sc.onboard_params)["TPL_EST_TYPE"] == 2.0   # the release
    truth = with_set(sc, {"sensors.feed": "truth", "timing.t_final_s": 2.0})
    assert not truth.sensors.hil and dict(truth.onboard_params).get("TPL_EST_TYPE") is None
    assert run_scenario(truth, RunOptions()).estimate is None
    # the ODOMETRY's noise belongs to the truth feed: on the sensors it is an error, named
    with pytest.raises(ScenarioError, match="sensors.odometry_noise"):
        with_set(sc, {"sensors.odometry_noise.pos_std_m": 0.01})
    # so are the ODOMETRY's faults, named, and both are fine on the truth feed
    drop = [{"kind": "dropout", "start_s": 1.0, "end_s": 2.0}]
    with pytest.raises(ScenarioError) as ei:
        with_set(sc, {"faults.odometry": drop})
    assert ei.value.field == "faults.odometry" and "flow_loss" in str(ei.value)
    ok = with_set(sc, {"sensors.feed": "truth", "faults.odometry": drop,
                       "sensors.odometry_noise.pos_std_m": 0.01})
    assert not ok.sensors.hil and len(ok.faults.odometry) == 1


@pytest.mark.flight
def test_a_lost_position_keeps_the_altitude_and_refuses_the_position_modes():
    """Over a plain floor the flow gives nothing: the position is lost once above 0.5 m
    (TPL_NOAID_TOUT). The vehicle holds level at its estimated altitude (sonar, baro), as
    PX4 falls back to altitude mode; before, it saw no vertical error either and kept the
    take-off's climb rate up to 5 m. It lands by TPL_POS_FS_DELAY and meanwhile refuses
    take-off and the modes that need a position."""
    from test_faults import _statustexts

    sc = with_set(load_scenario(HOVER), {"sensors.flow_floor": "plain", "timing.t_final_s": 6.0})
    res = run_scenario(sc, RunOptions())
    t, z = res.series[:, 0], res.series[:, 3]
    lost = res.estimate[:, -1]
    assert lost.any() and not lost[t < 0.5].any()
    assert z.min() > -1.2                       # the take-off's 1 m, not a runaway climb
    texts = _statustexts(res)
    # the app's first arm came before the estimator's 0.5 s of tilt alignment: refused
    assert texts[0] == "Arming denied: attitude not aligned yet (estimator)"
    assert "Position estimate lost, holding level" in texts
    fs = texts.index("Failsafe: no position estimate, landing")
    assert "AUTO.TAKEOFF denied: no local position" in texts[fs:]   # the app's retry
    t_lost = t[np.argmax(lost > 0)]
    held, landing = z[t > t_lost + 1.0][0], z[t > t_lost + 2.5][0]
    assert landing > held + 0.2                  # TPL_POS_FS_DELAY after: descending


@pytest.mark.flight
def test_seed_mission_on_the_estimate_meets_the_landing_and_coverage_targets():
    res = run_scenario(with_set(load_scenario(SEED), {"sensors.feed": "hil"}), RunOptions())
    assert res.exit_reason is ExitReason.MISSION_COMPLETE, res.message
    m = compute_metrics(res, res.scenario.world)
    assert m["landing_error_m"] <= 0.10 and m["track_coverage"] >= 0.98
    assert 0.0 < m["estimation_error_pos_rms_m"] < 0.5
    assert m["estimation_error_att_rms_deg"] < 3.0


def test_sonar_has_no_reading_below_its_minimum():
    su = SensorSuite(SensorsSpec(feed="hil"), 0, 0.005, (0.0, 0.0), True)
    for z, echo in ((-0.30, False), (-1.0, True)):
        for k in range(3):   # past the one-tick delay
            msgs, bad = hs.decode_bundle(su.encode(k * 5000, _y(z)))
        d = msgs[hs.DISTANCE_SENSOR.id]
        assert bad == 0
        assert (d[14] != hs.NO_ECHO) is echo
        if echo:
            assert abs(d[3] - 100) <= 5     # cm


def test_distance_sensor_carries_the_range_noise_variance():
    """DISTANCE_SENSOR's covariance is the variance in cm^2 (common.xml; PX4 reads it as the
    variance, 0 = an exact sensor), 255 when it does not fit (issue 44, item 3)."""
    su = SensorSuite(SensorsSpec(feed="hil"), 0, 0.005, (0.0, 0.0), True)
    for k in range(3):
        msgs, _ = hs.decode_bundle(su.encode(k * 5000, _y(-1.0)))
    assert msgs[hs.DISTANCE_SENSOR.id][7] == 1                  # range_noise_m 0.01: 1 cm^2
    assert [hs.range_covariance(n) for n in (0.0, 0.001, 0.01, 0.05, 0.159, 0.16, 1.0)] == [
        0, 1, 1, 25, 253, 255, 255]


def test_imu_at_rest_reads_gravity_with_the_template_noise():
    su = SensorSuite(SensorsSpec(feed="hil"), 3, 0.005, (0.0, 0.0), True)
    acc = np.array([hs.decode_bundle(su.encode(k * 5000, _y()))[0][hs.HIL_SENSOR.id][1:4]
                    for k in range(4000)])
    p = su.p
    assert np.allclose(acc.mean(axis=0),
                       (p.acc_bias[0], p.acc_bias[1], -9.81 * p.acc_scale[2] + p.acc_bias[2]),
                       atol=0.01)
    # band-limited noise std = sigma sqrt(weight / 5 ms), seen through the 190 rad/s filter
    assert 0.1 < acc[:, 0].std() < 0.25


def test_outliers_are_rejected_and_counted_never_propagated():
    est, st = _estimator()
    su = SensorSuite(SensorsSpec(feed="hil"), 0, 0.005, (0.0, 0.0), True)
    for k in range(50):
        est.on_hil(su.encode(k * 5000, _y(-1.0)))
    nan = float("nan")
    imu = hs.encode_hil_sensor(su.mav, 250_000, (nan, 0.0, -9.8), (0.0, 0.0, 0.0),
                               (0.2, 0.0, 0.4), 1012.0, 1.0, 25.0, 0x3FFF)
    flow = hs.encode_flow(su.mav, 250_000, 5000, nan, 1e9, 0.0, 0.0, 0.0, 255)
    rng = hs.encode_distance(su.mav, 250_000, 44, 400, 350, 100)   # 3.5 m: a jump
    before = dict(st)
    od = est.on_hil(imu + flow + rng + b"\xfd\x01garbage")
    grew = {k for k in st if st[k] != before[k]}
    assert {"est_rej_imu", "est_rej_flow", "est_rej_rng", "est_bad_frames"} <= grew
    assert not grew & {"est_flow_fused", "est_rng_fused", "est_baro_fused"}
    assert all(math.isfinite(v) for v in od[1:14])


@pytest.mark.flight
def test_sensor_faults_reach_the_estimate_and_are_counted():
    sc = _square(**{"faults.sensor": [
        {"kind": "flow_garbage", "start_s": 6.0, "end_s": 7.0, "value": [1, 0, 0]},
        {"kind": "sonar_dropout", "start_s": 7.0, "end_s": 8.0},
        {"kind": "mag_interference", "start_s": 8.0, "end_s": 9.0, "value": [0.3, 0, 0]},
        {"kind": "imu_bias", "start_s": 9.0, "end_s": 10.0, "value": [0.3, 0, 0]},
        {"kind": "baro_drift", "start_s": 10.0, "end_s": 11.0, "value": [20, 0, 0]},
        # (at 0.05 rad/s the rate loop goes blind and the vehicle flips within 0.3 s)
        {"kind": "gyro_saturation", "start_s": 11.0, "end_s": 11.5, "value": [0.5, 0, 0]},
        {"kind": "flow_loss", "start_s": 11.5, "end_s": 12.0}]})
    res = run_scenario(sc, RunOptions())
    kinds = [w for _, w in res.faults]
    assert kinds == ["sensor flow_garbage", "sensor sonar_dropout", "sensor mag_interference",
                     "sensor imu_bias", "sensor baro_drift", "sensor gyro_saturation",
                     "sensor flow_loss"]
    st = res.onboard_stats
    assert st["est_rej_flow"] >= 200            # 1 s of NaN flow, all rejected
    assert np.isfinite(res.estimate[:, :9]).all()


@pytest.mark.parametrize("table, value, field", [
    ({"feed": "odometry"}, None, "sensors.feed"),
    ({"imu": {"acc_noise": [0.1, -1, 0]}}, None, "sensors.imu.acc_noise"),
    ({"range": {"range_min_m": 5.0}}, None, "sensors.range.range_max_m"),
    ({"flow": {"flow_every": 0}}, None, "sensors.flow.flow_every"),
    ({"baro": {"typo": 1}}, None, "sensors.baro.typo"),
    ({"imu": {"imu_wn": 2000.0}}, None, "sensors.imu.imu_wn"),     # above Nyquist
    ({"gps": {"enabled": 1}}, None, "sensors.gps.enabled"),
])
def test_bad_sensor_fields_are_named(table, value, field):
    raw = dict(load_scenario(SQUARE).raw)
    raw["sensors"] = table
    from cosim.load import parse_scenario

    with pytest.raises(ScenarioError) as ei:
        parse_scenario(raw, source=str(SQUARE), base_dir=SQUARE.parent)
    assert ei.value.field == field


def test_a_sensor_feed_needs_the_estimator():
    with pytest.raises(ScenarioError) as ei:
        _square(**{"onboard.params.TPL_EST_TYPE": 0})
    assert ei.value.field == "onboard.params.TPL_EST_TYPE"


def test_bad_sensor_fault_is_named():
    with pytest.raises(ScenarioError) as ei:
        _square(**{"faults.sensor": [{"kind": "gyro_saturation", "start_s": 1.0}]})
    assert ei.value.field == "faults.sensor[0].value"


def test_estimator_status_flags_follow_the_aiding():
    from pymavlink.dialects.v20 import common as M

    est, st = _estimator()
    su = SensorSuite(SensorsSpec(feed="hil"), 0, 0.005, (0.0, 0.0), True)
    k = 0
    for z in [0.0] * 20 + [-0.01 * i for i in range(1, 101)] + [-1.0] * 100:   # climb to 1 m
        est.on_hil(su.encode(k * 5000, _y(z)))
        k += 1
    f = est.status_flags()
    good = (M.ESTIMATOR_ATTITUDE | M.ESTIMATOR_VELOCITY_HORIZ | M.ESTIMATOR_POS_HORIZ_REL
            | M.ESTIMATOR_POS_VERT_AGL | M.ESTIMATOR_VELOCITY_VERT | M.ESTIMATOR_POS_VERT_ABS)
    assert f == good, bin(f)
    su.faults = (SensorFaultFor("flow_loss", k * 0.005),)
    for _ in range(300):                          # 1.5 s without flow: position lost
        od = est.on_hil(su.encode(k * 5000, _y(-1.0)))
        k += 1
    f = est.status_flags()
    assert f & M.ESTIMATOR_CONST_POS_MODE and not f & M.ESTIMATOR_POS_HORIZ_REL
    assert od[16] == -1 and est.impl.lost


def SensorFaultFor(kind: str, start_s: float):
    from cosim.faults.sensors import SensorFault

    return SensorFault(kind, start_s, 1e9, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_estimator_status_on_request_on_odometry():
    from pymavlink.dialects.v20 import common as M
    from test_onboard_rig import Rig

    rig = Rig()
    rig.tick(3)
    rig.cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_ESTIMATOR_STATUS)
    rig.tick()
    es = rig.last("gcs", "ESTIMATOR_STATUS")
    assert es.flags & M.ESTIMATOR_POS_HORIZ_REL and es.flags & M.ESTIMATOR_ATTITUDE


@pytest.mark.flight
def test_gps_fixes_reach_the_estimate():
    res = run_scenario(_square(**{"sensors.gps.enabled": True, "timing.t_final_s": 8.0}),
                       RunOptions())
    st = res.onboard_stats
    # 5 Hz, every fix (the first one twice: the one-tick delay line starts full of it)
    assert st["est_gps_fused"] == 8.0 / 0.2 + 1 and st["est_rej_gps"] == 0


@pytest.mark.flight
def test_flow_lost_in_flight_is_a_lost_position_and_the_vehicle_lands():
    # type 1: on paper 1's release the vehicle has no horizontal velocity without the flow and
    # holds level on a gyro-only attitude, and the square drifts out of its 4.5 m arena
    # before it lands (docs/sensors.md, "Paper 1's release vs ours")
    sc = _square(**{"timing.t_final_s": 30.0, "onboard.params.TPL_EST_TYPE": 1,
                    "faults.sensor": [{"kind": "flow_loss", "start_s": 8.0}]})
    res = run_scenario(sc, RunOptions())
    st = res.onboard_stats
    lost = res.estimate[:, -1]
    t = res.series[:, 0]
    assert lost[t < 8.0].sum() == 0 and lost[(t > 9.5) & (t < 10.0)].all()
    assert st["odometry_lost"] > 0                   # the vehicle's failsafe saw it
    assert res.series[-1, 3] > -0.05                 # landed (z ~ 0), TPL_POS_FS_DELAY later


@pytest.mark.flight
def test_the_altitude_filter_learns_the_accelerometer_bias():
    """The altitude filter's third state (EKF2 learns the accelerometer's bias the same way):
    without it the Mambo's vertical accelerometer error (bias 0.08 m/s^2 and a 0.55 % scale
    factor, ~0.13 m/s^2 at 1 g) left the vertical speed estimate ~0.03 m/s off in hover while
    the altitude was right, and paper 2's oval (E3) missed its last key by that drift."""
    def vz_offset(lim: float) -> float:
        res = run_scenario(with_set(load_scenario(HOVER), {          # type 1's bias state
            "timing.t_final_s": 12.0, "onboard.params.EKF2_ABL_LIM": lim,
            "onboard.params.TPL_EST_TYPE": 1}), RunOptions())
        late = res.series[:, 0] > 6.0
        return float(np.mean(res.estimate[late, 5] - res.series[late, 6]))    # est_vz - vz

    assert abs(vz_offset(0.4)) < 0.005          # PX4's default limit: measured 0.002 m/s
    assert vz_offset(0.0) > 0.02                # no bias learnt (limit 0): 0.034 m/s


@pytest.mark.flight
def test_the_estimate_is_spooled_chunk_by_chunk_in_order():
    """The estimate rows go to disk a CHUNK at a time (memory flat over a long run, as the
    series): over 5000 ticks, across the first chunk's boundary, the spooled estimate is the
    one the series recorded tick by tick (its est_x/y/z columns), none lost or reordered."""
    from cosim.outputs.series import CHUNK, COL

    res = run_scenario(with_set(load_scenario(HOVER), {"timing.t_final_s": 25.0}), RunOptions())
    assert len(res.estimate) == res.ticks == 5000 > CHUNK
    rec = np.asarray(res.series)[:, [COL["est_x"], COL["est_y"], COL["est_z"]]]
    assert np.array_equal(np.asarray(res.estimate)[:, :3], rec)


@pytest.mark.parametrize("signed", [False, True])
def test_a_sensor_datagram_framed_at_once_is_its_frames_one_by_one(signed):
    """hs.frames (one buffer, the sensor datagram of a tick) == frame() per message, across a
    seq wrap, signed or not; pymavlink reads every frame back."""
    from pymavlink.dialects.v20 import common as M

    from mav import wire

    a, b = (M.MAVLink(None, 250, 190) for _ in range(2))
    for m in (a, b):
        m.seq = 254
        if signed:
            sg = m.signing
            sg.secret_key, sg.sign_outgoing, sg.link_id, sg.timestamp = bytes(32), True, 1, 7
    rests = [(hs.HIL_SENSOR, hs.hil_sensor_rest(0.1, -0.2, -9.8, 0.01, 0.0, 0.0, 0.2, 0.0, 0.4,
                                                1013.2, 1.5, 25.0, 0x1FFF)),
             (hs.DISTANCE_SENSOR, hs.distance_rest(44, 400, 0, hs.NO_ECHO, 1)),
             (hs.HIL_OPTICAL_FLOW, hs.flow_rest(20000, 0.0, 0.0, 0.0, 0.0, 0.0, 0)),
             ]
    parts = []
    for m, rest in rests:
        parts += [m, hs.stamp(m, 123456789, rest)]
    parts += [hs.HIL_STATE_QUATERNION,
              hs.truth_payload(123456789, 1.0, 0, 0, 0, 0, 0, 0, 1, 2, 3, 0, 0, 0)]
    one_by_one = b"".join(wire.frame(a, parts[i], parts[i + 1]) for i in range(0, 8, 2))
    assert hs.frames(b, parts) == one_by_one
    assert a.seq == b.seq == 2 and a.signing.timestamp == b.signing.timestamp
    reader = M.MAVLink(None, 1, 1)
    reader.signing.secret_key = bytes(32) if signed else None
    got = reader.parse_buffer(bytearray(one_by_one))
    assert [g.get_type() for g in got] == ["HIL_SENSOR", "DISTANCE_SENSOR", "HIL_OPTICAL_FLOW",
                                           "HIL_STATE_QUATERNION"]
    assert [g.get_seq() for g in got] == [254, 255, 0, 1]
    assert hs.decode_bundle(one_by_one)[1] == 0


def test_at_rest_on_the_floor_the_estimate_holds_still():
    """A vehicle left on the ground (flow messages every tick, all rejected below 0.4 m): the
    zero-velocity update holds the estimate (it walked ~6 cm/s while ZUPT waited for a tick
    without a flow message, found by a ground station in `cosim sitl`)."""
    sc = load_scenario(SQUARE)
    su = SensorSuite(sc.sensors, 0, 0.005, (0.0, 0.0), True)
    est, st = _estimator()
    far = 0.0
    for k in range(2400):                                  # 12 s
        est.on_hil(su.encode(k * 5000, _y(0.00024525)))
        far = max(far, math.hypot(est.impl.x, est.impl.y))
    assert st["est_rej_flow"] == 2400 and st["est_flow_fused"] == 0    # every tick, rejected
    assert far < 0.02, far


def _sys_status(res) -> list[tuple[float, int]]:
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(res.run_dir / "flight.tlog"))
    out = []
    while (m := log.recv_match(type="SYS_STATUS")) is not None:
        out.append((m._timestamp, m.onboard_control_sensors_health))
    return out


@pytest.mark.flight
@pytest.mark.parametrize("feed", ["hil", "truth"])
def test_sys_status_says_not_ready_until_the_estimator_is_aligned(feed, tmp_path):
    """As PX4 before EKF2's tilt alignment: the pre-arm check (a ground station's "Ready To
    Fly", MAVSDK's is_armable) and AHRS unhealthy while arming would be refused."""
    from pymavlink.dialects.v20 import common as M

    res = run_scenario(_square(**{"sensors.feed": feed, "timing.t_final_s": 3.0}),
                       RunOptions(mode="mil", out_dir=tmp_path))
    st = _sys_status(res)
    t0 = st[0][0]
    early = [h for t, h in st if t - t0 < 0.4]
    later = [h for t, h in st if t - t0 > 1.0]
    assert early and later
    ready = M.MAV_SYS_STATUS_PREARM_CHECK | M.MAV_SYS_STATUS_AHRS
    assert all(h & ready == ready for h in later)
    assert all(h & ready == (0 if feed == "hil" else ready) for h in early), early
