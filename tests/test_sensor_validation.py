"""Sensor settings the sensor models cannot send, and sensor faults the feed would not play, are
refused when the scenario is read (exit 2, naming the field), never at the first tick
(issue 43, items 8 and 11)."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set
from cosim.sensors.spec import WIRE_BOUNDS, SensorParams, SensorsSpec
from cosim.sensors.suite import SensorSuite
from mav import hil_sensors as hs

ROOT = Path(__file__).resolve().parent.parent
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
FIELDS = {"range_max_m": "range", "range_min_m": "range", "gps_noise_m": "gps",
          "gps_vel_noise_mps": "gps", "baro_gain": "baro"}


@pytest.mark.parametrize("field, value", [
    ("range_max_m", 1e6), ("gps_noise_m", 1000.0), ("gps_vel_noise_mps", 1e6),
    ("baro_gain", 1e-300), ("range_min_m", 700.0), ("baro_gain", 1e6)])
def test_a_setting_the_wire_cannot_carry_is_refused_and_named(field, value):
    name = f"sensors.{FIELDS[field]}.{field}"
    with pytest.raises(ScenarioError) as ei:
        with_set(load_scenario(SQUARE), {name: value, "sensors.gps.enabled": True})
    assert ei.value.field == name
    assert WIRE_BOUNDS[field][2] in str(ei.value)


@pytest.mark.parametrize("setting", ["sensors.range.range_max_m=1e6",
                                     "sensors.gps.gps_vel_noise_mps=1e6",
                                     "sensors.baro.baro_gain=1e-300"])
def test_the_cli_exits_2_naming_the_field(setting, tmp_path):
    """Through a subprocess, as a user runs it: before, a struct error at the first tick
    blamed on "onboard"."""
    cosim = Path(sys.executable).with_name("cosim")
    p = subprocess.run([str(cosim), "run", str(SQUARE), "--out", str(tmp_path / "r"),
                        "--set", setting, "--set", "sensors.gps.enabled=true"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    assert p.stderr.startswith("cosim: bad input: " + setting.split("=")[0]), p.stderr
    assert not (tmp_path / "r").exists()


def _y(z: float, v: float) -> list[float]:
    y = [0.0] * 21
    y[2], y[6], y[15] = z, 1.0, -9.81
    y[7] = y[8] = y[9] = v                      # m/s, NED velocity
    return y


@pytest.mark.parametrize("edge", ["lo", "hi"])
def test_every_sensor_at_its_bounds_encodes(edge):
    """Every bounded field at its limit (with GPS on, fast and high): the sensor datagrams
    encode and decode, tick after tick."""
    p = SensorParams()
    kw = {k: (lo if edge == "lo" else hi) for k, (lo, hi, _) in WIRE_BOUNDS.items()}
    if edge == "lo":
        kw["range_max_m"] = 0.5
    else:
        kw["range_min_m"] = 1.0
    p = replace(p, **kw, gps_every=1, baro_noise_pa=1e6)
    su = SensorSuite(SensorsSpec(feed="hil", gps=True, params=p), 0, 0.005, (0.0, 0.0), True)
    for k in range(400):
        msgs, bad = hs.decode_bundle(su.encode(k * 5000, _y(-300.0, 30.0)))
        assert bad == 0 and hs.HIL_GPS.id in msgs
    assert all(math.isfinite(v) for v in msgs[hs.HIL_SENSOR.id][1:13])


def test_a_sensor_fault_on_the_truth_feed_is_refused_and_named():
    flow = [{"kind": "flow_loss", "start_s": 1.0, "end_s": 2.0}]
    with pytest.raises(ScenarioError) as ei:
        with_set(load_scenario(SQUARE), {"sensors.feed": "truth", "faults.sensor": flow})
    assert ei.value.field == "faults.sensor" and "faults.odometry" in str(ei.value)
    ok = with_set(load_scenario(SQUARE), {"faults.sensor": flow})     # the sensor feed: fine
    assert ok.sensors.hil and len(ok.faults.sensors) == 1
