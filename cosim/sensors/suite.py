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

import cython
from cython.cimports.libc.math import acos as _acos

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
from mav import wire
from mav.hil import SIM_COMPID, SIM_SYSID
from mav.onboard.config import OnboardConfig
from mav.wire import FlatEarth

NAN = math.nan
INF = cython.declare(cython.double, math.inf)
SENSOR_FIELDS = hs.FIELDS_IMU | hs.FIELDS_MAG | hs.FIELDS_BARO
# the messages and constants read every tick as C globals (a module attribute is a lookup)
_SENSOR_FIELDS = cython.declare(cython.long, SENSOR_FIELDS)
_NO_ECHO = cython.declare(cython.long, hs.NO_ECHO)
_M_SENSOR = cython.declare(wire.FastMsg, hs.HIL_SENSOR)
_M_DIST = cython.declare(wire.FastMsg, hs.DISTANCE_SENSOR)
_M_FLOW = cython.declare(wire.FastMsg, hs.HIL_OPTICAL_FLOW)
_M_TRUTH = cython.declare(wire.FastMsg, hs.HIL_STATE_QUATERNION)
# the plant outputs' indices as C constants (read() indexes y 16 times a tick)
_YAX = cython.declare(cython.Py_ssize_t, Y_AX)
_YAY = cython.declare(cython.Py_ssize_t, Y_AY)
_YAZ = cython.declare(cython.Py_ssize_t, Y_AZ)
_YP = cython.declare(cython.Py_ssize_t, Y_P)
_YQ = cython.declare(cython.Py_ssize_t, Y_Q)
_YQW = cython.declare(cython.Py_ssize_t, Y_QW)
_YQX = cython.declare(cython.Py_ssize_t, Y_QX)
_YQY = cython.declare(cython.Py_ssize_t, Y_QY)
_YQZ = cython.declare(cython.Py_ssize_t, Y_QZ)
_YR = cython.declare(cython.Py_ssize_t, Y_R)
_YVX = cython.declare(cython.Py_ssize_t, Y_VX)
_YVY = cython.declare(cython.Py_ssize_t, Y_VY)
_YVZ = cython.declare(cython.Py_ssize_t, Y_VZ)
_YX = cython.declare(cython.Py_ssize_t, Y_X)
_YY = cython.declare(cython.Py_ssize_t, Y_Y)
_YZ = cython.declare(cython.Py_ssize_t, Y_Z)


class SensorSuite:
    """`encode(t_us, y) -> bytes`: the tick's HIL datagram. `measure(y)` is the truth tuple
    the loop records in the odometry columns (the estimate replaces it: cosim/sim/estimate.py).
    The per-tick parameters and state are C fields when compiled (suite.pxd)."""

    def __init__(self, spec: SensorsSpec, seed: int, h: float, home: tuple[float, float],
                 floor_textured: bool, faults: tuple = ()) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        p = self.p = spec.params
        self.spec = spec
        self.h = h
        self.mav = mavlink2.MAVLink(None, srcSystem=SIM_SYSID, srcComponent=SIM_COMPID)
        self.n = [Gauss(seed, i) for i in range(8)]   # imu acc, gyro, baro, mag, range, flow,
        self.home = home                               # gps, faults
        self.home_n, self.home_e = home
        g = 9.81
        self.acc = Imu3(p.imu_wn, p.imu_zeta, h, (0.0, 0.0, -g), p.acc_scale, p.acc_noise,
                        self.n[0])
        self.gyro = Imu3(p.imu_wn, p.imu_zeta, h, (0.0, 0.0, 0.0), p.gyro_scale, p.gyro_noise,
                         self.n[1])
        self.g_baro, self.g_mag, self.g_range, self.g_flow = self.n[2:6]
        self.ba0, self.ba1, self.ba2 = p.acc_bias
        self.bg0, self.bg1, self.bg2 = p.gyro_bias
        self.acc_max, self.gyro_max = p.acc_max, p.gyro_max
        self.baro_p0, self.baro_gain, self.baro_noise = p.baro_p0_pa, p.baro_gain, p.baro_noise_pa
        self.mag0, self.mag1, self.mag2 = p.mag_field
        self.mag_noise = p.mag_noise
        self.range_min, self.range_max, self.range_noise = (p.range_min_m, p.range_max_m,
                                                            p.range_noise_m)
        self.range_every, self.flow_every = p.range_every, p.flow_every
        self.flow_noise, self.flow_max_tilt, self.flow_max_rate = (
            p.flow_noise_rad_s, p.flow_max_tilt_rad, p.flow_max_rate_rad_s)
        self.delay = p.delay_ticks
        self.gps = spec.gps
        # min, max (cm) and the covariance (cm^2, the range noise's variance; 255 unknown)
        self.range_cm = (int(p.range_min_m * 100), int(p.range_max_m * 100),
                         hs.range_covariance(p.range_noise_m))
        self.flow_base = p.flow_quality_textured if floor_textured else p.flow_quality_plain
        self.fa0 = self.fa1 = self.fa2 = self.fa3 = self.fa4 = 0.0   # integrated flow x, y,
        self.flow_n = 0                                              # gyro x, y, z
        self.queue: list[list] = []
        cfg = OnboardConfig()
        self.geo = FlatEarth(cfg.origin_lat_deg, cfg.origin_lon_deg, cfg.origin_alt_m)
        self.faults = faults
        self.active: list = []
        self.fired: list[tuple[float, str]] = []
        self._seen: set[int] = set()
        self.n_flow = self.n_echo = self.n_none = self.n_gps = 0    # messages sent (`counts`)
        self.k = 0

    @property
    def counts(self) -> dict[str, int]:
        return {"flow_msgs": self.n_flow, "range_echoes": self.n_echo,
                "range_none": self.n_none, "gps_msgs": self.n_gps}

    @staticmethod
    def measure(y) -> tuple[float, ...]:
        return (y[Y_X], y[Y_Y], y[Y_Z])

    # ------------------------------------------------------------------ one tick
    def encode(self, t_us: int, y) -> bytes:
        """The datagram sent at t_us: the frames of `messages`."""
        return hs.frames(self.mav, self.messages(t_us, y, True))

    @cython.locals(q=list, parts=list, out=list)
    def messages(self, t_us: int, y, truth: bool) -> list:
        """The messages sent at t_us as [message, payload, ...]: this tick's readings are
        queued and the one `delay_ticks` old is sent (the first tick's repeated until the
        queue fills), then, with `truth`, the truth of this tick (HIL_STATE_QUATERNION, not
        delayed: for the simulator's logs, the vehicle never reads it). MIL's typed exchange
        hands them to the vehicle as they are, without the truth (cosim/sim/onboard.py)."""
        q = self.queue
        q.append(self.read(t_us, y))
        parts = q.pop(0) if len(q) > self.delay else q[0]
        out = hs.stamp_all(parts, t_us, [])     # (message, payload less its stamp) pairs
        if truth:
            out.append(_M_TRUTH)
            out.append(self.truth_of(t_us, y))
        return out

    def truth_of(self, t_us: int, y) -> bytes:
        """HIL_STATE_QUATERNION's payload of y(t_k), stamped t_k, in the vehicle's geodetic
        frame (origin = the start point)."""
        lat, lon, alt = self.geo.to_int(y[_YX] - self.home_n, y[_YY] - self.home_e, y[_YZ])
        return hs.truth_payload(t_us, y[_YQW], y[_YQX], y[_YQY], y[_YQZ], y[_YP], y[_YQ],
                                y[_YR], lat, lon, alt, _cms(y[_YVX]), _cms(y[_YVY]),
                                _cms(y[_YVZ]))

    @cython.locals(k=cython.longlong, t=cython.double, qw=cython.double, qx=cython.double,
                   qy=cython.double, qz=cython.double, pr=cython.double, qr=cython.double,
                   rr=cython.double, r00=cython.double, r01=cython.double, r02=cython.double,
                   r10=cython.double, r11=cython.double, r12=cython.double, r20=cython.double,
                   r21=cython.double, r22=cython.double, ba0=cython.double, ba1=cython.double,
                   ba2=cython.double, bg0=cython.double, bg1=cython.double, bg2=cython.double,
                   gsat=cython.double, height=cython.double, pa=cython.double,
                   p_alt=cython.double, mx=cython.double, my=cython.double, mz=cython.double,
                   sm=cython.double, m0=cython.double, m1=cython.double, m2=cython.double,
                   tilt_c=cython.double, slant=cython.double, rng=cython.double,
                   echo=cython.bint, vx=cython.double, vy=cython.double, vz=cython.double,
                   vbx=cython.double, vby=cython.double, d=cython.double, h=cython.double,
                   fn=cython.double, c=cython.double, tilt=cython.double, ok=cython.bint,
                   ix=cython.double, iy=cython.double, send=cython.bint, i=cython.Py_ssize_t,
                   buf=cython.double[::1], acc=Imu3, gyr=Imu3, parts=list, n0=cython.double,
                   n1=cython.double, n2=cython.double, lo=cython.long, hi=cython.long)
    def read(self, t_us: int, y) -> list:
        """The readings of y(t_k) as (message, payload less its stamp) pairs, flat (the delay
        line sends them one tick later, stamped with the lockstep time then)."""
        k = self.k
        self.k = k + 1
        t = 0.0
        if self.faults:
            t = t_us * 1e-6
            self._update_faults(t)
        act = self.active
        qw, qx, qy, qz = y[_YQW], y[_YQX], y[_YQY], y[_YQZ]
        pr, qr, rr = y[_YP], y[_YQ], y[_YR]
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
        ba0, ba1, ba2, bg0, bg1, bg2 = self.ba0, self.ba1, self.ba2, self.bg0, self.bg1, self.bg2
        gsat = self.gyro_max
        for f in act:
            if f.kind == "imu_bias":
                ba0, ba1, ba2 = ba0 + f.value[0], ba1 + f.value[1], ba2 + f.value[2]
                bg0, bg1, bg2 = bg0 + f.gyro[0], bg1 + f.gyro[1], bg2 + f.gyro[2]
            elif f.kind == "gyro_saturation" and f.value[0] < gsat:
                gsat = f.value[0]
        acc, gyr = self.acc, self.gyro
        acc.read(y[_YAX], y[_YAY], y[_YAZ], ba0, ba1, ba2, self.acc_max)
        gyr.read(pr, qr, rr, bg0, bg1, bg2, gsat)
        # barometer
        height = -y[_YZ]
        g = self.g_baro
        i = g.at(1)
        n0 = g.buf[i]                              # (noise as C doubles when compiled)
        pa = self.baro_p0 - self.baro_gain * height + self.baro_noise * n0
        for f in act:
            if f.kind == "baro_drift":
                pa += f.value[0] * (t - f.start_s)
        p_alt = (self.baro_p0 - pa) / self.baro_gain
        # magnetometer
        mx, my, mz = self.mag0, self.mag1, self.mag2
        sm = self.mag_noise
        g = self.g_mag
        i = g.at(3)
        buf = g.buf
        n0, n1, n2 = buf[i], buf[i + 1], buf[i + 2]
        m0 = r00 * mx + r10 * my + r20 * mz + sm * n0
        m1 = r01 * mx + r11 * my + r21 * mz + sm * n1
        m2 = r02 * mx + r12 * my + r22 * mz + sm * n2
        for f in act:
            if f.kind == "mag_interference":
                m0, m1, m2 = m0 + f.value[0], m1 + f.value[1], m2 + f.value[2]
        parts = [_M_SENSOR, hs.hil_sensor_rest(
            acc.o0, acc.o1, acc.o2, gyr.o0, gyr.o1, gyr.o2, m0, m1, m2, pa * 0.01, p_alt, 25.0,
            _SENSOR_FIELDS)]
        # range finder (down) and flow share the slant distance along body z
        tilt_c = r22                               # cos(roll) cos(pitch)
        slant = height / tilt_c if tilt_c > 0.05 else INF
        if k % self.range_every == 0:
            g = self.g_range
            i = g.at(1)
            n0 = g.buf[i]
            rng = slant + self.range_noise * n0
            echo = self.range_min <= rng <= self.range_max
            for f in act:
                if f.kind == "sonar_dropout":
                    echo = False
            if echo:
                self.n_echo += 1
            else:
                self.n_none += 1
            lo, hi, cov = self.range_cm
            parts.append(_M_DIST)
            parts.append(hs.distance_rest(lo, hi, _round(rng * 100) if echo else 0,
                                          100 if echo else _NO_ECHO, cov))
        # optical flow: body velocity over the slant distance, plus the body rates
        vx, vy, vz = y[_YVX], y[_YVY], y[_YVZ]
        vbx = r00 * vx + r10 * vy + r20 * vz
        vby = r01 * vx + r11 * vy + r21 * vz
        d = 0.05 if 0.05 > slant else slant        # max(slant, 0.05)
        h = self.h
        g = self.g_flow
        i = g.at(2)
        fn = self.flow_noise
        n0, n1 = g.buf[i], g.buf[i + 1]
        self.fa0 += (pr - vby / d + fn * n0) * h
        self.fa1 += (qr + vbx / d + fn * n1) * h
        self.fa2 += gyr.o0 * h
        self.fa3 += gyr.o1 * h
        self.fa4 += gyr.o2 * h
        self.flow_n += 1
        if self.flow_n >= self.flow_every:
            c = tilt_c if tilt_c < 1.0 else 1.0    # clamped to [-1, 1] as max(-1, min(1, .))
            c = c if c > -1.0 else -1.0
            tilt = _acos(c)
            ok = tilt < self.flow_max_tilt and abs(pr) < self.flow_max_rate and abs(
                qr) < self.flow_max_rate and height > 0.05
            qual = int(self.flow_base) if ok else 0
            ix, iy = self.fa0, self.fa1
            send = True
            for f in act:   # (none most ticks)
                if f.kind == "flow_loss":
                    send = False
                elif f.kind == "flow_garbage":
                    if f.value[0]:
                        ix = iy = NAN
                    else:
                        n0, n1 = g.take(2)
                        ix, iy = f.value[1] * n0, f.value[1] * n1
                    qual = 255
            if send:
                self.n_flow += 1
                parts.append(_M_FLOW)
                parts.append(hs.flow_rest(_round(self.flow_n * h * 1e6), ix, iy, self.fa2,
                                          self.fa3, self.fa4, qual))
            self.flow_n = 0
            self.fa0 = self.fa1 = self.fa2 = self.fa3 = self.fa4 = 0.0
        # GPS, in the vehicle's geodetic frame (origin = the start point)
        if self.gps and k % self.p.gps_every == 0:
            parts += self._gps(y)
        return parts

    def _gps(self, y) -> list:
        """A GPS fix of y: [HIL_GPS, its payload less the stamp]."""
        p = self.p
        g = self.n[6].take(6)
        sp, sv = p.gps_noise_m, p.gps_vel_noise_mps
        lat, lon, alt = self.geo.to_int(y[Y_X] - self.home_n + sp * g[0],
                                        y[Y_Y] - self.home_e + sp * g[1], y[Y_Z] + sp * g[2])
        self.n_gps += 1
        return [hs.HIL_GPS, hs.gps_rest(lat, lon, alt, _round(sp * 100),
                                        _cms(y[Y_VX] + sv * g[3]), _cms(y[Y_VY] + sv * g[4]),
                                        _cms(y[Y_VZ] + sv * g[5]))]

    def _update_faults(self, t: float) -> None:
        self.active = [f for f in self.faults if f.start_s <= t < f.end_s]
        for i, f in enumerate(self.faults):
            if f in self.active and i not in self._seen:
                self._seen.add(i)
                self.fired.append((t, f"sensor {f.kind}"))


@cython.cfunc
@cython.returns(cython.longlong)
@cython.locals(v=cython.double, r=cython.double)
def _round(v) -> int:
    """int(round(v)), as Python rounds (half to even: wire.round_even, in C doubles when
    compiled); a NaN or an infinity raises as round() does."""
    r = wire.round_even(v)
    if not -9.2e18 < r < 9.2e18:
        return int(r)              # raises (a NaN, an infinity), or too large for the field
    return cython.cast(cython.longlong, r)


@cython.cfunc
@cython.returns(cython.long)
@cython.locals(v=cython.double, c=cython.double)
def _cms(v) -> int:
    """cm/s, rounded as Python rounds and saturated to +-32767 (a NaN raises)."""
    c = v * 100.0
    if c >= 32767.0:
        return 32767
    if c <= -32767.0:
        return -32767
    return _round(c)
