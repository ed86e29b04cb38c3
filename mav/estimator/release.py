"""Paper 1's own estimator: the State Estimator of the Simulink project paper 1 released and flew
(GitHub mar4945/Vision-Based-Pure-Pursuing-Algorithm, folder UniSannio_Team/: the model
`controller/flightControlSystem.slx`, cited below as `FCS Lnnnn [SID]`, the line of the block
in its `simulink/blockdiagram.xml` and the block's SID; its numbers in `tasks/estimatorVars.m`,
cited `EV:n`, and `tasks/sensorsVars.m`, `SV:n`). TPL_EST_TYPE 2, the Mambo's default.

One 5 ms step, in the model's order (FCS L6328 [1847]):

1. Preprocessing (FCS L10406 [2085]): imu = inverseIMUGain .* (raw - c - [0 0 g 0 0 0])
   (EV:7; the gains SV:10-11); the accelerometer through a 6-tap FIR low-pass
   (designfilt('lowpassfir', 'FilterOrder', 5, 'CutoffFrequency', 0.1), EV:10-11), r through
   cheby2(5, 40, 0.8) (EV:12); p and q unfiltered.
2. Attitude, complementary filter (FCS L6363 [1852]): the gyro through the Euler-rate matrix,
   integrated; while |a| is within (1 +- 0.002) g (EV:14, relative) roll and pitch move by
   weight 0.001 (EV:15) toward atan(ay/az) and asin(ax/g); yaw is the gyro's alone.
3. Altitude (FCS L7587 [1926]): a Kalman filter on (z, vz) (FCS L7699 [1938]: A = [1 Ts; 0 1],
   B = [0; Ts], C = [1 0], G = [0; 1], Q = 0.0005, R = 0.1, EV:25-29, the current-estimator
   form with its steady-state gain), driven by the world-down acceleration, measured by the
   sonar alone; the measurement is used only when the sonar reads beyond its 0.44 m minimum
   (SV:53), is within 0.1 m of the last estimate (EV:32), and the estimate is not both 0.8 m
   from the butter(3, 0.01)-filtered pressure altitude (EV:21, 33) and 0.4 m from the
   butter(3, 0.01)-filtered sonar (EV:22, 34); reset to rest while the last estimate is below
   the floor (FCS L8270 [1973]).
4. Horizontal velocity, body axes (FCS L8581 [1985]): per axis a Kalman filter (A = 1,
   B = Ts, Q = 0.09, R = 5, EV:57-61, steady-state gain) driven by 0.2 (EV:39) x the body
   acceleration less gravity (only while the flow reads non-zero and above 0.4 m, EV:38),
   measured by the flow (after the first 4 s: 1.15 x the height x the flow rate,
   FCS L9995 [2068]); used only above 0.4 m, within 5 m/s of the last estimate (EV:54), and
   with |roll|, |pitch| <= 0.6 rad, |p|, |q| <= 7 rad/s and their rates of change (of the
   cheby2-filtered p, q) <= 80 rad/s^2 (EV:49, 50, 52), or in hover, |p|, |q| <= 0.5 rad/s
   (EV:51).
5. Position (FCS L10161 [2070]): the velocity rotated to the world, integrated (forward Euler)
   from 0; no position filter (the release's kfPos and vision numbers, EV:64-72, are not used
   by its model).

What differs, and why (docs/sensors.md, "paper 1's release vs ours"):
- The calibration c (accelerometer and gyro at rest, the reference pressure) is the mean of
  the first CAL_TICKS readings at rest, as the vehicle measures it before it may arm; the
  release reads the same quantities from `sensorCalibration.mat`, measured at rest before.
- The flow comes as PX4's HIL_OPTICAL_FLOW: its rates less the flow sensor's gyro (the Mambo's
  flow is delivered de-rotated); a sample the sensor marks unusable (quality below
  EKF2_OF_QMIN) is not fused (the Mambo sends zeros, which the release fuses).
- A sensor absent in a tick (a slower sonar or flow, `range_every`, `flow_every`) holds its
  last reading, as Simulink's zero-order hold does (the release's flow is 60 Hz held at 200 Hz).
- A reading not renewed for HOLD_US (a sensor that stopped sending) expires: the sonar is
  then absent, the flow reads zero.
- double precision throughout (the model casts its outputs to single); asin's argument held
  within [-1, 1]; roll not corrected when az is exactly 0 (the model would divide by it); yaw
  wrapped to +-pi. No GPS (the release has none: TPL_EST_TYPE 1 fuses it).
- The altitude starts (and the floor resets it) at 0, the start's height: the model's X0 is
  the plant's absolute -0.046 m; ours is relative to the floor the vehicle starts on.
- The outputs are what the vehicle's ODOMETRY carries: the velocity in world axes (the body
  velocity rotated, as the model integrates it) and the filter's world vz, where the model's
  bus carries body dx, dy and a mixed dz (FCS L7587 [1926], read by its own controller).
- Its tuning that the template's parameters share with type 1 is read from them: TPL_ACC_W
  (0.001, EV:15), TPL_OF_Q / TPL_OF_R (0.09 / 5, EV:59-60), TPL_OF_GATE (5 m/s, EV:54); their
  defaults are the release's numbers.
- The vehicle's own checks stay as with TPL_EST_TYPE 1: readings NaN or out of range rejected
  and counted, the position `lost` without aiding, the test ratios and the estimator failure.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cython
from cython.cimports.libc.math import asin as _asin
from cython.cimports.libc.math import atan as _atan
from cython.cimports.libc.math import cos as _cos
from cython.cimports.libc.math import sin as _sin
from cython.cimports.libc.math import sqrt as _sqrt
from cython.cimports.libc.math import tan as _tan

from mav.estimator.template import (
    CAL_TICKS,
    F_BARO,
    HGT_GATE_SD,
    TR_PER_TICK,
    VEL_GATE_SD,
    G,
    TemplateEstimator,
    _finite,
)
from mav.rotations import euler_to_world, wrap_pi

if TYPE_CHECKING:
    from mav.hil_sensors import Payload

f64 = cython.typedef(cython.double)
TS = 0.005                       # the model's step (UniSannio_Team/utilities/startVars.m:28)
# inverseIMUGain (EV:7) of the template's scale factors (SV:10-11)
ACC_GAIN = (1.00596, 1.00383, 0.99454)
INV_ACC = (1.0 / ACC_GAIN[0], 1.0 / ACC_GAIN[1], 1.0 / ACC_GAIN[2])
INV_GYRO = (1.0 / 0.99861, 1.0 / 1.00644, 1.0 / 0.99997)
# MATLAB's designs, as scipy.signal computes them (tests/test_estimator_release.py checks):
# designfilt('lowpassfir','FilterOrder',5,'CutoffFrequency',0.1) = fir1(5, 0.1), Hamming
FIR_ACC = (0.02640772492323808, 0.14053136276241623, 0.33306091231434565,
           0.33306091231434565, 0.14053136276241623, 0.02640772492323808)
CHEBY2_B = (0.28212412246252067, 1.2725392917168599, 2.4208439774454447, 2.4208439774454438,
            1.2725392917168596, 0.2821241224625206)          # cheby2(5, 40, 0.8), EV:12
CHEBY2_A = (1.0, 2.2287149173647673, 2.5244618916938624, 1.5772531712757025,
            0.5410224068298176, 0.07956239608550092)
BUTTER_B = (3.7568380197512637e-06, 1.1270514059253792e-05, 1.1270514059253792e-05,
            3.7568380197512637e-06)                           # butter(3, 0.01), EV:21-22
BUTTER_A = (1.0, -2.9371707284498907, 2.8762997234793315, -0.939098940325283)
ACC_THRESHOLD = 0.002            # EV:14: |a| within (1 +- this) g
ALT_Q, ALT_R = 0.0005, 0.1       # EV:27-28
SONAR_MIN = 0.44                 # SV:53
SONAR_JUMP = 0.1                 # EV:32 deltaSonarToCurrentMax
PRS_OFF = 0.8                    # EV:33 deltaPrsToCurrentThreshold
SONAR_OFF = 0.4                  # EV:34 deltaSonarToFilteredThreshold
OF_Z_MAX = -0.4                  # EV:38 opticalFlowZMax
ACC_INPUT_GAIN = 0.2             # EV:39 accelerationInputGain
OF_CORRECT = 1.15                # FCS L9995 [2068] opticalFlowErrorCorrect
OF_RAW_STEPS = 800               # FCS L8997 [2011]: the raw flow for the first 200*4 steps
OF_PITCH_ROLL_MAX = 0.6          # EV:49
OF_PQ_MAX = 7.0                  # EV:50
OF_PQ_HOV_MAX = 0.5              # EV:51
OF_DPQ_MAX = 80.0                # EV:52
HOLD_US = 100_000                # a reading held longer than this without a new one: none
_RHO_G = cython.declare(cython.double, 1.225 * G)     # SV:47-48 altToPrsGain
# the template module's figures as C values here (its C globals are its own)
_G = cython.declare(cython.double, G)
_CAL = cython.declare(cython.long, CAL_TICKS)
_F_BARO = cython.declare(cython.long, F_BARO)
TR_K = cython.declare(cython.double, TR_PER_TICK)
VEL_GATE2 = cython.declare(cython.double, VEL_GATE_SD * VEL_GATE_SD)
# C copies of the constants the per-tick step compares and scales with (compiled, a Python
# float would be boxed per comparison)
_TS = cython.declare(cython.double, TS)
_ACC_THRESHOLD = cython.declare(cython.double, ACC_THRESHOLD)
_SONAR_MIN = cython.declare(cython.double, SONAR_MIN)
_SONAR_JUMP = cython.declare(cython.double, SONAR_JUMP)
_PRS_OFF = cython.declare(cython.double, PRS_OFF)
_SONAR_OFF = cython.declare(cython.double, SONAR_OFF)
_OF_Z_MAX = cython.declare(cython.double, OF_Z_MAX)
_OF_CORRECT = cython.declare(cython.double, OF_CORRECT)
_ACC_INPUT_GAIN = cython.declare(cython.double, ACC_INPUT_GAIN)
_OF_PITCH_ROLL_MAX = cython.declare(cython.double, OF_PITCH_ROLL_MAX)
_OF_PQ_MAX = cython.declare(cython.double, OF_PQ_MAX)
_OF_PQ_HOV_MAX = cython.declare(cython.double, OF_PQ_HOV_MAX)
_OF_DPQ_MAX = cython.declare(cython.double, OF_DPQ_MAX)
_OF_RAW_STEPS = cython.declare(cython.long, OF_RAW_STEPS)
_INV_ACC0 = cython.declare(cython.double, INV_ACC[0])
_INV_ACC1 = cython.declare(cython.double, INV_ACC[1])
_INV_ACC2 = cython.declare(cython.double, INV_ACC[2])
_INV_GYRO0 = cython.declare(cython.double, INV_GYRO[0])
_INV_GYRO1 = cython.declare(cython.double, INV_GYRO[1])
_INV_GYRO2 = cython.declare(cython.double, INV_GYRO[2])
HGT_GATE2 = cython.declare(cython.double, HGT_GATE_SD * HGT_GATE_SD)


class Lti:
    """One channel of MATLAB's filter(b, a, x) (direct form II transposed, zero initial state):
    `step(x)` -> y. At most 6 coefficients."""

    def __init__(self, b: tuple[float, ...], a: tuple[float, ...]) -> None:
        if not (1 <= len(b) <= 6 and 1 <= len(a) <= len(b) and a[0] != 0.0):
            raise ValueError(f"an Lti filter takes 1-6 coefficients b and as many or fewer "
                             f"a, a[0] not 0 (got {len(b)} and {len(a)})")
        self.n = len(b)
        self.b = [0.0] * 6
        self.a = [0.0] * 6
        self.z = [0.0] * 6
        for i in range(self.n):
            self.b[i] = b[i] / a[0]
            self.a[i] = a[i] / a[0] if i < len(a) else 0.0

    @cython.locals(y=f64, i=cython.int)
    def step(self, x: float) -> float:
        y = self.b[0] * x + self.z[0]
        for i in range(1, self.n):
            self.z[i - 1] = self.b[i] * x + self.z[i] - self.a[i] * y
        return y

    @cython.locals(i=cython.int)
    def reset(self) -> None:
        for i in range(6):
            self.z[i] = 0.0


def steady_gain_alt(q: float, r: float, ts: float) -> tuple[float, float]:
    """The altitude filter's steady-state gain M (current-estimator form) for A = [1 ts; 0 1],
    C = [1 0], process noise G Q G' with G = [0; 1]: the prior covariance iterated to its
    fixed point (the discrete Riccati equation), then M = P C' / (C P C' + R)."""
    p00, p01, p11 = 10.0, 0.0, 10.0
    for _ in range(200_000):
        s = p00 + r                                   # update
        u00, u01, u11 = p00 - p00 * p00 / s, p01 - p00 * p01 / s, p11 - p01 * p01 / s
        n00 = u00 + 2.0 * ts * u01 + ts * ts * u11    # predict: A U A' + Q
        n01 = u01 + ts * u11
        n11 = u11 + q
        done = abs(n00 - p00) + abs(n01 - p01) + abs(n11 - p11) < 1e-15
        p00, p01, p11 = n00, n01, n11
        if done:
            break
    return p00 / (p00 + r), p01 / (p00 + r)


def steady_prior_vel(q: float, r: float) -> float:
    """The velocity filter's steady-state prior variance per axis (A = 1, C = 1): the positive
    root of P^2 - q P - q r = 0."""
    return (q + math.sqrt(q * q + 4.0 * q * r)) / 2.0


class ReleaseEstimator(TemplateEstimator):
    """Paper 1's released estimator (the module's docstring); the estimate in the same fields
    as TemplateEstimator's (x, y, z, vx, vy, vz world NED from the start; roll, pitch, yaw;
    p, q, r), and the same health (`lost`, `fail`, the test ratios)."""

    def __init__(self, own: dict[str, float], stats: dict[str, int]) -> None:
        super().__init__(own, stats)
        self.fir0, self.fir1, self.fir2 = (Lti(FIR_ACC, (1.0,)), Lti(FIR_ACC, (1.0,)),
                                           Lti(FIR_ACC, (1.0,)))
        self.chp, self.chq, self.chr = (Lti(CHEBY2_B, CHEBY2_A), Lti(CHEBY2_B, CHEBY2_A),
                                        Lti(CHEBY2_B, CHEBY2_A))
        self.bw_prs, self.bw_son = Lti(BUTTER_B, BUTTER_A), Lti(BUTTER_B, BUTTER_A)
        self.ka0, self.ka1 = steady_gain_alt(ALT_Q, ALT_R, TS)
        self.pz_ss = self.ka0 * ALT_R / (1.0 - self.ka0)     # its prior variance of z
        pv = steady_prior_vel(self.of_q, self.of_r)
        self.pv_ss = pv
        self.kv = pv / (pv + self.of_r)
        self.c0 = self.c1 = self.c2 = 0.0          # the accelerometer at rest (calibration)
        self._restart()

    def _restart(self) -> None:
        """The filters' states at rest (at start, and after a state that is not finite)."""
        for f in (self.fir0, self.fir1, self.fir2, self.chp, self.chq, self.chr, self.bw_prs,
                  self.bw_son):
            f.reset()
        self.zpr = self.vpr = 0.0                  # altitude filter: the prior (z, vz)
        self.z_prev = 0.0
        self.z_son = 0.0                           # the sonar (NED, held), the pressure
        self.z_prs = 0.0                           # altitude (held)
        self.son_ok = False                        # a sonar reading held
        self.fx = self.fy = 0.0                    # flow rate, body x and y (held)
        self.of_ok = False                         # a usable flow reading held
        self.bx = self.by = 0.0                    # velocity filter (body): the prior
        self.bx_out = self.by_out = 0.0            # ... and its last output
        self.pf_prev = self.qf_prev = 0.0          # cheby2-filtered p, q of the last step
        self.sx = self.sy = 0.0                    # position integrator
        self.son_us = self.of_us = -1
        self.x = self.y = self.z = self.vx = self.vy = self.vz = 0.0
        self.roll = self.pitch = self.yaw = 0.0
        self.p = self.q = self.r = 0.0
        self.tr_tilt = self.tr_vel = self.tr_hgt = 0.0

    @cython.locals(dt=f64, ok=cython.bint)
    def update(self, imu: Payload | None, flow: Payload | None, rng: Payload | None,
               gps: Payload | None, geo, t_us: int) -> None:
        """One tick (TemplateEstimator.update's arguments; `gps` and `geo` are not used)."""
        dt = self._dt(t_us)
        if rng is not None:
            self._sonar(rng)
        elif self.son_ok and t_us - self.son_us > HOLD_US:
            self.son_ok = False          # the sonar has stopped: its last reading expires
        new_flow = False
        if flow is not None:
            new_flow = self._of(flow)
        elif self.of_ok and t_us - self.of_us > HOLD_US:
            self.of_ok = False           # the flow has stopped: as the Mambo's zeros
            self.fx = self.fy = 0.0
        ok = imu is not None and self._imu_ok(imu)
        if ok:
            self._step(imu, dt, t_us, new_flow)
        if not _finite(self.x + self.y + self.z + self.vx + self.vy + self.vz + self.roll
                       + self.pitch + self.yaw + self.p + self.q + self.r + self.zpr
                       + self.vpr + self.bx + self.by + self.sx + self.sy):
            self.resets += 1
            self.stats["est_resets"] += 1
            self._restart()
        self._health(t_us)
        if imu is not None:
            self.stats["est_imu"] += 1

    @cython.locals(lo=cython.long, hi=cython.long, cur=cython.long, quality=cython.long)
    def _sonar(self, m: Payload) -> None:
        # m: time_boot_ms, min, max, current (cm), type, id, orientation, covariance, ...,
        #    signal_quality (14)
        lo, hi, cur, quality = m.i(1), m.i(2), m.i(3), m.i(14)
        if quality == 1 or cur < lo or cur > hi:
            self.stats["est_rng_none"] += 1
            self.son_ok = False
            return
        self.z_son = -cur * 0.01                   # FCS L8261 [1972]: no tilt compensation
        self.son_ok = True
        self.son_us = self.t_us

    @cython.locals(dt_us=cython.longlong, ix=f64, iy=f64, gx=f64, gy=f64, quality=cython.long,
                   dt=f64)
    def _of(self, m: Payload) -> bool:
        """A flow sample: its rates (body x, y; rad/s) held; whether it is usable."""
        dt_us, ix, iy, gx, gy, quality = m.i(1), m.f(2), m.f(3), m.f(4), m.f(5), m.i(11)
        if not (_finite(ix + iy + gx + gy) and 0 < dt_us < 1_000_000
                and quality >= self.of_qmin):
            self.stats["est_rej_flow"] += 1
            self.of_ok = False         # as the Mambo's zeros: the acceleration input stops
            self.fx = self.fy = 0.0    # too (the release's gate on a non-zero flow)
            return False
        dt = dt_us * 1e-6
        gx -= self.bg0 * dt            # the flow sensor's gyro integral is the IMU's: less
        gy -= self.bg1 * dt            # its bias
        self.fx = (iy - gy) / dt       # body x velocity over height (the Mambo's de-rotated
        self.fy = -(ix - gx) / dt      # flow)
        self.of_ok = True
        self.of_us = self.t_us
        return True

    @cython.locals(n=cython.long, ax=f64, ay=f64, az=f64, gx=f64, gy=f64, gz=f64, p=f64,
                   q=f64, r=f64, a0=f64, a1=f64, a2=f64, pf=f64, qf=f64, ph=f64, th=f64,
                   ps=f64, sph=f64, cph=f64, sth=f64, cth=f64, tth=f64, an=f64, w=f64,
                   s=f64, hpa=f64, u=f64, zp=f64, e=f64, en=cython.bint, zk=f64, vzk=f64,
                   ofx=f64, ofy=f64, alx=f64, aly=f64, ux=f64, uy=f64, dp=f64, dq=f64,
                   sps=f64, cps=f64, dz=f64, bx=f64, by=f64, k=f64, fields=cython.long,
                   prs_f=f64, son_f=f64)
    def _step(self, m: Payload, dt: float, t_us: int, new_flow: bool) -> None:
        st = self.stats
        ax, ay, az, gx, gy, gz = self.ra0, self.ra1, self.ra2, self.rg0, self.rg1, self.rg2
        n = self.n
        self.n = n + 1
        if n < _CAL:                 # at rest: the calibration c, and the checks' figures
            self.alp0 += (ax - self.alp0) / (n + 1)      # the mean reading at rest
            self.alp1 += (ay - self.alp1) / (n + 1)
            self.alp2 += (az - self.alp2) / (n + 1)
            self.bg0 += (gx - self.bg0) / (n + 1)
            self.bg1 += (gy - self.bg1) / (n + 1)
            self.bg2 += (gz - self.bg2) / (n + 1)
            self.sg2 += (gx * gx + gy * gy + gz * gz - self.sg2) / (n + 1)
            # c such that a level vehicle at rest reads (0, 0, -g) after the gain: the mean
            # less gain x gravity, plus the g the preprocessing takes off again (so the
            # release's file holds c(3) = -9.473 for a reading of -9.419 at rest)
            self.c0, self.c1 = self.alp0, self.alp1
            self.c2 = self.alp2 + _G * (ACC_GAIN[2] - 1.0)
        else:                        # the preflight checks' specific force, low-passed
            self.alp0 += 0.1 * (ax - self.alp0)
            self.alp1 += 0.1 * (ay - self.alp1)
            self.alp2 += 0.1 * (az - self.alp2)
        # 1. preprocessing: imu = inverseIMUGain .* (raw - c - [0 0 g 0 0 0])
        a0 = self.fir0.step((ax - self.c0) * _INV_ACC0)
        a1 = self.fir1.step((ay - self.c1) * _INV_ACC1)
        a2 = self.fir2.step((az - self.c2 - _G) * _INV_ACC2)
        p = (gx - self.bg0) * _INV_GYRO0
        q = (gy - self.bg1) * _INV_GYRO1
        r = self.chr.step((gz - self.bg2) * _INV_GYRO2)
        self.p, self.q, self.r = p, q, r
        # 2. attitude: the Euler rates of the last attitude and this gyro, integrated
        ph, th, ps = self.roll, self.pitch, self.yaw
        sph, cph, cth, tth = _sin(ph), _cos(ph), _cos(th), _tan(th)
        self.roll = ph + (p + sph * tth * q + cph * tth * r) * dt
        self.pitch = th + (cph * q - sph * r) * dt
        self.yaw = wrap_pi(ps + (sph * q + cph * r) / cth * dt)
        an = _sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if (1.0 - _ACC_THRESHOLD) * _G < an < (1.0 + _ACC_THRESHOLD) * _G:
            w = self.w_acc
            s = min(1.0, max(-1.0, a0 / _G))
            self.pitch = (1.0 - w) * self.pitch + w * _asin(s)
            if a2 != 0.0:
                self.roll = (1.0 - w) * self.roll + w * _atan(a1 / a2)
        an = _sqrt(self.alp0 * self.alp0 + self.alp1 * self.alp1 + self.alp2 * self.alp2)
        if n >= _CAL and abs(an - _G) < self.acc_gate:
            self._watch_tilt(self.alp0, self.alp1, self.alp2)
        # 3. altitude. The pressure altitude (reference: the mean at rest)
        fields = self.rfields
        if (fields & _F_BARO) == _F_BARO:
            hpa = m.f(10)
            if not (_finite(hpa) and 300.0 < hpa < 1200.0):
                st["est_rej_baro"] += 1
            elif n < _CAL:
                self.nb += 1
                self.p0_hpa = hpa if self.nb == 1 else self.p0_hpa + (hpa - self.p0_hpa) / self.nb
            elif self.nb == 0:       # none at rest: the first, at the altitude estimated then
                self.nb = 1
                self.p0_hpa = hpa - self.z * _RHO_G / 100.0
            else:
                st["est_baro_fused"] += 1
                self.z_prs = (hpa - self.p0_hpa) * 100.0 / _RHO_G
                # the height test ratio: against the altitude's steady prior variance plus
                # the barometer's (TPL_BARO_NOISE), gate 5 SD (HGT_GATE2), as with type 1
                self.tr_hgt += TR_K * ((self.z_prs - self.z) * (self.z_prs - self.z)
                                       / ((self.pz_ss + self.r_baro) * HGT_GATE2)
                                       - self.tr_hgt)
        ph, th, ps = self.roll, self.pitch, self.yaw
        u = euler_to_world(ph, th, ps, a0, a1, a2)[2] + _G          # world-down acceleration
        zp = self.z_prev
        if zp > 0.0:                                          # below the floor: at rest
            self.zpr, self.vpr = 0.0, 0.0
        prs_f = self.bw_prs.step(self.z_prs)
        son_f = self.bw_son.step(self.z_son)
        en = (self.son_ok and abs(zp - min(self.z_son, -_SONAR_MIN)) <= _SONAR_JUMP
              and self.z_son < -_SONAR_MIN
              and not (abs(prs_f - zp) >= _PRS_OFF and abs(son_f - zp) >= _SONAR_OFF))
        zk, vzk = self.zpr, self.vpr
        if en:
            e = self.z_son - zk
            zk += self.ka0 * e
            vzk += self.ka1 * e
            if self.son_us == t_us:          # a new reading (a held one is not counted)
                self.rng_us = t_us
                st["est_rng_fused"] += 1
        elif self.son_ok and self.son_us == t_us:
            st["est_rej_rng"] += 1
        self.zpr = zk + dt * vzk
        self.vpr = vzk + dt * u
        self.z, self.z_prev = zk, zk
        # 4. velocity (body axes)
        if n < _OF_RAW_STEPS:
            ofx, ofy = self.fx, self.fy
        else:
            ofx, ofy = _OF_CORRECT * -zk * self.fx, _OF_CORRECT * -zk * self.fy
        sth = _sin(th)
        sph, cph, cth = _sin(ph), _cos(ph), _cos(th)
        alx = a0 - _G * sth                       # the acceleration less gravity, body
        aly = a1 + _G * sph * cth
        ux = uy = 0.0
        if (ofx != 0.0 or ofy != 0.0) and zk <= _OF_Z_MAX:
            ux, uy = _ACC_INPUT_GAIN * alx, _ACC_INPUT_GAIN * aly
        pf, qf = self.chp.step(p), self.chq.step(q)
        dp, dq = (pf - self.pf_prev) / _TS, (qf - self.qf_prev) / _TS
        self.pf_prev, self.qf_prev = pf, qf
        en = (self.of_ok and zk <= _OF_Z_MAX
              and abs(ofx - self.bx_out) <= self.of_gate and abs(ofy - self.by_out) <= self.of_gate
              and ((abs(th) <= _OF_PITCH_ROLL_MAX and abs(ph) <= _OF_PITCH_ROLL_MAX
                    and abs(p) <= _OF_PQ_MAX and abs(q) <= _OF_PQ_MAX
                    and abs(dp) <= _OF_DPQ_MAX and abs(dq) <= _OF_DPQ_MAX)
                   or (abs(p) <= _OF_PQ_HOV_MAX and abs(q) <= _OF_PQ_HOV_MAX)))
        bx, by = self.bx, self.by
        if self.of_ok and zk <= _OF_Z_MAX:
            self.tr_vel += TR_K * (max((ofx - bx) * (ofx - bx), (ofy - by) * (ofy - by))
                                   / ((self.pv_ss + self.of_r) * VEL_GATE2) - self.tr_vel)
        if en:
            k = self.kv
            bx += k * (ofx - bx)
            by += k * (ofy - by)
            if new_flow:
                self.aid_us = t_us
                st["est_flow_fused"] += 1
        elif new_flow:
            st["est_rej_flow"] += 1
        # 5. position: the velocity to the world (the body z velocity from the last body
        # x, y velocity and this vz), integrated from 0
        sps, cps = _sin(ps), _cos(ps)
        dz = ((cph * sth * cps + sph * sps) * self.bx_out
              + (cph * sth * sps - sph * cps) * self.by_out + cph * cth * vzk)
        self.bx_out, self.by_out = bx, by
        self.bx, self.by = bx + dt * ux, by + dt * uy
        self.vx, self.vy, _ = euler_to_world(ph, th, ps, bx, by, dz)
        self.vz = vzk
        self.x, self.y = self.sx, self.sy
        self.sx += dt * self.vx
        self.sy += dt * self.vy
