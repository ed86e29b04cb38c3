"""MAVLink on the wire: a fast codec for the per-tick messages, framing, and wire units.

Everything here produces and accepts exactly the bytes pymavlink (dialect `common`, MAVLink 2)
does; pymavlink stays the reference and handles every other message. The fast path exists
because each HIL tick costs at least one ODOMETRY decode and one HIL_ACTUATOR_CONTROLS encode,
and offboard apps send SET_POSITION_TARGET_LOCAL_NED at up to 200 Hz.

Fast messages: ODOMETRY (331), HIL_ACTUATOR_CONTROLS (93), SET_POSITION_TARGET_LOCAL_NED (84),
LOCAL_POSITION_NED (32), ATTITUDE (30). Their layouts (field order, struct format, CRC_EXTRA)
are taken from pymavlink's generated classes at import, so they cannot drift from it.

Encoding shares state with a pymavlink `MAVLink` object (`mav`): the sequence number,
srcSystem/srcComponent and the signing state, so fast and generic sends on one link interleave
with one seq counter and one signing timestamp, exactly as `mav.send` would.
Decoding returns the fields in pymavlink's wire order (`ordered_fieldnames`, arrays
flattened) or None for anything that is not a well-formed, CRC-correct frame of that type.

Wire units live here and in `mav/` only: geodetic positions (degE7, mm), cm/s, cdeg.
"""

from __future__ import annotations

import hashlib
import math
import struct

import cython
from cython.cimports.libc.math import floor as _floor
from cython.cimports.libc.math import fmod as _fmod
from pymavlink.dialects.v20 import common as mavlink2

from mav import crc as _crc
from mav.crc import crc16
from mav.fields import new_payload

MAGIC_V2 = 0xFD
MAGIC_V1 = 0xFE
HEADER_LEN_V2 = 10
HEADER_LEN_V1 = 6
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
# the same as C constants for the compiled frame walkers (a module global is a Python object)
_MAGIC2 = cython.declare(cython.long, MAGIC_V2)
_MAGIC1 = cython.declare(cython.long, MAGIC_V1)
_HDR2 = cython.declare(cython.Py_ssize_t, HEADER_LEN_V2)
_HDR1 = cython.declare(cython.Py_ssize_t, HEADER_LEN_V1)
_SIGLEN = cython.declare(cython.Py_ssize_t, SIGNATURE_LEN)
_SIGNED = cython.declare(cython.long, IFLAG_SIGNED)


class FastMsg:
    """Layout of one message type, derived from pymavlink's generated class."""

    __slots__ = ("cls", "id", "name", "crc_extra", "extra", "st", "size", "id3", "zeros",
                 "unpack_from")

    def __init__(self, cls: type) -> None:
        self.cls = cls
        self.id = cls.id
        self.name = cls.msgname
        self.crc_extra = cls.crc_extra
        self.extra = bytes((cls.crc_extra,))
        self.st = cls.unpacker            # struct.Struct in wire order
        self.size = cls.unpacker.size
        self.id3 = struct.pack("<I", cls.id)[:3]
        self.zeros = bytes(self.size)
        self.unpack_from = cls.unpacker.unpack_from    # bound once, for the decoders


ODOMETRY = FastMsg(mavlink2.MAVLink_odometry_message)
HIL_ACTUATOR_CONTROLS = FastMsg(mavlink2.MAVLink_hil_actuator_controls_message)
SET_POSITION_TARGET_LOCAL_NED = FastMsg(mavlink2.MAVLink_set_position_target_local_ned_message)
LOCAL_POSITION_NED = FastMsg(mavlink2.MAVLink_local_position_ned_message)
ATTITUDE = FastMsg(mavlink2.MAVLink_attitude_message)
# telemetry streamed at >= 1 Hz: encoded with `pack(mav, MSG, *wire_order_values)`
HEARTBEAT = FastMsg(mavlink2.MAVLink_heartbeat_message)
SYS_STATUS = FastMsg(mavlink2.MAVLink_sys_status_message)
GLOBAL_POSITION_INT = FastMsg(mavlink2.MAVLink_global_position_int_message)
EXTENDED_SYS_STATE = FastMsg(mavlink2.MAVLink_extended_sys_state_message)
POSITION_TARGET_LOCAL_NED = FastMsg(mavlink2.MAVLink_position_target_local_ned_message)
VFR_HUD = FastMsg(mavlink2.MAVLink_vfr_hud_message)
# telemetry streamed at <= 1 Hz by default, fast-packed too (pymavlink's message objects cost
# 5-20 us each to build and pack; these layouts give the same bytes, tests/test_onboard_wire.py)
BATTERY_STATUS = FastMsg(mavlink2.MAVLink_battery_status_message)
GPS_RAW_INT = FastMsg(mavlink2.MAVLink_gps_raw_int_message)
HOME_POSITION = FastMsg(mavlink2.MAVLink_home_position_message)
HIGHRES_IMU = FastMsg(mavlink2.MAVLink_highres_imu_message)
MISSION_CURRENT = FastMsg(mavlink2.MAVLink_mission_current_message)


class _ProtocolVersionLayout:
    """PROTOCOL_VERSION (#300, MAVLink's minimal/common XML), which none of pymavlink 2.4.50's
    generated dialects has (v20 common, standard, minimal, all, development: checked), so its
    layout is stated here, in the form `FastMsg` reads from a pymavlink class. Wire order (the
    uint16 fields before the uint8 arrays): version, min_version, max_version,
    spec_version_hash[8], library_version_hash[8] (22 bytes). CRC_EXTRA 217: what pymavlink's
    own generator computes from that XML definition (tests/test_onboard_telemetry.py
    regenerates it with mavgen and decodes our bytes with the result) and the
    MAVLINK_MSG_ID_PROTOCOL_VERSION_CRC of MAVLink's generated C headers."""

    id = 300
    msgname = "PROTOCOL_VERSION"
    crc_extra = 217
    unpacker = struct.Struct("<HHH8B8B")


# sent on request only (not a pymavlink class: not in FAST_BY_ID, which mirrors pymavlink's)
PROTOCOL_VERSION = FastMsg(_ProtocolVersionLayout)

FAST_BY_ID: dict[int, FastMsg] = {
    m.id: m
    for m in (ODOMETRY, HIL_ACTUATOR_CONTROLS, SET_POSITION_TARGET_LOCAL_NED, LOCAL_POSITION_NED,
              ATTITUDE, HEARTBEAT, SYS_STATUS, GLOBAL_POSITION_INT, EXTENDED_SYS_STATE,
              POSITION_TARGET_LOCAL_NED, VFR_HUD, BATTERY_STATUS, GPS_RAW_INT, HOME_POSITION,
              HIGHRES_IMU, MISSION_CURRENT)
}

# Field positions in the decoded (wire-order, arrays flattened) tuples.
# ODOMETRY: time_usec, x, y, z, q[4], vx, vy, vz, rollspeed, pitchspeed, yawspeed,
#           pose_covariance[21], velocity_covariance[21], frame_id, child_frame_id, ...
ODO_FRAME_ID = 1 + 3 + 4 + 3 + 3 + 42      # = 56
ODO_CHILD_FRAME_ID = ODO_FRAME_ID + 1
# SET_POSITION_TARGET_LOCAL_NED: time_boot_ms, x, y, z, vx, vy, vz, afx, afy, afz, yaw,
#           yaw_rate, type_mask, target_system, target_component, coordinate_frame

_HDR = struct.Struct("<BBBBBBB")           # magic, len, incompat, compat, seq, sysid, compid
_HDR6 = struct.Struct("<BBBBBB")           # the same without the magic byte
_CRC = struct.Struct("<H")
_MAGIC2_B = bytes((MAGIC_V2,))
_SIGN_TS = struct.Struct("<BQ")
# time_usec, flags, controls[0..3], controls[4..15] = 0 (pad bytes), mode
_HIL_CTRL = struct.Struct("<QQ4f48xB")
HIL_CTRL_PACK = _HIL_CTRL.pack
assert _HIL_CTRL.size == HIL_ACTUATOR_CONTROLS.size


# ----------------------------------------------------------------------------------- encoding
@cython.locals(seq=cython.int, n=cython.Py_ssize_t, p=cython.p_uchar)
def frame(mav, m: FastMsg, payload: bytes) -> bytes:
    """Frame a packed payload as MAVLink 2, as `mav.send(msg)` would (and advance mav.seq).

    Trailing zero bytes of the payload are trimmed (at least one byte stays), the header
    carries mav's seq/srcSystem/srcComponent, the CRC includes CRC_EXTRA, and if
    `mav.signing.sign_outgoing` the packet is signed with mav's key, link id and timestamp.
    """
    n = trimmed_len(payload)
    seq = mav.seq
    mav.seq = (seq + 1) & 0xFF
    signing = mav.signing
    if signing.sign_outgoing:
        trimmed = payload.rstrip(b"\x00") or payload[:1]
        signed = _HDR.pack(MAGIC_V2, len(trimmed), IFLAG_SIGNED, 0, seq, mav.srcSystem,
                           mav.srcComponent)
        signed += m.id3 + trimmed
        signed += _CRC.pack(crc16(signed[1:] + m.extra))
        signed += _SIGN_TS.pack(signing.link_id, signing.timestamp)[:7]
        signed += hashlib.sha256(signing.secret_key + signed).digest()[:6]
        signing.timestamp += 1
        return signed
    if not cython.compiled:
        out = new_payload(_HDR2 + n + 2)
        put_frame(out, 0, seq, mav.srcSystem, mav.srcComponent, m, payload, n)
        return bytes(out)
    # compiled: written into a new bytes object, which nothing else holds until it is returned
    out = PyBytes_FromStringAndSize(cython.NULL, _HDR2 + n + 2)  # noqa: F821
    p = cython.cast(cython.p_uchar, PyBytes_AS_STRING(out))      # noqa: F821
    _frame_at(p, out, 0, seq, mav.srcSystem, mav.srcComponent, m, payload, n)
    return out


@cython.locals(n=cython.Py_ssize_t)
def trimmed_len(payload: bytes) -> int:
    """The payload's length less its trailing zero bytes (at least one byte stays);
    ValueError past MAVLink 2's 255 bytes (its length field is one byte)."""
    n = len(payload)
    while n > 1 and payload[n - 1] == 0:
        n -= 1
    if n > 255:
        raise ValueError(f"a payload of {n} bytes: a MAVLink 2 frame carries at most 255")
    return n


@cython.locals(p=cython.p_uchar)
def put_frame(out: bytearray, at: int, seq: int, sysid: int, compid: int, m: FastMsg,
              payload: bytes, n: int) -> int:
    """Write the unsigned MAVLink 2 frame of payload[:n] at out[at:at + n + 12]: header,
    payload, checksum (IndexError when that is not inside out and payload). `payload` None:
    its n bytes are already at out[at + 10:] (written in place: mav/hil.py's ODOMETRY)."""
    if payload is not None and (n < 0 or n > len(payload)):
        raise IndexError(f"put_frame: {n} bytes of a {len(payload)}-byte payload")
    _frame_span(out, at, n)
    if cython.compiled:
        p = cython.cast(cython.p_uchar, PyByteArray_AS_STRING(out)) + at  # noqa: F821
    else:
        p = memoryview(out)[at:]
    return _frame_at(p, out, at, seq, sysid, compid, m, payload, n)


@cython.cfunc
@cython.exceptval(-1)
@cython.returns(cython.int)
@cython.locals(at=cython.Py_ssize_t, n=cython.Py_ssize_t)
def _frame_span(out: bytearray, at: int, n: int) -> int:
    """IndexError unless an n-byte payload's frame fits at out[at:]."""
    if at < 0 or n < 0 or n > 255 or at + _HDR2 + n + 2 > len(out):
        raise IndexError(f"a frame of {n} payload bytes at {at} of a {len(out)}-byte buffer")
    return 0


@cython.cfunc
@cython.exceptval(-1)
@cython.returns(cython.int)
@cython.locals(p=cython.p_uchar, q=cython.p_uchar, at=cython.Py_ssize_t, n=cython.Py_ssize_t,
               k=cython.Py_ssize_t, mid=cython.long, crc=cython.long, seq=cython.int,
               sysid=cython.int, compid=cython.int)
def _frame_at(p, out, at: int, seq: int, sysid: int, compid: int, m: FastMsg, payload, n: int
              ) -> int:
    """The frame at p (out's buffer at `at`, checked by the caller) of payload[:n] (None: the
    n bytes already after the header): the payload, the header, the checksum."""
    if payload is not None:
        if cython.compiled:
            q = cython.cast(cython.p_uchar, cython.cast(cython.p_char, payload))
            for k in range(n):
                p[_HDR2 + k] = q[k]
        else:
            p[_HDR2:_HDR2 + n] = payload[:n]
    p[0] = _MAGIC2
    p[1] = n
    p[2] = 0                    # incompat_flags: not signed
    p[3] = 0                    # compat_flags
    p[4] = seq
    p[5] = sysid
    p[6] = compid
    mid = m.id
    p[7] = mid & 0xFF
    p[8] = (mid >> 8) & 0xFF
    p[9] = mid >> 16
    crc = _crc.crc_of(out, at + 1, at + _HDR2 + n, m.crc_extra)
    p[_HDR2 + n] = crc & 0xFF
    p[_HDR2 + n + 1] = crc >> 8
    return 0


def pack(mav, m: FastMsg, *values) -> bytes:
    """Encode message `m` from its field values in WIRE order (`m.cls.ordered_fieldnames`,
    arrays flattened), e.g. HEARTBEAT: custom_mode, type, autopilot, base_mode,
    system_status, mavlink_version."""
    return frame(mav, m, m.st.pack(*values))


def encode_hil_actuator_controls(mav, time_usec: int, u1: float, u2: float, u3: float,
                                 u4: float, mode: int, flags: int = 1) -> bytes:
    """HIL_ACTUATOR_CONTROLS with controls[0..3] = u1..u4 and controls[4..15] = 0."""
    return frame(mav, HIL_ACTUATOR_CONTROLS, _HIL_CTRL.pack(time_usec, flags, u1, u2, u3, u4, mode))


def encode_odometry(mav, time_usec: int, x: float, y: float, z: float, qw: float, qx: float,
                    qy: float, qz: float, vx: float, vy: float, vz: float, p: float, q: float,
                    r: float, frame_id: int = 1, child_frame_id: int = 1,
                    pose_cov0: float = math.nan, vel_cov0: float = math.nan,
                    reset_counter: int = 0, estimator_type: int = 0, quality: int = 0) -> bytes:
    """ODOMETRY; covariances are [pose_cov0, 0...] and [vel_cov0, 0...] (NaN = unknown)."""
    pl = ODOMETRY.st.pack(time_usec, x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r,
                          pose_cov0, *_Z20, vel_cov0, *_Z20, frame_id, child_frame_id,
                          reset_counter, estimator_type, quality)
    return frame(mav, ODOMETRY, pl)


_Z20 = (0.0,) * 20


def encode_set_position_target_local_ned(mav, time_boot_ms: int, target_system: int,
                                         target_component: int, coordinate_frame: int,
                                         type_mask: int, x: float, y: float, z: float, vx: float,
                                         vy: float, vz: float, afx: float, afy: float,
                                         afz: float, yaw: float, yaw_rate: float) -> bytes:
    pl = SET_POSITION_TARGET_LOCAL_NED.st.pack(
        time_boot_ms, x, y, z, vx, vy, vz, afx, afy, afz, yaw, yaw_rate, type_mask,
        target_system, target_component, coordinate_frame)
    return frame(mav, SET_POSITION_TARGET_LOCAL_NED, pl)


def encode_local_position_ned(mav, time_boot_ms: int, x: float, y: float, z: float,
                              vx: float, vy: float, vz: float) -> bytes:
    return frame(mav, LOCAL_POSITION_NED, LOCAL_POSITION_NED.st.pack(time_boot_ms, x, y, z,
                                                                     vx, vy, vz))


def encode_attitude(mav, time_boot_ms: int, roll: float, pitch: float, yaw: float,
                    rollspeed: float, pitchspeed: float, yawspeed: float) -> bytes:
    return frame(mav, ATTITUDE, ATTITUDE.st.pack(time_boot_ms, roll, pitch, yaw, rollspeed,
                                                 pitchspeed, yawspeed))


def send_msg(mav, msg) -> bytes:
    """Pack any pymavlink message on `mav` (seq advanced like `mav.send`); returns the bytes."""
    buf = msg.pack(mav)
    mav.seq = (mav.seq + 1) & 0xFF
    return buf


# ----------------------------------------------------------------------------------- decoding
@cython.locals(n=cython.Py_ssize_t, end=cython.Py_ssize_t, magic=cython.long)
def frame_end(data: bytes, i: int = 0) -> int:
    """End index of the frame starting at data[i], or -1 if data[i] is not a magic byte or
    the frame is truncated (the length field points past the end of `data`)."""
    n = len(data)
    if i >= n:
        return -1
    magic = data[i]
    if magic == _MAGIC2:
        if i + 3 > n:
            return -1
        end = i + _HDR2 + data[i + 1] + 2
        if data[i + 2] & _SIGNED:
            end += _SIGLEN
    elif magic == _MAGIC1:
        if i + 2 > n:
            return -1
        end = i + _HDR1 + data[i + 1] + 2
    else:
        return -1
    return end if end <= n else -1


def msgid_of(data: bytes, i: int = 0) -> int:
    """Message id of the (complete) frame starting at data[i]."""
    if data[i] == _MAGIC2:
        return data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
    return data[i + 5]


@cython.locals(flags=cython.long, plen=cython.Py_ssize_t, crc_at=cython.Py_ssize_t)
def frame_ok(m: FastMsg, data: bytes, i: int, end: int) -> bool:
    """Whether data[i:end] is one well-formed, CRC-correct MAVLink 2 frame of type `m` (the
    signature block, if any, is not checked: see `decode_fast`)."""
    if i < 0 or end > len(data) or end - i < _HDR2 + 2 or data[i] != _MAGIC2 or msgid_of(
            data, i) != m.id:
        return False
    flags = data[i + 2]
    if flags & ~_SIGNED:
        return False
    plen = data[i + 1]
    crc_at = i + _HDR2 + plen
    if crc_at + 2 + (_SIGLEN if flags else 0) != end:
        return False
    return _crc.crc_of(data, i + 1, crc_at, m.crc_extra) == (
        data[crc_at] | data[crc_at + 1] << 8)


@cython.locals(plen=cython.Py_ssize_t)
def decode_fast(m: FastMsg, data: bytes, i: int = 0, end: int = -1) -> tuple | None:
    """Decode one MAVLink 2 frame data[i:end] of type `m`; None unless it is well formed,
    of that type and CRC-correct. The signature block (if any) is NOT checked: use this only
    where signing is not required (pymavlink's decoder checks signatures).

    Returns the payload fields in wire order with arrays flattened (pymavlink's unpacker
    tuple); trimmed payloads are zero-extended as pymavlink does.
    """
    if end < 0:
        end = frame_end(data, i)
        if end < 0:
            return None
    if not frame_ok(m, data, i, end):
        return None
    plen = data[i + 1]
    if plen >= m.size:
        return m.unpack_from(data, i + _HDR2)
    return m.st.unpack(data[i + _HDR2:i + _HDR2 + plen] + m.zeros[plen:])


def one_frame_decoder(m: FastMsg, used: struct.Struct):
    """A decoder for a datagram holding exactly one frame of `m`: the leading fields that
    `used` unpacks (same offsets as m's payload), or None. Same checks and values as
    `decode_fast(m, ...)` on those fields (`used = m.st`: all of them); for the per-tick paths.
    `decode(data, i, end)` reads the datagram data[i:end] in place (a part of a larger one)."""
    mid, zeros, used_len, crc_extra = m.id, m.zeros, used.size, m.crc_extra
    unpack, unpack_from = used.unpack, used.unpack_from

    @cython.locals(data=bytes, i=cython.Py_ssize_t, end=cython.Py_ssize_t,
                   flags=cython.long, crc_at=cython.Py_ssize_t, plen=cython.Py_ssize_t)
    def decode(data: bytes, i: int = 0, end: int = -1) -> tuple | None:
        # data[i:end] (end < 0: to the end of data) is the datagram: one frame, nothing else
        if end < 0:
            end = len(data)
        if i < 0 or end > len(data) or end - i < 12 or data[i] != _MAGIC2 or msgid_of(
                data, i) != mid:
            return None
        flags = data[i + 2]
        crc_at = i + _HDR2 + data[i + 1]
        if flags == 0:
            if end != crc_at + 2:
                return None
        elif flags != _SIGNED or end != crc_at + 2 + _SIGLEN:
            return None
        if _crc.crc_of(data, i + 1, crc_at, crc_extra) != (data[crc_at] | data[crc_at + 1] << 8):
            return None
        plen = data[i + 1]
        if plen >= used_len:
            return unpack_from(data, i + _HDR2)
        return unpack(data[i + _HDR2:crc_at] + zeros[plen:used_len])

    return decode


# ODOMETRY -> (time_usec, x, y, z, qw, qx, qy, qz, vx, vy, vz, rollspeed, pitchspeed, yawspeed,
# frame_id, child_frame_id, quality): the covariances, reset counter and estimator type, which
# the onboard stack does not use, are skipped (the onboard stack's per-tick HIL input).
# quality (int8): -1 the estimate has failed, 0 unknown, 1..100 worst..best (MAVLink).
ODOMETRY_USED = struct.Struct("<Q13f168xBB2xb")
decode_odometry = one_frame_decoder(ODOMETRY, ODOMETRY_USED)

# HIL_ACTUATOR_CONTROLS -> (time_usec, controls[0..3]): the four motors the simulator applies
# (the simulator's per-tick HIL input).
HIL_ACTUATOR_CONTROLS_USED = struct.Struct("<Q8x4f")
decode_hil_actuator_controls = one_frame_decoder(HIL_ACTUATOR_CONTROLS,
                                                  HIL_ACTUATOR_CONTROLS_USED)


def header_of(data: bytes, i: int = 0) -> tuple[int, int, int]:
    """(seq, srcSystem, srcComponent) of the complete frame at data[i]."""
    if data[i] == MAGIC_V2:
        return data[i + 4], data[i + 5], data[i + 6]
    return data[i + 2], data[i + 3], data[i + 4]


# ------------------------------------------------------------------------------- wire units
# WGS-84, as the Simulink "Flat Earth to LLA" block of the Minidrone template uses it.
WGS84_A = 6378137.0                 # m, equatorial radius
WGS84_F = 1.0 / 298.257223563       # flattening
_E2 = WGS84_F * (2.0 - WGS84_F)     # first eccentricity squared


class FlatEarth:
    """Flat-earth conversion between local NED (m) and geodetic (deg, m AMSL) about an origin.

    The meridian and prime-vertical radii of curvature are evaluated once at the origin
    latitude (Simulink's Flat Earth to LLA with zero azimuth); good to mm over a room and to
    cm over a few km, far beyond what a Minidrone arena needs.
    """

    __slots__ = ("lat0_deg", "lon0_deg", "alt0_m", "_dlat_dn", "_dlon_de")

    def __init__(self, lat0_deg: float, lon0_deg: float, alt0_m: float) -> None:
        self.lat0_deg, self.lon0_deg, self.alt0_m = lat0_deg, lon0_deg, alt0_m
        s = math.sin(math.radians(lat0_deg))
        den = 1.0 - _E2 * s * s
        r_n = WGS84_A / math.sqrt(den)                 # prime vertical radius, m
        r_m = r_n * (1.0 - _E2) / den                  # meridian radius, m
        self._dlat_dn = math.degrees(math.atan2(1.0, r_m))                     # deg/m north
        self._dlon_de = math.degrees(math.atan2(1.0, r_n * math.cos(math.radians(lat0_deg))))

    @cython.locals(lon=cython.double)
    def to_geodetic(self, n_m: float, e_m: float, d_m: float) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_m AMSL) of the NED point (n, e, d) in m."""
        lon = self.lon0_deg + e_m * self._dlon_de
        lon = (lon + 180.0) % 360.0 - 180.0
        return self.lat0_deg + n_m * self._dlat_dn, lon, self.alt0_m - d_m

    def to_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """(n, e, d) in m of a geodetic point; inverse of `to_geodetic`."""
        dlon = (lon_deg - self.lon0_deg + 180.0) % 360.0 - 180.0
        return ((lat_deg - self.lat0_deg) / self._dlat_dn, dlon / self._dlon_de,
                self.alt0_m - alt_m)

    @cython.locals(lat=cython.double, lon=cython.double, alt=cython.double)
    def to_int(self, n_m: float, e_m: float, d_m: float) -> tuple[int, int, int]:
        """(lat_e7, lon_e7, alt_mm) as GLOBAL_POSITION_INT and HOME_POSITION carry them
        (rounded as Python's round: `round_even`)."""
        lat, lon, alt = self.to_geodetic(n_m, e_m, d_m)
        return (int(round_even(lat * 1e7)), int(round_even(lon * 1e7)),
                int(round_even(alt * 1000.0)))


@cython.locals(x=cython.double, f=cython.double, d=cython.double)
def round_even(x: float) -> float:
    """x rounded as Python's round(x) rounds a float (to the nearest integer, halves to even),
    as a float: int(round_even(x)) == round(x), and a NaN or an infinity comes back as it is
    (int() of it raises as round() does). Compiled: C doubles and libm's floor, no call into
    Python. x - floor(x) is exact for x >= 0 and for x <= -1; in between, where the difference
    may round, it is > 0.5 or rounds to 0.5 from above with floor(x) = -1 odd: both give 0,
    the nearest integer (tests/test_onboard_wire.py compares it with round)."""
    if x - x != 0.0:
        return x
    f = _floor(x)
    d = x - f
    if d > 0.5 or (d == 0.5 and _fmod(f, 2.0) != 0.0):
        f += 1.0
    return float(f)


def clamp_int(v: float, lo: int, hi: int) -> int:
    """Round to int and saturate to [lo, hi] (NaN -> 0): for cm/s, cdeg, mV fields."""
    if v != v:
        return 0
    if v >= hi:
        return hi
    if v <= lo:
        return lo
    return int(round(v))
