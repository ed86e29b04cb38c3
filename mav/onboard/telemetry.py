"""Telemetry: the periodic streams of each link and the messages sent on request.

To add a message: write its `emit_<name>(ch)` here, register it in `emitters()`, and (for a
periodic stream) add it to `defs.STREAMS` with default rates in `defs.API_RATES_HZ` /
`GCS_RATES_HZ`. SET_MESSAGE_INTERVAL, REQUEST_MESSAGE and REQUEST_DATA_STREAM then work for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from heapq import heappop, heappush

import cython

from mav import wire
from mav.onboard.channels import Chan, Outbox, Stream
from mav.onboard.commander import Commander
from mav.onboard.defs import (
    CAPABILITIES,
    FLIGHT_SW_VERSION,
    FRAME_LOCAL_NED,
    IGN_ACCEL,
    IGN_VX,
    IGN_VY,
    IGN_VZ,
    IGN_X,
    IGN_Y,
    IGN_YAW,
    IGN_YAW_RATE,
    IGN_Z,
    MAV_AUTOPILOT,
    MAV_TYPE,
    MSG_ID_PROTOCOL_VERSION,
    PARAM_BURST,
    SENSORS,
    SENSORS_HEALTH,
    M,
    px4_custom_mode,
)
from mav.onboard.parameters import Parameters
from mav.onboard.status import VehicleStatus
from mav.rotations import euler_from_quat, rotate_body_to_world

# GPS_RAW_INT: the position is the estimate's (there is no receiver model); the rest is what a
# healthy receiver reports, so a ground station's GPS indicator shows a 3-D fix
GPS_EPH, GPS_EPV = 70, 100           # HDOP, VDOP x 100
GPS_SATS = 12
GPS_H_ACC_MM, GPS_V_ACC_MM, GPS_VEL_ACC_MMPS = 300, 500, 100
GPS_COG_MIN_MPS = 0.2                # m/s: slower than this the course is unknown (65535)
# PROTOCOL_VERSION: MAVLink 2 spoken, MAVLink 1 understood; no spec/library git hashes known
PROTO_VERSION, PROTO_MIN, PROTO_MAX = 200, 100, 200
_NO_HASH = (0,) * 16
# BATTERY_STATUS: cells 2..10 not reported; charge state by the number of warnings given
_NO_CELLS = (65535,) * 9
_CHARGE_STATES = (M.MAV_BATTERY_CHARGE_STATE_OK, M.MAV_BATTERY_CHARGE_STATE_LOW,
                  M.MAV_BATTERY_CHARGE_STATE_CRITICAL, M.MAV_BATTERY_CHARGE_STATE_EMERGENCY)
# HIGHRES_IMU: fields_updated bits of xacc..zgyro (the only fields filled in)
IMU_ACC_GYRO_BITS = 0x3F


class Telemetry:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander,
                 params: Parameters, geo: wire.FlatEarth, sysid: int, origin_alt_m: float,
                 mission, g_mps2: float = 9.81) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.params = params
        self.geo = geo
        self.sysid = sysid
        self.origin_alt_m = origin_alt_m
        self.mission = mission
        self.g_mps2 = g_mps2           # m/s^2, gravity in HIGHRES_IMU's specific force
        self.chans = outbox.chans
        self.estimator = None          # the vehicle's estimator (mav/estimator) when it has one
        self._emitters = self.emitters()

    def emitters(self) -> dict[int, Callable[[Chan], None]]:
        """message id -> the function that sends it on a link."""
        return {
            M.MAVLINK_MSG_ID_HEARTBEAT: self.emit_heartbeat,
            M.MAVLINK_MSG_ID_SYS_STATUS: self.emit_sys_status,
            M.MAVLINK_MSG_ID_ATTITUDE: self.emit_attitude,
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.emit_local_position,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.emit_global_position,
            M.MAVLINK_MSG_ID_HOME_POSITION: self.emit_home_position,
            M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.emit_extended_sys_state,
            M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: self.emit_position_target,
            M.MAVLINK_MSG_ID_BATTERY_STATUS: self.emit_battery_status,
            M.MAVLINK_MSG_ID_VFR_HUD: self.emit_vfr_hud,
            M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.emit_autopilot_version,
            M.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission.emit_current,
            M.MAVLINK_MSG_ID_GPS_RAW_INT: self.emit_gps_raw_int,
            M.MAVLINK_MSG_ID_ESTIMATOR_STATUS: self.emit_estimator_status,
            M.MAVLINK_MSG_ID_ODOMETRY: self.emit_odometry,
            M.MAVLINK_MSG_ID_HIGHRES_IMU: self.emit_highres_imu,
            MSG_ID_PROTOCOL_VERSION: self.emit_protocol_version,
        }

    def emitter(self, msgid: int) -> Callable[[Chan], None] | None:
        return self._emitters.get(msgid)

    def stream_emitter(self, msgid: int) -> Callable[[Chan], None] | None:
        """What a periodic stream calls: the emitter."""
        return self._emitters.get(msgid)

    def request_message(self, msgid: int) -> tuple[int, int | None]:
        """MAV_CMD_REQUEST_MESSAGE: (result, the message id to send after the ACK or None)."""
        if msgid not in self._emitters:
            self.vs.stats["commands_unsupported"] += 1
            return M.MAV_RESULT_UNSUPPORTED, None
        if msgid == M.MAVLINK_MSG_ID_HOME_POSITION and self.vs.home is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED, None
        return M.MAV_RESULT_ACCEPTED, msgid

    # ------------------------------------------------------------------ per tick
    @cython.locals(ch=Chan)
    def publish(self, t: int) -> None:
        """Everything due at t on each link: event messages, streams, queued PARAM_VALUEs.
        The vehicle's tick calls it only when something is (its test of next_due, the param
        queues and the event flags, vehicle.py); with nothing due it would send nothing."""
        vs = self.vs
        for ch in self.chans:
            if ch.signed:
                self.out.sync_signing(ch)
            if vs.hb_now:
                self.emit_heartbeat(ch)
            if vs.ext_now:
                self.emit_extended_sys_state(ch)
            if vs.home_now:
                self.emit_home_position(ch)
            if vs.mission_now:
                self.mission.emit_current(ch)
            if t >= ch.next_due:
                self._emit_due(ch, t)
            q = ch.param_queue
            if q:
                n = len(self.params.table)
                for idx in q[:PARAM_BURST]:
                    if idx < n:
                        self.params.send_value(ch, idx)
                del q[:PARAM_BURST]
        vs.hb_now = vs.ext_now = vs.home_now = vs.mission_now = False

    @staticmethod
    @cython.locals(ch=Chan, s=Stream)
    def _emit_due(ch: Chan, t: int) -> None:
        """The streams due at t, in the order of `ch.streams`; each then set to its next
        time (one interval on, or one interval from now if it fell behind)."""
        sched = ch.schedule
        if sched is None:
            ch.recompute_due()
            sched = ch.schedule
        due = []
        while sched and sched[0][0] <= t:
            due.append(heappop(sched)[1])
        if len(due) > 1:
            due.sort()
        streams = ch.streams
        for i in due:
            s = streams[i]
            s.emit(ch)
            iv = s.interval_us
            nxt = s.next_us + iv
            if nxt <= t:
                nxt = t + iv
            s.next_us = nxt
            heappush(sched, (nxt, i))
        ch.next_due = sched[0][0] if sched else 1 << 62

    # ------------------------------------------------------------------ the messages
    def _time_boot_ms(self) -> int:
        return (self.vs.t_us // 1000) & 0xFFFFFFFF

    def emit_heartbeat(self, ch: Chan) -> None:
        vs = self.vs
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if vs.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        status = M.MAV_STATE_ACTIVE if vs.armed else M.MAV_STATE_STANDBY
        ch.send(wire.pack(ch.mav, wire.HEARTBEAT, px4_custom_mode(vs.mode), MAV_TYPE,
                          MAV_AUTOPILOT, base, status, 3))

    def emit_sys_status(self, ch: Chan) -> None:
        b = self.vs.battery
        health = SENSORS_HEALTH
        pre = self.cmd.preflight
        if not self.vs.armed and pre is not None and pre() is not None:
            health &= ~M.MAV_SYS_STATUS_PREARM_CHECK     # as PX4: a ground station shows
            est = self.estimator                         # "not ready" (MAVSDK: not armable)
            if est is not None and est.enabled and not est.aligned:
                health &= ~M.MAV_SYS_STATUS_AHRS
        # wire order: sensors present/enabled/health, load, voltage mV, current cA, drop rate,
        # errors comm, errors 1..4, remaining %, extended present/enabled/health
        ch.send(wire.pack(ch.mav, wire.SYS_STATUS, SENSORS, SENSORS, health, 0,
                          wire.clamp_int(b.voltage * 1000.0, 0, 65534),
                          wire.clamp_int(b.current * 100.0, 0, 32767), 0, 0, 0, 0, 0, 0,
                          wire.clamp_int(100.0 * b.remaining, 0, 100), 0, 0, 0))

    def emit_attitude(self, ch: Chan) -> None:
        s = self.vs.state
        roll, pitch, yaw = euler_from_quat(s.qw, s.qx, s.qy, s.qz)
        ch.send(wire.encode_attitude(ch.mav, self._time_boot_ms(), roll, pitch, yaw,
                                     s.p, s.q, s.r))

    def emit_local_position(self, ch: Chan) -> None:
        s = self.vs.state
        ch.send(wire.encode_local_position_ned(ch.mav, self._time_boot_ms(), s.x, s.y, s.z,
                                               s.vx, s.vy, s.vz))

    def emit_global_position(self, ch: Chan) -> None:
        s = self.vs.state
        lat, lon, alt = self.geo.to_int(s.x, s.y, s.z)
        rel = wire.clamp_int(self.cmd.agl() * 1000.0, -(1 << 31), (1 << 31) - 1)
        hdg = wire.clamp_int(math.degrees(self.cmd.heading()) % 360.0 * 100.0, 0, 35999)
        ci = wire.clamp_int
        ch.send(wire.pack(ch.mav, wire.GLOBAL_POSITION_INT, self._time_boot_ms(), lat, lon, alt,
                          rel, ci(s.vx * 100.0, -32768, 32767), ci(s.vy * 100.0, -32768, 32767),
                          ci(s.vz * 100.0, -32768, 32767), hdg))

    def emit_home_position(self, ch: Chan) -> None:
        home = self.vs.home
        if home is None:
            return
        hx, hy, hz = home
        lat, lon, alt = self.geo.to_int(hx, hy, hz)
        # wire order: lat, lon, alt, x, y, z, q[4], approach x, y, z, time_usec
        ch.send(wire.pack(ch.mav, wire.HOME_POSITION, lat, lon, alt, hx, hy, hz, 1.0, 0.0, 0.0,
                          0.0, 0.0, 0.0, 0.0, self.vs.t_us))

    def emit_extended_sys_state(self, ch: Chan) -> None:
        ch.send(wire.pack(ch.mav, wire.EXTENDED_SYS_STATE, M.MAV_VTOL_STATE_UNDEFINED,
                          self.vs.landed_state))

    def emit_position_target(self, ch: Chan) -> None:
        sp = self.vs.setpoint
        mask = IGN_ACCEL
        vals = []
        for bit, v in ((IGN_X, sp.x), (IGN_Y, sp.y), (IGN_Z, sp.z), (IGN_VX, sp.vx),
                       (IGN_VY, sp.vy), (IGN_VZ, sp.vz), (IGN_YAW, sp.yaw),
                       (IGN_YAW_RATE, sp.yaw_rate)):
            if v != v:
                mask |= bit
                v = 0.0
            vals.append(v)
        x, y, z, vx, vy, vz, yaw, yaw_rate = vals
        ch.send(wire.pack(ch.mav, wire.POSITION_TARGET_LOCAL_NED, self._time_boot_ms(), x, y, z,
                          vx, vy, vz, 0.0, 0.0, 0.0, yaw, yaw_rate, mask, M.MAV_FRAME_LOCAL_NED))

    def emit_battery_status(self, ch: Chan) -> None:
        vs = self.vs
        b = vs.battery
        ci = wire.clamp_int
        cell_mv = ci(b.voltage * 1000.0, 0, 65534)
        # wire order: current_consumed, energy_consumed, temperature, voltages[10],
        # current_battery, id, battery_function, type, battery_remaining, time_remaining,
        # charge_state, voltages_ext[4], mode, fault_bitmask
        ch.send(wire.pack(
            ch.mav, wire.BATTERY_STATUS, ci(b.consumed_mah, 0, (1 << 31) - 1),
            ci(b.energy_j / 100.0, 0, (1 << 31) - 1), 32767, cell_mv, *_NO_CELLS,
            ci(b.current * 100.0, 0, 32767), 0, M.MAV_BATTERY_FUNCTION_ALL,
            M.MAV_BATTERY_TYPE_LIPO, ci(100.0 * b.remaining, 0, 100),
            ci(b.time_remaining_s(), 0, (1 << 31) - 1), _CHARGE_STATES[min(vs.bat_warned, 3)],
            0, 0, 0, 0, 0, 0))

    def emit_vfr_hud(self, ch: Chan) -> None:
        s = self.vs.state
        gs = math.hypot(s.vx, s.vy)
        u = self.vs.u
        thr = wire.clamp_int(25.0 * (u[0] + u[1] + u[2] + u[3]), 0, 100)
        ch.send(wire.pack(ch.mav, wire.VFR_HUD, gs, gs, self.origin_alt_m - s.z, -s.vz,
                          wire.clamp_int(math.degrees(self.cmd.heading()) % 360.0, 0, 359), thr))

    def emit_autopilot_version(self, ch: Chan) -> None:
        ch.send(wire.send_msg(ch.mav, M.MAVLink_autopilot_version_message(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, list(b"cosim\x00\x00\x00"), [0] * 8,
            [0] * 8, 0, 0, self.sysid, [0] * 18)))

    def emit_protocol_version(self, ch: Chan) -> None:
        """PROTOCOL_VERSION (MAV_CMD_REQUEST_PROTOCOL_VERSION, REQUEST_MESSAGE 300): always
        MAVLink 2 (mav/wire.py has its layout; pymavlink's dialects lack it)."""
        ch.send(wire.pack(ch.mav, wire.PROTOCOL_VERSION, PROTO_VERSION, PROTO_MIN, PROTO_MAX,
                          *_NO_HASH))

    def emit_gps_raw_int(self, ch: Chan) -> None:
        """GPS_RAW_INT from the estimate: lat/lon/alt by the same flat-earth conversion as
        GLOBAL_POSITION_INT (equal to it), ground speed and course; fix, DOPs, satellites and
        accuracies of a healthy receiver (constants above). alt_ellipsoid = alt: the flat-earth
        model has no geoid, so the separation is taken as 0."""
        s = self.vs.state
        lat, lon, alt = self.geo.to_int(s.x, s.y, s.z)
        gs = math.hypot(s.vx, s.vy)
        cog = 65535 if gs < GPS_COG_MIN_MPS else wire.clamp_int(
            math.degrees(math.atan2(s.vy, s.vx)) % 360.0 * 100.0, 0, 35999)
        # wire order: time_usec, lat, lon, alt, eph, epv, vel, cog, fix_type, satellites,
        # alt_ellipsoid, h_acc, v_acc, vel_acc, hdg_acc, yaw
        ch.send(wire.pack(ch.mav, wire.GPS_RAW_INT, self.vs.t_us, lat, lon, alt, GPS_EPH,
                          GPS_EPV, wire.clamp_int(gs * 100.0, 0, 65534), cog,
                          M.GPS_FIX_TYPE_3D_FIX, GPS_SATS, alt, GPS_H_ACC_MM, GPS_V_ACC_MM,
                          GPS_VEL_ACC_MMPS, 0, 0))

    def emit_odometry(self, ch: Chan) -> None:
        """ODOMETRY as PX4 streams its estimator output (ODOMETRY.hpp): pose in LOCAL_NED,
        velocity in LOCAL_NED, body rates; covariances unknown (NaN), quality 100 (the
        estimate is the simulator's state)."""
        s = self.vs.state
        ch.send(wire.encode_odometry(
            ch.mav, self.vs.t_us, s.x, s.y, s.z, s.qw, s.qx, s.qy, s.qz, s.vx, s.vy, s.vz,
            s.p, s.q, s.r, frame_id=FRAME_LOCAL_NED, child_frame_id=FRAME_LOCAL_NED,
            estimator_type=M.MAV_ESTIMATOR_TYPE_AUTOPILOT, quality=100))

    def emit_estimator_status(self, ch: Chan) -> None:
        """ESTIMATOR_STATUS: the flags of the estimate in use (on request, like PX4's). On
        ODOMETRY the estimate is the simulator's: attitude, velocity and position while it is
        valid; with the onboard estimator its own flags (`Estimator.status_flags`)."""
        vs = self.vs
        est = self.estimator
        r_vel = r_hgt = 0.0
        if est is not None and est.enabled and est.active:
            flags = est.status_flags()
            r_vel, r_hgt = est.impl.tr_vel, est.impl.tr_hgt    # its test ratios, low-passed
        elif vs.have_state:
            flags = (M.ESTIMATOR_ATTITUDE | M.ESTIMATOR_VELOCITY_VERT | M.ESTIMATOR_POS_VERT_ABS
                     | (M.ESTIMATOR_CONST_POS_MODE if vs.pos_lost_us >= 0 else
                        M.ESTIMATOR_VELOCITY_HORIZ | M.ESTIMATOR_POS_HORIZ_REL))
        else:
            flags = 0
        ch.send(wire.send_msg(ch.mav, M.MAVLink_estimator_status_message(
            vs.t_us, flags, r_vel, 0.0, r_hgt, 0.0, 0.0, 0.0, 0.0, 0.0)))

    def emit_highres_imu(self, ch: Chan) -> None:
        """HIGHRES_IMU DERIVED from the estimate, not a sensor model: accelerometer = specific
        force f_B = R_BW (a_W - g_W), with a_W the mean acceleration over the last tick (the
        difference of successive velocity estimates, as an IMU reports its delta velocity over
        its integration interval: PX4's HIGHRES_IMU.hpp divides delta_velocity by its dt);
        gyroscope = the body rates. At rest level it reads (0, 0, -g). No noise, bias,
        vibration or magnetometer/baro fields (fields_updated = accel and gyro only); odometry
        noise, if any, is amplified by 1/tick."""
        vs = self.vs
        s = vs.state
        if vs.dt_us > 0:
            k = 1e6 / vs.dt_us
            px, py, pz = vs.v_prev
            ax, ay, az = (s.vx - px) * k, (s.vy - py) * k, (s.vz - pz) * k
        else:
            ax = ay = az = 0.0
        # world -> body: rotate by the conjugate of the body -> world quaternion
        fx, fy, fz = rotate_body_to_world(s.qw, -s.qx, -s.qy, -s.qz, ax, ay, az - self.g_mps2)
        ch.send(wire.pack(ch.mav, wire.HIGHRES_IMU, vs.t_us, fx, fy, fz, s.p, s.q, s.r, 0.0, 0.0,
                          0.0, 0.0, 0.0, 0.0, 0.0, IMU_ACC_GYRO_BITS, 0))
