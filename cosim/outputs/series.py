"""Recording a run without growing memory: per-tick rows spooled to disk, one chunk at a time.

The tick loop appends one packed float64 row per tick (`SeriesSpool.pack`, `.append`) and
calls `flush()` every `CHUNK` ticks: the rows are written to a spool file as one block, and
the list is emptied. Memory stays at one chunk whatever the mission length. A finished run's
series (`SeriesFile`) is read back from the file: whole (a read-only memory map, for short runs
and tests), by column, or block by block (what the outputs use, so a long run's report does not
pull the whole file into memory either).

A spool whose disk is full (its folder is in TMPDIR: ENOSPC) loses nothing: the file is cut
back to its last whole block and the rows from there on are held in memory (`held`, `error`
says why; the master names TMPDIR in one line), up to `HELD_MAX` bytes (~1 simulated hour);
beyond that `flush` raises the disk's error and the run ends with what it recorded.
"""

from __future__ import annotations

import contextlib
import errno
import os
import struct
from collections.abc import Iterator
from pathlib import Path

import cython
import numpy as np

from cosim.plant.fmu import OUTPUT_NAMES

# the recorded columns, one row per tick (units: docs/outputs.md)
SERIES_COLUMNS = (
    ("t",) + OUTPUT_NAMES + ("u1", "u2", "u3", "u4", "est_x", "est_y", "est_z",
                             "sp_x", "sp_y", "sp_z", "phase")
)
COL = {name: i for i, name in enumerate(SERIES_COLUMNS)}
# a sensor-fed run's estimate per tick (cosim/sim/estimate.py records it; RunResult.estimate)
ESTIMATE_COLUMNS = ("est_x", "est_y", "est_z", "est_vx", "est_vy", "est_vz", "est_roll",
                    "est_pitch", "est_yaw", "est_lost")
CHUNK = 4096               # rows per spooled block (4096 x 30 x 8 B ~ 1 MB)
READ_BLOCK = 8192          # rows per block when reading back (~2 MB)
HELD_MAX = 1 << 30         # bytes of rows held in memory when the spool's disk is full


def pack10(p, a: float, b: float, c: float, d: float, e: float, f: float, g: float,
           h: float, i: float, j: float) -> int:
    """Ten doubles written at the C buffer p as `struct.pack("<10d", ...)` writes them
    (struct's own packer); compiled callers only (series.pxd), on a buffer they made."""
    PyFloat_Pack8(a, p, 1)            # noqa: F821
    PyFloat_Pack8(b, p + 8, 1)        # noqa: F821
    PyFloat_Pack8(c, p + 16, 1)       # noqa: F821
    PyFloat_Pack8(d, p + 24, 1)       # noqa: F821
    PyFloat_Pack8(e, p + 32, 1)       # noqa: F821
    PyFloat_Pack8(f, p + 40, 1)       # noqa: F821
    PyFloat_Pack8(g, p + 48, 1)       # noqa: F821
    PyFloat_Pack8(h, p + 56, 1)       # noqa: F821
    PyFloat_Pack8(i, p + 64, 1)       # noqa: F821
    PyFloat_Pack8(j, p + 72, 1)       # noqa: F821
    return 0


@cython.cfunc
@cython.inline
@cython.returns(cython.bint)
def _num(x) -> bool:
    """A value `pack` takes as it is (its float, or an int's)."""
    return type(x) is float or type(x) is int


class SeriesSpool:
    """Rows in, float64 blocks out to `path`. The per-tick call is `append(pack(*values))`:
    `pack` turns one row's `ncols` numbers into its float64 bytes in one C call (3x cheaper
    than a tuple per row turned into an array at flush), `append` keeps them until `flush`."""

    def __init__(self, path: Path, ncols: int = len(SERIES_COLUMNS)) -> None:
        self.path = Path(path)
        self.ncols = ncols
        self.pack = struct.Struct(f"<{ncols}d").pack
        self.rows: list[bytes] = []
        self.append = self.rows.append
        self.ticks = 0                       # rows already written to the file
        self.held: list[bytes] = []          # blocks the file could not take (disk full)
        self.held_bytes = 0
        self.error: OSError | None = None    # why rows are held
        # unbuffered: a write that fails leaves nothing behind in a buffer to fail again
        self._f = open(self.path, "wb", buffering=0)  # noqa: SIM115 (closed in finish())

    @cython.locals(n=cython.Py_ssize_t, i=cython.Py_ssize_t, p=cython.p_char, yl=list)
    def row(self, t: float, y: list, u1: float, u2: float, u3: float, u4: float, m0: float,
            m1: float, m2: float, s0: float, s1: float, s2: float, ph: float) -> bytes:
        """One tick's row of SERIES_COLUMNS as `pack` makes it: t, the plant's outputs y, the
        motor commands, the estimate, the setpoint, the phase index. Compiled, y's floats are
        written straight into the row (struct's own packer, PyFloat_Pack8), without a tuple of
        the values; anything else (a y that is not a list of floats or of another length, a
        value that is not a float or an int) goes through `pack`, its result and its errors."""
        if (cython.compiled and type(y) is list and len(y) + 12 == self.ncols
                and _num(t) and _num(u1) and _num(u2) and _num(u3) and _num(u4) and _num(m0)
                and _num(m1) and _num(m2) and _num(s0) and _num(s1) and _num(s2)
                and _num(ph)):
            yl = y
            n = len(yl)
            for i in range(n):
                if type(yl[i]) is not float:
                    break
            else:
                out = PyBytes_FromStringAndSize(cython.NULL, 8 * (n + 12))    # noqa: F821
                p = PyBytes_AS_STRING(out)                                     # noqa: F821
                PyFloat_Pack8(t, p, 1)                                         # noqa: F821
                for i in range(n):
                    PyFloat_Pack8(yl[i], p + 8 * (i + 1), 1)                   # noqa: F821
                p += 8 * (n + 1)
                pack10(p, u1, u2, u3, u4, m0, m1, m2, s0, s1, s2)
                PyFloat_Pack8(ph, p + 80, 1)                                   # noqa: F821
                return out
        return self.pack(t, *y, u1, u2, u3, u4, m0, m1, m2, s0, s1, s2, ph)

    def flush(self) -> None:
        rows = self.rows
        if not rows:
            return
        data = b"".join(rows)
        n = len(rows)
        rows.clear()
        if self.error is None:
            try:
                view = memoryview(data)
                while view:                  # a raw write may take part of it
                    view = view[self._f.write(view):]
                self.ticks += n
                return
            except OSError as exc:           # ENOSPC: cut back to the last whole block
                self.error = exc
                with contextlib.suppress(OSError):
                    os.ftruncate(self._f.fileno(), self.ticks * 8 * self.ncols)
                    self._f.seek(0, os.SEEK_END)
        if self.held_bytes + len(data) > HELD_MAX:
            rows.append(data)                # kept for finish(): what fits in memory is all
            raise OSError(self.error.errno or errno.ENOSPC,
                          f"{self.error.strerror} (the spool's folder {self.path.parent}; "
                          f"{HELD_MAX >> 20} MB of rows held in memory already)")
        self.held.append(data)
        self.held_bytes += len(data)

    def since(self, start: int) -> bytes:
        """The rows from row `start` on (file, held, then the rows not written yet)."""
        rb = 8 * self.ncols
        out = []
        if start < self.ticks:
            with open(self.path, "rb") as f:
                f.seek(start * rb)
                out.append(f.read((self.ticks - start) * rb))
            start = self.ticks
        skip = (start - self.ticks) * rb
        for block in (*self.held, b"".join(self.rows)):
            if skip < len(block):
                out.append(block[skip:])
                skip = 0
            else:
                skip -= len(block)
        return b"".join(out)

    def finish(self) -> SeriesFile:
        """Write what is left and close; the recorded series, read from the file (and the
        rows held in memory)."""
        if not self._f.closed:
            if self.rows and self.held_bytes <= HELD_MAX:
                with contextlib.suppress(OSError):     # past HELD_MAX: held as they are
                    self.flush()
            self.held.extend(self.rows)
            self.rows.clear()
            self._f.close()
        held = b"".join(self.held)
        return SeriesFile(self.path, self.ncols, self.ticks + len(held) // (8 * self.ncols),
                          held=held, error=self.error)


class SeriesFile:
    """A recorded series on disk: `ticks` rows of `ncols` float64 values (the last of them in
    memory, `held`, when the disk was full: `error`)."""

    def __init__(self, path: Path, ncols: int, ticks: int, held: bytes = b"",
                 error: OSError | None = None) -> None:
        self.path, self.ncols, self.ticks = Path(path), ncols, ticks
        self.held, self.error = held, error
        self.on_disk = ticks - len(held) // (8 * ncols)   # rows in the file (then: held)
        self._map: np.ndarray | None = None

    def __len__(self) -> int:
        return self.ticks

    def array(self) -> np.ndarray:
        """All of it as a read-only (ticks, ncols) array, memory-mapped (pages load on use;
        in memory when some rows are held there)."""
        if self._map is None:
            if self.ticks == 0:
                self._map = np.empty((0, self.ncols))
            elif self.held:
                self._map = np.concatenate(list(self.blocks()))
            else:
                self._map = np.memmap(self.path, dtype=np.float64, mode="r",
                                      shape=(self.ticks, self.ncols))
        return self._map

    def blocks(self, rows: int = READ_BLOCK) -> Iterator[np.ndarray]:
        """Consecutive (<= rows, ncols) arrays, read with plain file reads (no mapping), then
        the rows held in memory."""
        with open(self.path, "rb") as f:
            left = self.on_disk
            while left > 0:
                n = min(rows, left)
                yield np.fromfile(f, dtype=np.float64, count=n * self.ncols).reshape(
                    n, self.ncols)
                left -= n
        held = np.frombuffer(self.held, dtype=np.float64).reshape(-1, self.ncols)
        for i in range(0, len(held), rows):
            yield held[i:i + rows]

    def decimated(self, max_rows: int = 20_000) -> np.ndarray:
        """Every n-th row so that at most about `max_rows` remain (all rows of a short run)."""
        step = max(1, -(-self.ticks // max_rows))
        parts, offset = [], 0
        for b in self.blocks():
            first = (-offset) % step
            parts.append(b[first::step].copy())   # a copy: a view would keep the block
            offset += len(b)
        return np.concatenate(parts) if parts else np.empty((0, self.ncols))

    def columns(self, *names: str) -> tuple[np.ndarray, ...]:
        """Whole columns by name, read block by block (memory: the columns asked for)."""
        idx = [COL[n] for n in names]
        out = [np.empty(self.ticks) for _ in idx]
        i = 0
        for b in self.blocks():
            for o, j in zip(out, idx, strict=True):
                o[i:i + len(b)] = b[:, j]
            i += len(b)
        return tuple(out)
