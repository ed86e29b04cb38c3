"""The sensor set's parameters: one record per vehicle preset, every field overridable in the
scenario's `[sensors]` table (validated; a bad value names its field, exit 2).

    [sensors]
    feed = "hil"               # hil (default): HIL_SENSOR, HIL_OPTICAL_FLOW, DISTANCE_SENSOR,
                               # HIL_GPS and the vehicle's own estimator (TPL_EST_TYPE 1) |
                               # truth: ODOMETRY (the plant's state, like PX4 on motion capture)
    flow_floor = "auto"        # auto (a room's floor by its texture; a flat world's floor
                               # stands in for the template's aerial photograph: textured)
                               # | textured | plain (the flow fails)
    [sensors.imu]              # any field of SensorParams below, by sensor table
    acc_noise = [0.2, 0.2, 0.2]
    [sensors.gps]
    enabled = true             # a GPS receiver (outdoor worlds; default none)

Mambo numbers: reference/minidrone.md §2.1 (the template's sensorsVars.m): IMU second order
190 rad/s / 0.707, scale factors, +-50 m/s^2 and +-10 rad/s limits, band-limited white noise
of power weight * sigma^2 sampled at 5 ms (std = sigma * sqrt(weight / 0.005)), sonar with no
reading below 0.44 m, pressure = 101270.95 - 1.225 g h, all delayed one 5 ms sample. The
biases are illustrative (the template reads them from a calibration file the reference does
not give). The magnetic field: the World Magnetic Model WMM2020 at its epoch 2020.0, at the
template's origin (42.30 N, 71.35 W, sea level), chosen as the model of the template's time.
Checked against WMM2020's coefficients (docs/sensors.md): X 0.1971, Y -0.0502, Z 0.4765 G,
declination -14.30 deg, inclination 66.89 deg; ours has that declination (-14.31 deg, as
EKF2_MAG_DECL) and a horizontal field 1.8 % stronger (inclination 66.53 deg, 0.520 G), kept
so that the flights do not move (the estimator uses only the heading). Bebop 2: the same
structure with its sonar (up to 8 m: Parrot's spec says "ultrasound sensor, 8 m range"), a
barometer and its vertical camera's flow; numbers not published are the Mambo's. What parts
these numbers stand for, and how they compare with the parts' datasheets: docs/sensors.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from cosim.errors import ScenarioError
from cosim.scenario.validate import boolean, no_unknown, number, string


def _w(sig: tuple[float, ...], weight: float) -> tuple[float, ...]:
    """Band-limited white noise of power weight * sigma^2 sampled at 5 ms -> std per sample."""
    return tuple(s * math.sqrt(weight / 0.005) for s in sig)


@dataclass(frozen=True)
class SensorParams:
    # IMU (body FRD)
    imu_wn: float = 190.0                                   # rad/s, second-order sensor
    imu_zeta: float = 0.707
    acc_scale: tuple[float, ...] = (1.00596, 1.00383, 0.99454)
    gyro_scale: tuple[float, ...] = (0.99861, 1.00644, 0.99997)
    acc_bias: tuple[float, ...] = (0.05, -0.04, 0.08)       # m/s^2 (illustrative)
    gyro_bias: tuple[float, ...] = (0.002, -0.003, 0.001)   # rad/s (illustrative)
    acc_noise: tuple[float, ...] = _w((0.01652, 0.01526, 0.02158), 0.8)
    gyro_noise: tuple[float, ...] = _w((0.000653, 0.000722, 0.000691), 0.025)
    acc_max: float = 50.0                                   # m/s^2
    gyro_max: float = 10.0                                  # rad/s
    delay_ticks: int = 1                                    # every reading, 5 ms late
    # barometer
    baro_p0_pa: float = 101270.95                           # Pa at the floor
    baro_gain: float = 1.225 * 9.81                         # Pa per m of height
    baro_noise_pa: float = 1.5                              # Pa (~0.12 m)
    # magnetometer (gauss, world NED; body reading = R^T m)
    mag_field: tuple[float, ...] = (0.2007, -0.0512, 0.4769)  # WMM2020 at 2020.0 (above)
    mag_noise: float = 0.004                                # gauss
    # downward range finder (ultrasonic)
    range_min_m: float = 0.44
    range_max_m: float = 4.0
    range_noise_m: float = 0.01
    range_every: int = 1                                    # ticks between samples
    # downward optical flow
    flow_every: int = 1                                     # ticks between samples
    flow_noise_rad_s: float = 0.02                          # rad/s of flow rate
    flow_quality_textured: float = 200.0                    # 0-255 over a textured floor
    flow_quality_plain: float = 0.0                         # over a texture-less floor
    flow_max_tilt_rad: float = 0.6                          # quality 0 beyond (and beyond
    flow_max_rate_rad_s: float = 7.0                        # this rate)
    # GPS (outdoor)
    gps_every: int = 40                                     # 5 Hz
    gps_noise_m: float = 0.5
    gps_vel_noise_mps: float = 0.1


PRESET_SENSORS = {
    "mambo": SensorParams(),
    "bebop2": SensorParams(range_max_m=8.0),
}
TRIPLES = {"acc_scale", "gyro_scale", "acc_bias", "gyro_bias", "acc_noise", "gyro_noise",
           "mag_field"}
INTS = {"delay_ticks": (0, 10), "range_every": (1, 200), "flow_every": (1, 200),
        "gps_every": (1, 2000)}
# Bounds a field's reading must keep to be sent at all (the wire format of its message) or to
# be the sensor it names (physics): (lo, hi, why). Outside, the sensor models could not encode
# the first tick (a struct error blamed on the flight stack, issue 43) or would model nothing.
WIRE_BOUNDS = {
    # DISTANCE_SENSOR min/max/current_distance: uint16 cm, UINT16_MAX = unknown
    "range_min_m": (0.0, 655.34, "DISTANCE_SENSOR carries cm in a uint16"),
    "range_max_m": (0.0, 655.34, "DISTANCE_SENSOR carries cm in a uint16"),
    # HIL_GPS eph (= the noise) and epv (= 2 eph) in uint16 cm, UINT16_MAX = unknown
    "gps_noise_m": (0.0, 327.67, "HIL_GPS carries epv = 2 x eph in a uint16 of cm"),
    # HIL_GPS vn/ve/vd: int16 cm/s (+-327.67 m/s): a 6-sigma draw of 50 m/s fits with the
    # vehicle's own speed (and a larger one saturates); more is no velocity measurement
    "gps_vel_noise_mps": (0.0, 50.0, "HIL_GPS carries vn/ve/vd in an int16 of cm/s"),
    # Pa per m of height = air density x g: 0.1 (~18 km up) .. 2 kg/m^3 (1.225 at sea level);
    # the pressure altitude is the pressure over it (a float32 overflows near 0)
    "baro_gain": (1.0, 20.0, "air density 0.1..2 kg/m^3 times g"),
}
# the sensor table each field is set in, [sensors.<table>]
TABLES = {"imu": ("imu_wn", "imu_zeta", "acc_scale", "gyro_scale", "acc_bias", "gyro_bias",
                  "acc_noise", "gyro_noise", "acc_max", "gyro_max", "delay_ticks"),
          "baro": ("baro_p0_pa", "baro_gain", "baro_noise_pa"),
          "mag": ("mag_field", "mag_noise"),
          "range": ("range_min_m", "range_max_m", "range_noise_m", "range_every"),
          "flow": ("flow_every", "flow_noise_rad_s", "flow_quality_textured",
                   "flow_quality_plain", "flow_max_tilt_rad", "flow_max_rate_rad_s"),
          "gps": ("gps_every", "gps_noise_m", "gps_vel_noise_mps")}
assert {f for t in TABLES.values() for f in t} == {f.name for f in fields(SensorParams)}


@dataclass(frozen=True)
class SensorsSpec:
    feed: str = "hil"                   # "hil" (sensor messages) | "truth" (ODOMETRY)
    flow_floor: str = "auto"
    gps: bool = False
    params: SensorParams = SensorParams()

    @property
    def hil(self) -> bool:
        return self.feed == "hil"

    def describe(self) -> str:
        if not self.hil:
            return "truth ODOMETRY"
        return "IMU, baro, mag, sonar, flow" + (", GPS" if self.gps else "")


def parse_sensors(s: Mapping[str, Any], vehicle: str) -> SensorsSpec:
    """The `[sensors]` table less its `odometry_noise` (parsed with the ODOMETRY sensor)."""
    p = PRESET_SENSORS.get(vehicle, SensorParams())
    ov: dict[str, Any] = {}
    for tname, names in TABLES.items():
        if tname not in s:
            continue
        where = f"sensors.{tname}"
        t = s[tname]
        if not isinstance(t, Mapping):
            raise ScenarioError(where, t, "a table")
        no_unknown(t, set(names) | ({"enabled"} if tname == "gps" else set()), where)
        for k in t:
            if k != "enabled":
                ov[k] = _value(t, k, where)
    if ov:
        p = replace(p, **ov)
    if p.range_max_m <= p.range_min_m:
        raise ScenarioError("sensors.range.range_max_m", p.range_max_m,
                            f"more than range_min_m = {p.range_min_m:g}")
    return SensorsSpec(feed=string(s, "feed", "sensors", "hil", ("hil", "truth")),
                       flow_floor=string(s, "flow_floor", "sensors", "auto",
                                         ("auto", "textured", "plain")),
                       gps=boolean(s.get("gps", {}), "enabled", "sensors.gps", False),
                       params=p)


def _value(t: Mapping, k: str, where: str) -> Any:
    if k in TRIPLES:
        v = t[k]
        lo = 0.0 if k in ("acc_noise", "gyro_noise") else -1e3
        if (not isinstance(v, list) or len(v) != 3
                or any(isinstance(x, bool) or not isinstance(x, int | float)
                       or not math.isfinite(x) or not lo <= x <= 1e3 for x in v)):
            raise ScenarioError(f"{where}.{k}", v, f"3 finite numbers in [{lo:g}, 1000]")
        return tuple(float(x) for x in v)
    if k in INTS:
        from cosim.scenario.validate import integer

        lo, hi = INTS[k]
        return integer(t, k, where, lo=lo, hi=hi)
    if k == "imu_wn":        # below Nyquist at 5 ms (pi / h = 628 rad/s): the discrete filter
        return number(t, k, where, lo=1.0, hi=600.0)
    if k in ("flow_quality_textured", "flow_quality_plain"):
        return number(t, k, where, lo=0.0, hi=255.0)
    if k in WIRE_BOUNDS:
        lo, hi, why = WIRE_BOUNDS[k]
        v = t[k]
        open_lo = k == "range_max_m"
        if (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
                or not lo <= v <= hi or (open_lo and v == lo)):
            raise ScenarioError(f"{where}.{k}", v, f"a finite number in {'(' if open_lo else '['}"
                                                   f"{lo:g}, {hi:g}] ({why})")
        return float(v)
    lo_open = k in ("imu_wn", "imu_zeta", "acc_max", "gyro_max")
    return number(t, k, where, lo=0.0, hi=1e6, lo_open=lo_open)
