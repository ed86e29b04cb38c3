"""The onboard stack's definitions: modes, landed states, frames, limits, telemetry streams.

Shared by every part of the stack; it imports none of them.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from mav import wire

M = mavlink2
NAN = math.nan
TWO_PI = 2.0 * math.pi

# ---- PX4 custom modes (px4_custom_mode.h): custom_mode = main << 16 | sub << 24
PX4_MAIN_MANUAL, PX4_MAIN_ALTCTL, PX4_MAIN_POSCTL, PX4_MAIN_AUTO = 1, 2, 3, 4
PX4_MAIN_OFFBOARD = 6
PX4_SUB_TAKEOFF, PX4_SUB_LOITER, PX4_SUB_MISSION, PX4_SUB_RTL, PX4_SUB_LAND = 2, 3, 4, 5, 6

# internal mode numbers
POSCTL, TAKEOFF, LOITER, LAND, OFFBOARD, RTL, MISSION = 0, 1, 2, 3, 4, 5, 6
MODE_NAMES = ("POSCTL", "AUTO.TAKEOFF", "AUTO.LOITER", "AUTO.LAND", "OFFBOARD", "AUTO.RTL",
              "AUTO.MISSION")
MODE_PX4 = ((PX4_MAIN_POSCTL, 0), (PX4_MAIN_AUTO, PX4_SUB_TAKEOFF), (PX4_MAIN_AUTO, PX4_SUB_LOITER),
            (PX4_MAIN_AUTO, PX4_SUB_LAND), (PX4_MAIN_OFFBOARD, 0), (PX4_MAIN_AUTO, PX4_SUB_RTL),
            (PX4_MAIN_AUTO, PX4_SUB_MISSION))
MODE_BY_PX4 = {px4: i for i, px4 in enumerate(MODE_PX4)}
MODE_BY_PX4[(PX4_MAIN_POSCTL, 1)] = POSCTL            # POSCTL sub modes (orbit, slow)
MODE_BY_PX4[(PX4_MAIN_POSCTL, 2)] = POSCTL


def px4_custom_mode(mode: int) -> int:
    main, sub = MODE_PX4[mode]
    return main << 16 | sub << 24


FRAME_LOCAL_NED = M.MAV_FRAME_LOCAL_NED
FRAME_BODY_NED = M.MAV_FRAME_BODY_NED
FRAME_BODY_OFFSET_NED = M.MAV_FRAME_BODY_OFFSET_NED    # 9: a relative move (moveby.py)
SP_ID3 = wire.SET_POSITION_TARGET_LOCAL_NED.id3
FRAME_BODY_FRD = M.MAV_FRAME_BODY_FRD
HIL_MODE_DISARMED = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED       # HIL_ACTUATOR_CONTROLS.mode
HIL_MODE_ARMED = M.MAV_MODE_FLAG_SAFETY_ARMED | M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED

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
TOUCH_VZ_MPS = 0.10         # m/s, |vz| (low-passed, TOUCH_VZ_TAU_S) below this while landing ...
TOUCH_VZ_TAU_S = 0.25       # s, the land detector's filter on vz: odometry noise must not
                            # reset it (PX4 decides on the estimator's filtered velocity)
TOUCH_AGL_M = 0.30          # ... and below this height above home ...
TOUCH_TRIG_US = 200_000     # ... for this long: touched down
TOUCH_STALL_US = 500_000    # or not descending (vz < TOUCH_VZ_MPS) this long after
                            # LAND_STALL_AFTER (any height)
LAND_STALL_AFTER_US = 2_000_000
TKO_ACCEPT_M = 0.10         # m, takeoff complete within this of the target height
TKO_SETTLE_US = 3_000_000   # or this long after the ramp reached the target
TKO_EASE_S = 0.4            # s, time constant of the takeoff reference near the target
TKO_SNAP_M = 0.002          # m, the reference snaps to the target from this close
LEG_SNAP_M = 0.002          # m, a leg's reference snaps to its target from this close
LEG_ACC_LEAD_S = 0.25       # s, a leg's acceleration feed-forward leads by this (tilt lag)
LEG_FACE_M = 1.0            # m, a leg at least this long with no yaw given: face along it
LEG_SETTLE_US = 5_000_000   # us, a leg counts as reached this long after its reference did

FORCE_DISARM_MAGIC = 21196
REJECT_TEXT_EVERY_US = 1_000_000   # STATUSTEXT about rejected input at most this often per kind
PARAM_BURST = 16            # PARAM_VALUEs per link per tick while a list is being sent
# datagrams handled per link per tick (bounded work under flood; the rest waits in the socket
# buffer and what overflows it is dropped by the kernel, counted as dropped_kernel_<link>).
# 32 a tick is 6400 datagrams/s a link, far above any client's traffic, and at ~10 us each
# (garbage, frames for other systems) 0.3 ms of a 5 ms tick; 256 made a flooded tick 9-12 ms
# on a 2-core host (cosim bench --flood, docs/performance.md)
DRAIN_MAX = 32
FRAMES_MAX = 32             # frames handled per datagram

SIGNING_EPOCH_2024 = 1704067200.0   # s, Unix time of 2024-01-01: signing timestamps start here
SIGNING_EPOCH_2015 = 1420070400    # s, Unix time of MAVLink's signing epoch

MAV_TYPE = M.MAV_TYPE_QUADROTOR
MAV_AUTOPILOT = M.MAV_AUTOPILOT_PX4
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255   # "1.14.0" official, PX4 style
CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
)
SENSORS = (
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
    "MISSION_CURRENT": M.MAVLINK_MSG_ID_MISSION_CURRENT,
}
API_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "ATTITUDE": 50.0, "LOCAL_POSITION_NED": 50.0,
    "GLOBAL_POSITION_INT": 10.0, "HOME_POSITION": 0.5, "EXTENDED_SYS_STATE": 5.0,
    "POSITION_TARGET_LOCAL_NED": 10.0, "BATTERY_STATUS": 1.0, "VFR_HUD": 0.0,
    "MISSION_CURRENT": 1.0,
}
GCS_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "ATTITUDE": 20.0, "LOCAL_POSITION_NED": 10.0,
    "GLOBAL_POSITION_INT": 5.0, "HOME_POSITION": 0.5, "EXTENDED_SYS_STATE": 1.0,
    "POSITION_TARGET_LOCAL_NED": 2.0, "BATTERY_STATUS": 0.5, "VFR_HUD": 4.0,
    "MISSION_CURRENT": 1.0,
}
# legacy REQUEST_DATA_STREAM groups (MAV_DATA_STREAM) -> streams
DATA_STREAM_GROUPS: dict[int, tuple[str, ...]] = {
    M.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "EXTENDED_SYS_STATE", "BATTERY_STATUS",
                                        "POSITION_TARGET_LOCAL_NED", "MISSION_CURRENT"),
    M.MAV_DATA_STREAM_POSITION: ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT"),
    M.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    M.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    M.MAV_DATA_STREAM_EXTRA3: ("HOME_POSITION",),
}
DATA_STREAM_GROUPS[M.MAV_DATA_STREAM_ALL] = tuple(
    n for g in list(DATA_STREAM_GROUPS.values()) for n in g)


def hz_to_us(hz: float) -> int:
    return int(round(1e6 / hz)) if hz > 0.0 else -1


def text_of(s) -> str:
    if isinstance(s, bytes | bytearray):
        return bytes(s).split(b"\x00", 1)[0].decode("ascii", errors="replace")
    return str(s).split("\x00", 1)[0]


# ==================================================================================================
# Appended for issue 13 item 4 (telemetry a ground station expects) and items 2 and 7
# (setpoints, parameter answers); kept at the end so the tables above stay as they were.
MSG_ID_PROTOCOL_VERSION = 300      # not in pymavlink 2.4.50's dialects: mav/wire.PROTOCOL_VERSION
# GPS_RAW_INT streamed (PX4's GCS link: 1 Hz, mavlink_main.cpp configure_stream_local); ODOMETRY
# and HIGHRES_IMU off by default (REQUEST_MESSAGE, SET_MESSAGE_INTERVAL)
STREAMS.update({
    "GPS_RAW_INT": M.MAVLINK_MSG_ID_GPS_RAW_INT,
    "ODOMETRY": M.MAVLINK_MSG_ID_ODOMETRY,
    "HIGHRES_IMU": M.MAVLINK_MSG_ID_HIGHRES_IMU,
    "ESTIMATOR_STATUS": M.MAVLINK_MSG_ID_ESTIMATOR_STATUS,
})
API_RATES_HZ.update({"GPS_RAW_INT": 1.0, "ODOMETRY": 0.0, "HIGHRES_IMU": 0.0,
                     "ESTIMATOR_STATUS": 0.0})
GCS_RATES_HZ.update({"GPS_RAW_INT": 1.0, "ODOMETRY": 0.0, "HIGHRES_IMU": 0.0,
                     "ESTIMATOR_STATUS": 0.0})
# GPS_RAW_INT in the legacy EXTENDED_STATUS group, as ArduPilot groups it; ODOMETRY and
# HIGHRES_IMU in none, so MAVProxy's REQUEST_DATA_STREAM(ALL) does not switch them on
DATA_STREAM_GROUPS[M.MAV_DATA_STREAM_EXTENDED_STATUS] += ("GPS_RAW_INT",)
DATA_STREAM_GROUPS[M.MAV_DATA_STREAM_ALL] += ("GPS_RAW_INT",)
# SYS_STATUS health: PX4 sets a component's health bit unless an error is reported for it,
# present or not (mavlink/streams/SYS_STATUS.hpp, fillOutComponent), but never reports the
# geofence, and MAVProxy's fence module says "fence breach" as soon as the GEOFENCE health bit
# is clear (mavproxy_fence.py, handle_sys_status). There is no fence here: not present, not
# enabled, healthy (nothing breached) by PX4's rule.
SENSORS_HEALTH = SENSORS | M.MAV_SYS_STATUS_GEOFENCE
