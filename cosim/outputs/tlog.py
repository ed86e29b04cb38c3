"""MAVLink telemetry logs (.tlog): every datagram with an 8-byte big-endian microsecond stamp.

pymavlink's `setup_logfile` writes nothing on UDP links, so the master taps the links itself.
Stamps are simulation time (us since t = 0), so the log of a run is deterministic.
`mavlogdump.py flight.tlog` and MAVExplorer read the result.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import struct
from pathlib import Path

_STAMP = struct.Struct(">Q")


class Tlog:
    """A tlog streamed to `path` as the datagrams pass (memory stays flat); `t_us` is the stamp
    the master sets each tick, `count` the datagrams logged."""

    __slots__ = ("path", "t_us", "count", "error", "_f", "_write", "_stamp_us", "_stamp")

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.t_us = 0
        self._stamp_us = 0                     # the stamp packed last (a tick's datagrams
        self._stamp = _STAMP.pack(0)           # share it)
        self.count = 0
        self.error: OSError | None = None      # a write that failed (disk full): see close()
        # through pathlib (io.open at call time), not the open builtin a compiled module binds
        # when imported: tests/test_nothing_lost.py's full disk then reaches this file too
        self._f = self.path.open("wb", buffering=1 << 16)  # noqa: SIM115 (closed in close())
        self._write = self._f.write

    def add(self, data: bytes) -> None:
        if self.t_us != self._stamp_us:
            self._stamp = _STAMP.pack(self.t_us)
            self._stamp_us = self.t_us
        self._write(self._stamp + data)
        self.count += 1

    def close(self) -> None:
        """Close the file. A write that fails (disk full) does not raise here: `error` keeps
        it and the file is cut back to its last whole record, so what it holds reads."""
        if self._f.closed:
            return
        try:
            self._f.close()
        except OSError as exc:
            self.error = exc
        if self.error is not None:
            with contextlib.suppress(OSError):
                keep_whole_records(self.path)

    def flush(self) -> None:
        """Write what the buffer holds (a run killed later keeps the log up to here). A write
        that fails (disk full) does not raise: `error` keeps it, as in `close`."""
        if self._f.closed or self.error is not None:
            return
        try:
            self._f.flush()
        except OSError as exc:
            self.error = exc

    def read(self) -> bytes:
        """Everything logged so far."""
        if not self._f.closed:
            self._f.flush()
        return self.path.read_bytes()

    def write(self, path: Path) -> None:
        """Copy the log to `path` (nothing to do when it is already there)."""
        path = Path(path)
        if path.resolve() != self.path.resolve():
            if not self._f.closed:
                self._f.flush()
            shutil.copyfile(self.path, path)


class TapLink:
    """Wraps a link; every datagram sent or received is appended to a Tlog."""

    __slots__ = ("inner", "log")

    def __init__(self, inner, log: Tlog) -> None:
        self.inner = inner
        self.log = log

    def send(self, data: bytes) -> None:
        self.log.add(data)
        self.inner.send(data)

    def recv(self) -> bytes | None:
        data = self.inner.recv()
        if data is not None:
            self.log.add(data)
        return data

    def close(self) -> None:
        self.inner.close()


def tap(inner, log: Tlog) -> TapLink:
    """A TapLink on `inner`."""
    return TapLink(inner, log)


def keep_whole_records(path: Path) -> int:
    """Cut a tlog after its last whole record (a write that failed midway); its new size."""
    raw = Path(path).read_bytes()
    i = 0
    while i + 10 <= len(raw):
        b = raw[i + 8]
        if b == 0xFD:
            n = 12 + raw[i + 9] + (13 if i + 10 < len(raw) and raw[i + 10] & 1 else 0)
        elif b == 0xFE:
            n = 8 + raw[i + 9]
        else:
            break
        if i + 8 + n > len(raw):
            break
        i += 8 + n
    if i != len(raw):
        os.truncate(path, i)
    return i


def read_tlog(path: Path) -> list[tuple[int, bytes]]:
    """Split a tlog into (t_us, datagram) records (for tests and tools)."""
    raw = Path(path).read_bytes()
    out = []
    i = 0
    while i + 8 <= len(raw):
        (t,) = _STAMP.unpack_from(raw, i)
        i += 8
        # a MAVLink 2 frame: 0xFD, len, ..., or MAVLink 1: 0xFE, len
        if raw[i] == 0xFD:
            n = 12 + raw[i + 1] + (13 if raw[i + 2] & 1 else 0)
        elif raw[i] == 0xFE:
            n = 8 + raw[i + 1]
        else:
            raise ValueError(f"{path}: not a MAVLink frame at byte {i}")
        out.append((t, raw[i:i + n]))
        i += n
    return out
