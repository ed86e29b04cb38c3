"""The simulator's end of the HIL link: ODOMETRY out, HIL_ACTUATOR_CONTROLS in (and, from
the fault injector, battery failures: `encode_inject_failure`).

The simulator speaks as its own MAVLink system (SIM_SYSID, MAV_COMP_ID_SYSTEM_CONTROL), like
PX4 SITL's simulator bridge. ODOMETRY carries float position (world NED), the body->world
quaternion, world-NED velocity (child_frame_id = MAV_FRAME_LOCAL_NED) and body rates.
Both directions use the fast codec of mav/wire.py (byte-identical to pymavlink's, tested).
"""

from __future__ import annotations

import math
import struct

import cython
from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.fields import Layout, copy_of, done, f32, put_f, put_i

SIM_SYSID = 250
SIM_COMPID = mavlink2.MAV_COMP_ID_SYSTEM_CONTROL
# The lockstep clock: a HIL datagram that would make a tick (ODOMETRY, or a sensor datagram
# led by HIL_SENSOR) must be stamped later than the last tick, by at most HIL_MAX_STEP_US.
# 20 ms: PX4's EKF never integrates a longer IMU interval (ecl's EstimatorInterface::setIMUData
# constrains it to 0.1..20 ms), a lockstep simulator at 50 Hz or more stays within it (this
# project's steps by 5 ms and never skips a tick: a real-time stall moves the wall clock, not
# the stamps), and it is shorter than every timer of the vehicle (COM_OF_LOSS_T >= 0.1 s, the
# land detector's 0.2 s), so no one datagram can fire a timer or step the battery by more
# than 20 ms of flight. A simulator whose clock jumps further (a restart) restarts the vehicle.
HIL_MAX_STEP_US = 20_000


def tick_refusal(sysid: int, t_us: int, last_us: int) -> str | None:
    """Why a HIL datagram of system `sysid` stamped t_us (us) cannot be the tick after the one
    at last_us (-1: no tick yet, any stamp starts the clock): the vehicle's counter of such
    drops, or None (a tick). Another system than the simulator's: `dropped_foreign_hil`; a
    stamp not later than the last (a repeat, a replay, a clock gone back):
    `dropped_stale_hil`; later by more than HIL_MAX_STEP_US: `dropped_jump_hil`."""
    if sysid != SIM_SYSID:
        return "dropped_foreign_hil"
    if last_us < 0:
        return None
    if t_us <= last_us:
        return "dropped_stale_hil"
    if t_us - last_us > HIL_MAX_STEP_US:
        return "dropped_jump_hil"
    return None
INJECT_COMPID = mavlink2.MAV_COMP_ID_USER1   # the simulator's fault injector (own sequence)
MAX_R_SCALE = 1000.0       # battery sag: the largest resistance factor the vehicle accepts
MAX_V_DROP = 100.0         # V, battery sag: the largest fixed drop

# ODOMETRY payload = time_usec and the 13 measured values, then a tail that is the same every
# tick (covariances [NaN, 0, ...], frame ids, reset counter, estimator type, quality): the
# frame of a tick is a copy of a template frame holding that tail, written in place (the head
# with mav/fields.py, the header and checksum with wire.put_frame)
_ODO_PAYLOAD = wire.ODOMETRY.st.pack(0, *(0.0,) * 13, math.nan, *(0.0,) * 20, math.nan,
                                     *(0.0,) * 20, mavlink2.MAV_FRAME_LOCAL_NED,
                                     mavlink2.MAV_FRAME_LOCAL_NED, 0, 1, 100)
_ODO_N = cython.declare(cython.Py_ssize_t, len(_ODO_PAYLOAD))   # never trimmed: quality != 0
_HDR = cython.declare(cython.Py_ssize_t, wire.HEADER_LEN_V2)
_ODO_T = cython.declare(bytes, bytes(_HDR) + _ODO_PAYLOAD + bytes(2))
_ODO_T_LOST = cython.declare(bytes, _ODO_T[:_HDR + _ODO_N - 1] + struct.pack("<b", -1)
                             + bytes(2))                      # quality -1: the estimate failed
_ODO_L = cython.declare(Layout, Layout(wire.ODOMETRY.st.format, _HDR))
_ODO_MSG = cython.declare(wire.FastMsg, wire.ODOMETRY)


def odometry(mav, t_us: int, m: tuple[float, ...], lost: bool) -> bytes:
    """ODOMETRY of m = (x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r) on mav: the same bytes as
    `wire.encode_odometry(mav, t_us, *m, estimator_type=1, quality=100)` (quality -1 if
    `lost`). The simulator's truth (`odometry_of` the tuple)."""
    return odometry_of(mav, t_us, m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9],
                       m[10], m[11], m[12], lost)


@cython.locals(seq=cython.int)
def odometry_of(mav, t_us: int, x: float, y: float, z: float, qw: float, qx: float,
                qy: float, qz: float, vx: float, vy: float, vz: float, p: float, q: float,
                r: float, lost: bool) -> bytes:
    """`odometry` of C values: the onboard estimator's estimate (mav/estimator/core.py)."""
    out = copy_of(_ODO_T_LOST if lost else _ODO_T)
    put_i(out, _ODO_L, 0, t_us)
    put_f(out, _ODO_L, 1, x)
    put_f(out, _ODO_L, 2, y)
    put_f(out, _ODO_L, 3, z)
    put_f(out, _ODO_L, 4, qw)
    put_f(out, _ODO_L, 5, qx)
    put_f(out, _ODO_L, 6, qy)
    put_f(out, _ODO_L, 7, qz)
    put_f(out, _ODO_L, 8, vx)
    put_f(out, _ODO_L, 9, vy)
    put_f(out, _ODO_L, 10, vz)
    put_f(out, _ODO_L, 11, p)
    put_f(out, _ODO_L, 12, q)
    put_f(out, _ODO_L, 13, r)
    if mav.signing.sign_outgoing:
        return wire.frame(mav, _ODO_MSG, bytes(out[_HDR:_HDR + _ODO_N]))
    seq = mav.seq
    mav.seq = (seq + 1) & 0xFF
    wire.put_frame(out, 0, seq, mav.srcSystem, mav.srcComponent, _ODO_MSG, None, _ODO_N)
    return done(out)


_FRAME_LOCAL_NED = cython.declare(cython.int, mavlink2.MAV_FRAME_LOCAL_NED)


def odometry_record(t_us: int, x: float, y: float, z: float, qw: float, qx: float,
                    qy: float, qz: float, vx: float, vy: float, vz: float, p: float, q: float,
                    r: float, lost: bool) -> tuple:
    """What the vehicle's tick reads (`wire.decode_odometry`) from `odometry_of`'s frame of
    the same values, without the frame: (time_usec, x .. r each rounded to a float as the
    frame carries it, frame ids LOCAL_NED, quality 100, -1 if `lost`). MIL's typed HIL
    exchange (cosim/sim/onboard.py), tested to give the framed path's flights."""
    return (t_us, f32(x), f32(y), f32(z), f32(qw), f32(qx), f32(qy), f32(qz), f32(vx),
            f32(vy), f32(vz), f32(p), f32(q), f32(r), _FRAME_LOCAL_NED, _FRAME_LOCAL_NED,
            -1 if lost else 100)


class HilSimulatorCodec:
    def __init__(self) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=SIM_SYSID, srcComponent=SIM_COMPID)

    def encode_odometry(self, t_us: int, m: tuple[float, ...]) -> bytes:
        """m = (x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r), SI, NED/FRD (`odometry`)."""
        return odometry(self.mav, t_us, m, False)

    def encode_odometry_lost(self, t_us: int, m: tuple[float, ...]) -> bytes:
        """The same with quality -1 (MAVLink: odometry has failed): the position and velocity
        in `m` are stale, attitude and rates live (a fault: cosim.faults.core)."""
        return odometry(self.mav, t_us, m, True)

    def record_odometry(self, t_us: int, m: tuple[float, ...]) -> tuple:
        """`encode_odometry` as the typed record the vehicle reads (`odometry_record`)."""
        return odometry_record(t_us, m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8],
                               m[9], m[10], m[11], m[12], False)

    def record_odometry_lost(self, t_us: int, m: tuple[float, ...]) -> tuple:
        return odometry_record(t_us, m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8],
                               m[9], m[10], m[11], m[12], True)

    def decode_record(self, ans: tuple) -> tuple[int, float, float, float, float]:
        """(t_us, u1..u4) of the vehicle's typed answer (`Onboard.step_record`)."""
        return ans[0]

    def decode_actuators(self, data: bytes) -> tuple[int, float, float, float, float]:
        f = wire.decode_hil_actuator_controls(data)
        if f is None:
            raise ValueError(f"not a valid HIL_ACTUATOR_CONTROLS frame ({len(data)} bytes)")
        return f


def encode_inject_failure(mav, failure_type: int, param4: float = 0.0,
                          param5: float = 0.0) -> bytes:
    """COMMAND_LONG MAV_CMD_INJECT_FAILURE for the vehicle's battery, to whoever is on the HIL
    link (target 0/0): FAILURE_TYPE_OK (0) ends a sag, OFF (1) drops the charge to param4
    (0..1), WRONG (4) sags the voltage (resistance x param4, minus param5 V). The contract and
    the project's use of the reserved param4/5: `mav/onboard/inject.py`. `mav`: a MAVLink
    instance of (SIM_SYSID, INJECT_COMPID)."""
    return wire.send_msg(mav, mavlink2.MAVLink_command_long_message(
        0, 0, mavlink2.MAV_CMD_INJECT_FAILURE, 0, mavlink2.FAILURE_UNIT_SYSTEM_BATTERY,
        failure_type, 0, param4, param5, 0, 0))
