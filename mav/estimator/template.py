"""The Minidrone template's estimator (reference/minidrone.md §2.2), as its own part like PX4's
EKF2: sensor messages in, a state estimate out, in plain floats (200 Hz in the vehicle's tick).

- Attitude: complementary filter on Euler angles. The gyro (less its bias measured at rest in
  the first `CAL_TICKS` ticks) is integrated; the low-passed accelerometer corrects roll and
  pitch with weight TPL_ACC_W per tick while its norm is within TPL_ACC_GATE of g; the
  tilt-compensated compass corrects the heading with weight TPL_MAG_W.
- Altitude: Kalman filter on (z, vz) driven by the vertical acceleration, corrected by the
  barometer (altitude from the pressure drop since start) and the sonar (slant range times
  cos roll cos pitch). The template's outlier rules: sonar > TPL_RNG_GATE (0.3 m) and pressure
  > TPL_BARO_GATE (0.8 m) from the estimate are rejected; a sonar rejected for 0.5 s in a row
  resets the altitude to it (the estimate, not the sonar, had gone wrong).
- Horizontal velocity: per axis a Kalman filter (Q = TPL_OF_Q, R = TPL_OF_R: the template's
  0.09 / 5) driven by the horizontal acceleration, corrected by the flow velocity (flow rate
  less the flow sensor's gyro, times the distance to the floor along the optical axis), used
  only with quality >= EKF2_OF_QMIN, above 0.4 m, |roll|, |pitch| < 0.6 rad, |p|, |q| < 7
  rad/s, within TPL_OF_GATE (5 m/s) of the estimate (template rules).
- Horizontal position: the velocity integrated (the template has no absolute position without
  its marker); with a GPS, each fix pulls it by TPL_GPS_W.
- On the ground (estimated height < 0.15 m, no flow) the velocity decays to zero (as PX4's
  zero-velocity update while landed); the floor it started on bounds the altitude (without
  that the estimate kept "descending" after a touchdown and the land detector waited).

A reading that is NaN or outside its sensor's range is rejected and counted (`stats`), never
propagated. The position is `lost` when no flow or GPS was fused for TPL_NOAID_TOUT above
0.5 m, until one is fused again (a descent below 0.5 m on dead reckoning regains nothing).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cython
from cython.cimports.libc.math import atan2 as _atan2
from cython.cimports.libc.math import cos as _cos
from cython.cimports.libc.math import sin as _sin
from cython.cimports.libc.math import sqrt as _sqrt
from cython.cimports.libc.math import tan as _tan

from mav.rotations import euler_to_world, wrap_pi

if TYPE_CHECKING:
    from mav.hil_sensors import Payload

# (compiled: the estimator's state as C doubles in template.pxd, its arithmetic in C doubles
# and C's libm, the functions Python's math module calls: the same results bit for bit)
f64 = cython.typedef(cython.double)
G = 9.81
CAL_TICKS = 100              # at rest: the gyro bias and the initial tilt, the mean of the
                             # first 100 readings (0.5 s; the vehicle refuses to arm before,
                             # as PX4 before its tilt alignment: 10 readings left ~1 deg of
                             # tilt error, which a take-off into wind turned into drift)
BIAS_KI = cython.declare(cython.double, 2e-6)   # rad/s per rad and tick: the gyro bias
                                                # follows the accelerometer
ACC_LP = cython.declare(cython.double, 0.1)     # accelerometer low-pass weight per tick (~50 ms)
RNG_RESET_US = 500_000       # us of consecutive sonar rejections that reset the altitude
# beyond: not a reading (NaN, garbage) -> rejected
ACC_MAX = cython.declare(cython.double, 160.0)
GYRO_MAX = cython.declare(cython.double, 35.0)
ZUPT_DECAY = cython.declare(cython.double, 0.9)   # per tick, on the ground
_G = cython.declare(cython.double, G)
_CAL = cython.declare(cython.long, CAL_TICKS)
# HIL_SENSOR fields_updated (MAVLink HIL_SENSOR_UPDATED_FLAGS), as PX4's simulator interface
# reads them: accel bits 0-2 and gyro 3-5, mag 6-8, baro = abs pressure 9, pressure alt 11,
# temperature 12 (SensorSource::BARO)
_F_IMU = cython.declare(cython.long, 0x3F)
_F_MAG = cython.declare(cython.long, 0x1C0)
F_BARO = 0x1A00
_F_BARO = cython.declare(cython.long, F_BARO)

STATS = ("est_imu", "est_rej_imu", "est_rej_baro", "est_baro_fused", "est_rej_rng",
         "est_rng_fused", "est_rng_none", "est_rej_flow", "est_flow_fused", "est_rej_mag",
         "est_gps_fused", "est_rej_gps", "est_rng_resets", "est_resets", "est_gps_resets")
# EKF2's GPS checks, PX4's defaults (ekf2 module.yaml): EKF2_REQ_EPH 3 m, EKF2_REQ_NSATS 6, a
# 3D fix; gate EKF2_GPS_P_GATE 5 SD of max(eph, EKF2_GPS_P_NOISE 0.5 m); reset after 7 s gated
GPS_REQ_EPH_CM = 300
GPS_REQ_NSATS = 6
GPS_P_GATE = cython.declare(cython.double, 5.0)
GPS_P_NOISE_M = cython.declare(cython.double, 0.5)
GPS_RESET_US = 7_000_000
# Innovation test ratios, EKF2's: innovation^2 / (gate^2 * innovation variance), > 1 outside
# the gate; each low-passed by TR_K (1 s: a ratio above 1 is sustained, not one noisy sample)
# in tr_tilt (accelerometer's gravity against roll and pitch, gate TILT_GATE rad), tr_vel
# (flow, EKF2_OF_GATE's default 3 SD of P + TPL_OF_R), tr_hgt (barometer, EKF2_BARO_GATE's
# 5 SD of P + R). A tilt or velocity ratio above 1 in flight: failed (`fail`), for good.
VEL_GATE_SD, HGT_GATE_SD, TR_PER_TICK = 3.0, 5.0, 0.005     # TR_PER_TICK: 1 s at 200 Hz
TILT_GATE2 = cython.declare(cython.double, 0.2 * 0.2)
VEL_GATE2 = cython.declare(cython.double, VEL_GATE_SD * VEL_GATE_SD)
HGT_GATE2 = cython.declare(cython.double, HGT_GATE_SD * HGT_GATE_SD)
TR_K = cython.declare(cython.double, TR_PER_TICK)
FAIL_TILT, FAIL_VEL = 1, 2                        # `fail`: what failed (0: nothing)


def _finite(s: float) -> bool:
    """Of a sum of readings: whether all are finite (a NaN or an infinity among them makes the
    sum NaN or infinite; finite ones whose sum overflows are rejected too)."""
    return s - s == 0.0


class TemplateEstimator:
    """`update(hil_sensor, flow, distance, gps, t_us)`: one tick; the estimate in the fields
    (x, y, z, vx, vy, vz m and m/s world NED relative to the start; roll, pitch, yaw rad;
    p, q, r rad/s), `lost` when the position is not aided. Its fields' C types are in
    template.pxd."""

    def __init__(self, own: dict[str, float], stats: dict[str, int]) -> None:
        self.stats = stats
        for k in STATS:
            stats.setdefault(k, 0)
        self.configure(own)
        self.n = 0
        self.t_us = -1
        self.x = self.y = self.z = 0.0
        self.vx = self.vy = self.vz = 0.0
        self.roll = self.pitch = self.yaw = 0.0
        self.p = self.q = self.r = 0.0
        self.bg0 = self.bg1 = self.bg2 = 0.0              # gyro bias
        self.alp0, self.alp1, self.alp2 = 0.0, 0.0, -G     # low-passed specific force
        self.p0_hpa = math.nan
        self.nb = 0                                        # barometer readings in p0_hpa
        self.resets = 0                                    # non-finite states reset
        self.bz = 0.0                                      # accelerometer bias, world down
        # altitude covariance (z, vz, bz): at rest on the floor, z = vz = 0 known (with 1 m^2
        # the first barometer reading, 2.5 sigma of noise at seed 0, jumped it by 0.31 m)
        self.pzz, self.pzv, self.pvv = 1e-4, 0.0, 1e-4
        self.pzb = self.pvb = 0.0
        self.pbb = self.abl_lim * self.abl_lim
        self.pvx = self.pvy = 1.0                          # velocity variances
        self.aid_us = 0                                    # last flow / GPS fused
        self.rng_us = -(1 << 62)                           # last sonar fused
        self.gps_us = 0                                    # last GPS fix fused
        self.imu_us = -1                                   # last IMU reading used
        self.ra0 = self.ra1 = self.ra2 = self.rg0 = self.rg1 = self.rg2 = 0.0
        self.rfields = 0
        self.rng_rej_since = -1
        self.gps_rej_since = -1                            # fixes gated out since
        self.lost = False
        self.tr_tilt = self.tr_vel = self.tr_hgt = 0.0     # innovation test ratios (low-passed)
        self.fail = 0                                      # FAIL_TILT, FAIL_VEL: failed
        self.sg2 = 0.0                # at rest (alignment): the gyro's mean squared norm

    def configure(self, own: dict[str, float]) -> None:
        self.w_acc, self.acc_gate = own["TPL_ACC_W"], own["TPL_ACC_GATE"]
        self.w_mag, self.decl = own["TPL_MAG_W"], math.radians(own["EKF2_MAG_DECL"])
        self.q_acc, self.q_ab = own["TPL_ACC_NOISE"] ** 2, own["EKF2_ACC_B_NOISE"] ** 2
        self.abl_lim = own["EKF2_ABL_LIM"]
        self.r_baro, self.baro_gate = own["TPL_BARO_NOISE"] ** 2, own["TPL_BARO_GATE"]
        self.r_rng, self.rng_gate = own["TPL_RNG_NOISE"] ** 2, own["TPL_RNG_GATE"]
        self.of_q, self.of_r = own["TPL_OF_Q"], own["TPL_OF_R"]
        self.of_qmin, self.of_gate = own["EKF2_OF_QMIN"], own["TPL_OF_GATE"]
        self.noaid_us, self.w_gps = int(own["TPL_NOAID_TOUT"] * 1e6), own["TPL_GPS_W"]

    # ------------------------------------------------------------------ one tick
    @cython.locals(dt=f64, fused=cython.bint)
    def update(self, imu: Payload | None, flow: Payload | None, rng: Payload | None,
               gps: Payload | None, geo, t_us: int) -> None:
        """imu: HIL_SENSOR's payload (mav/hil_sensors.py's Payload: its fields in wire
        order); flow: HIL_OPTICAL_FLOW's; rng: DISTANCE_SENSOR's; gps: HIL_GPS's; None when
        absent this tick. `geo`: FlatEarth."""
        st = self.stats
        dt = self._dt(t_us)
        if imu is not None:
            self._imu(imu, dt)
        if rng is not None:
            self._range(rng, t_us)
        fused = False
        if flow is not None:
            fused = self._flow(flow, t_us)
        # resting on the floor, the flow not fused (rejected below 0.4 m): ZUPT. (Once only on
        # ticks without a flow message: a vehicle on the ground drifted ~6 cm/s.)
        if not fused and self.z > -0.15 and abs(self.vz) < 0.3:
            self.vx *= ZUPT_DECAY
            self.vy *= ZUPT_DECAY
        if self.z > 0.0:       # below the floor it started on: it is on it (a flat floor; the
            self.z = 0.0       # sonar sees nothing this low), and not moving down
            if self.vz > 0.0:
                self.vz = 0.0
        if gps is not None:
            self._gps(gps, geo, t_us)
        self.x += self.vx * dt
        self.y += self.vy * dt
        if not _finite(self.x + self.y + self.z + self.vx + self.vy + self.vz + self.roll
                       + self.pitch + self.yaw + self.p + self.q + self.r + self.bz + self.pzz
                       + self.pvv + self.pbb + self.pvx + self.pvy):
            self._reset()
        self._health(t_us)
        if imu is not None:
            st["est_imu"] += 1

    @cython.locals(dt=f64)
    def _dt(self, t_us: int) -> float:
        """The time since the last tick (5 ms at the first and after a gap: the stamps were
        checked before, mav.hil.tick_refusal), and the tick's stamp taken."""
        dt = (t_us - self.t_us) * 1e-6 if self.t_us >= 0 else 0.005
        if not 0.0 < dt < 1.0:
            dt = 0.005
        self.t_us = t_us
        return dt

    @cython.locals(lost=cython.bint)
    def _health(self, t_us: int) -> None:
        """After a tick: a failed estimate (a test ratio above 1 in flight) and a lost
        position, as the vehicle reads them."""
        if self.fail == 0 and self.z < -0.15:      # in flight (the vehicle acts on it)
            if self.tr_tilt > 1.0:
                self.fail = FAIL_TILT
            elif self.tr_vel > 1.0:
                self.fail = FAIL_VEL
        if self.fail:              # the estimate failed: the position lost for good (PX4: the
            lost = True            # local position invalid, "Land and recalibrate sensors")
        elif self.lost:      # regained only by an aiding source fused, never by descending
            lost = self.aid_us != t_us      # below 0.5 m on dead reckoning (issue 43)
        else:
            lost = self.z < -0.5 and t_us - self.aid_us > self.noaid_us
        if lost != self.lost:
            self.lost = lost

    @cython.locals(fields=cython.long, a0=f64, a1=f64, a2=f64, g0=f64, g1=f64, g2=f64)
    def _imu_ok(self, m: Payload) -> bool:
        """HIL_SENSOR carries a new, finite, in-range accelerometer and gyro reading (else it
        is counted, est_rej_imu, and nothing of it is used). A reading that passes is kept
        for the step that uses it (ra0-ra2, rg0-rg2, rfields: each field read once)."""
        fields = m.i(14)                  # fields_updated: what this message carries new
        if (fields & _F_IMU) == _F_IMU:
            a0, a1, a2, g0, g1, g2 = m.f(1), m.f(2), m.f(3), m.f(4), m.f(5), m.f(6)
            if (_finite(a0 + a1 + a2 + g0 + g1 + g2)
                    and abs(a0) < ACC_MAX and abs(a1) < ACC_MAX and abs(a2) < ACC_MAX
                    and abs(g0) < GYRO_MAX and abs(g1) < GYRO_MAX and abs(g2) < GYRO_MAX):
                self.ra0, self.ra1, self.ra2 = a0, a1, a2
                self.rg0, self.rg1, self.rg2 = g0, g1, g2
                self.rfields = fields
                self.imu_us = self.t_us
                return True
        self.stats["est_rej_imu"] += 1
        return False

    @cython.locals(a0=f64, a1=f64, a2=f64, er=f64, ep=f64)
    def _watch_tilt(self, a0: float, a1: float, a2: float) -> None:
        """The tilt test ratio: the specific force's gravity direction (a0, a1, a2, low-passed,
        near g in norm) against the estimated roll and pitch."""
        er = _atan2(-a1, -a2) - self.roll
        ep = _atan2(a0, _sqrt(a1 * a1 + a2 * a2)) - self.pitch
        self.tr_tilt += TR_K * ((er * er + ep * ep) / TILT_GATE2 - self.tr_tilt)

    @cython.locals(ax=f64, ay=f64, az=f64, gx=f64, gy=f64, gz=f64, n=cython.long, p=f64,
                   q=f64, r=f64, ph=f64, th=f64, sph=f64, cph=f64, sth=f64, cth=f64, tth=f64,
                   fn=f64, w=f64, er=f64, ep=f64, mx=f64, my=f64, mz=f64, hx=f64, hy=f64,
                   yaw_m=f64, fx_w=f64, fy_w=f64, fz_w=f64, az_w=f64, qa=f64, pzz=f64,
                   pzv=f64, pvv=f64, pzb=f64, pvb=f64, pbb=f64, h=f64, a0=f64, a1=f64, a2=f64,
                   b1=f64, b2=f64, hpa=f64, z_b=f64, fields=cython.long)
    def _imu(self, m: Payload, dt: float) -> None:
        # m: time_usec, xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag, abs_pressure,
        #    diff_pressure, pressure_alt, temperature, fields_updated, id
        st = self.stats
        if not self._imu_ok(m):
            return
        ax, ay, az, gx, gy, gz = self.ra0, self.ra1, self.ra2, self.rg0, self.rg1, self.rg2
        fields = self.rfields
        n = self.n
        self.n = n + 1
        if n < _CAL:                               # at rest: gyro bias and initial attitude
            self.bg0 += (gx - self.bg0) / (n + 1)
            self.bg1 += (gy - self.bg1) / (n + 1)
            self.bg2 += (gz - self.bg2) / (n + 1)
            # the mean specific force at rest
            self.alp0 += (ax - self.alp0) / (n + 1)
            self.alp1 += (ay - self.alp1) / (n + 1)
            self.alp2 += (az - self.alp2) / (n + 1)
            self.sg2 += (gx * gx + gy * gy + gz * gz - self.sg2) / (n + 1)
            self.roll = _atan2(-self.alp1, -self.alp2)
            self.pitch = _atan2(self.alp0, _sqrt(self.alp1 * self.alp1 + self.alp2 * self.alp2))
        p, q, r = gx - self.bg0, gy - self.bg1, gz - self.bg2
        self.p, self.q, self.r = p, q, r
        # attitude: Euler-rate integration of the gyro
        ph, th = self.roll, self.pitch
        sph, cph = _sin(ph), _cos(ph)
        cth = _cos(th)
        tth = _tan(th)
        self.roll = ph + (p + (sph * q + cph * r) * tth) * dt
        self.pitch = th + (cph * q - sph * r) * dt
        self.yaw = wrap_pi(self.yaw + (sph * q + cph * r) / cth * dt)
        if n < _CAL:
            ax, ay, az = self.alp0, self.alp1, self.alp2
        self.alp0 += ACC_LP * (ax - self.alp0)
        self.alp1 += ACC_LP * (ay - self.alp1)
        self.alp2 += ACC_LP * (az - self.alp2)
        fn = _sqrt(self.alp0 * self.alp0 + self.alp1 * self.alp1 + self.alp2 * self.alp2)
        if abs(fn - _G) < self.acc_gate:
            w = self.w_acc
            er = _atan2(-self.alp1, -self.alp2) - self.roll
            ep = _atan2(self.alp0, _sqrt(self.alp1 * self.alp1 + self.alp2 * self.alp2)) \
                - self.pitch
            self._watch_tilt(self.alp0, self.alp1, self.alp2)
            self.roll += w * er
            self.pitch += w * ep
            if n >= _CAL:                          # near level: body p, q ~ roll, pitch rates
                self.bg0 -= BIAS_KI * er
                self.bg1 -= BIAS_KI * ep
        # heading from the compass
        mx, my, mz = m.f(7), m.f(8), m.f(9)
        if (fields & _F_MAG) != _F_MAG:
            pass                                   # no new magnetometer reading
        elif _finite(mx + my + mz) and 0.05 < mx * mx + my * my + mz * mz < 4.0:
            ph, th = self.roll, self.pitch
            sph, cph, sth, cth = _sin(ph), _cos(ph), _sin(th), _cos(th)
            hx = mx * cth + my * sph * sth + mz * cph * sth
            hy = my * cph - mz * sph
            yaw_m = wrap_pi(_atan2(-hy, hx) + self.decl)
            w = 1.0 / (n + 1) if n < _CAL else self.w_mag
            self.yaw = wrap_pi(self.yaw + w * wrap_pi(yaw_m - self.yaw))
        else:
            st["est_rej_mag"] += 1
        # world acceleration from the specific force
        fx_w, fy_w, fz_w = euler_to_world(self.roll, self.pitch, self.yaw, ax, ay, az)
        az_w = fz_w + _G - self.bz if n >= _CAL else 0.0
        # altitude filter (z, vz and the accelerometer's bias bz, as EKF2 estimates it):
        # predict with F = [[1, dt, -dt^2/2], [0, 1, -dt], [0, 0, 1]], P = F P F' + Q
        self.z += self.vz * dt + 0.5 * az_w * dt * dt
        self.vz += az_w * dt
        qa = self.q_acc
        h = 0.5 * dt * dt
        pzz, pzv, pvv = self.pzz, self.pzv, self.pvv
        pzb, pvb, pbb = self.pzb, self.pvb, self.pbb
        a0 = pzz + dt * pzv - h * pzb               # rows of F P
        a1 = pzv + dt * pvv - h * pvb
        a2 = pzb + dt * pvb - h * pbb
        b1 = pvv - dt * pvb
        b2 = pvb - dt * pbb
        self.pzz = a0 + dt * a1 - h * a2 + qa * h * h
        self.pzv = a1 - dt * a2 + qa * dt * h
        self.pzb = a2
        self.pvv = b1 - dt * b2 + qa * dt * dt
        self.pvb = b2
        self.pbb = pbb + self.q_ab * dt
        if n >= _CAL:
            self.vx += fx_w * dt
            self.vy += fy_w * dt
            self.pvx += self.of_q
            self.pvy += self.of_q
        # barometer: altitude from the pressure drop since the start (the floor); the
        # reference is the mean of the readings accepted at rest, or, with none by the end of
        # the alignment, the first accepted one at the altitude estimated then
        if (fields & _F_BARO) != _F_BARO:
            return                                 # no new pressure (PX4: the same bits)
        hpa = m.f(10)
        if not (_finite(hpa) and 300.0 < hpa < 1200.0):
            st["est_rej_baro"] += 1
            return
        if n < _CAL:
            self.nb += 1
            self.p0_hpa = hpa if self.nb == 1 else self.p0_hpa + (hpa - self.p0_hpa) / self.nb
            return
        if self.nb == 0:
            self.nb = 1
            self.p0_hpa = hpa - self.z * (1.225 * _G) / 100.0
            return
        z_b = (hpa - self.p0_hpa) * 100.0 / (1.225 * _G)
        self.tr_hgt += TR_K * ((z_b - self.z) * (z_b - self.z) / ((self.pzz + self.r_baro)
                                                                * HGT_GATE2) - self.tr_hgt)
        if abs(z_b - self.z) > self.baro_gate:
            st["est_rej_baro"] += 1
            return
        st["est_baro_fused"] += 1
        self._z_fuse(z_b, self.r_baro)

    def _reset(self) -> None:
        """A state that is no longer finite (no reading may make one; if one ever does): each
        part that is not finite starts again as at rest, and `resets` counts it (the vehicle
        says so)."""
        self.resets += 1
        self.stats["est_resets"] += 1
        if not _finite(self.roll + self.pitch + self.yaw + self.p + self.q + self.r):
            self.roll = self.pitch = self.yaw = self.p = self.q = self.r = 0.0
        if not _finite(self.z + self.vz + self.bz + self.pzz + self.pvv + self.pbb):
            self.z, self.vz, self.bz = min(0.0, self.z) if _finite(self.z) else 0.0, 0.0, 0.0
            self.pzz, self.pzv, self.pvv, self.pzb, self.pvb = 1.0, 0.0, 1.0, 0.0, 0.0
            self.pbb = self.abl_lim * self.abl_lim
        if not _finite(self.x + self.y + self.vx + self.vy + self.pvx + self.pvy):
            self.x = self.x if _finite(self.x) else 0.0
            self.y = self.y if _finite(self.y) else 0.0
            self.vx = self.vy = 0.0
            self.pvx = self.pvy = 1.0

    @cython.locals(pzz=f64, pzv=f64, pvv=f64, pzb=f64, pvb=f64, s=f64, kz=f64, kv=f64,
                   kb=f64, e=f64, lim=f64)
    def _z_fuse(self, zm: float, r: float) -> None:
        pzz, pzv, pvv, pzb, pvb = self.pzz, self.pzv, self.pvv, self.pzb, self.pvb
        s = pzz + r
        kz, kv, kb = pzz / s, pzv / s, pzb / s
        e = zm - self.z
        self.z += kz * e
        self.vz += kv * e
        lim = self.abl_lim                # EKF2_ABL_LIM: the bias learned stays within it
        self.bz = min(lim, max(-lim, self.bz + kb * e))
        self.pzz, self.pzv, self.pzb = (1.0 - kz) * pzz, (1.0 - kz) * pzv, (1.0 - kz) * pzb
        self.pvv, self.pvb = pvv - kv * pzv, pvb - kv * pzb
        self.pbb -= kb * pzb

    @cython.locals(lo=cython.long, hi=cython.long, cur=cython.long, quality=cython.long,
                   c=f64, zm=f64)
    def _range(self, m: Payload, t_us: int) -> None:
        # m: time_boot_ms, min, max, current (cm), type, id, orientation, covariance, hfov,
        #    vfov, quaternion[4], signal_quality
        st = self.stats
        lo, hi, cur, quality = m.i(1), m.i(2), m.i(3), m.i(14)
        if quality == 1 or cur < lo or cur > hi:
            st["est_rng_none"] += 1
            self.rng_rej_since = -1
            return
        c = _cos(self.roll) * _cos(self.pitch)
        zm = -cur * 0.01 * c
        if abs(zm - self.z) > self.rng_gate:
            st["est_rej_rng"] += 1
            if self.rng_rej_since < 0:
                self.rng_rej_since = t_us
            elif t_us - self.rng_rej_since > RNG_RESET_US:
                st["est_rng_resets"] += 1
                self.z, self.rng_rej_since = zm, -1
            return
        self.rng_rej_since = -1
        self.rng_us = t_us
        st["est_rng_fused"] += 1
        self._z_fuse(zm, self.r_rng)

    @cython.locals(dt_us=cython.longlong, ix=f64, iy=f64, gx=f64, gy=f64, quality=cython.long,
                   ok=cython.bint, dt=f64, ph=f64, th=f64, ps=f64, sph=f64, cph=f64, sth=f64,
                   cth=f64, d=f64, vbx=f64, vby=f64, sps=f64, cps=f64, vbz=f64, vn=f64, ve=f64,
                   r=f64, k=f64)
    def _flow(self, m: Payload, t_us: int) -> bool:
        """Fuse a flow message; whether it was fused."""
        # m: time_usec, integration_time_us, integrated_x, integrated_y, integrated_xgyro,
        #    integrated_ygyro, integrated_zgyro, time_delta_distance_us, distance,
        #    temperature, sensor_id, quality
        st = self.stats
        dt_us, ix, iy, gx, gy, quality = m.i(1), m.f(2), m.f(3), m.f(4), m.f(5), m.i(11)
        ok = (_finite(ix + iy + gx + gy) and 0 < dt_us < 1_000_000 and quality >= self.of_qmin
              and self.z < -0.4 and abs(self.roll) < 0.6 and abs(self.pitch) < 0.6
              and abs(self.p) < 7.0 and abs(self.q) < 7.0)
        if not ok:
            st["est_rej_flow"] += 1
            return False
        dt = dt_us * 1e-6
        gx -= self.bg0 * dt            # the flow sensor's gyro integral is the IMU's: less its
        gy -= self.bg1 * dt            # bias (uncorrected, 3 mrad/s x 1.1 m = 3 mm/s of drift)
        ph, th, ps = self.roll, self.pitch, self.yaw
        sph, cph, sth, cth = _sin(ph), _cos(ph), _sin(th), _cos(th)
        d = -self.z / (cph * cth)
        vbx = (iy - gy) / dt * d
        vby = -(ix - gx) / dt * d
        # body z velocity from the estimate, then the body velocity to world N, E
        sps, cps = _sin(ps), _cos(ps)
        vbz = (cph * sth * cps + sph * sps) * self.vx + (cph * sth * sps - sph * cps) * self.vy \
            + cph * cth * self.vz
        vn, ve, _ = euler_to_world(ph, th, ps, vbx, vby, vbz)
        self.tr_vel += TR_K * (max((vn - self.vx) * (vn - self.vx) / (self.pvx + self.of_r),
                                   (ve - self.vy) * (ve - self.vy) / (self.pvy + self.of_r))
                               / VEL_GATE2 - self.tr_vel)
        if abs(vn - self.vx) > self.of_gate or abs(ve - self.vy) > self.of_gate:
            st["est_rej_flow"] += 1
            return False
        st["est_flow_fused"] += 1
        r = self.of_r
        k = self.pvx / (self.pvx + r)
        self.vx += k * (vn - self.vx)
        self.pvx *= 1.0 - k
        k = self.pvy / (self.pvy + r)
        self.vy += k * (ve - self.vy)
        self.pvy *= 1.0 - k
        self.aid_us = t_us
        return True

    def _gps(self, m: Payload, geo, t_us: int) -> None:
        # m: time_usec, lat, lon, alt, eph, epv, vel, vn, ve, vd, cog, fix_type,
        #    satellites_visible, ...
        st = self.stats
        lat, lon, alt, eph, fix, nsat = m.i(1), m.i(2), m.i(3), m.i(4), m.i(11), m.i(12)
        if fix < 3 or eph > GPS_REQ_EPH_CM or nsat < GPS_REQ_NSATS or not (
                -900_000_000 <= lat <= 900_000_000 and -1_800_000_000 <= lon <= 1_800_000_000):
            st["est_rej_gps"] += 1                 # EKF2's quality checks
            return
        n, e, _ = geo.to_ned(lat * 1e-7, lon * 1e-7, alt * 1e-3)
        # EKF2's innovation gate: EKF2_GPS_P_GATE standard deviations of the fix's accuracy
        # (at least EKF2_GPS_P_NOISE); rejected for GPS_RESET_US in a row, the position is
        # reset to the fix (as EKF2 resets to GPS when its fusion has timed out)
        sd = max(eph * 0.01, GPS_P_NOISE_M)
        if (n - self.x) ** 2 + (e - self.y) ** 2 > (GPS_P_GATE * sd) ** 2:
            if self.gps_rej_since < 0:
                self.gps_rej_since = t_us
            if t_us - self.gps_rej_since < GPS_RESET_US:
                st["est_rej_gps"] += 1
                return
            st["est_gps_resets"] += 1
            self.x, self.y = n, e
        self.gps_rej_since = -1
        w = self.w_gps
        self.x += w * (n - self.x)
        self.y += w * (e - self.y)
        st["est_gps_fused"] += 1
        self.aid_us = self.gps_us = t_us
