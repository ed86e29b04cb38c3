"""The onboard flight stack: a PX4-style MAVLink vehicle around the low-level controller.

Three links (see `mav/links.py`): `hil` (the simulator: ODOMETRY in, HIL_ACTUATOR_CONTROLS out),
`api` (offboard apps, like PX4's link to 14540) and `gcs` (ground stations, like 14550).

Lockstep contract (ARCHITECTURE.md, "Time and order within a tick"): `poll()` does nothing
unless a HIL datagram is waiting. With a valid ODOMETRY it first drains and handles everything
queued on `api` and `gcs` (on the vehicle clock of the previous tick), then sets the vehicle
clock to the ODOMETRY's time_usec, copies the state (the estimator, today), runs modes and
failsafes and the controller, publishes due telemetry and answers on `hil` with exactly one
HIL_ACTUATOR_CONTROLS stamped with the same time_usec. Every timer runs on this clock, so a
run is deterministic; the api/gcs links are read only at HIL time.

Embedded style: the state, setpoint and motor-command records are preallocated and updated in
place; the per-tick path uses the fast codec of `mav/wire.py`; telemetry is only encoded when
due. Everything parsed from a link is guarded: a bad datagram is counted in `stats`, never
raised, and never delays the HIL answer.

Run as a process (SIL): `python -m mav.onboard --help`.
"""

from __future__ import annotations

import argparse
import math
import select
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.airframe import Airframe, get_airframe
from mav.battery import BATTERIES, Battery
from mav.params import ONBOARD_PARAMS, ParamError, ParamTable, f32, read_param_file
from mav.types import Setpoint, VehicleState

M = mavlink2
NAN = math.nan
TWO_PI = 2.0 * math.pi

# ---- PX4 custom modes (px4_custom_mode.h): custom_mode = main << 16 | sub << 24
PX4_MAIN_MANUAL, PX4_MAIN_ALTCTL, PX4_MAIN_POSCTL, PX4_MAIN_AUTO = 1, 2, 3, 4
PX4_MAIN_OFFBOARD = 6
PX4_SUB_TAKEOFF, PX4_SUB_LOITER, PX4_SUB_LAND = 2, 3, 6

# internal mode numbers
POSCTL, TAKEOFF, LOITER, LAND, OFFBOARD = 0, 1, 2, 3, 4
MODE_NAMES = ("POSCTL", "AUTO.TAKEOFF", "AUTO.LOITER", "AUTO.LAND", "OFFBOARD")
MODE_PX4 = ((PX4_MAIN_POSCTL, 0), (PX4_MAIN_AUTO, PX4_SUB_TAKEOFF), (PX4_MAIN_AUTO, PX4_SUB_LOITER),
            (PX4_MAIN_AUTO, PX4_SUB_LAND), (PX4_MAIN_OFFBOARD, 0))
_MODE_BY_PX4 = {px4: i for i, px4 in enumerate(MODE_PX4)}
_MODE_BY_PX4[(PX4_MAIN_POSCTL, 1)] = POSCTL            # POSCTL sub modes (orbit, slow)
_MODE_BY_PX4[(PX4_MAIN_POSCTL, 2)] = POSCTL


def px4_custom_mode(mode: int) -> int:
    main, sub = MODE_PX4[mode]
    return main << 16 | sub << 24


_FRAME_LOCAL_NED = M.MAV_FRAME_LOCAL_NED
_FRAME_BODY_NED = M.MAV_FRAME_BODY_NED
_SP_ID3 = wire.SET_POSITION_TARGET_LOCAL_NED.id3
_FRAME_BODY_FRD = M.MAV_FRAME_BODY_FRD
_HIL_MODE_DISARMED = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED       # HIL_ACTUATOR_CONTROLS.mode
_HIL_MODE_ARMED = M.MAV_MODE_FLAG_SAFETY_ARMED | M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED

# ---- landed states (MAV_LANDED_STATE)
ON_GROUND = M.MAV_LANDED_STATE_ON_GROUND
IN_AIR = M.MAV_LANDED_STATE_IN_AIR
TAKING_OFF = M.MAV_LANDED_STATE_TAKEOFF
LANDING = M.MAV_LANDED_STATE_LANDING

# ---- SET_POSITION_TARGET_LOCAL_NED type_mask bits (set = ignore)
IGN_X, IGN_Y, IGN_Z, IGN_VX, IGN_VY, IGN_VZ = 1, 2, 4, 8, 16, 32
IGN_AX, IGN_AY, IGN_AZ, FORCE_SET, IGN_YAW, IGN_YAW_RATE = 64, 128, 256, 512, 1024, 2048
IGN_ACCEL = IGN_AX | IGN_AY | IGN_AZ
SP_MAX_POS_M = 1.0e4        # m, |x|, |y|, |z| above this: rejected
SP_MAX_VEL_MPS = 20.0       # m/s, |vx|, |vy|, |vz|
SP_MAX_YAW_RAD = 2.0 * TWO_PI
SP_MAX_YAW_RATE = 20.0      # rad/s

# ---- ground / air detection
AIRBORNE_AGL_M = 0.15       # m above home: airborne (ON_GROUND -> IN_AIR)
TOUCH_VZ_MPS = 0.10         # m/s, |vz| below this while landing ...
TOUCH_AGL_M = 0.30          # ... and below this height above home ...
TOUCH_TRIG_US = 200_000     # ... for this long: touched down
TOUCH_STALL_US = 500_000    # or descent stalled this long after LAND_STALL_AFTER (any height)
LAND_STALL_AFTER_US = 2_000_000
TKO_ACCEPT_M = 0.10         # m, takeoff complete within this of the target height
TKO_SETTLE_US = 3_000_000   # or this long after the ramp reached the target
TKO_EASE_S = 0.4            # s, time constant of the takeoff reference near the target
TKO_SNAP_M = 0.002          # m, the reference snaps to the target from this close

FORCE_DISARM_MAGIC = 21196
REJECT_TEXT_EVERY_US = 1_000_000   # STATUSTEXT about rejected input at most this often per kind
PARAM_BURST = 16            # PARAM_VALUEs per link per tick while a list is being sent
DRAIN_MAX = 256             # datagrams handled per link per tick (bounded work under flood)
FRAMES_MAX = 32             # frames handled per datagram

SIGNING_EPOCH_2024 = 1704067200.0   # s, Unix time of 2024-01-01: signing timestamps start here
_SIGNING_EPOCH_2015 = 1420070400    # s, Unix time of MAVLink's signing epoch

MAV_TYPE = M.MAV_TYPE_QUADROTOR
MAV_AUTOPILOT = M.MAV_AUTOPILOT_PX4
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255   # "1.14.0" official, PX4 style
CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
)
_SENSORS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY | M.MAV_SYS_STATUS_PREARM_CHECK
)

# ---- telemetry streams: name -> message id; default rates (Hz) per link
STREAMS: dict[str, int] = {
    "HEARTBEAT": M.MAVLINK_MSG_ID_HEARTBEAT,
    "SYS_STATUS": M.MAVLINK_MSG_ID_SYS_STATUS,
    "ATTITUDE": M.MAVLINK_MSG_ID_ATTITUDE,
    "LOCAL_POSITION_NED": M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "GLOBAL_POSITION_INT": M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    "HOME_POSITION": M.MAVLINK_MSG_ID_HOME_POSITION,
    "EXTENDED_SYS_STATE": M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    "POSITION_TARGET_LOCAL_NED": M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    "BATTERY_STATUS": M.MAVLINK_MSG_ID_BATTERY_STATUS,
    "VFR_HUD": M.MAVLINK_MSG_ID_VFR_HUD,
}
API_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "ATTITUDE": 50.0, "LOCAL_POSITION_NED": 50.0,
    "GLOBAL_POSITION_INT": 10.0, "HOME_POSITION": 0.5, "EXTENDED_SYS_STATE": 5.0,
    "POSITION_TARGET_LOCAL_NED": 10.0, "BATTERY_STATUS": 1.0, "VFR_HUD": 0.0,
}
GCS_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "ATTITUDE": 20.0, "LOCAL_POSITION_NED": 10.0,
    "GLOBAL_POSITION_INT": 5.0, "HOME_POSITION": 0.5, "EXTENDED_SYS_STATE": 1.0,
    "POSITION_TARGET_LOCAL_NED": 2.0, "BATTERY_STATUS": 0.5, "VFR_HUD": 4.0,
}
# legacy REQUEST_DATA_STREAM groups (MAV_DATA_STREAM) -> streams
_DATA_STREAM_GROUPS: dict[int, tuple[str, ...]] = {
    M.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "EXTENDED_SYS_STATE", "BATTERY_STATUS",
                                        "POSITION_TARGET_LOCAL_NED"),
    M.MAV_DATA_STREAM_POSITION: ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT"),
    M.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    M.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    M.MAV_DATA_STREAM_EXTRA3: ("HOME_POSITION",),
}
_DATA_STREAM_GROUPS[M.MAV_DATA_STREAM_ALL] = tuple(
    n for g in list(_DATA_STREAM_GROUPS.values()) for n in g)


@dataclass
class OnboardConfig:
    """Everything the vehicle is built from. Times in s, rates in Hz, angles in deg."""

    vehicle: str = "mambo"                 # 'mambo' | 'bebop2'
    sysid: int = 1                         # MAVLink system id of the vehicle
    compid: int = M.MAV_COMP_ID_AUTOPILOT1
    origin_lat_deg: float = 42.299886      # geodetic origin of the local NED frame
    origin_lon_deg: float = -71.350447
    origin_alt_m: float = 71.3232          # m AMSL
    api_rates_hz: dict[str, float] = field(default_factory=lambda: dict(API_RATES_HZ))
    gcs_rates_hz: dict[str, float] = field(default_factory=lambda: dict(GCS_RATES_HZ))
    offboard_loss_s: float = 1.0           # COM_OF_LOSS_T default
    failsafe_land_s: float = 5.0           # COM_FAIL_ACT_T default: hold this long, then land
    signing_key: bytes | None = None       # 32 bytes: sign api/gcs and reject unsigned input
    signing_epoch_unix_s: float = SIGNING_EPOCH_2024   # signing timestamp at vehicle time 0
    param_file: str | None = None          # NAME VALUE lines (QGC .params tolerated)
    control_dt_s: float = 0.005            # s, controller period (= HIL tick)

    def __post_init__(self) -> None:
        get_airframe(self.vehicle)          # ValueError naming the choices
        if not 1 <= self.sysid <= 255:
            raise ValueError(f"sysid: got {self.sysid}; allowed 1..255")
        if not 1 <= self.compid <= 255:
            raise ValueError(f"compid: got {self.compid}; allowed 1..255")
        if self.signing_key is not None and len(self.signing_key) != 32:
            raise ValueError(f"signing_key: got {len(self.signing_key)} bytes; need 32")
        for name, lim in (("origin_lat_deg", 90.0), ("origin_lon_deg", 180.0),
                          ("origin_alt_m", 1e5)):
            v = getattr(self, name)
            if not (math.isfinite(v) and -lim <= v <= lim):
                raise ValueError(f"{name}: got {v!r}; allowed: finite, in [-{lim:g}, {lim:g}]")
        for which in ("api_rates_hz", "gcs_rates_hz"):
            for name, hz in getattr(self, which).items():
                if name not in STREAMS:
                    raise ValueError(f"{which}.{name}: unknown stream; known: "
                                     f"{', '.join(STREAMS)}")
                if not (math.isfinite(hz) and hz >= 0.0):
                    raise ValueError(f"{which}.{name}: got {hz!r}; need a rate >= 0 Hz")
        for name in ("offboard_loss_s", "failsafe_land_s", "control_dt_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name}: got {v!r}; need a time > 0 s")


class _Stream:
    __slots__ = ("msgid", "default_us", "interval_us", "next_us", "emit")

    def __init__(self, msgid: int, default_us: int, emit: Callable) -> None:
        self.msgid = msgid
        self.default_us = default_us      # -1: off by default
        self.interval_us = default_us
        self.next_us = 0
        self.emit = emit


class _Chan:
    """One MAVLink link of the vehicle (api or gcs): codec state, streams, pending params."""

    __slots__ = ("name", "link", "mav", "streams", "by_msgid", "next_due", "param_queue",
                 "signed", "peer", "stats", "tx_key", "rx_key", "bad_key")

    def __init__(self, name: str, link, mav, stats: dict[str, int]) -> None:
        self.name = name
        self.stats = stats
        self.tx_key = "tx_" + name
        self.rx_key = "rx_" + name
        self.bad_key = "dropped_bad_" + name
        self.link = link
        self.mav = mav
        self.streams: list[_Stream] = []
        self.by_msgid: dict[int, _Stream] = {}
        self.next_due = 0
        self.param_queue: list[int] = []
        self.signed = False
        self.peer: tuple[int, int] | None = None   # (sysid, compid) of the last sender

    def send(self, data: bytes) -> None:
        self.stats[self.tx_key] += 1
        self.link.send(data)

    def recompute_due(self) -> None:
        due = [s.next_us for s in self.streams if s.interval_us > 0]
        self.next_due = min(due) if due else 1 << 62


def _hz_to_us(hz: float) -> int:
    return int(round(1e6 / hz)) if hz > 0.0 else -1


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % TWO_PI - math.pi


def _text(s) -> str:
    if isinstance(s, bytes | bytearray):
        return bytes(s).split(b"\x00", 1)[0].decode("ascii", errors="replace")
    return str(s).split("\x00", 1)[0]


class Onboard:
    """The vehicle. `poll()` once per HIL datagram; see the module docstring for the contract.

    Attributes for the master and tests: `stats` (dict of counters), `mode` (int, see
    MODE_NAMES), `mode_name`, `armed`, `landed_state`, `state` (VehicleState), `setpoint`
    (the Setpoint in use), `u` (the last motor commands), `params` (ParamTable),
    `warnings` (parameter-file notes).
    """

    def __init__(self, config: OnboardConfig, hil, api, gcs, *, controller=None) -> None:
        self.cfg = cfg = config
        self._hil = hil
        self.vehicle: Airframe = get_airframe(cfg.vehicle)
        self.geo = wire.FlatEarth(cfg.origin_lat_deg, cfg.origin_lon_deg, cfg.origin_alt_m)
        self.stats: dict[str, int] = {
            "ticks": 0,
            "rx_hil": 0, "rx_api": 0, "rx_gcs": 0,
            "tx_api": 0, "tx_gcs": 0,
            "dropped_bad_hil": 0, "dropped_bad_api": 0, "dropped_bad_gcs": 0,
            "hil_ignored": 0, "hil_bad_values": 0,
            "unknown_msgs": 0, "unhandled_msgs": 0, "not_for_us": 0,
            "unsigned_rejected": 0, "badsig_rejected": 0,
            "setpoints": 0, "rejected_setpoints": 0,
            "commands": 0, "commands_unsupported": 0, "param_sets": 0, "param_rejected": 0,
            "drain_deferred": 0, "handler_errors": 0,
        }
        self._hil_mav = M.MAVLink(None, cfg.sysid, cfg.compid)
        self._chans: list[_Chan] = []
        for i, (name, link, rates) in enumerate((("api", api, cfg.api_rates_hz),
                                                  ("gcs", gcs, cfg.gcs_rates_hz))):
            mav = M.MAVLink(None, cfg.sysid, cfg.compid)
            ch = _Chan(name, link, mav, self.stats)
            if cfg.signing_key is not None:
                sg = mav.signing
                sg.secret_key = bytes(cfg.signing_key)
                sg.sign_outgoing = True
                sg.allow_unsigned_callback = None
                sg.link_id = i
                sg.timestamp = self._signing_ts(0)
                ch.signed = True
            for sname, msgid in STREAMS.items():
                st = _Stream(msgid, _hz_to_us(rates.get(sname, 0.0)), self._emitter(msgid))
                ch.streams.append(st)
                ch.by_msgid[msgid] = st
            self._chans.append(ch)
        self._api, self._gcs = self._chans

        # ---- preallocated records (updated in place every tick)
        self.state = VehicleState()
        self._sp = Setpoint()          # what modes other than OFFBOARD fly
        self._of = Setpoint()          # the last valid offboard setpoint (world NED)
        self.setpoint = self._sp       # the one in use
        self.u = [0.0, 0.0, 0.0, 0.0]

        # ---- vehicle status
        self._t_us = 0                 # vehicle clock (HIL time_usec of the last tick)
        self._have_state = False
        self.armed = False
        self.mode = POSCTL
        self.landed_state = ON_GROUND
        self._home: tuple[float, float, float] | None = None   # NED, m
        self._hb_now = False           # send a HEARTBEAT at the end of this tick (mode/arm)
        self._ext_now = False          # EXTENDED_SYS_STATE now (landed state changed)
        self._home_now = False
        # takeoff
        self._tko_x = self._tko_y = self._tko_z = self._tko_yaw = 0.0
        self._tko_ramp_z = 0.0
        self._tko_started = False
        self._tko_ramp_done_us = -1
        # landing / ground detection
        self._land_t0 = 0
        self._touch_since = -1
        self._stall_since = -1
        self._ground_since = -1        # landed after LAND: when (for COM_DISARM_LAND)
        # offboard stream & failsafe
        self._of_last_us = -(1 << 62)
        self._fs_active = False
        self._fs_t0 = 0
        self._reject_text_us: dict[str, int] = {}
        self._bat_warned = 0           # 0 none, 1 low, 2 critical

        # ---- controller, parameters, battery
        self._own: dict[str, float] = {}
        self._user_params: dict[str, float] = {}
        self.warnings: list[str] = []
        self._ctrl_factory = None
        if controller is None:
            from mav.control import make_controller

            self._ctrl_factory = make_controller
            controller = make_controller(self.vehicle, dt=cfg.control_dt_s)
        self._ctrl = controller
        self.battery = Battery(BATTERIES[cfg.vehicle], self.vehicle.u_hover)
        self._build_params()
        self._own["COM_OF_LOSS_T"] = cfg.offboard_loss_s
        self._own["COM_FAIL_ACT_T"] = cfg.failsafe_land_s
        if cfg.param_file:
            self.load_params(cfg.param_file)
        self._apply_own_params()

        self._handlers: dict[int, Callable] = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self._on_heartbeat,
            M.MAVLINK_MSG_ID_COMMAND_LONG: self._on_command_long,
            M.MAVLINK_MSG_ID_COMMAND_INT: self._on_command_int,
            M.MAVLINK_MSG_ID_SET_MODE: self._on_set_mode,
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: self._on_setpoint_msg,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self._on_param_request_list,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self._on_param_request_read,
            M.MAVLINK_MSG_ID_PARAM_SET: self._on_param_set,
            M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: self._on_mission_request_list,
            M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: self._on_mission_clear_all,
            M.MAVLINK_MSG_ID_MISSION_COUNT: self._on_mission_count,
            M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: self._on_request_data_stream,
            M.MAVLINK_MSG_ID_TIMESYNC: self._on_timesync,
            M.MAVLINK_MSG_ID_PING: self._on_ping,
            M.MAVLINK_MSG_ID_COMMAND_ACK: self._ignore,
            M.MAVLINK_MSG_ID_SYSTEM_TIME: self._ignore,
        }

    # ------------------------------------------------------------------ public helpers
    @property
    def mode_name(self) -> str:
        return MODE_NAMES[self.mode]

    @property
    def t(self) -> float:
        """Vehicle clock, s."""
        return self._t_us * 1e-6

    @property
    def home(self) -> tuple[float, float, float] | None:
        return self._home

    def set_airframe(self, vehicle: Airframe) -> None:
        """Use other airframe values (scenario overrides): rebuilds the controller, keeps
        parameters the user set."""
        self.vehicle = vehicle
        if self._ctrl_factory is not None:
            self._ctrl = self._ctrl_factory(vehicle, dt=self.cfg.control_dt_s)
        self.battery = Battery(self.battery.p, vehicle.u_hover)
        own = dict(self._own)
        self._build_params()
        self._own.update(own)
        for name, v in self._user_params.items():
            try:
                self.params.set(name, v)
            except ParamError as exc:
                self.warnings.append(str(exc))
        self._apply_own_params()

    def load_params(self, path: str) -> None:
        """Apply a parameter file; unknown names are noted in `warnings`, bad values raise."""
        unknown = []
        for name, v in read_param_file(path):
            if self.params.index(name) < 0:
                unknown.append(name)
                continue
            try:
                self.params.set(name, v)
            except ParamError as exc:
                raise ValueError(f"{path}: {exc}") from None
            self._user_params[name] = v
        if unknown:
            self.warnings.append(f"{path}: ignored {len(unknown)} unknown parameter(s): "
                                 + ", ".join(unknown[:8]) + (" ..." if len(unknown) > 8 else ""))

    # ------------------------------------------------------------------ the tick
    def poll(self) -> bool:
        """Handle one waiting HIL datagram (see module docstring). False if none was waiting
        or it was not a usable ODOMETRY (then nothing else is touched)."""
        data = self._hil.recv()
        if data is None:
            return False
        st = self.stats
        st["rx_hil"] += 1
        try:
            od = wire.decode_odometry(data)
        except Exception:   # defensive: the decoder is total on bytes, but never crash here
            od = None
        if od is None:
            self._hil_not_odometry(data)
            return False
        (t_us, x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r, frame_id, child) = od
        chk = x + y + z + qw + qx + qy + qz + vx + vy + vz + p + q + r
        if chk - chk != 0.0 or frame_id != _FRAME_LOCAL_NED or (
                child != _FRAME_LOCAL_NED and child != _FRAME_BODY_FRD):
            st["hil_bad_values"] += 1
            return False
        if not self._have_state:
            self._t_us = t_us
        # 1. the offboard and GCS links, at the clock of the previous tick
        self._drain(self._api)
        self._drain(self._gcs)
        # 2. clock and estimator (ground truth from ODOMETRY)
        dt_us = t_us - self._t_us
        self._t_us = t_us
        s = self.state
        s.t = t_us * 1e-6
        s.x, s.y, s.z = x, y, z
        s.qw, s.qx, s.qy, s.qz = qw, qx, qy, qz
        if child == _FRAME_LOCAL_NED:
            s.vx, s.vy, s.vz = vx, vy, vz
        else:   # body FRD velocity -> world NED
            s.vx, s.vy, s.vz = _rotate_body_to_world(qw, qx, qy, qz, vx, vy, vz)
        s.p, s.q, s.r = p, q, r
        if not self._have_state:
            self._have_state = True
            self._set_home()
            self._hold_here()
        # 3. modes, failsafes, ground detection, controller
        self._step_modes(t_us)
        u = self.u
        if self.armed:
            if self._motors_idle():
                idle = self._own["MOT_IDLE_RATIO"] * self.vehicle.u_hover
                u[0] = u[1] = u[2] = u[3] = idle
            else:
                sp = self.setpoint
                sp.armed = True
                self._ctrl.update(s, sp, u)
        else:
            u[0] = u[1] = u[2] = u[3] = 0.0
        if dt_us > 0:
            self.battery.step(dt_us * 1e-6, u[0], u[1], u[2], u[3])
        # 4. telemetry when due, then the HIL answer
        self._publish(t_us)
        self._hil.send(wire.encode_hil_actuator_controls(
            self._hil_mav, t_us, u[0], u[1], u[2], u[3],
            _HIL_MODE_ARMED if self.armed else _HIL_MODE_DISARMED))
        st["ticks"] += 1
        return True

    def _hil_not_odometry(self, data: bytes) -> None:
        """Count a HIL datagram that is not a valid ODOMETRY: another message or garbage."""
        end = wire.frame_end(data, 0)
        if end == len(data):
            try:
                msg = self._hil_mav.decode(bytearray(data))
            except Exception:
                msg = None
            if msg is not None and not isinstance(msg, M.MAVLink_unknown):
                self.stats["hil_ignored"] += 1     # e.g. a HEARTBEAT, HIL_SENSOR (later)
                return
        self.stats["dropped_bad_hil"] += 1

    # ------------------------------------------------------------------ link input
    def _drain(self, ch: _Chan) -> None:
        recv = ch.link.recv
        data = recv()
        if data is None:           # the common case: nothing arrived since the last tick
            return
        st = self.stats
        rx_key = ch.rx_key
        if ch.signed:
            self._sync_signing(ch)
        for n in range(DRAIN_MAX):
            if n:
                data = recv()
                if data is None:
                    return
            st[rx_key] += 1
            try:
                self._handle_datagram(ch, data)
            except Exception:   # a handler bug must not take the vehicle down: count it
                st[ch.bad_key] += 1
                if st["handler_errors"] < 5:
                    traceback.print_exc(file=sys.stderr)
                st["handler_errors"] += 1
        st["drain_deferred"] += 1

    def _handle_datagram(self, ch: _Chan, data: bytes) -> None:
        n = len(data)
        # the 200 Hz case first: a datagram that is one unsigned-link MAVLink 2
        # SET_POSITION_TARGET_LOCAL_NED frame (what the loop below does with it, minus the loop)
        if (not ch.signed and n > 12 and data[0] == wire.MAGIC_V2 and data[7:10] == _SP_ID3
                and wire.frame_end(data, 0) == n):
            f = wire.decode_fast(wire.SET_POSITION_TARGET_LOCAL_NED, data, 0, n)
            if f is None:
                self.stats[ch.bad_key] += 1
            else:
                ch.peer = (data[5], data[6])
                self._on_setpoint(ch, f)
            return
        st = self.stats
        i = 0
        frames = 0
        bad_key = ch.bad_key
        while i < n and frames < FRAMES_MAX:
            end = wire.frame_end(data, i)
            if end < 0:
                # garbage or truncated: count once and resync at the next magic byte
                st[bad_key] += 1
                j = i + 1
                while j < n and data[j] != wire.MAGIC_V2 and data[j] != wire.MAGIC_V1:
                    j += 1
                i = j
                continue
            frames += 1
            msgid = wire.msgid_of(data, i)
            if (msgid == M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED and not ch.signed
                    and data[i] == wire.MAGIC_V2):
                f = wire.decode_fast(wire.SET_POSITION_TARGET_LOCAL_NED, data, i, end)
                if f is None:
                    st[bad_key] += 1
                else:
                    self._peer(ch, data, i)
                    self._on_setpoint(ch, f)
                i = end
                continue
            frame = bytearray(data[i:end])
            i = end
            try:
                msg = ch.mav.decode(frame)
            except Exception as exc:
                if "signature" in str(exc):
                    if frame[0] == wire.MAGIC_V2 and frame[2] & wire.IFLAG_SIGNED:
                        st["badsig_rejected"] += 1
                    else:
                        st["unsigned_rejected"] += 1
                else:
                    st[bad_key] += 1
                continue
            if isinstance(msg, M.MAVLink_unknown):
                st["unknown_msgs"] += 1
                continue
            h = self._handlers.get(msg.get_msgId())
            if h is None:
                st["unhandled_msgs"] += 1
                continue
            ch.peer = (msg.get_srcSystem(), msg.get_srcComponent())
            h(ch, msg)
        if i < n:
            st[bad_key] += 1      # more frames than FRAMES_MAX: the rest is dropped

    @staticmethod
    def _peer(ch: _Chan, data: bytes, i: int) -> None:
        _, sysid, compid = wire.header_of(data, i)
        ch.peer = (sysid, compid)

    def _for_us(self, target_system: int, target_component: int | None = None,
                allow_broadcast: bool = True) -> bool:
        ok = target_system == self.cfg.sysid or (allow_broadcast and target_system == 0)
        if ok and target_component is not None:
            ok = target_component in (0, self.cfg.compid)
        if not ok:
            self.stats["not_for_us"] += 1
        return ok

    def _ignore(self, ch: _Chan, msg) -> None:
        pass

    def _on_heartbeat(self, ch: _Chan, msg) -> None:
        pass   # the peer is noted in _handle_datagram; links do not time out (lockstep)

    # ------------------------------------------------------------------ offboard setpoints
    def _on_setpoint_msg(self, ch: _Chan, msg) -> None:
        self._on_setpoint(ch, (msg.time_boot_ms, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz,
                               msg.afx, msg.afy, msg.afz, msg.yaw, msg.yaw_rate, msg.type_mask,
                               msg.target_system, msg.target_component, msg.coordinate_frame))

    def _on_setpoint(self, ch: _Chan, f: tuple) -> None:
        """SET_POSITION_TARGET_LOCAL_NED in wire order (see wire.py)."""
        (_, x, y, z, vx, vy, vz, _ax, _ay, _az, yaw, yaw_rate, mask, tsys, tcomp, frame) = f
        if tsys != self.cfg.sysid or tcomp not in (0, self.cfg.compid):
            return self._reject_sp("target", f"setpoint for system {tsys}/{tcomp} rejected")
        if frame == _FRAME_BODY_NED:
            mask |= IGN_X | IGN_Y | IGN_Z          # PX4: position is ignored in BODY_NED
        elif frame != _FRAME_LOCAL_NED:
            return self._reject_sp("frame", f"setpoint frame {frame} unsupported (1 or 8)")
        pxy = mask & (IGN_X | IGN_Y)
        vxy = mask & (IGN_VX | IGN_VY)
        use_pxy, use_vxy = pxy == 0, vxy == 0
        use_pz, use_vz = not mask & IGN_Z, not mask & IGN_VZ
        use_yaw, use_rate = not mask & IGN_YAW, not mask & IGN_YAW_RATE
        if (pxy not in (0, IGN_X | IGN_Y) or vxy not in (0, IGN_VX | IGN_VY)
                or not (use_pxy or use_vxy) or not (use_pz or use_vz)):
            return self._reject_sp("mask", f"setpoint type_mask 0x{mask:04X} unsupported")
        if use_pxy and not (abs(x) <= SP_MAX_POS_M and abs(y) <= SP_MAX_POS_M) or (
                use_pz and not abs(z) <= SP_MAX_POS_M):
            return self._reject_sp("range", "setpoint position not finite or out of range")
        if use_vxy and not (abs(vx) <= SP_MAX_VEL_MPS and abs(vy) <= SP_MAX_VEL_MPS) or (
                use_vz and not abs(vz) <= SP_MAX_VEL_MPS):
            return self._reject_sp("range", "setpoint velocity not finite or out of range")
        if use_yaw and not abs(yaw) <= SP_MAX_YAW_RAD or (
                use_rate and not abs(yaw_rate) <= SP_MAX_YAW_RATE):
            return self._reject_sp("range", "setpoint yaw not finite or out of range")
        if frame == _FRAME_BODY_NED and use_vxy:
            yaw_now = self._heading()
            c, s = math.cos(yaw_now), math.sin(yaw_now)
            vx, vy = c * vx - s * vy, s * vx + c * vy
        of = self._of
        of.x = x if use_pxy else NAN
        of.y = y if use_pxy else NAN
        of.z = z if use_pz else NAN
        of.vx = vx if use_vxy else NAN
        of.vy = vy if use_vxy else NAN
        of.vz = vz if use_vz else NAN
        of.yaw = _wrap_pi(yaw) if use_yaw else NAN
        of.yaw_rate = yaw_rate if use_rate else NAN
        self._of_last_us = self._t_us
        self.stats["setpoints"] += 1

    def _reject_sp(self, kind: str, text: str) -> None:
        st = self.stats
        st["rejected_setpoints"] += 1
        key = "sp_reject_" + kind
        st[key] = st.get(key, 0) + 1
        self._warn_rate_limited(kind, text)

    def _warn_rate_limited(self, kind: str, text: str) -> None:
        last = self._reject_text_us.get(kind)
        if last is None or self._t_us - last >= REJECT_TEXT_EVERY_US:
            self._reject_text_us[kind] = self._t_us
            self.statustext(text, M.MAV_SEVERITY_WARNING)

    def _offboard_stream_ok(self) -> bool:
        # PX4 (commander, HealthAndArmingChecks/checks/offboardCheck.cpp): offboard is
        # available while the newest setpoint is younger than COM_OF_LOSS_T; no minimum
        # stream duration (MAVSDK's Offboard.start() sends one setpoint, then the mode).
        return self._t_us - self._of_last_us <= self._of_loss_us

    # ------------------------------------------------------------------ modes
    def _set_mode(self, mode: int) -> None:
        """Enter `mode` (already checked allowed). Entry actions set the mode's setpoint."""
        prev = self.mode
        self.mode = mode
        self._fs_active = False
        if mode != prev:
            self._hb_now = True
        sp = self._sp
        sp.takeoff_boost = False
        if mode in (POSCTL, LOITER):
            if prev != mode:
                self._hold_here()
            if self.landed_state in (TAKING_OFF, LANDING):
                self._set_landed(IN_AIR if self._agl() > AIRBORNE_AGL_M else ON_GROUND)
        elif mode == LAND:
            self._land_t0 = self._t_us
            self._touch_since = self._stall_since = -1
            sp.clear()
            sp.x, sp.y = self.state.x, self.state.y
            sp.vz = self._own["MPC_LAND_SPEED"]
            sp.yaw = self._heading()
            if self.landed_state != ON_GROUND:
                self._set_landed(LANDING)
            elif self.armed and self._ground_since < 0:
                self._ground_since = self._t_us     # already down: disarm after the delay
        elif mode == OFFBOARD:
            if self.armed and self.landed_state == ON_GROUND:
                self._ctrl.reset()
            if self.landed_state in (TAKING_OFF, LANDING):
                self._set_landed(IN_AIR)
        elif mode == TAKEOFF:
            self._tko_started = False
            self._tko_ramp_done_us = -1
        self.setpoint = self._of if mode == OFFBOARD else sp

    def _heading(self) -> float:
        """Heading (rad) of the current state; computed on demand, not every tick."""
        s = self.state
        return wire.yaw_from_quat(s.qw, s.qx, s.qy, s.qz)

    def _hold_here(self) -> None:
        sp = self._sp
        s = self.state
        sp.clear()
        sp.x, sp.y, sp.z, sp.yaw = s.x, s.y, s.z, self._heading()

    def _set_landed(self, ls: int) -> None:
        if ls != self.landed_state:
            self.landed_state = ls
            self._ext_now = True

    def _agl(self) -> float:
        home = self._home
        return home[2] - self.state.z if home is not None else 0.0

    def _motors_idle(self) -> bool:
        """Armed but on the ground in a mode that does not take off: idle speed."""
        return self.landed_state == ON_GROUND and self.mode in (POSCTL, LOITER, LAND)

    def _set_home(self) -> None:
        s = self.state
        self._home = (s.x, s.y, s.z)
        self._home_now = True

    def _step_modes(self, t: int) -> None:
        mode = self.mode
        own = self._own
        if mode == OFFBOARD:
            if t - self._of_last_us > self._of_loss_us:
                self.statustext("Failsafe: offboard setpoints lost, holding position",
                                M.MAV_SEVERITY_CRITICAL)
                self._set_mode(LOITER)
                self._fs_active, self._fs_t0 = True, t
                mode = LOITER
        elif mode == TAKEOFF:
            if self.armed:
                self._step_takeoff(t)
        elif mode == LAND:
            if self.armed:
                self._step_land(t)
        if self._fs_active and mode == LOITER and t - self._fs_t0 > self._fail_act_us:
            self._fs_active = False
            if self.landed_state != ON_GROUND:
                self.statustext("Failsafe: offboard not back, landing", M.MAV_SEVERITY_CRITICAL)
                self._set_mode(LAND)
        # airborne detection for modes that run the controller from the ground
        if (self.armed and self.landed_state == ON_GROUND and self.mode in (OFFBOARD, TAKEOFF)
                and self._agl() > AIRBORNE_AGL_M):
            self._set_landed(TAKING_OFF if self.mode == TAKEOFF else IN_AIR)
        # auto-disarm after a landing
        if self._ground_since >= 0 and self.armed:
            if t - self._ground_since >= int(own["COM_DISARM_LAND"] * 1e6):
                self._ground_since = -1
                self._disarm("Landing detected, disarmed")
        # battery warnings
        if self.battery.consumed_mah > self._bat_warn_mah:
            self._battery_warning()

    def _step_takeoff(self, t: int) -> None:
        sp = self._sp
        s = self.state
        if not self._tko_started:
            self._tko_started = True
            self._tko_ramp_z = min(s.z, self._home[2]) if self._home else s.z
            sp.clear()
            sp.x, sp.y, sp.yaw = self._tko_x, self._tko_y, self._tko_yaw
            if self.landed_state == ON_GROUND:
                self._ctrl.reset()
                self._set_landed(TAKING_OFF)
        # the reference climbs at MPC_TKO_SPEED and eases into the target (first order,
        # TKO_EASE_S), its velocity fed forward: no windup, no overshoot
        zt = self._tko_z
        rz = self._tko_ramp_z
        rem = zt - rz
        if rem != 0.0:
            speed = self._own["MPC_TKO_SPEED"]
            v = abs(rem) / TKO_EASE_S
            if v > speed:
                v = speed
            dz = v * self.cfg.control_dt_s
            if abs(rem) <= max(dz, TKO_SNAP_M):
                rz, v = zt, 0.0
            else:
                rz += dz if rem > 0.0 else -dz
            sp.vz = v if rem > 0.0 else -v
        else:
            sp.vz = NAN
        self._tko_ramp_z = rz
        sp.z = rz
        # Setpoint.takeoff_boost (the Mambo template's step take-off) stays off: with a ramped
        # reference and its velocity fed forward the boost only adds overshoot (measured:
        # 2.5 cm low and slow to recover with it, 2 cm over and settled in 1.5 s without).
        if rz == zt:
            if self._tko_ramp_done_us < 0:
                self._tko_ramp_done_us = t
            if abs(s.z - zt) < TKO_ACCEPT_M or t - self._tko_ramp_done_us > TKO_SETTLE_US:
                self._set_landed(IN_AIR)
                self._set_mode(LOITER)
                sp.x, sp.y, sp.z, sp.yaw = self._tko_x, self._tko_y, zt, self._tko_yaw
                self.statustext("Takeoff complete", M.MAV_SEVERITY_INFO)

    def _step_land(self, t: int) -> None:
        s = self.state
        if self.landed_state == ON_GROUND:
            return
        slow = abs(s.vz) < TOUCH_VZ_MPS
        if slow and self._agl() < TOUCH_AGL_M:
            if self._touch_since < 0:
                self._touch_since = t
        else:
            self._touch_since = -1
        if slow and t - self._land_t0 > LAND_STALL_AFTER_US:
            if self._stall_since < 0:
                self._stall_since = t
        else:
            self._stall_since = -1
        if (self._touch_since >= 0 and t - self._touch_since >= TOUCH_TRIG_US) or (
                self._stall_since >= 0 and t - self._stall_since >= TOUCH_STALL_US):
            self._set_landed(ON_GROUND)
            self._ground_since = t
            self.statustext("Touchdown", M.MAV_SEVERITY_INFO)

    # ------------------------------------------------------------------ arming
    def _arm(self) -> int:
        if self.armed:
            return M.MAV_RESULT_ACCEPTED
        if not self._have_state:
            self.statustext("Arming denied: no position estimate yet", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.mode == LAND:
            self.statustext("Arming denied: vehicle is in AUTO.LAND", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_DENIED
        if self.mode == OFFBOARD and not self._offboard_stream_ok():
            self.statustext("Arming denied: no offboard setpoints", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.landed_state == ON_GROUND:
            self._set_home()
            if self.mode == TAKEOFF and not self._tko_started:
                self._tko_x, self._tko_y = self.state.x, self.state.y
        self.armed = True
        self._ground_since = -1
        self._ctrl.reset()
        self._hb_now = True
        self.statustext("Armed", M.MAV_SEVERITY_INFO)
        return M.MAV_RESULT_ACCEPTED

    def _disarm(self, text: str = "Disarmed") -> None:
        if self.armed:
            self.armed = False
            self._hb_now = True
            self._ground_since = -1
            self.statustext(text, M.MAV_SEVERITY_INFO)

    # ------------------------------------------------------------------ commands
    def _on_command_long(self, ch: _Chan, msg) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        self._command(ch, msg.command, msg.param1, msg.param2, msg.param3, msg.param4,
                      msg.param5, msg.param6, msg.param7, None)

    def _on_command_int(self, ch: _Chan, msg) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        self._command(ch, msg.command, msg.param1, msg.param2, msg.param3, msg.param4,
                      msg.x, msg.y, msg.z, msg.frame)

    def _command(self, ch: _Chan, cmd: int, p1: float, p2: float, p3: float, p4: float,
                 p5: float, p6: float, p7: float, frame: int | None) -> None:
        """One COMMAND_LONG (frame None) or COMMAND_INT (p5, p6 = x, y ints; p7 = z)."""
        self.stats["commands"] += 1
        after = None
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            if p1 == 1.0:
                res = self._arm()
            elif p1 == 0.0:
                if self.armed and self.landed_state != ON_GROUND and p2 != FORCE_DISARM_MAGIC:
                    self.statustext("Disarming denied: not landed", M.MAV_SEVERITY_CRITICAL)
                    res = M.MAV_RESULT_DENIED
                else:
                    self._disarm("Disarmed (forced)" if p2 == FORCE_DISARM_MAGIC else "Disarmed")
                    res = M.MAV_RESULT_ACCEPTED
            else:
                res = M.MAV_RESULT_DENIED
        elif cmd == M.MAV_CMD_NAV_TAKEOFF:
            res = self._cmd_takeoff(p4, p7, frame)
        elif cmd == M.MAV_CMD_NAV_LAND:
            self._set_mode(LAND)
            res = M.MAV_RESULT_ACCEPTED
        elif cmd == M.MAV_CMD_DO_SET_MODE:
            res = self._request_mode(p1, p2, p3)
        elif cmd == M.MAV_CMD_REQUEST_MESSAGE:
            msgid = int(p1) if math.isfinite(p1) else -1
            res, after = self._request_message(msgid)
        elif cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            res, after = M.MAV_RESULT_ACCEPTED, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        elif cmd == M.MAV_CMD_GET_HOME_POSITION:
            res, after = self._request_message(M.MAVLINK_MSG_ID_HOME_POSITION)
        elif cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            res = self._set_interval(ch, p1, p2)
        elif cmd == M.MAV_CMD_GET_MESSAGE_INTERVAL:
            res = self._get_interval(ch, p1)
        else:
            res = M.MAV_RESULT_UNSUPPORTED
            self.stats["commands_unsupported"] += 1
        peer = ch.peer or (0, 0)
        ch.send(wire.send_msg(ch.mav, M.MAVLink_command_ack_message(
            cmd, res, 0, 0, peer[0], peer[1])))
        if after is not None:
            self._emitter(after)(ch)

    def _cmd_takeoff(self, yaw_deg: float, alt: float, frame: int | None) -> int:
        if not self._have_state or self._home is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if not self.armed and self.landed_state == ON_GROUND:
            self._set_home()
        home_n, home_e, home_d = self._home
        home_amsl = self.cfg.origin_alt_m - home_d
        default = self._own["MIS_TAKEOFF_ALT"]
        if isinstance(alt, float) and math.isnan(alt):
            rel = default
        elif frame is None or frame in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT):
            rel = alt - home_amsl            # PX4: param7 is AMSL
        elif frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            rel = alt
        else:
            self.statustext(f"Takeoff denied: frame {frame} unsupported", M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        if not (math.isfinite(rel) and 0.1 <= rel <= 100.0):
            self.statustext(f"Takeoff denied: altitude {rel:.2f} m above home out of 0.1..100",
                            M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        s = self.state
        self._tko_x, self._tko_y = s.x, s.y
        self._tko_z = home_d - rel
        self._tko_yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) else self._heading()
        self._set_mode(TAKEOFF)
        return M.MAV_RESULT_ACCEPTED

    def _request_mode(self, base_mode: float, main: float, sub: float) -> int:
        if not (math.isfinite(base_mode) and int(base_mode) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            self.statustext("Mode change denied: base_mode needs CUSTOM_MODE_ENABLED",
                            M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        key = (int(main) if math.isfinite(main) else -1, int(sub) if math.isfinite(sub) else -1)
        if key[0] != PX4_MAIN_AUTO and key[1] == -1:
            key = (key[0], 0)
        mode = _MODE_BY_PX4.get(key)
        if mode is None:
            self.statustext(f"Mode change denied: mode {key[0]}/{key[1]} unsupported",
                            M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_DENIED
        return self._try_mode(mode)

    def _try_mode(self, mode: int) -> int:
        if mode == self.mode:
            return M.MAV_RESULT_ACCEPTED
        if mode == OFFBOARD and not self._offboard_stream_ok():
            self.statustext("Switching to OFFBOARD denied: no setpoint stream",
                            M.MAV_SEVERITY_WARNING)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == TAKEOFF:
            if not self._have_state:
                return M.MAV_RESULT_TEMPORARILY_REJECTED
            return self._cmd_takeoff(NAN, NAN, None)
        if not self._have_state:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        self._set_mode(mode)
        return M.MAV_RESULT_ACCEPTED

    def _on_set_mode(self, ch: _Chan, msg) -> None:
        if not self._for_us(msg.target_system, None, allow_broadcast=False):
            return
        cm = msg.custom_mode
        self._request_mode(float(msg.base_mode), float((cm >> 16) & 0xFF),
                           float((cm >> 24) & 0xFF))

    def _set_interval(self, ch: _Chan, p1: float, p2: float) -> int:
        if not (math.isfinite(p1) and math.isfinite(p2)):
            return M.MAV_RESULT_DENIED
        st = ch.by_msgid.get(int(p1))
        if st is None:
            return M.MAV_RESULT_UNSUPPORTED
        iv = int(p2)
        if iv == 0:
            st.interval_us = st.default_us
        elif iv == -1:
            st.interval_us = -1
        elif iv > 0:
            st.interval_us = iv
        else:
            return M.MAV_RESULT_DENIED
        st.next_us = self._t_us
        ch.recompute_due()
        return M.MAV_RESULT_ACCEPTED

    def _get_interval(self, ch: _Chan, p1: float) -> int:
        """MESSAGE_INTERVAL for message id p1: its interval (us), -1 if off, 0 if not here."""
        if not (math.isfinite(p1) and 0 <= p1 <= 65535):
            return M.MAV_RESULT_DENIED
        msgid = int(p1)
        st = ch.by_msgid.get(msgid)
        iv = (min(st.interval_us, (1 << 31) - 1) if st.interval_us > 0 else -1) if st else 0
        ch.send(wire.send_msg(ch.mav, M.MAVLink_message_interval_message(msgid, iv)))
        return M.MAV_RESULT_ACCEPTED

    def _on_request_data_stream(self, ch: _Chan, msg) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        names = _DATA_STREAM_GROUPS.get(msg.req_stream_id)
        if names is None:
            return
        for n in names:
            st = ch.by_msgid[STREAMS[n]]
            if msg.start_stop and msg.req_message_rate > 0:
                st.interval_us = _hz_to_us(float(msg.req_message_rate))
                st.next_us = self._t_us
            elif not msg.start_stop:
                st.interval_us = -1
        ch.recompute_due()

    # ------------------------------------------------------------------ params
    def _build_params(self) -> None:
        t = ParamTable()
        ctrl = self._ctrl
        for spec in ctrl.param_table():
            def _get(n=spec.name) -> float:
                return self._ctrl.get_param(n)

            def _set(v: float, n=spec.name) -> None:
                self._ctrl.set_param(n, v)

            t.add(spec, _get, _set)
        own = self._own
        own.clear()
        t.add_store(ONBOARD_PARAMS, own)
        self.params = t

    def _apply_own_params(self) -> None:
        own = self._own
        self._of_loss_us = int(round(own["COM_OF_LOSS_T"] * 1e6))
        self._fail_act_us = int(round(own["COM_FAIL_ACT_T"] * 1e6))
        self.battery.configure(own["BAT1_CAPACITY"], own["BAT1_R_INTERNAL"])
        cap = self.battery.capacity_mah
        thr = own["BAT_LOW_THR"] if self._bat_warned == 0 else own["BAT_CRIT_THR"]
        self._bat_warn_mah = (1.0 - thr) * cap if self._bat_warned < 2 else math.inf

    def _battery_warning(self) -> None:
        self._bat_warned += 1
        low = self._bat_warned == 1
        self.statustext(f"Battery {'low' if low else 'critical'}: "
                        f"{100.0 * self.battery.remaining:.0f}% remaining",
                        M.MAV_SEVERITY_WARNING if low else M.MAV_SEVERITY_CRITICAL)
        self._apply_own_params()

    def _param_value(self, ch: _Chan, index: int) -> None:
        t = self.params
        name = t.name_at(index)
        ch.send(wire.send_msg(ch.mav, M.MAVLink_param_value_message(
            name.encode(), f32(t.get(name)), M.MAV_PARAM_TYPE_REAL32, len(t), index)))

    def _on_param_request_list(self, ch: _Chan, msg) -> None:
        if self._for_us(msg.target_system, msg.target_component):
            ch.param_queue = list(range(len(self.params)))

    def _on_param_request_read(self, ch: _Chan, msg) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        idx = msg.param_index
        if idx < 0:
            idx = self.params.index(_text(msg.param_id))
        if 0 <= idx < len(self.params):
            self._param_value(ch, idx)
        else:
            self._warn_rate_limited("param", f"Unknown parameter {_text(msg.param_id)!r}")

    def _on_param_set(self, ch: _Chan, msg) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        name = _text(msg.param_id)
        idx = self.params.index(name)
        if idx < 0:
            self.stats["param_rejected"] += 1
            self._warn_rate_limited("param", f"Unknown parameter {name!r}")
            return
        try:
            self.params.set(name, msg.param_value)
            self._user_params[name] = float(msg.param_value)
            self.stats["param_sets"] += 1
            if name in self._own:
                self._apply_own_params()
        except ParamError as exc:
            self.stats["param_rejected"] += 1
            self.statustext(f"Param rejected: {exc}", M.MAV_SEVERITY_WARNING)
        for c in self._chans:          # echo the value now in effect on every link
            self._param_value(c, idx)

    # ------------------------------------------------------------------ missions & misc
    def _on_mission_request_list(self, ch: _Chan, msg) -> None:
        if self._for_us(msg.target_system, msg.target_component):
            peer = ch.peer or (0, 0)
            ch.send(wire.send_msg(ch.mav, M.MAVLink_mission_count_message(
                peer[0], peer[1], 0, msg.mission_type)))

    def _on_mission_clear_all(self, ch: _Chan, msg) -> None:
        if self._for_us(msg.target_system, msg.target_component):
            peer = ch.peer or (0, 0)
            ch.send(wire.send_msg(ch.mav, M.MAVLink_mission_ack_message(
                peer[0], peer[1], M.MAV_MISSION_ACCEPTED, msg.mission_type)))

    def _on_mission_count(self, ch: _Chan, msg) -> None:
        if self._for_us(msg.target_system, msg.target_component):
            peer = ch.peer or (0, 0)
            res = M.MAV_MISSION_ACCEPTED if msg.count == 0 else M.MAV_MISSION_UNSUPPORTED
            ch.send(wire.send_msg(ch.mav, M.MAVLink_mission_ack_message(
                peer[0], peer[1], res, msg.mission_type)))

    def _on_timesync(self, ch: _Chan, msg) -> None:
        if msg.tc1 == 0:
            ch.send(wire.send_msg(ch.mav, M.MAVLink_timesync_message(self._t_us * 1000,
                                                                     msg.ts1)))

    def _on_ping(self, ch: _Chan, msg) -> None:
        if msg.target_system == 0 and msg.target_component == 0:
            peer = ch.peer or (0, 0)
            ch.send(wire.send_msg(ch.mav, M.MAVLink_ping_message(
                msg.time_usec, msg.seq, peer[0], peer[1])))

    def statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """Send a STATUSTEXT (<= 50 characters) on the api and gcs links."""
        raw = text.encode("ascii", errors="replace")[:50]
        for ch in self._chans:
            if ch.signed:
                self._sync_signing(ch)
            ch.send(wire.send_msg(ch.mav, M.MAVLink_statustext_message(severity, raw, 0, 0)))

    # ------------------------------------------------------------------ telemetry
    def _sync_signing(self, ch: _Chan) -> None:
        sg = ch.mav.signing
        ts = self._signing_ts(self._t_us)
        if ts > sg.timestamp:
            sg.timestamp = ts

    def _signing_ts(self, t_us: int) -> int:
        """Signing timestamp (10 us units since 2015-01-01) at vehicle time t_us."""
        base = int(round((self.cfg.signing_epoch_unix_s - _SIGNING_EPOCH_2015) * 1e5))
        return base + t_us // 10

    def _publish(self, t: int) -> None:
        api, gcs = self._api, self._gcs
        if (t < api.next_due and t < gcs.next_due and not api.param_queue
                and not gcs.param_queue and not (self._hb_now or self._ext_now or self._home_now)):
            return
        for ch in self._chans:
            if ch.signed:
                self._sync_signing(ch)
            if self._hb_now:
                self._emit_heartbeat(ch)
            if self._ext_now:
                self._emit_extended_sys_state(ch)
            if self._home_now:
                self._emit_home_position(ch)
            if t >= ch.next_due:
                due = 1 << 62
                for s in ch.streams:
                    iv = s.interval_us
                    if iv > 0:
                        nxt = s.next_us
                        if t >= nxt:
                            s.emit(ch)
                            nxt += iv
                            if nxt <= t:
                                nxt = t + iv
                            s.next_us = nxt
                        if nxt < due:
                            due = nxt
                ch.next_due = due
            q = ch.param_queue
            if q:
                for idx in q[:PARAM_BURST]:
                    if idx < len(self.params):
                        self._param_value(ch, idx)
                del q[:PARAM_BURST]
        self._hb_now = self._ext_now = self._home_now = False

    def _emitter(self, msgid: int) -> Callable[[_Chan], None]:
        return {
            M.MAVLINK_MSG_ID_HEARTBEAT: self._emit_heartbeat,
            M.MAVLINK_MSG_ID_SYS_STATUS: self._emit_sys_status,
            M.MAVLINK_MSG_ID_ATTITUDE: self._emit_attitude,
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._emit_local_position,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._emit_global_position,
            M.MAVLINK_MSG_ID_HOME_POSITION: self._emit_home_position,
            M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._emit_extended_sys_state,
            M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: self._emit_position_target,
            M.MAVLINK_MSG_ID_BATTERY_STATUS: self._emit_battery_status,
            M.MAVLINK_MSG_ID_VFR_HUD: self._emit_vfr_hud,
            M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._emit_autopilot_version,
        }.get(msgid, self._emit_nothing)

    def _request_message(self, msgid: int) -> tuple[int, int | None]:
        if self._emitter(msgid) == self._emit_nothing:
            self.stats["commands_unsupported"] += 1
            return M.MAV_RESULT_UNSUPPORTED, None
        if msgid == M.MAVLINK_MSG_ID_HOME_POSITION and self._home is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED, None
        return M.MAV_RESULT_ACCEPTED, msgid

    def _emit_nothing(self, ch: _Chan) -> None:
        pass

    def _time_boot_ms(self) -> int:
        return (self._t_us // 1000) & 0xFFFFFFFF

    def _emit_heartbeat(self, ch: _Chan) -> None:
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        status = M.MAV_STATE_ACTIVE if self.armed else M.MAV_STATE_STANDBY
        ch.send(wire.pack(ch.mav, wire.HEARTBEAT, px4_custom_mode(self.mode), MAV_TYPE,
                          MAV_AUTOPILOT, base, status, 3))

    def _emit_sys_status(self, ch: _Chan) -> None:
        b = self.battery
        # wire order: sensors present/enabled/health, load, voltage mV, current cA, drop rate,
        # errors comm, errors 1..4, remaining %, extended present/enabled/health
        ch.send(wire.pack(ch.mav, wire.SYS_STATUS, _SENSORS, _SENSORS, _SENSORS, 0,
                          wire.clamp_int(b.voltage * 1000.0, 0, 65534),
                          wire.clamp_int(b.current * 100.0, 0, 32767), 0, 0, 0, 0, 0, 0,
                          wire.clamp_int(100.0 * b.remaining, 0, 100), 0, 0, 0))

    def _emit_attitude(self, ch: _Chan) -> None:
        s = self.state
        roll, pitch, yaw = wire.euler_from_quat(s.qw, s.qx, s.qy, s.qz)
        ch.send(wire.encode_attitude(ch.mav, self._time_boot_ms(), roll, pitch, yaw,
                                     s.p, s.q, s.r))

    def _emit_local_position(self, ch: _Chan) -> None:
        s = self.state
        ch.send(wire.encode_local_position_ned(ch.mav, self._time_boot_ms(), s.x, s.y, s.z,
                                               s.vx, s.vy, s.vz))

    def _emit_global_position(self, ch: _Chan) -> None:
        s = self.state
        lat, lon, alt = self.geo.to_int(s.x, s.y, s.z)
        rel = wire.clamp_int(self._agl() * 1000.0, -(1 << 31), (1 << 31) - 1)
        hdg = wire.clamp_int(math.degrees(self._heading()) % 360.0 * 100.0, 0, 35999)
        ci = wire.clamp_int
        ch.send(wire.pack(ch.mav, wire.GLOBAL_POSITION_INT, self._time_boot_ms(), lat, lon, alt,
                          rel, ci(s.vx * 100.0, -32768, 32767), ci(s.vy * 100.0, -32768, 32767),
                          ci(s.vz * 100.0, -32768, 32767), hdg))

    def _emit_home_position(self, ch: _Chan) -> None:
        if self._home is None:
            return
        hx, hy, hz = self._home
        lat, lon, alt = self.geo.to_int(hx, hy, hz)
        ch.send(wire.send_msg(ch.mav, M.MAVLink_home_position_message(
            lat, lon, alt, hx, hy, hz, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, self._t_us)))

    def _emit_extended_sys_state(self, ch: _Chan) -> None:
        ch.send(wire.pack(ch.mav, wire.EXTENDED_SYS_STATE, M.MAV_VTOL_STATE_UNDEFINED,
                          self.landed_state))

    def _emit_position_target(self, ch: _Chan) -> None:
        sp = self.setpoint
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

    def _emit_battery_status(self, ch: _Chan) -> None:
        b = self.battery
        cells = [wire.clamp_int(b.voltage * 1000.0, 0, 65534)] + [65535] * 9
        ch.send(wire.send_msg(ch.mav, M.MAVLink_battery_status_message(
            0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 32767, cells,
            wire.clamp_int(b.current * 100.0, 0, 32767),
            wire.clamp_int(b.consumed_mah, 0, (1 << 31) - 1),
            wire.clamp_int(b.energy_j / 100.0, 0, (1 << 31) - 1),
            wire.clamp_int(100.0 * b.remaining, 0, 100),
            wire.clamp_int(b.time_remaining_s(), 0, (1 << 31) - 1),
            M.MAV_BATTERY_CHARGE_STATE_OK if self._bat_warned == 0 else (
                M.MAV_BATTERY_CHARGE_STATE_LOW if self._bat_warned == 1
                else M.MAV_BATTERY_CHARGE_STATE_CRITICAL),
            [0, 0, 0, 0], 0, 0)))

    def _emit_vfr_hud(self, ch: _Chan) -> None:
        s = self.state
        gs = math.hypot(s.vx, s.vy)
        u = self.u
        thr = wire.clamp_int(25.0 * (u[0] + u[1] + u[2] + u[3]), 0, 100)
        ch.send(wire.pack(ch.mav, wire.VFR_HUD, gs, gs, self.cfg.origin_alt_m - s.z, -s.vz,
                          wire.clamp_int(math.degrees(self._heading()) % 360.0, 0, 359), thr))

    def _emit_autopilot_version(self, ch: _Chan) -> None:
        ch.send(wire.send_msg(ch.mav, M.MAVLink_autopilot_version_message(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, list(b"cosim\x00\x00\x00"), [0] * 8,
            [0] * 8, 0, 0, self.cfg.sysid, [0] * 18)))


def _rotate_body_to_world(qw: float, qx: float, qy: float, qz: float, bx: float, by: float,
                          bz: float) -> tuple[float, float, float]:
    """v_W = R_WB(q) v_B for the body->world quaternion q."""
    tx = 2.0 * (qy * bz - qz * by)
    ty = 2.0 * (qz * bx - qx * bz)
    tz = 2.0 * (qx * by - qy * bx)
    return (bx + qw * tx + qy * tz - qz * ty,
            by + qw * ty + qz * tx - qx * tz,
            bz + qw * tz + qx * ty - qy * tx)


# ====================================================================== the SIL process
def _hostport(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    try:
        p = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port of {text!r} is not a number") from None
    if not 0 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port {p} out of 0..65535")
    return host, p


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mav.onboard",
        description="The onboard flight stack as a process: a PX4-style MAVLink vehicle in "
                    "HIL lockstep with a simulator (ODOMETRY in, HIL_ACTUATOR_CONTROLS out).",
        epilog="examples:\n"
               "  python -m mav.onboard --vehicle mambo\n"
               "  python -m mav.onboard --hil-bind 127.0.0.1:0 --api-bind 127.0.0.1:0 "
               "--gcs-bind 127.0.0.1:0   # prints 'PORTS hil=.. api=.. gcs=..' first\n"
               "  python -m mav.onboard --params my.params --signing-key $(openssl rand -hex 32)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--vehicle", default="mambo", choices=("mambo", "bebop2"))
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--hil-bind", type=_hostport, default=("127.0.0.1", 4560), metavar="HOST:PORT",
                   help="simulator link; answers whoever sent the ODOMETRY (default "
                        "127.0.0.1:4560; port 0 = any free port)")
    p.add_argument("--api-bind", type=_hostport, default=("127.0.0.1", 0), metavar="HOST:PORT",
                   help="offboard API link local address (default 127.0.0.1:0)")
    p.add_argument("--api-remote", type=_hostport, default=("127.0.0.1", 14540),
                   metavar="HOST:PORT", help="where the API link sends (default 127.0.0.1:14540)")
    p.add_argument("--gcs-bind", type=_hostport, default=("127.0.0.1", 0), metavar="HOST:PORT",
                   help="ground station link local address (default 127.0.0.1:0)")
    p.add_argument("--gcs-remote", type=_hostport, default=("127.0.0.1", 14550),
                   metavar="HOST:PORT", help="where the GCS link sends (default 127.0.0.1:14550)")
    p.add_argument("--params", metavar="FILE", help="parameter file: NAME VALUE per line "
                   "(QGroundControl .params accepted)")
    p.add_argument("--signing-key", metavar="HEX", help="MAVLink 2 signing key, 64 hex digits: "
                   "sign the api/gcs links and reject unsigned messages on them")
    p.add_argument("--signing-epoch", default="2024", metavar="2024|now",
                   help="signing timestamps start at 2024-01-01 + vehicle time (deterministic, "
                        "default) or at the wall clock 'now' (for GCSs that check freshness)")
    p.add_argument("--origin", metavar="LAT,LON,ALT",
                   help="geodetic origin of the local frame, deg,deg,m AMSL "
                        "(default 42.299886,-71.350447,71.3232)")
    p.add_argument("--vehicle-param", action="append", default=[], metavar="FIELD=VALUE",
                   help="override an airframe value of the preset (a mav.airframe."
                        "Airframe field, SI units), e.g. mass=0.07; repeatable")
    p.add_argument("--hil-timeout", type=float, default=10.0, metavar="SECONDS",
                   help="exit (code 0) when the simulator is silent this long, wall clock "
                        "(default 10)")
    return p


def _vehicle_with_overrides(parser, name: str, items: list[str]) -> Airframe:
    """The preset with FIELD=VALUE overrides; parser.error (exit 2) names a bad one."""
    vp = get_airframe(name)
    fields = set(vp.values())
    kw = {}
    for it in items:
        key, sep, val = it.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            parser.error(f"--vehicle-param: got {it!r}; expected FIELD=VALUE with FIELD one of "
                         f"{', '.join(sorted(fields))}")
        try:
            v = float(val)
        except ValueError:
            v = math.nan
        if not (math.isfinite(v) and (v > 0.0 or (key == "drag_rot" and v == 0.0))):
            parser.error(f"--vehicle-param {key}: got {val!r}; expected a finite number > 0")
        kw[key] = v
    return vp.with_overrides(**kw)


def main(argv: list[str] | None = None) -> int:
    """Entry point of `python -m mav.onboard` and `cosim onboard`. Returns the exit code."""
    from mav.links import UdpLink

    parser = _build_parser()
    args = parser.parse_args(argv)
    kw: dict = {"vehicle": args.vehicle, "sysid": args.sysid, "param_file": args.params}
    if args.signing_key:
        try:
            kw["signing_key"] = bytes.fromhex(args.signing_key)
        except ValueError:
            parser.error("--signing-key: expected 64 hex digits")
    if args.signing_epoch == "now":
        kw["signing_epoch_unix_s"] = time.time()
    elif args.signing_epoch != "2024":
        parser.error("--signing-epoch: expected 2024 or now")
    if args.origin:
        try:
            lat, lon, alt = (float(v) for v in args.origin.split(","))
        except ValueError:
            parser.error("--origin: expected LAT,LON,ALT")
        kw.update(origin_lat_deg=lat, origin_lon_deg=lon, origin_alt_m=alt)
    if not (args.hil_timeout > 0):
        parser.error("--hil-timeout: expected seconds > 0")
    try:
        cfg = OnboardConfig(**kw)
    except ValueError as exc:
        parser.error(str(exc))
    vehicle = _vehicle_with_overrides(parser, args.vehicle, args.vehicle_param)
    try:
        hil = UdpLink(args.hil_bind)
        api = UdpLink(args.api_bind, args.api_remote)
        gcs = UdpLink(args.gcs_bind, args.gcs_remote)
    except OSError as exc:
        print(f"onboard: cannot bind: {exc}", file=sys.stderr)
        return 1
    try:
        onboard = Onboard(cfg, hil, api, gcs)
        if args.vehicle_param:
            onboard.set_airframe(vehicle)
    except (ValueError, OSError) as exc:
        print(f"onboard: {exc}", file=sys.stderr)
        return 2
    for w in onboard.warnings:
        print(f"onboard: {w}", file=sys.stderr)
    print(f"PORTS hil={hil.local_address[1]} api={api.local_address[1]} "
          f"gcs={gcs.local_address[1]}", flush=True)

    stop = []
    if threading.current_thread() is threading.main_thread():
        def _stop(signum, _frame) -> None:
            stop.append(signum)

        old = {s: signal.signal(s, _stop) for s in (signal.SIGTERM, signal.SIGINT)}
    else:
        old = {}
    code = 0
    # one poll() per readable event: a further datagram already queued makes the next wait
    # return at once, and no recvfrom is spent on finding the socket empty
    poller = select.poll()
    poller.register(hil.sock.fileno(), select.POLLIN)
    wait = poller.poll
    last_rx = time.monotonic()
    try:
        while not stop:
            try:
                r = wait(100)
            except InterruptedError:
                continue
            now = time.monotonic()
            if r:
                last_rx = now
                onboard.poll()
            elif now - last_rx > args.hil_timeout:
                print(f"onboard: no HIL input for {args.hil_timeout:g} s, exiting",
                      file=sys.stderr)
                break
    except Exception:
        traceback.print_exc(file=sys.stderr)
        code = 1
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        for link in (hil, api, gcs):
            link.close()
        st = {k: v for k, v in onboard.stats.items() if v}
        print(f"onboard: exit {code}; stats {st}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
