"""The estimator's front (`Estimator`, re-exported by mav/estimator/__init__.py, which says
what it does): TPL_EST_TYPE, the sensor bundle decoded, the estimate as ODOMETRY's fields,
ESTIMATOR_STATUS's flags. Its own module so the per-tick part is compiled (mav/__init__.py).
"""

from __future__ import annotations

import math

import cython
from pymavlink.dialects.v20 import common as M

from mav import hil_sensors as hs
from mav.estimator.release import ReleaseEstimator
from mav.estimator.template import CAL_TICKS, FAIL_TILT, G, TemplateEstimator
from mav.hil import SIM_SYSID, odometry_of, odometry_record, tick_refusal
from mav.params import EST_OURS, EST_RELEASE
from mav.rotations import quat_from_euler

# The preflight checks of the IMU at rest (its CAL_TICKS readings of the alignment, then the
# low-passed specific force), as PX4's commander's with its defaults: COM_ARM_IMU_ACC 0.7 m/s^2
# and COM_ARM_IMU_GYR 0.25 rad/s (imuConsistencyCheck: with one IMU, the accelerometer against
# gravity's magnitude, the gyro's spread at rest), the gyro bias under 0.75 x EKF2_GYR_B_LIM
# 0.15 rad/s (estimatorCheck's "High Gyro Bias"), roll and pitch within the failure detector's
# FD_FAIL_R / FD_FAIL_P 60 deg (failureDetectorCheck)
ARM_IMU_ACC = 0.7
ARM_IMU_GYR = 0.25
ARM_GYRO_BIAS = 0.75 * 0.15
ARM_TILT = math.radians(60.0)


class Estimator:
    def __init__(self, own: dict[str, float], stats: dict[str, int], geo) -> None:
        self.own, self.stats, self.geo = own, stats, geo
        # read once, when the vehicle starts (as PX4 picks its estimator at boot): 1 the
        # template's structure with this stack's additions (template.py), 2 paper 1's release
        kind = own.get("TPL_EST_TYPE", 0.0)
        self.impl = (ReleaseEstimator(own, stats) if kind == EST_RELEASE
                     else TemplateEstimator(own, stats))
        self.bundle = hs.Bundle()          # the sensor messages of a tick, read in place
        self.enabled = kind >= EST_OURS
        for k in ("est_bad_frames", "est_lost", "dropped_stale_hil", "dropped_jump_hil",
                  "dropped_foreign_hil"):
            stats.setdefault(k, 0)
        self.refused = False               # the last datagram was a sensor datagram refused

    @property
    def aligned(self) -> bool:
        """Its attitude is initialised (the first CAL_TICKS readings at rest)."""
        return self.impl.n >= CAL_TICKS

    @property
    def active(self) -> bool:
        """It has had sensor messages (the vehicle flies on it)."""
        return self.impl.n > 0

    @cython.locals(e=TemplateEstimator)
    def preflight(self) -> str | None:
        """Why arming must wait or is refused: the attitude not aligned yet (the first
        CAL_TICKS readings at rest, as PX4 waits for EKF2's tilt alignment), an implausible IMU
        at rest ("Preflight Fail: ...", see ARM_IMU_ACC), or an estimate that failed in flight."""
        e = self.impl
        if e.n < CAL_TICKS:
            return "attitude not aligned yet (estimator)"
        if e.fail:
            return "Preflight Fail: estimator failed, reboot"
        a = math.sqrt(e.alp0 * e.alp0 + e.alp1 * e.alp1 + e.alp2 * e.alp2)
        if not abs(a - G) <= ARM_IMU_ACC:
            return f"Preflight Fail: Accel 0 reads {a:.1f} m/s^2 at rest"
        b = math.sqrt(e.bg0 * e.bg0 + e.bg1 * e.bg1 + e.bg2 * e.bg2)
        if not b <= ARM_GYRO_BIAS:
            return "Preflight Fail: High Gyro Bias"
        if not math.sqrt(max(0.0, e.sg2 - b * b)) <= ARM_IMU_GYR:
            return "Preflight Fail: Gyro 0 inconsistent at rest"
        if not (abs(e.roll) <= ARM_TILT and abs(e.pitch) <= ARM_TILT):
            return "Preflight Fail: Attitude failure (" + (
                "roll)" if abs(e.roll) > ARM_TILT else "pitch)")
        return None

    def status_flags(self) -> int:
        """ESTIMATOR_STATUS_FLAGS of the estimate: attitude once calibrated, vertical from the
        barometer, height above ground while the sonar is fused, horizontal velocity and
        relative position while the flow (or GPS) aids it, else constant-position mode."""
        e = self.impl
        t = e.t_us
        f = M.ESTIMATOR_VELOCITY_VERT | M.ESTIMATOR_POS_VERT_ABS
        if e.n >= CAL_TICKS:
            f |= M.ESTIMATOR_ATTITUDE
        if 0 <= t - e.rng_us < 200_000:
            f |= M.ESTIMATOR_POS_VERT_AGL
        if e.aid_us > 0 and not e.lost and t - e.aid_us < e.noaid_us:
            f |= M.ESTIMATOR_VELOCITY_HORIZ | M.ESTIMATOR_POS_HORIZ_REL
        else:
            f |= M.ESTIMATOR_CONST_POS_MODE
        if 0 < e.gps_us and t - e.gps_us < 1_000_000:
            f |= M.ESTIMATOR_POS_HORIZ_ABS
        if e.fail == FAIL_TILT:
            f |= M.ESTIMATOR_ACCEL_ERROR       # the accelerometer and the attitude disagree
        return f


    @cython.locals(b=hs.Bundle)
    def estimate(self, data: bytes) -> bool:
        """Run on a HIL datagram: True if it was a sensor datagram with a HIL_SENSOR (the
        estimate moved on: `odometry`), False for anything else (nothing done). A sensor
        datagram that cannot be the next tick (`mav.hil.tick_refusal`: another system's, a
        stamp not later than the last or too far ahead) is counted by its reason and sets
        `refused` (nothing else done: no step of the estimate, no tick of the vehicle)."""
        self.refused = False
        if not self.enabled or not hs.is_sensor_bundle(data):
            return False
        b = self.bundle
        b.read(data)
        return self._estimate(b, data[b.imu.at + 5] if b.imu.data is not None else -1)

    @cython.locals(b=hs.Bundle)
    def estimate_parts(self, parts: list) -> bool:
        """`estimate` of the simulator's sensor messages handed over unframed, as
        parts = [message, payload, ...] (`hil_sensors.stamp_all`'s): MIL's typed HIL
        exchange (cosim/sim/onboard.py), the same estimate as of their frames."""
        self.refused = False
        if not self.enabled:
            return False
        b = self.bundle
        b.take(parts)
        return self._estimate(b, SIM_SYSID)

    @cython.locals(e=TemplateEstimator, imu=hs.Payload)
    def _estimate(self, b: hs.Bundle, sysid: int) -> bool:
        """The estimate's step on the messages in `b`, HIL_SENSOR's sent by system `sysid`."""
        st = self.stats
        if b.bad:
            st["est_bad_frames"] += b.bad
        imu = b.imu
        e = self.impl
        if imu.data is None:
            if b.foreign:                          # the HIL_SENSOR was another system's
                st["dropped_foreign_hil"] += 1
                self.refused = True
            return False
        t_us = imu.i(0)
        why = tick_refusal(sysid, t_us, e.t_us)
        if why is not None:
            st[why] += 1
            self.refused = True
            return False
        e.update(imu, b.flow if b.flow.data is not None else None,
                 b.rng if b.rng.data is not None else None,
                 b.gps if b.gps.data is not None else None, self.geo, t_us)
        if e.lost:
            self.stats["est_lost"] += 1
        return True

    @cython.locals(e=TemplateEstimator)
    def odometry(self, mav) -> bytes:
        """The estimate as the ODOMETRY frame the vehicle's tick reads (frame ids LOCAL_NED,
        estimator type 1; quality -1 when the position is lost), stamped with the last
        HIL_SENSOR's time_usec, on mav."""
        e = self.impl
        qw, qx, qy, qz = quat_from_euler(e.roll, e.pitch, e.yaw)
        return odometry_of(mav, e.t_us, e.x, e.y, e.z, qw, qx, qy, qz, e.vx, e.vy, e.vz, e.p,
                           e.q, e.r, e.lost)

    @cython.locals(e=TemplateEstimator)
    def record(self) -> tuple:
        """The estimate as the fields the vehicle's tick reads from `odometry`'s frame
        (`mav.hil.odometry_record`: the same values, without the frame)."""
        e = self.impl
        qw, qx, qy, qz = quat_from_euler(e.roll, e.pitch, e.yaw)
        return odometry_record(e.t_us, e.x, e.y, e.z, qw, qx, qy, qz, e.vx, e.vy, e.vz, e.p,
                               e.q, e.r, e.lost)

    def on_hil(self, data: bytes) -> tuple | None:
        """`estimate`, then the estimate as ODOMETRY's fields (`record`; None if it did not
        move on)."""
        if not self.estimate(data):
            return None
        return self.record()

    def link(self, hil, mav):
        """The vehicle's HIL link with this estimator in front of its tick (link.py); a link
        that already has one (a rebooted vehicle's) gets a fresh one."""
        from mav.estimator.link import EstimatorLink

        return EstimatorLink(getattr(hil, "inner", hil) if isinstance(hil, EstimatorLink)
                             else hil, self, mav)
