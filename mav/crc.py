"""MAVLink's checksum, CRC-16/MCRF4XX (X.25): what pymavlink computes, bit for bit.

`crc16(data)` is fastcrc's (pymavlink's own choice when installed; the table-driven loop below
without it). `crc_of(data, start, end, crc_extra)` is the per-frame checksum of the fast codec
(mav/wire.py): compiled, it runs over the frame's own buffer in C, four bytes per step, where
the call into fastcrc and the slice it needs cost more than the checksum of a short frame;
interpreted, it calls `crc16`. tests/test_onboard_wire.py compares both with pymavlink's bytes.
"""

from __future__ import annotations

import cython

try:  # pymavlink itself uses fastcrc when it is installed; so do we
    from fastcrc.crc16 import mcrf4xx as _mcrf4xx
except ImportError:  # pragma: no cover - the project pins fastcrc
    _mcrf4xx = None


# CRC-16/MCRF4XX (X.25, reflected polynomial 0x8408) tables for slicing by 4: _CRC_T[256 k + i]
# is the CRC register's change from byte i followed by k zero bytes (k = 0..3)
_CRC_T = cython.declare(cython.ushort[1024])


@cython.locals(i=cython.int, c=cython.uint, _j=cython.int)
def _crc_tables() -> None:
    for i in range(256):
        c = i
        for _j in range(8):
            c = (c >> 1) ^ 0x8408 if c & 1 else c >> 1
        _CRC_T[i] = c
    for i in range(256, 1024):
        c = _CRC_T[i - 256]
        _CRC_T[i] = (c >> 8) ^ _CRC_T[c & 0xFF]


_crc_tables()


@cython.cfunc
@cython.inline
@cython.exceptval(check=False)
@cython.returns(cython.uint)
@cython.locals(p=cython.p_uchar, start=cython.Py_ssize_t, end=cython.Py_ssize_t,
               crc=cython.uint, x=cython.uint, k=cython.Py_ssize_t)
def _x25(p, start: int, end: int, crc: int) -> int:
    """CRC-16/MCRF4XX (X.25) as MAVLink uses it, of p[start:end] continuing from `crc`: four
    bytes per step (slicing by 4), then byte by byte. Compiled: over a C buffer (`crc_of`);
    interpreted: over bytes, as the fallback when fastcrc is missing."""
    k = start
    while k + 4 <= end:
        x = crc ^ (p[k] | (p[k + 1] << 8))
        crc = (_CRC_T[768 + (x & 0xFF)] ^ _CRC_T[512 + (x >> 8)] ^ _CRC_T[256 + p[k + 2]]
               ^ _CRC_T[p[k + 3]])
        k += 4
    while k < end:
        crc = (crc >> 8) ^ _CRC_T[(crc ^ p[k]) & 0xFF]
        k += 1
    return crc


def _crc16_py(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/MCRF4XX of `data` (pure Python fallback)."""
    return _x25(data, 0, len(data), crc)  # pragma: no cover - the project pins fastcrc


crc16 = _mcrf4xx if _mcrf4xx is not None else _crc16_py


@cython.locals(start=cython.Py_ssize_t, end=cython.Py_ssize_t, crc=cython.uint,
               ex=cython.uchar, p=cython.p_uchar)
def crc_of(data, start: int, end: int, extra: int) -> int:
    """The checksum of a MAVLink frame whose CRC-covered bytes are data[start:end] (bytes or
    a bytearray): the CRC of them followed by the byte `extra` (the message's CRC_EXTRA).
    Compiled: in C over data's own buffer (no slice, no call into fastcrc); interpreted:
    `crc16` of the slice and CRC_EXTRA (a loop in Python would cost ~100x). Both check the
    span and the byte first and raise the same errors."""
    if not isinstance(data, (bytes, bytearray)):
        raise TypeError(f"crc_of: bytes or a bytearray, not {type(data).__name__}")
    if start < 0 or end > len(data) or start > end:
        raise IndexError("crc_of: span outside the data")
    if extra < 0 or extra > 255:
        raise ValueError("bytes must be in range(0, 256)")
    if not cython.compiled:
        return crc16(bytes(data[start:end]) + bytes((extra,)))
    if type(data) is bytes:
        p = cython.cast(cython.p_uchar, PyBytes_AS_STRING(data))        # noqa: F821
    else:
        p = cython.cast(cython.p_uchar, PyByteArray_AS_STRING(data))    # noqa: F821
    crc = _x25(p, start, end, 0xFFFF)
    ex = extra
    return _x25(cython.address(ex), 0, 1, crc)
