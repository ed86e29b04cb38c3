"""PX4's simulator interface on the HIL link: the sensor messages, both ends.

The simulator sends, per tick, ONE datagram holding several MAVLink 2 frames (PX4's simulator
bridge sends the same messages back to back on its stream):

- HIL_SENSOR (#107): accelerometer (m/s^2), gyro (rad/s), magnetometer (gauss), absolute
  pressure (hPa), pressure altitude (m), temperature; `fields_updated` says which are new
  (bits 0-2 accel, 3-5 gyro, 6-8 mag, 9 abs pressure, 11 pressure altitude, 12 temperature);
- HIL_OPTICAL_FLOW (#114) when the flow sensor has a sample: integrated flow (rad) about the
  sensor's x and y axes over `integration_time_us`, the sensor's own integrated gyro, quality
  0-255 (PX4's convention: a RH rotation about +x gives positive integrated_x, motion along +y
  negative; motion along +x gives positive integrated_y);
- DISTANCE_SENSOR (#132) when the range finder has a sample (cm; signal_quality 1: no echo);
- HIL_GPS (#113) when a GPS exists and has a fix sample;
- HIL_STATE_QUATERNION (#115): the ground truth, for logs (the vehicle does not fly on it).

All are stamped with the lockstep time (time_usec; DISTANCE_SENSOR time_boot_ms). The vehicle
answers one HIL_ACTUATOR_CONTROLS as with ODOMETRY. `decode_bundle` is the vehicle's reader:
total on bytes, it returns what it could decode and counts the rest.
"""

from __future__ import annotations

import struct

import cython
from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.fields import Layout, done, get_f, get_i, new_payload, put_f, put_i
from mav.hil import SIM_SYSID

HIL_SENSOR = wire.FastMsg(mavlink2.MAVLink_hil_sensor_message)
HIL_OPTICAL_FLOW = wire.FastMsg(mavlink2.MAVLink_hil_optical_flow_message)
DISTANCE_SENSOR = wire.FastMsg(mavlink2.MAVLink_distance_sensor_message)
HIL_GPS = wire.FastMsg(mavlink2.MAVLink_hil_gps_message)
HIL_STATE_QUATERNION = wire.FastMsg(mavlink2.MAVLink_hil_state_quaternion_message)

SENSOR_MSGS = {m.id: m for m in (HIL_SENSOR, HIL_OPTICAL_FLOW, DISTANCE_SENSOR, HIL_GPS,
                                 HIL_STATE_QUATERNION)}
FIELDS_IMU = 0x3F            # accel + gyro
FIELDS_MAG = 0x1C0
FIELDS_BARO = 0x200 | 0x800 | 0x1000   # abs pressure, pressure altitude, temperature
NO_ECHO = 1                  # DISTANCE_SENSOR.signal_quality: invalid signal (MAVLink)
ORIENT_DOWN = mavlink2.MAV_SENSOR_ROTATION_PITCH_270
RANGE_ULTRASOUND = mavlink2.MAV_DISTANCE_SENSOR_ULTRASOUND


# Each message's payload less its first field, the stamp (time_usec; DISTANCE_SENSOR's
# time_boot_ms): a reading is packed once when it is taken and framed when it is sent, with
# the stamp of that tick (the simulator's delay line, cosim/sensors/suite.py)
def _rest(m: wire.FastMsg) -> struct.Struct:
    return struct.Struct("<" + m.st.format[2:])


_HDR2 = cython.declare(cython.Py_ssize_t, wire.HEADER_LEN_V2)
_STAMP_US = struct.Struct("<Q").pack      # bound once (a Struct's method lookup per call
_STAMP_MS = struct.Struct("<I").pack      # costs as much as the packing)
# the payloads' layouts (less the stamp but HIL_STATE_QUATERNION's), written field by field
# from C values (mav/fields.py: struct's bytes, no Python float per field)
_SENSOR_L = cython.declare(Layout, Layout(_rest(HIL_SENSOR).format))
_FLOW_L = cython.declare(Layout, Layout(_rest(HIL_OPTICAL_FLOW).format))
_DIST_L = cython.declare(Layout, Layout(_rest(DISTANCE_SENSOR).format))
_GPS_REST = _rest(HIL_GPS).pack
_TRUTH_L = cython.declare(Layout, Layout(HIL_STATE_QUATERNION.st.format))


def stamped(mav, m: wire.FastMsg, t_us: int, rest: bytes) -> bytes:
    """The frame of message m stamped t_us (us; ms for DISTANCE_SENSOR) with the payload's
    other fields `rest` (packed by the *_rest functions below)."""
    return wire.frame(mav, m, stamp(m, t_us, rest))


def stamp(m: wire.FastMsg, t_us: int, rest: bytes) -> bytes:
    """The payload of message m: its stamp t_us (us; ms for DISTANCE_SENSOR), then `rest`."""
    return stamp_all([m, rest], t_us, [])[1]


@cython.locals(parts=list, out=list, i=cython.Py_ssize_t)
def stamp_all(parts: list, t_us: int, out: list) -> list:
    """`out` with the pairs of parts = [message, rest, message, rest, ...] appended as
    [message, payload, ...], each payload `stamp`ed t_us (each stamp packed once a call)."""
    us = _STAMP_US(t_us)
    ms = None
    for i in range(0, len(parts), 2):
        m = parts[i]
        if m is DISTANCE_SENSOR:
            if ms is None:
                ms = _STAMP_MS(t_us // 1000)
            out.append(m)
            out.append(ms + parts[i + 1])
        else:
            out.append(m)
            out.append(us + parts[i + 1])
    return out


@cython.locals(parts=list, k=cython.Py_ssize_t, i=cython.Py_ssize_t, n=cython.Py_ssize_t,
               size=cython.Py_ssize_t, at=cython.Py_ssize_t, seq=cython.int,
               sysid=cython.int, compid=cython.int, out=bytearray)
def frames(mav, parts: list) -> bytes:
    """The frames of parts = [message, payload, message, payload, ...] back to back: the
    same bytes as b"".join(wire.frame(mav, m, payload) for each pair), one seq each, built
    in one buffer with mav's fields read once (the sensor datagram of a tick)."""
    k = len(parts) // 2
    if mav.signing.sign_outgoing:
        return b"".join([wire.frame(mav, parts[2 * i], parts[2 * i + 1]) for i in range(k)])
    seq = mav.seq
    mav.seq = (seq + k) & 0xFF
    sysid, compid = mav.srcSystem, mav.srcComponent
    size = 0
    for i in range(k):
        size += wire.trimmed_len(parts[2 * i + 1]) + _HDR2 + 2
    out = new_payload(size)
    at = 0
    for i in range(k):
        payload = parts[2 * i + 1]
        n = wire.trimmed_len(payload)
        wire.put_frame(out, at, (seq + i) & 0xFF, sysid, compid, parts[2 * i], payload, n)
        at += _HDR2 + n + 2
    return bytes(out)


# (fields left zero are written as struct writes 0 / 0.0: diff_pressure, the sensor ids, ...)
def hil_sensor_rest(ax: float, ay: float, az: float, gx: float, gy: float, gz: float,
                    mx: float, my: float, mz: float, abs_hpa: float, p_alt: float,
                    temp_c: float, fields_updated: int) -> bytes:
    """HIL_SENSOR less time_usec: xacc..zmag, abs_pressure, diff_pressure 0, pressure_alt,
    temperature, fields_updated, id 0."""
    b = new_payload(_SENSOR_L.size)
    put_f(b, _SENSOR_L, 0, ax)
    put_f(b, _SENSOR_L, 1, ay)
    put_f(b, _SENSOR_L, 2, az)
    put_f(b, _SENSOR_L, 3, gx)
    put_f(b, _SENSOR_L, 4, gy)
    put_f(b, _SENSOR_L, 5, gz)
    put_f(b, _SENSOR_L, 6, mx)
    put_f(b, _SENSOR_L, 7, my)
    put_f(b, _SENSOR_L, 8, mz)
    put_f(b, _SENSOR_L, 9, abs_hpa)
    put_f(b, _SENSOR_L, 11, p_alt)
    put_f(b, _SENSOR_L, 12, temp_c)
    put_i(b, _SENSOR_L, 13, fields_updated)
    return done(b)


def flow_rest(dt_us: int, ix: float, iy: float, gx: float, gy: float, gz: float,
              quality: int) -> bytes:
    """HIL_OPTICAL_FLOW less time_usec: integration_time_us, integrated x, y, gyro x, y, z,
    time_delta_distance_us 0, distance -1 (the sensor has none of its own: the vehicle uses
    its altitude), temperature 0, sensor_id 0, quality."""
    b = new_payload(_FLOW_L.size)
    put_i(b, _FLOW_L, 0, dt_us)
    put_f(b, _FLOW_L, 1, ix)
    put_f(b, _FLOW_L, 2, iy)
    put_f(b, _FLOW_L, 3, gx)
    put_f(b, _FLOW_L, 4, gy)
    put_f(b, _FLOW_L, 5, gz)
    put_f(b, _FLOW_L, 7, -1.0)
    put_i(b, _FLOW_L, 10, quality)
    return done(b)


def range_covariance(noise_m: float) -> int:
    """DISTANCE_SENSOR's covariance for a range noise of standard deviation `noise_m`: the
    variance in cm^2 (common.xml: uint8, UINT8_MAX = unknown), at least 1 cm^2 for any noise
    (PX4 reads the field as the variance, covariance * 1e-4 m^2: a 0 would claim an exact
    sensor), 255 (unknown) when it exceeds 254 cm^2 (a standard deviation over 15.9 cm)."""
    var = (noise_m * 100.0) ** 2
    if not var > 0.0:
        return 0
    return min(255, max(1, round(var))) if var <= 254.0 else 255


def distance_rest(min_cm: int, max_cm: int, cur_cm: int, quality: int,
                  covariance: int) -> bytes:
    """DISTANCE_SENSOR less time_boot_ms: min, max, current (cm), type ultrasound, id 0,
    orientation down, covariance (cm^2, `range_covariance`), fovs and quaternion 0,
    signal_quality."""
    b = new_payload(_DIST_L.size)
    put_i(b, _DIST_L, 0, min_cm)
    put_i(b, _DIST_L, 1, max_cm)
    put_i(b, _DIST_L, 2, cur_cm)
    put_i(b, _DIST_L, 3, RANGE_ULTRASOUND)
    put_i(b, _DIST_L, 5, ORIENT_DOWN)
    put_i(b, _DIST_L, 6, covariance)
    put_i(b, _DIST_L, 13, quality)
    return done(b)


def gps_rest(lat_e7: int, lon_e7: int, alt_mm: int, eph_cm: int, vn_cms: int, ve_cms: int,
             vd_cms: int) -> bytes:
    vel = int(min(65534, (vn_cms * vn_cms + ve_cms * ve_cms) ** 0.5))
    return _GPS_REST(lat_e7, lon_e7, alt_mm, eph_cm, eph_cm * 2, vel, vn_cms, ve_cms,
                          vd_cms, 65535, 3, 10, 0, 0)


def truth_payload(t_us: int, qw: float, qx: float, qy: float, qz: float, p: float, q: float,
                  r: float, lat_e7: int, lon_e7: int, alt_mm: int, vn_cms: int, ve_cms: int,
                  vd_cms: int) -> bytes:
    """HIL_STATE_QUATERNION's whole payload (stamped t_us: the truth is sent the tick it is
    read, not delayed); airspeeds and accelerations 0."""
    b = new_payload(_TRUTH_L.size)
    put_i(b, _TRUTH_L, 0, t_us)
    put_f(b, _TRUTH_L, 1, qw)
    put_f(b, _TRUTH_L, 2, qx)
    put_f(b, _TRUTH_L, 3, qy)
    put_f(b, _TRUTH_L, 4, qz)
    put_f(b, _TRUTH_L, 5, p)
    put_f(b, _TRUTH_L, 6, q)
    put_f(b, _TRUTH_L, 7, r)
    put_i(b, _TRUTH_L, 8, lat_e7)
    put_i(b, _TRUTH_L, 9, lon_e7)
    put_i(b, _TRUTH_L, 10, alt_mm)
    put_i(b, _TRUTH_L, 11, vn_cms)
    put_i(b, _TRUTH_L, 12, ve_cms)
    put_i(b, _TRUTH_L, 13, vd_cms)
    return done(b)


def encode_hil_sensor(mav, t_us: int, acc: tuple, gyro: tuple, mag: tuple, abs_hpa: float,
                      p_alt: float, temp_c: float, fields: int) -> bytes:
    return stamped(mav, HIL_SENSOR, t_us, hil_sensor_rest(
        acc[0], acc[1], acc[2], gyro[0], gyro[1], gyro[2], mag[0], mag[1], mag[2], abs_hpa,
        p_alt, temp_c, fields))


def encode_flow(mav, t_us: int, dt_us: int, ix: float, iy: float, gx: float, gy: float,
                gz: float, quality: int) -> bytes:
    return stamped(mav, HIL_OPTICAL_FLOW, t_us, flow_rest(dt_us, ix, iy, gx, gy, gz, quality))


def encode_distance(mav, t_us: int, min_cm: int, max_cm: int, cur_cm: int,
                    quality: int, covariance: int = 255) -> bytes:
    return stamped(mav, DISTANCE_SENSOR, t_us,
                   distance_rest(min_cm, max_cm, cur_cm, quality, covariance))


class Payload:
    """One received message's payload read in place: field k of its wire order (arrays
    flattened, as pymavlink's tuple) as a float, `f(k)`, or an integer, `i(k)` (zero past a
    trimmed payload's end, as pymavlink). `data` is None while the message is absent."""

    __slots__ = ("lay", "data", "p0", "plen", "at", "end")

    def __init__(self, m: wire.FastMsg) -> None:
        self.lay = Layout(m.st.format)
        self.data = None
        self.p0 = self.plen = self.at = self.end = 0

    def f(self, k: int) -> float:
        return get_f(self.data, self.p0, self.plen, self.lay, k)

    def i(self, k: int) -> int:
        return get_i(self.data, self.p0, self.plen, self.lay, k)


class Bundle:
    """The sensor messages of one HIL datagram (`read`), kept and reused by the vehicle's
    estimator: a Payload each for HIL_SENSOR, HIL_OPTICAL_FLOW, DISTANCE_SENSOR and HIL_GPS
    (the last of each type if repeated), and `bad`, the number of frames that were not
    well-formed sensor messages (a datagram that is not all frames stops at the first thing
    that is not one, which counts). HIL_STATE_QUATERNION (the truth, for the simulator's logs;
    the vehicle never reads it) is checked like the others but not kept. Frames from another
    system than the simulator's (SIM_SYSID) are not read: `foreign` counts them."""

    __slots__ = ("imu", "flow", "rng", "gps", "bad", "foreign")

    def __init__(self) -> None:
        self.imu = Payload(HIL_SENSOR)
        self.flow = Payload(HIL_OPTICAL_FLOW)
        self.rng = Payload(DISTANCE_SENSOR)
        self.gps = Payload(HIL_GPS)
        self.bad = self.foreign = 0

    @cython.locals(i=cython.Py_ssize_t, n=cython.Py_ssize_t, end=cython.Py_ssize_t,
                   bad=cython.long, foreign=cython.long, mid=cython.long, m=wire.FastMsg,
                   v=Payload)
    def read(self, data: bytes) -> None:
        self.imu.data = self.flow.data = self.rng.data = self.gps.data = None
        bad = foreign = 0
        i, n = 0, len(data)
        while i < n:
            end = wire.frame_end(data, i)
            if end < 0:
                bad += 1
                break
            if data[i] == _MAGIC2 and data[i + 5] != _SIM_SYSID:
                foreign += 1               # another system's frame (a v1 frame: bad below)
                i = end
                continue
            mid = wire.msgid_of(data, i)
            v = None
            if mid == _ID_SENSOR:
                m, v = _M_SENSOR, self.imu
            elif mid == _ID_FLOW:
                m, v = _M_FLOW, self.flow
            elif mid == _ID_DIST:
                m, v = _M_DIST, self.rng
            elif mid == _ID_GPS:
                m, v = _M_GPS, self.gps
            elif mid == _ID_TRUTH:
                m = _M_TRUTH
            else:
                bad += 1
                i = end
                continue
            if not wire.frame_ok(m, data, i, end):
                bad += 1
            elif v is not None:
                v.data, v.p0, v.plen, v.at, v.end = data, i + _HDR2, data[i + 1], i, end
            i = end
        self.bad = bad
        self.foreign = foreign


    @cython.locals(i=cython.Py_ssize_t, m=wire.FastMsg, v=Payload, p=bytes)
    def take(self, parts: list) -> None:
        """The messages of parts = [message, payload, message, payload, ...] (`stamp_all`'s:
        the simulator's own, whole payloads, not framed) as `read` finds them in their frames:
        MIL's typed HIL exchange (cosim/sim/onboard.py)."""
        self.imu.data = self.flow.data = self.rng.data = self.gps.data = None
        for i in range(0, len(parts), 2):
            m = parts[i]
            p = parts[i + 1]
            if m is _M_SENSOR:
                v = self.imu
            elif m is _M_FLOW:
                v = self.flow
            elif m is _M_DIST:
                v = self.rng
            elif m is _M_GPS:
                v = self.gps
            else:                          # the truth (HIL_STATE_QUATERNION): not kept
                continue
            v.data, v.p0, v.plen, v.at, v.end = p, 0, len(p), 0, len(p)
        self.bad = 0
        self.foreign = 0


_SIM_SYSID = cython.declare(cython.long, SIM_SYSID)
_MAGIC2 = cython.declare(cython.long, wire.MAGIC_V2)
_M_SENSOR = cython.declare(wire.FastMsg, HIL_SENSOR)
_M_FLOW = cython.declare(wire.FastMsg, HIL_OPTICAL_FLOW)
_M_DIST = cython.declare(wire.FastMsg, DISTANCE_SENSOR)
_M_GPS = cython.declare(wire.FastMsg, HIL_GPS)
_M_TRUTH = cython.declare(wire.FastMsg, HIL_STATE_QUATERNION)
_ID_SENSOR = cython.declare(cython.long, HIL_SENSOR.id)
_ID_FLOW = cython.declare(cython.long, HIL_OPTICAL_FLOW.id)
_ID_DIST = cython.declare(cython.long, DISTANCE_SENSOR.id)
_ID_GPS = cython.declare(cython.long, HIL_GPS.id)
_ID_TRUTH = cython.declare(cython.long, HIL_STATE_QUATERNION.id)


@cython.locals(b=Bundle, v=Payload)
def decode_bundle(data: bytes) -> tuple[dict[int, tuple], int]:
    """The sensor frames of one HIL datagram as tuples: ({msgid: payload tuple in wire
    order}, number of frames that were not well-formed sensor messages), as `Bundle.read`
    finds them (HIL_STATE_QUATERNION checked, no entry); ({}, n) for anything else."""
    b = Bundle()
    b.read(data)
    out: dict[int, tuple] = {}
    for m, v in ((HIL_SENSOR, b.imu), (HIL_OPTICAL_FLOW, b.flow), (DISTANCE_SENSOR, b.rng),
                 (HIL_GPS, b.gps)):
        if v.data is not None:
            out[m.id] = wire.decode_fast(m, data, v.at, v.end)
    return out, b.bad


def is_sensor_bundle(data: bytes) -> bool:
    """Whether a HIL datagram starts with a HIL_SENSOR frame (the sensor-fed tick)."""
    return len(data) > 10 and data[0] == wire.MAGIC_V2 and wire.msgid_of(data) == HIL_SENSOR.id
