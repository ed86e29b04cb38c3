"""Failsafes, each with its PX4 parameter and a STATUSTEXT:

- offboard setpoints lost: hold, then land (COM_OF_LOSS_T, COM_FAIL_ACT_T);
- ground-station link lost: no HEARTBEAT from a MAV_TYPE_GCS component for COM_DL_LOSS_T,
  once one has been heard, while flying: NAV_DLL_ACT (0 off, 1 hold, 2 return, 3 land);
- battery: warnings at BAT_LOW_THR, BAT_CRIT_THR, BAT_EMERGEN_THR remaining; COM_LOW_BAT_ACT
  (0 warn only, 2 land at critical, 3 return at critical and land at emergency);
- position estimate lost (ODOMETRY quality -1; the onboard estimator: no flow or GPS fused
  for TPL_NOAID_TOUT): held level, at its altitude on the estimator (sonar, baro), at hover
  thrust on a lost ODOMETRY feed; after TPL_POS_FS_DELAY while flying, land;
- geofence: a cylinder about home, GF_MAX_HOR_DIST radius and GF_MAX_VER_DIST height (0: no
  limit), checked while flying: GF_ACTION (0 none, 1 warn, 2 hold, 3 return, 5 land);
- IMU failed (the onboard estimator without a usable IMU reading for IMU_FAIL_US in flight):
  land, blind (`imu_missing`);
- estimator failed (its tilt or velocity innovation test ratio, mav/estimator/template.py,
  above 1 in flight): the position lost for good, land (`estimator_failed`).

An action fires once per event (the link lost, a battery level crossed, the fence breached);
the user can take over with a new mode at once, as on PX4. Nothing fires on the ground."""

from __future__ import annotations

import math

from mav.estimator.template import FAIL_TILT
from mav.onboard.channels import Outbox
from mav.onboard.commander import Commander
from mav.onboard.defs import LAND, LOITER, ON_GROUND, RTL, M
from mav.onboard.status import VehicleStatus

# A tick of the onboard estimator without a usable IMU reading (NaN, out of range) leaves the
# estimate where it was: nothing that reads it runs (modes, land detector, controller; PX4's
# rate controller too runs only on a new gyro sample) and the motors keep their collective
# thrust without torque (held commands, with the attitude loop's last torque in them, tip a
# Mambo in tenths of a second).
# Without one for IMU_FAIL_US in flight, the IMU has failed: the vehicle descends blind, all
# motors at the thrust of PX4's descent without a vertical estimate (FlightTaskDescend: a
# constant BLIND_ACC down, "crash landing"; no attitude is left to hold, so no mode can run),
# and disarms once that descent has had time to reach the floor from the last height
# estimated, plus BLIND_MARGIN_M. 0.1 s (PX4 declares the attitude invalid after 1 s without
# an estimate, commander's estimatorCheck, but its vehicle is still controlled meanwhile).
IMU_FAIL_US = 100_000
BLIND_ACC = 0.15             # m/s^2, downward (PX4 FlightTaskDescend)
BLIND_MARGIN_M = 0.6         # m, added to the height the descent must cover (drag slows it:
                             # from 1.05 m the Mambo took 4.3 s, ~0.11 m/s^2; with 0.3 m it
                             # was disarmed 60 ms above the floor and fell the rest)


class Failsafe:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander,
                 apply_params) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.apply_params = apply_params   # recomputes the limits that derive from params
        self.blind_us = -1         # the IMU failsafe's blind descent: since when (-1: none)
        self.blind_end_us = 0      # ... and when it disarms
        self.u_blind = 0.0         # ... at this command on every motor
        self.est_fail = 0          # the estimator's failure acted on (template.FAIL_*)

    def offboard_lost(self, t: int) -> None:
        """OFFBOARD without a setpoint for COM_OF_LOSS_T: hold position."""
        self.out.statustext("Failsafe: offboard setpoints lost, holding position",
                            M.MAV_SEVERITY_CRITICAL)
        self.cmd.set_mode(LOITER)
        self.vs.fs_active, self.vs.fs_t0 = True, t

    def hold_expired(self) -> None:
        """Held COM_FAIL_ACT_T after the loss and offboard did not come back: land."""
        vs = self.vs
        vs.fs_active = False
        if vs.landed_state != ON_GROUND:
            self.out.statustext("Failsafe: offboard not back, landing", M.MAV_SEVERITY_CRITICAL)
            self.cmd.set_mode(LAND)

    def act(self, action: int, why: str) -> None:
        """PX4's failsafe actions by NAV_DLL_ACT / GF_ACTION number: 1 hold, 2 return, 3 land
        (0 and other numbers: the message alone)."""
        vs = self.vs
        flying = vs.armed and vs.landed_state != ON_GROUND
        mode = {1: LOITER, 2: RTL, 3: LAND}.get(action) if flying else None
        if mode is None:
            self.out.statustext(why[0].upper() + why[1:], M.MAV_SEVERITY_WARNING)
            return
        what = {LOITER: "holding", RTL: "returning", LAND: "landing"}[mode]
        self.out.statustext(f"Failsafe: {why}, {what}", M.MAV_SEVERITY_CRITICAL)
        if mode == LOITER:         # hold here, also ending a go-to in AUTO.LOITER
            self.cmd.set_mode(LOITER)
            self.cmd.hold_here()
        elif mode is not None and vs.mode != mode:
            self.cmd.set_mode(mode)

    # ------------------------------------------------------------------ GCS link
    def on_heartbeat(self, ch, msg) -> None:
        if msg.type == M.MAV_TYPE_GCS:
            vs = self.vs
            if vs.gcs_lost:
                vs.gcs_lost = False
                self.out.statustext("GCS connection regained", M.MAV_SEVERITY_INFO)
            vs.gcs_last_us = vs.t_us

    def check_gcs(self, t: int) -> None:
        vs = self.vs
        if vs.gcs_last_us < 0 or vs.gcs_lost:
            return
        if t - vs.gcs_last_us > int(vs.own["COM_DL_LOSS_T"] * 1e6):
            vs.gcs_lost = True
            act = int(vs.own["NAV_DLL_ACT"])
            if vs.armed and vs.landed_state != ON_GROUND:
                self.act(act, "GCS connection lost")
            else:
                self.out.statustext("GCS connection lost", M.MAV_SEVERITY_WARNING)

    # ------------------------------------------------------------------ position estimate
    def position_lost(self, t: int) -> None:
        vs = self.vs
        vs.pos_lost_us, vs.pos_fs_done = t, False
        self.out.statustext("Position estimate lost, holding level", M.MAV_SEVERITY_CRITICAL)

    def position_regained(self) -> None:
        self.vs.pos_lost_us = -1
        self.out.statustext("Position estimate regained", M.MAV_SEVERITY_INFO)

    def check_position(self, t: int) -> None:
        """No estimate for TPL_POS_FS_DELAY while flying: land (it descends once an estimate
        is back; a blind descent is not modelled)."""
        vs = self.vs
        vs.stats["odometry_lost"] += 1
        if (not vs.pos_fs_done and vs.armed and vs.landed_state != ON_GROUND
                and t - vs.pos_lost_us > int(vs.own["TPL_POS_FS_DELAY"] * 1e6)):
            vs.pos_fs_done = True
            self.act(3, "no position estimate")

    # ------------------------------------------------------------------ IMU
    def imu_missing(self, t: int, e, airframe) -> None:
        """A tick whose IMU reading the estimator `e` rejected (see IMU_FAIL_US): the blind
        descent once the IMU has been silent IMU_FAIL_US in flight, its disarm when it has
        had time to reach the floor."""
        vs = self.vs
        if self.blind_us < 0:
            if vs.armed and vs.landed_state != ON_GROUND and t - e.imu_us > IMU_FAIL_US:
                self.blind_us = t
                h = max(0.0, -e.z)                  # m above the floor it started on
                self.blind_end_us = t + int(math.sqrt(2.0 * (h + BLIND_MARGIN_M)
                                                      / BLIND_ACC) * 1e6)
                self.u_blind = airframe.u_hover * math.sqrt(1.0 - BLIND_ACC / airframe.g)
                vs.stats["failsafe_imu"] += 1
                self.act(3, "no valid IMU data")
        elif t >= self.blind_end_us and vs.armed:
            self.cmd.set_landed(ON_GROUND)
            self.cmd.disarm("Blind descent over, disarmed")

    def imu_ok(self, e) -> None:
        """A tick with an IMU reading, while blind or when the estimate `e` has just failed:
        the estimator's failsafe, or the blind descent's end (the IMU is back)."""
        if e.fail != self.est_fail:
            self.est_fail = e.fail
            self.estimator_failed(e)
        elif self.blind_us >= 0:         # an IMU reading again: the blind descent ends (the
            self.blind_us = -1           # landing goes on, estimated)
            self.out.statustext("IMU data back", M.MAV_SEVERITY_WARNING)

    def estimator_failed(self, e) -> None:
        """The estimator's tilt or velocity test ratio stayed above 1 in flight (template.py):
        it has failed for good (PX4: "Navigation failure! Land and recalibrate sensors") and
        its position is lost (held level on the estimated attitude, at the estimated altitude,
        as PX4 with its local position invalid): land. (A blind descent, all motors equal as
        without an IMU, keeps a tilt the estimate got wrong: measured, it flew 4 m off and
        touched down at 3.1 m/s where this landing landed.)"""
        vs = self.vs
        tilt = e.fail == FAIL_TILT
        vs.stats["failsafe_est_tilt" if tilt else "failsafe_est_vel"] += 1
        why = "estimator failure (" + ("attitude)" if tilt else "velocity)")
        self.act(3, why)

    # ------------------------------------------------------------------ geofence
    def check_geofence(self) -> None:
        vs = self.vs
        own = vs.own
        r_max, h_max = own["GF_MAX_HOR_DIST"], own["GF_MAX_VER_DIST"]
        if (r_max <= 0.0 and h_max <= 0.0) or vs.home is None or not vs.armed \
                or vs.landed_state == ON_GROUND:
            return
        s, (hx, hy, hz) = vs.state, vs.home
        out = (r_max > 0.0 and math.hypot(s.x - hx, s.y - hy) > r_max) or (
            h_max > 0.0 and hz - s.z > h_max)
        if out and not vs.fence_breached:
            vs.fence_breached = True
            act = int(own["GF_ACTION"])
            if act > 0:
                self.act({2: 1, 3: 2, 4: 1, 5: 3}.get(act, 0), "geofence breached")
        elif not out and vs.fence_breached:
            vs.fence_breached = False

    # ------------------------------------------------------------------ battery
    def battery_warning(self) -> None:
        vs = self.vs
        vs.bat_warned += 1
        level = ("low", "critical", "emergency")[min(vs.bat_warned, 3) - 1]
        text = f"Battery {level}: {100.0 * vs.battery.remaining:.0f}% remaining"
        act = int(vs.own["COM_LOW_BAT_ACT"])
        self.apply_params()
        # PX4 COM_LOW_BAT_ACT: 2 land at critical; 3 return at critical, land at emergency
        action = 0
        if vs.bat_warned == 2 and act in (2, 3):
            action = 3 if act == 2 else 2
        elif vs.bat_warned >= 3 and act in (2, 3):
            action = 3
        if action and vs.armed and vs.landed_state != ON_GROUND:
            self.act(action, f"battery {level}")
        else:
            self.out.statustext(text, M.MAV_SEVERITY_WARNING if vs.bat_warned == 1
                                else M.MAV_SEVERITY_CRITICAL)
