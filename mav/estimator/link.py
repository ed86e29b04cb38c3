"""The estimator between the vehicle's HIL link and its tick (TPL_EST_TYPE 1).

PX4's EKF2 publishes its estimate on uORB (`vehicle_odometry`) for the controllers to read;
here the estimator hands the vehicle's tick its estimate as the ODOMETRY frame the tick already
reads, so the tick (`Onboard.poll`) is unchanged:

- `recv()`: a sensor datagram (HIL_SENSOR first) from the simulator -> the estimator runs ->
  an ODOMETRY of the estimate stamped with the HIL_SENSOR's time_usec (quality -1 when the
  position estimate is lost); a sensor datagram the estimator refused (not the next tick:
  `mav.hil.tick_refusal`, counted there) -> None, as if nothing had come (it is counted in
  `rx_hil` too); anything else passes through untouched;
- `send(data)`: the tick's HIL answer, followed (after a sensor tick) by that ODOMETRY, so the
  simulator logs the estimate beside the truth;
- `decoded(data)`: the tick's decoder of what `recv` returned (`wire.decode_odometry`'s
  fields): of the frame it has just made, read from it without checking it again.
"""

from __future__ import annotations

from typing import Any

from mav import wire

_ODO_LEN = wire.HEADER_LEN_V2 + wire.ODOMETRY_USED.size + 2   # the frame untrimmed, unsigned
_ODO_READ = wire.ODOMETRY_USED.unpack_from


class EstimatorLink:
    __slots__ = ("inner", "est", "mav", "_frame")

    def __init__(self, inner, estimator, mav) -> None:
        self.inner = inner            # the HIL link (count_kernel_drops walks `inner`)
        self.est = estimator
        self.mav = mav                # the vehicle's HIL MAVLink instance (its sysid)
        self._frame = b""             # the estimate of the last sensor tick, for the answer

    def recv(self) -> bytes | None:
        data = self.inner.recv()
        if data is None:
            return None
        est = self.est
        if not est.estimate(data):    # ODOMETRY (motion capture), a fault command, garbage
            self._frame = b""
            if est.refused:           # not the next tick (counted by its reason): no tick
                est.stats["rx_hil"] = est.stats.get("rx_hil", 0) + 1
                return None
            return data
        self._frame = fr = est.odometry(self.mav)   # quality -1 when lost
        return fr

    def made(self, data: bytes) -> bool:
        """Whether `data` is the ODOMETRY this link made of the estimate (the vehicle's own
        system's frame, not the simulator's)."""
        return data is self._frame

    def decoded(self, data: bytes) -> tuple | None:
        if data is self._frame and len(data) == _ODO_LEN:
            return _ODO_READ(data, wire.HEADER_LEN_V2)
        return wire.decode_odometry(data)

    def send(self, data: bytes) -> None:
        fr = self._frame
        if fr:
            self._frame = b""
            data = data + fr
        self.inner.send(data)

    def __getattr__(self, name: str) -> Any:     # pending, close, local_address, ...
        if name in EstimatorLink.__slots__:       # not set (before __init__): no recursion,
            raise AttributeError(name)            # which compiled would overflow the C stack
        return getattr(self.inner, name)
