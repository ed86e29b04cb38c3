"""A MAVLink payload's fields written and read one at a time as C values.

`Layout(fmt)` is a payload's layout from its `struct` format (pymavlink's, e.g. HIL_SENSOR's
"<Q13fIB": little-endian, packed, arrays flattened): each field's offset and type code.
`put_f` / `put_i` write field k of a payload being built (a `bytearray` of its own:
`new_payload(n)` or `copy_of(template)`, then `done` for its bytes), and
`get_f` / `get_i` read field k of a received frame's payload in place, zero-extended past its
(trimmed) length as pymavlink does. The bytes are `struct`'s, bit for bit: floats go through
the functions `struct` itself uses (`PyFloat_Pack4` / `PyFloat_Unpack4`, the same rounding, the
same OverflowError for a finite value too large for a float), integers out of their field's
range raise `struct.error`. Why: a per-tick message packed by `struct` boxes every value into
a Python float and unboxes it again; written here from C doubles it is not (compiled).
Interpreted, every function is `struct.pack_into` / `unpack_from` of the one field.
Both builds check every index, offset and length first (`_field`, `_span`) and raise the same
IndexError / TypeError: compiled code reads and writes only inside the buffers it is given,
and writes only into a bytearray, never into a `bytes` object Python may share.
tests/test_onboard_wire.py compares both with `struct` and pymavlink.
"""

from __future__ import annotations

import re
import struct

import cython

MAXF = 96                    # fields of the largest layout used (ODOMETRY: 61)
_SIZES = {"B": 1, "b": 1, "H": 2, "h": 2, "I": 4, "i": 4, "Q": 8, "q": 8, "f": 4, "d": 8}
_RANGE = {c: ((0, (1 << (8 * n)) - 1) if c.isupper() else
              (-(1 << (8 * n - 1)), (1 << (8 * n - 1)) - 1)) for c, n in _SIZES.items()
          if c not in "fd"}
_ST = {c: struct.Struct("<" + c) for c in _SIZES}


class Layout:
    """Offsets and type codes of a payload's fields (C arrays when compiled: fields.pxd);
    `base`: where the payload starts in the buffer written (10: in a MAVLink 2 frame)."""

    def __init__(self, fmt: str, base: int = 0) -> None:
        if not fmt.startswith("<"):
            raise ValueError(f"not a little-endian struct format: {fmt!r}")
        if not cython.compiled:
            self.off = [0] * MAXF
            self.code = [0] * MAXF
        self.fmt = fmt
        at, n = base, 0
        for count, c in re.findall(r"(\d*)([A-Za-z])", fmt[1:]):
            if c not in _SIZES:
                raise ValueError(f"field type {c!r} of {fmt!r} has no typed access")
            for _ in range(int(count or 1)):
                if n == MAXF:
                    raise ValueError(f"{fmt!r} has more than {MAXF} fields")
                self.off[n] = at
                self.code[n] = ord(c)
                at += _SIZES[c]
                n += 1
        if at - base != struct.calcsize(fmt):
            raise ValueError(f"{fmt!r}: {at - base} bytes laid out, struct says "
                             f"{struct.calcsize(fmt)}")
        self.n, self.size = n, at - base


@cython.locals(b=bytearray)
def new_payload(n: int) -> bytearray:
    """A zeroed payload of n bytes to write with put_f / put_i, then hand to `done`.
    (Compiled: made by the C API, not by a call of the bytearray type, ~6x the work.)"""
    if not cython.compiled:
        return bytearray(n)
    if n < 0:
        raise ValueError("negative count")                      # as bytearray(n)
    b = PyByteArray_FromStringAndSize(cython.NULL, n)           # noqa: F821 (fields.pxd)
    memset(PyByteArray_AS_STRING(b), 0, n)                      # noqa: F821
    return b


def copy_of(template: bytes) -> bytearray:
    """A new buffer holding template's bytes, to write in place (then `done`)."""
    _readable(template)
    return bytearray(template)


def done(buf: bytearray) -> bytes:
    """The bytes of a payload written in place (compiled: copied by the C API)."""
    _writable(buf)
    if not cython.compiled:
        return bytes(buf)
    return PyBytes_FromStringAndSize(PyByteArray_AS_STRING(buf),   # noqa: F821 (fields.pxd)
                                     PyByteArray_GET_SIZE(buf))    # noqa: F821


def _writable(out) -> int:
    """TypeError unless `out` is a bytearray (the only buffer put_f / put_i write into).
    (A C call when compiled, fields.pxd: every field written tests it.)"""
    if type(out) is not bytearray:
        raise TypeError(f"a payload to write is a bytearray, not {type(out).__name__}")
    return 0


def _readable(data) -> int:
    """TypeError unless `data` is bytes (a received datagram)."""
    if type(data) is not bytes:
        raise TypeError(f"a payload to read is bytes, not {type(data).__name__}")
    return 0


@cython.cfunc
@cython.exceptval(-1)
@cython.returns(cython.Py_ssize_t)
@cython.locals(lay=Layout, k=cython.Py_ssize_t)
def _field(lay: Layout, k: int) -> int:
    """Field k's offset, IndexError unless the layout has a field k."""
    if k < 0 or k >= lay.n:
        raise IndexError(f"field {k} of {lay.fmt!r}, which has {lay.n}")
    return lay.off[k]


@cython.cfunc
@cython.exceptval(-1)
@cython.returns(cython.int)
@cython.locals(size=cython.Py_ssize_t, p0=cython.Py_ssize_t, plen=cython.Py_ssize_t)
def _span(size: int, p0: int, plen: int) -> int:
    """IndexError unless [p0, p0 + plen) lies inside a buffer of `size` bytes."""
    if p0 < 0 or plen < 0 or p0 > size or plen > size - p0:
        raise IndexError(f"payload [{p0}, {p0} + {plen}) outside a buffer of {size} bytes")
    return 0


@cython.locals(p=cython.p_char, c=cython.int, at=cython.Py_ssize_t)
def put_f(out: bytearray, lay: Layout, k: int, v: float) -> int:
    """Field k ('f' or 'd') of the payload `out` := v."""
    _writable(out)
    at = _field(lay, k)
    c = lay.code[k]
    _span(len(out), at, 8 if c == 100 else 4)
    if cython.compiled:
        p = PyByteArray_AS_STRING(out) + at            # noqa: F821 (fields.pxd)
        if c == 102:                                    # 'f'
            PyFloat_Pack4(v, p, 1)     # noqa: F821 (fields.pxd)
        elif c == 100:                                  # 'd'
            PyFloat_Pack8(v, p, 1)     # noqa: F821
        else:
            raise TypeError(f"field {k} of {lay.fmt!r} is not a float")
    else:
        if chr(c) not in "fd":
            raise TypeError(f"field {k} of {lay.fmt!r} is not a float")
        _ST[chr(c)].pack_into(out, at, v)
    return 0


@cython.locals(p=cython.p_uchar, c=cython.int, at=cython.Py_ssize_t, n=cython.Py_ssize_t,
               j=cython.Py_ssize_t, u=cython.ulonglong)
def put_i(out: bytearray, lay: Layout, k: int, v: int) -> int:
    """Field k (an integer type) of the payload `out` := v (struct.error if out of range;
    compiled, v is a C long long: a 'Q' field up to 2**63 - 1)."""
    _writable(out)
    at = _field(lay, k)
    c = lay.code[k]
    _span(len(out), at, _size(c))
    if cython.compiled:
        n = _int_size(lay, k)
        if not _in_range(c, n, v):
            raise struct.error(f"{chr(c)!r} format requires {_RANGE[chr(c)][0]} <= number <= "
                               f"{_RANGE[chr(c)][1]}")
        p = cython.cast(cython.p_uchar, PyByteArray_AS_STRING(out)) + at  # noqa: F821
        u = cython.cast(cython.ulonglong, v)
        for j in range(n):
            p[j] = (u >> (8 * j)) & 0xFF
    else:
        if chr(c) in "fd":
            raise TypeError(f"field {k} of {lay.fmt!r} is not an integer")
        _ST[chr(c)].pack_into(out, at, v)
    return 0


@cython.locals(p=cython.p_char, c=cython.int, at=cython.Py_ssize_t, n=cython.Py_ssize_t,
               j=cython.Py_ssize_t)
def get_f(data: bytes, p0: int, plen: int, lay: Layout, k: int) -> float:
    """Field k ('f' or 'd') of the payload data[p0:p0 + plen] (zero past plen)."""
    _readable(data)
    at = _field(lay, k)
    c = lay.code[k]
    _span(len(data), p0, plen)
    if cython.compiled:
        n = 4 if c == 102 else 8 if c == 100 else 0
        if n == 0:
            raise TypeError(f"field {k} of {lay.fmt!r} is not a float")
        p = PyBytes_AS_STRING(data) + p0 + at          # noqa: F821 (fields.pxd)
        if at + n > plen:                               # a trimmed payload
            tmp = cython.declare(cython.char[8])
            for j in range(n):
                tmp[j] = p[j] if at + j < plen else 0
            p = tmp
        return PyFloat_Unpack4(p, 1) if n == 4 else PyFloat_Unpack8(p, 1)  # noqa: F821
    else:
        if chr(c) not in "fd":
            raise TypeError(f"field {k} of {lay.fmt!r} is not a float")
        return _unpack(data, p0, plen, c, at)


@cython.locals(p=cython.p_uchar, c=cython.int, at=cython.Py_ssize_t, n=cython.Py_ssize_t,
               j=cython.Py_ssize_t, u=cython.ulonglong)
def get_i(data: bytes, p0: int, plen: int, lay: Layout, k: int) -> int:
    """Field k (an integer type) of the payload data[p0:p0 + plen] (zero past plen)."""
    _readable(data)
    at = _field(lay, k)
    c = lay.code[k]
    _span(len(data), p0, plen)
    if cython.compiled:
        n = _int_size(lay, k)
        p = cython.cast(cython.p_uchar, PyBytes_AS_STRING(data)) + p0  # noqa: F821
        u = 0
        for j in range(n):
            if at + j < plen:
                u |= cython.cast(cython.ulonglong, p[at + j]) << (8 * j)
        if c >= 97 and n < 8 and u >> (8 * n - 1):     # a lower-case code: signed
            u |= ~cython.cast(cython.ulonglong, 0) << (8 * n)
        return cython.cast(cython.longlong, u)
    else:
        if chr(c) in "fd":
            raise TypeError(f"field {k} of {lay.fmt!r} is not an integer")
        return _unpack(data, p0, plen, c, at)


@cython.locals(tmp=cython.char[4])
def f32(v: float) -> float:
    """v as a MAVLink 'f' field carries it: rounded to the nearest float (the value get_f
    reads back after put_f wrote v; OverflowError for a finite v too large, as put_f), for
    a typed exchange that must give what the framed one gives (cosim/sim/onboard.py)."""
    if cython.compiled:
        PyFloat_Pack4(v, tmp, 1)                        # noqa: F821 (fields.pxd)
        return PyFloat_Unpack4(tmp, 1)                  # noqa: F821
    else:
        return _F32.unpack(_F32.pack(v))[0]


_F32 = _ST["f"]


def _unpack(data: bytes, p0: int, plen: int, c: int, at: int):
    """Interpreted: field `chr(c)` at `at` of data[p0:p0 + plen], zero past plen."""
    payload = bytes(data[p0:p0 + plen]) + bytes(at + 8)
    return _ST[chr(c)].unpack(payload[at:at + _SIZES[chr(c)]])[0]


@cython.cfunc
@cython.returns(cython.Py_ssize_t)
@cython.exceptval(-1)
@cython.locals(lay=Layout, k=cython.Py_ssize_t, c=cython.int, n=cython.Py_ssize_t)
def _int_size(lay: Layout, k: int) -> int:
    """The size of field k, an integer type (TypeError for a float)."""
    c = lay.code[k]
    n = _size(c)
    if n == 0 or c == 102 or c == 100:
        raise TypeError(f"field {k} of {lay.fmt!r} is not an integer")
    return n


@cython.cfunc
@cython.inline
@cython.exceptval(check=False)
@cython.returns(cython.Py_ssize_t)
@cython.locals(c=cython.int)
def _size(c: int) -> int:
    if c == 66 or c == 98:               # B b
        return 1
    if c == 72 or c == 104:              # H h
        return 2
    if c == 73 or c == 105 or c == 102:  # I i f
        return 4
    if c == 81 or c == 113 or c == 100:  # Q q d
        return 8
    return 0


@cython.cfunc
@cython.inline
@cython.exceptval(check=False)
@cython.returns(cython.bint)
@cython.locals(c=cython.int, n=cython.Py_ssize_t, v=cython.longlong)
def _in_range(c: int, n: int, v: int) -> bool:
    if c >= 97:                          # signed
        return n == 8 or -(cython.cast(cython.longlong, 1) << (8 * n - 1)) <= v < (
            cython.cast(cython.longlong, 1) << (8 * n - 1))
    return v >= 0 and (n == 8 or v < (cython.cast(cython.longlong, 1) << (8 * n)))
