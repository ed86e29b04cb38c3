"""The master's end of a sensor-fed HIL link (`[sensors] feed = "hil"`): the sensor models'
datagram out, HIL_ACTUATOR_CONTROLS and the vehicle's estimate (ODOMETRY, after it in the same
datagram) back. The estimate is logged per tick beside the truth: in the series' est_x/y/z
columns (world NED, as the truth) and in full (`array()`: ESTIMATE_COLUMNS) for the outputs.

It is both the sensor and the codec of the master's tick (cosim/sim/tick.py `Tick`):
`measure(y)` (the list the tick records as est_x/y/z, filled in by `decode_actuators` of the
same tick), `encode_odometry(t_us, meas)` (the sensor datagram; `encode_odometry_lost` is the
same: a sensor-fed vehicle loses its position through the sensor faults) and
`decode_actuators(ans)`; for MIL's typed exchange (cosim/sim/onboard.py) `record_odometry`
and `decode_record`, the same without the frames.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import cython
import numpy as np

from cosim import tempdirs
from cosim.outputs.series import CHUNK, ESTIMATE_COLUMNS, SeriesSpool
from cosim.sensors.suite import SensorSuite
from mav import wire
from mav.fields import Layout, get_f, get_i
from mav.rotations import euler_from_quat

# a row of the estimate (doubles), and the answer's ODOMETRY read in place (fields by index:
# 0 time_usec, 1-3 x y z, 4-7 q, 8-10 vx vy vz, ..., 60 quality)
_ROW = struct.Struct(f"<{len(ESTIMATE_COLUMNS)}d")          # a row of the estimate log
assert _ROW.size == 80
_NAN_ROW = _ROW.pack(*[math.nan] * len(ESTIMATE_COLUMNS))   # an answer without an estimate
_ODO = cython.declare(wire.FastMsg, wire.ODOMETRY)
_ODO_L = cython.declare(Layout, Layout(wire.ODOMETRY.st.format))
_QUALITY = cython.declare(cython.Py_ssize_t, _ODO_L.n - 1)
_HDR = cython.declare(cython.Py_ssize_t, wire.HEADER_LEN_V2)


def floor_textured(world) -> bool:
    """`flow_floor = "auto"`: a room's floor by its texture (a plain one gives the flow
    nothing); a flat world's floor is textured: it stands in for the Minidrone template's
    aerial photograph (MWAerial.png) under the track, its one colour is for the camera's line
    detection only. `flow_floor = "plain"` makes the flow fail."""
    room = world.scene.room
    return room is None or room.floor.kind != "plain"


class SensorFeed:
    """`spool`: the file the estimate rows go to, a chunk at a time (memory does not grow with
    the mission, as the series'); None: a temporary file, removed when the feed is. `keep`
    False: the rows are dropped a chunk at a time instead (cosim sitl, which runs for hours:
    its series' odometry columns hold the estimate)."""

    def __init__(self, sc, h: float, spool: Path | None = None, keep: bool = True) -> None:
        spec = sc.sensors
        floor = spec.flow_floor
        textured = floor_textured(sc.world) if floor == "auto" else floor == "textured"
        faults = getattr(sc.faults, "sensors", ()) or ()
        self.home = (sc.start.n, sc.start.e)
        self._make = lambda: SensorSuite(spec, sc.seed, h, self.home, textured, faults)
        self.suite = self._make()
        self.keep = keep
        self.est = [math.nan, math.nan, math.nan]
        self._y = None
        if spool is None:
            self._tmp = tempdirs.folder("estimate")
            spool = Path(self._tmp.name) / "estimate.f64"
        self.spool = SeriesSpool(spool, len(ESTIMATE_COLUMNS))
        self.rows: list[bytes] = self.spool.rows
        self.bad_answers = 0

    def measure(self, y) -> list[float]:
        self._y = y
        if len(self.rows) >= CHUNK:
            if self.keep:
                self.spool.flush()
            else:
                self.rows.clear()
        return self.est

    def reset(self) -> None:
        """The sensors as at the start (a respawned vehicle: the plant reset, the flight stack
        rebooted): their filters, delay line and noise streams."""
        self.suite = self._make()

    def close(self) -> None:
        """The spool closed and a temporary one removed (idempotent)."""
        self.spool.finish()
        tmp = getattr(self, "_tmp", None)
        if tmp is not None:
            tmp.cleanup()

    def encode_odometry(self, t_us: int, meas) -> bytes:
        return self.suite.encode(t_us, self._y)

    encode_odometry_lost = encode_odometry

    @cython.locals(end=cython.Py_ssize_t, n=cython.Py_ssize_t, p0=cython.Py_ssize_t,
                   plen=cython.Py_ssize_t)
    def decode_actuators(self, ans: bytes) -> tuple[int, float, float, float, float]:
        """(t_us, u1..u4) of the answer's HIL_ACTUATOR_CONTROLS (ValueError if it has none,
        as HilSimulatorCodec's); its estimate (if any: the ODOMETRY after it, the checks of
        wire.decode_odometry, its fields read in place) is logged."""
        end = wire.frame_end(ans, 0)
        act = wire.decode_hil_actuator_controls(ans, 0, end) if end > 0 else None
        if act is None:
            raise ValueError(f"not a valid HIL_ACTUATOR_CONTROLS frame ({len(ans)} bytes)")
        n = len(ans)
        if end >= n or not wire.frame_ok(_ODO, ans, end, n):
            self._log_none()
            return act
        p0, plen = end + _HDR, ans[end + 1]
        _log_row(self.rows, self.est, self.home[0], self.home[1],
                 get_f(ans, p0, plen, _ODO_L, 1), get_f(ans, p0, plen, _ODO_L, 2),
                 get_f(ans, p0, plen, _ODO_L, 3), get_f(ans, p0, plen, _ODO_L, 4),
                 get_f(ans, p0, plen, _ODO_L, 5), get_f(ans, p0, plen, _ODO_L, 6),
                 get_f(ans, p0, plen, _ODO_L, 7), get_f(ans, p0, plen, _ODO_L, 8),
                 get_f(ans, p0, plen, _ODO_L, 9), get_f(ans, p0, plen, _ODO_L, 10),
                 get_i(ans, p0, plen, _ODO_L, _QUALITY) < 0, False)
        return act

    def record_odometry(self, t_us: int, meas) -> list:
        """MIL's typed exchange (cosim/sim/onboard.py): the messages of `encode_odometry`'s
        datagram the vehicle reads, not framed (the truth, for logs, left out)."""
        return self.suite.messages(t_us, self._y, False)

    record_odometry_lost = record_odometry

    def decode_record(self, ans: tuple) -> tuple[int, float, float, float, float]:
        """`decode_actuators` of the vehicle's typed answer (`Onboard.step_record`):
        (t_us, u1..u4), its estimate logged."""
        od = ans[1]
        if od is None:
            self._log_none()
        else:
            _log_row(self.rows, self.est, self.home[0], self.home[1], od[1], od[2], od[3],
                     od[4], od[5], od[6], od[7], od[8], od[9], od[10], od[16] < 0, False)
        return ans[0]

    def _log_none(self) -> None:
        """An answer without an estimate: NaN logged (counted in `bad_answers`)."""
        self.bad_answers += 1
        _log_row(self.rows, self.est, 0.0, 0.0, math.nan, math.nan, math.nan, 1.0, 0.0, 0.0, 0.0,
             math.nan, math.nan, math.nan, False, True)

    def array(self) -> np.ndarray:
        """The estimate rows of the run so far, (ticks, ESTIMATE_COLUMNS): the spool closed
        and read back (a read-only memory map)."""
        return self.spool.finish().array()

    def fired(self) -> list[tuple[float, str]]:
        return list(self.suite.fired)


@cython.cfunc
@cython.exceptval(-1)
@cython.returns(cython.int)
@cython.locals(rows=list, est=list, home_n=cython.double, home_e=cython.double,
               x=cython.double, y=cython.double, z=cython.double, qw=cython.double,
               qx=cython.double, qy=cython.double, qz=cython.double, vx=cython.double,
               vy=cython.double, vz=cython.double, lost=cython.bint, none=cython.bint,
               roll=cython.double, pitch=cython.double, yaw=cython.double,
               flag=cython.double, p=cython.p_char)
def _log_row(rows: list, est: list, home_n: float, home_e: float, x: float, y: float, z: float,
         qw: float, qx: float, qy: float, qz: float, vx: float, vy: float, vz: float,
         lost: bool, none: bool) -> int:
    """One row of the estimate log (ESTIMATE_COLUMNS) appended to `rows`, its position in
    `est`: the estimate's (x, y in its local frame, shifted by home to world NED), or NaN in
    every column (`none`: an answer without an estimate). (A C call when compiled: a tick's
    ten doubles are not boxed.)"""
    if none:
        est[0] = est[1] = est[2] = math.nan
        rows.append(_NAN_ROW)
        return 0
    x += home_n
    y += home_e
    est[0], est[1], est[2] = x, y, z
    roll, pitch, yaw = euler_from_quat(qw, qx, qy, qz)
    flag = 1.0 if lost else 0.0
    if not cython.compiled:
        rows.append(_ROW.pack(x, y, z, vx, vy, vz, roll, pitch, yaw, flag))
        return 0
    # compiled: the ten doubles written as _ROW packs them (struct's own packer) into a new
    # bytes object, which nothing else holds until it is appended
    row = PyBytes_FromStringAndSize(cython.NULL, 80)     # noqa: F821
    p = PyBytes_AS_STRING(row)                            # noqa: F821
    pack10(p, x, y, z, vx, vy, vz, roll, pitch, yaw, flag)   # noqa: F821
    rows.append(row)
    return 0
