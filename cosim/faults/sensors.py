"""Faults on the sensor messages, `[[faults.sensor]]` (only with `[sensors] feed = "hil"`):

    [[faults.sensor]]
    kind = "imu_bias"          # imu_bias: accel `value` m/s^2 and gyro `gyro` rad/s added
    start_s = 20.0             #   (a bias step) | gyro_saturation: the gyro clips at `value`
    end_s = 30.0               #   rad/s | sonar_dropout: no echo | flow_garbage: the flow
    value = [0.5, 0.0, 0.0]    #   reads NaN (`value` = [1, 0, 0]) or noise of `value[0]`
    gyro = [0.0, 0.0, 0.0]     #   rad/s (`value` = [0, s, 0]) at full quality | flow_loss: no
                               #   flow message | baro_drift: the pressure drifts value[0]
                               #   Pa/s from start_s | mag_interference: `value` gauss added

Every window is [start_s, end_s) of simulated time; random draws (flow garbage) come from the
sensor's own seeded stream, so a faulty run is as reproducible as a clean one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from cosim.errors import ScenarioError
from cosim.scenario.validate import no_unknown, string

KINDS = ("imu_bias", "gyro_saturation", "sonar_dropout", "flow_garbage", "flow_loss",
         "baro_drift", "mag_interference")


@dataclass(frozen=True)
class SensorFault:
    kind: str
    start_s: float
    end_s: float
    value: tuple[float, float, float]
    gyro: tuple[float, float, float]


def _triple(e: Mapping, k: str, w: str, default: tuple) -> tuple[float, float, float]:
    v = e.get(k, list(default))
    if (not isinstance(v, list) or len(v) != 3 or any(
            isinstance(b, bool) or not isinstance(b, int | float) or not abs(b) <= 1e5
            for b in v)):
        raise ScenarioError(f"{w}.{k}", v, "3 numbers, each within 1e5")
    return (float(v[0]), float(v[1]), float(v[2]))


def parse_sensor_faults(entries: list[tuple[str, dict]],
                        window: Callable) -> tuple[SensorFault, ...]:
    out = []
    for w, e in entries:
        no_unknown(e, {"kind", "start_s", "end_s", "value", "gyro"}, w)
        kind = string(e, "kind", w, choices=KINDS)
        start, end = window(e, w)
        value = _triple(e, "value", w, (0.0, 0.0, 0.0))
        gyro = _triple(e, "gyro", w, (0.0, 0.0, 0.0))
        if kind == "gyro_saturation" and not value[0] > 0.0:
            raise ScenarioError(f"{w}.value", list(value), "[limit rad/s > 0, 0, 0]")
        if kind in ("imu_bias", "baro_drift", "mag_interference") and not (
                any(value) or any(gyro)):
            raise ScenarioError(f"{w}.value", list(value), f"a non-zero value for {kind}")
        out.append(SensorFault(kind, start, end, value, gyro))
    return tuple(out)
