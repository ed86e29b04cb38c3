"""The vehicle's sensors: plant outputs y(t_k) -> one HIL datagram of PX4 sensor messages
(mav/hil_sensors.py) stamped t_k. Plain floats per tick; noise from one seeded stream per
sensor (`Gauss(seed, i)`), drawn in a fixed order, so a seed gives the same readings bit for
bit, MIL or SIL.

- IMU: the plant's specific force (outputs ax, ay, az: body FRD, m/s^2) and body rates through
  the second-order sensor, scale, bias, noise, limits;
- barometer: pressure of the height above the floor (-z) plus noise and drift;
- magnetometer: the world field in body axes plus noise and interference;
- range finder (down): the slant range -z / (cos roll cos pitch), cm; below its minimum
  (Mambo 0.44 m) or above its maximum: no echo (signal_quality 1);
- optical flow (down): computed from the truth and the floor's texture, not from the render.
  Why: the downward camera renders at 5 Hz (160 x 120), the flow sensor integrates at 200 Hz;
  rendering every tick for flow would cost ~40x the camera's time and image flow from a
  160 x 120 frame of a plain floor is noise. The floor's texture sets the quality instead:
  `flow_quality_textured` / `flow_quality_plain` (a plain floor gives 0: the flow fails, as
  PX4's does); tilt or rate beyond the sensor's limits give 0 too;
- GPS (outdoor worlds, `[sensors.gps] enabled = true`): position and velocity with white noise;
- HIL_STATE_QUATERNION: the truth, for the logs.

Every reading is delayed `delay_ticks` ticks (the template: one 5 ms sample).
"""

from __future__ import annotations

import math

from cosim.plant.fmu import (
    Y_AX,
    Y_AY,
    Y_AZ,
    Y_P,
    Y_Q,
    Y_QW,
    Y_QX,
    Y_QY,
    Y_QZ,
    Y_R,
    Y_VX,
    Y_VY,
    Y_VZ,
    Y_X,
    Y_Y,
    Y_Z,
)
from cosim.sensors.imu import Gauss, Imu3
from cosim.sensors.spec import SensorsSpec
from mav import hil_sensors as hs
from mav.hil import SIM_COMPID, SIM_SYSID
from mav.onboard.config import OnboardConfig
from mav.wire import FlatEarth

NAN = math.nan


class SensorSuite:
    """`encode(t_us, y) -> bytes`: the tick's HIL datagram. `measure(y)` is the truth tuple
    the loop records in the odometry columns (the estimate replaces it: cosim/sim/estimate.py)."""

    def __init__(self, spec: SensorsSpec, seed: int, h: float, home: tuple[float, float],
                 floor_textured: bool, faults: tuple = ()) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        p = self.p = spec.params
        self.spec = spec
        self.h = h
        self.mav = mavlink2.MAVLink(None, srcSystem=SIM_SYSID, srcComponent=SIM_COMPID)
        self.n = [Gauss(seed, i) for i in range(8)]   # imu acc, gyro, baro, mag, range, flow,
        self.home = home                               # gps, faults
        g = 9.81
        self.acc = Imu3(p.imu_wn, p.imu_zeta, h, (0.0, 0.0, -g), p.acc_scale, p.acc_noise,
                        self.n[0])
        self.gyro = Imu3(p.imu_wn, p.imu_zeta, h, (0.0, 0.0, 0.0), p.gyro_scale, p.gyro_noise,
                         self.n[1])
        self.range_cm = (int(p.range_min_m * 100), int(p.range_max_m * 100))
        self.flow_base = p.flow_quality_textured if floor_textured else p.flow_quality_plain
        self.flow_acc = [0.0, 0.0, 0.0, 0.0, 0.0]      # integrated x, y, gyro x, y, z
        self.flow_n = 0
        self.queue: list[bytes] = []
        cfg = OnboardConfig()
        self.geo = FlatEarth(cfg.origin_lat_deg, cfg.origin_lon_deg, cfg.origin_alt_m)
        self.faults = faults
        self.active: list = []
        self.fired: list[tuple[float, str]] = []
        self._seen: set[int] = set()
        self.counts = {"flow_msgs": 0, "range_echoes": 0, "range_none": 0, "gps_msgs": 0}
        self.k = 0

    @staticmethod
    def measure(y) -> tuple[float, ...]:
        return (y[Y_X], y[Y_Y], y[Y_Z])

    # ------------------------------------------------------------------ one tick
    def encode(self, t_us: int, y) -> bytes:
        """The datagram sent at t_us: this tick's readings are queued and the one
        `delay_ticks` old is sent (the first tick's repeated until the queue fills), then the
        truth of this tick (HIL_STATE_QUATERNION, not delayed)."""
        data = self.read(t_us, y)
        truth = data.pop()
        q = self.queue
        q.append(data)
        parts = q.pop(0) if len(q) > self.p.delay_ticks else q[0]
        return b"".join([f(t_us) for f in parts]) + truth(t_us)

    def read(self, t_us: int, y) -> list:
        """The readings of y(t_k) as closures that encode them at a given stamp (the delay
        line sends them one tick later, stamped with the lockstep time then)."""
        p, n, mav = self.p, self.n, self.mav
        k = self.k
        self.k = k + 1
        t = t_us * 1e-6
        if self.faults:
            self._update_faults(t)
        act = self.active
        qw, qx, qy, qz = y[Y_QW], y[Y_QX], y[Y_QY], y[Y_QZ]
        pr, qr, rr = y[Y_P], y[Y_Q], y[Y_R]
        # rotation body -> world (rows); R^T v is world -> body
        r00 = 1 - 2 * (qy * qy + qz * qz)
        r01 = 2 * (qx * qy - qw * qz)
        r02 = 2 * (qx * qz + qw * qy)
        r10 = 2 * (qx * qy + qw * qz)
        r11 = 1 - 2 * (qx * qx + qz * qz)
        r12 = 2 * (qy * qz - qw * qx)
        r20 = 2 * (qx * qz - qw * qy)
        r21 = 2 * (qy * qz + qw * qx)
        r22 = 1 - 2 * (qx * qx + qy * qy)
        # IMU
        bias_a, bias_g, gsat = p.acc_bias, p.gyro_bias, p.gyro_max
        for f in act:
            if f.kind == "imu_bias":
                bias_a = tuple(b + v for b, v in zip(bias_a, f.value, strict=True))
                bias_g = tuple(b + v for b, v in zip(bias_g, f.gyro, strict=True))
            elif f.kind == "gyro_saturation":
                gsat = min(gsat, f.value[0])
        acc = self.acc.read(y[Y_AX], y[Y_AY], y[Y_AZ], bias_a, p.acc_max)
        gyr = self.gyro.read(pr, qr, rr, bias_g, gsat)
        # barometer
        height = -y[Y_Z]
        pa = p.baro_p0_pa - p.baro_gain * height + p.baro_noise_pa * n[2].take(1)[0]
        for f in act:
            if f.kind == "baro_drift":
                pa += f.value[0] * (t - f.start_s)
        p_alt = (p.baro_p0_pa - pa) / p.baro_gain
        # magnetometer
        mx, my, mz = p.mag_field
        sm = p.mag_noise
        n0, n1, n2 = n[3].take(3)
        mag = (r00 * mx + r10 * my + r20 * mz + sm * n0, r01 * mx + r11 * my + r21 * mz + sm * n1,
               r02 * mx + r12 * my + r22 * mz + sm * n2)
        for f in act:
            if f.kind == "mag_interference":
                mag = tuple(m + v for m, v in zip(mag, f.value, strict=True))
        parts = [_sensor(mav, acc, gyr, mag, pa * 0.01, p_alt)]
        # range finder (down) and flow share the slant distance along body z
        tilt_c = r22                               # cos(roll) cos(pitch)
        slant = height / tilt_c if tilt_c > 0.05 else math.inf
        if k % p.range_every == 0:
            rng = slant + p.range_noise_m * n[4].take(1)[0]
            echo = p.range_min_m <= rng <= p.range_max_m and not (act and any(
                f.kind == "sonar_dropout" for f in act))
            self.counts["range_echoes" if echo else "range_none"] += 1
            lo, hi = self.range_cm
            parts.append(_distance(mav, lo, hi, int(round(rng * 100)) if echo else 0,
                                   100 if echo else hs.NO_ECHO))
        # optical flow: body velocity over the slant distance, plus the body rates
        vx, vy, vz = y[Y_VX], y[Y_VY], y[Y_VZ]
        vbx = r00 * vx + r10 * vy + r20 * vz
        vby = r01 * vx + r11 * vy + r21 * vz
        d = max(slant, 0.05)
        nf, h = n[5], self.h
        fa = self.flow_acc
        n0, n1 = nf.take(2)
        fa[0] += (pr - vby / d + p.flow_noise_rad_s * n0) * h
        fa[1] += (qr + vbx / d + p.flow_noise_rad_s * n1) * h
        fa[2] += gyr[0] * h
        fa[3] += gyr[1] * h
        fa[4] += gyr[2] * h
        self.flow_n += 1
        if self.flow_n >= p.flow_every:
            tilt = math.acos(max(-1.0, min(1.0, tilt_c)))
            ok = tilt < p.flow_max_tilt_rad and abs(pr) < p.flow_max_rate_rad_s and abs(
                qr) < p.flow_max_rate_rad_s and height > 0.05
            qual = int(self.flow_base) if ok else 0
            ix, iy = fa[0], fa[1]
            send = True
            for f in act:   # (none most ticks)
                if f.kind == "flow_loss":
                    send = False
                elif f.kind == "flow_garbage":
                    if f.value[0]:
                        ix = iy = NAN
                    else:
                        n0, n1 = nf.take(2)
                        ix, iy = f.value[1] * n0, f.value[1] * n1
                    qual = 255
            if send:
                self.counts["flow_msgs"] += 1
                parts.append(_flow(mav, int(round(self.flow_n * h * 1e6)), ix, iy, fa[2],
                                   fa[3], fa[4], qual))
            self.flow_n = 0
            fa[0] = fa[1] = fa[2] = fa[3] = fa[4] = 0.0
        # GPS and the truth, in the vehicle's geodetic frame (origin = the start point)
        hn, he = self.home
        if self.spec.gps and k % p.gps_every == 0:
            g = n[6].take(6)
            sp, sv = p.gps_noise_m, p.gps_vel_noise_mps
            lat, lon, alt = self.geo.to_int(y[Y_X] - hn + sp * g[0], y[Y_Y] - he + sp * g[1],
                                            y[Y_Z] + sp * g[2])
            self.counts["gps_msgs"] += 1
            parts.append(_gps(mav, lat, lon, alt, int(round(sp * 100)),
                              int(round((vx + sv * g[3]) * 100)),
                              int(round((vy + sv * g[4]) * 100)),
                              int(round((vz + sv * g[5]) * 100))))
        lat, lon, alt = self.geo.to_int(y[Y_X] - hn, y[Y_Y] - he, y[Y_Z])
        parts.append(_truth(mav, (qw, qx, qy, qz), (pr, qr, rr), lat, lon, alt,
                            (_cms(vx), _cms(vy), _cms(vz))))
        return parts

    def _update_faults(self, t: float) -> None:
        self.active = [f for f in self.faults if f.start_s <= t < f.end_s]
        for i, f in enumerate(self.faults):
            if f in self.active and i not in self._seen:
                self._seen.add(i)
                self.fired.append((t, f"sensor {f.kind}"))


def _cms(v: float) -> int:
    return max(-32767, min(32767, int(round(v * 100))))


# each reading as a closure that frames it at the stamp it is sent with (after the delay)
def _sensor(mav, acc, gyr, mag, hpa, p_alt):
    fields = hs.FIELDS_IMU | hs.FIELDS_MAG | hs.FIELDS_BARO
    return lambda t_us: hs.encode_hil_sensor(mav, t_us, acc, gyr, mag, hpa, p_alt, 25.0, fields)


def _distance(mav, lo, hi, cur, quality):
    return lambda t_us: hs.encode_distance(mav, t_us, lo, hi, cur, quality)


def _flow(mav, dt_us, ix, iy, gx, gy, gz, quality):
    return lambda t_us: hs.encode_flow(mav, t_us, dt_us, ix, iy, gx, gy, gz, quality)


def _gps(mav, lat, lon, alt, eph, vn, ve, vd):
    return lambda t_us: hs.encode_gps(mav, t_us, lat, lon, alt, eph, vn, ve, vd)


def _truth(mav, q, pqr, lat, lon, alt, v):
    return lambda t_us: hs.encode_truth(mav, t_us, q, pqr, lat, lon, alt, v)
