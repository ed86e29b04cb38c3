"""mav/fields.py: a payload's fields written and read one at a time give struct's bytes and
values, compiled and interpreted (floats rounded alike, NaN and infinities kept, a finite
value too large for a float refused alike, integers checked against their field's range,
trimmed payloads read as zero-extended)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_BOTH_MODES = """
import math, random, struct, sys
from pymavlink.dialects.v20 import common as M
from mav import fields
r = random.Random(5)
msgs = [M.MAVLink_hil_sensor_message, M.MAVLink_hil_optical_flow_message,
        M.MAVLink_distance_sensor_message, M.MAVLink_hil_gps_message,
        M.MAVLink_hil_state_quaternion_message, M.MAVLink_odometry_message,
        M.MAVLink_hil_actuator_controls_message]
specials = [0.0, -0.0, math.nan, math.inf, -math.inf, 3.4028234e38, 1e-46, -1e-300, 1.5]
def value(c):
    if c in "fd":
        return r.choice(specials) if r.random() < 0.2 else r.uniform(-1e6, 1e6)
    n = struct.calcsize(c)
    lo, hi = (0, 256 ** n - 1) if c.isupper() else (-(256 ** n) // 2, 256 ** n // 2 - 1)
    hi = min(hi, 2 ** 63 - 1)           # put_i takes a C long long (a stamp: 292k years)
    return r.choice([lo, hi, 0, r.randint(lo, min(hi, 2 ** 62))])
checked = 0
for cls in msgs:
    fmt = cls.unpacker.format if hasattr(cls, "unpacker") else None
    fmt = struct.Struct(cls.native_format.decode() if isinstance(cls.native_format, bytes)
                        else cls.native_format).format if fmt is None else fmt
    fmt = "<" + fmt.lstrip("<")
    lay = fields.Layout(fmt)
    codes = [c for n, c in __import__("re").findall(r"(\\d*)([A-Za-z])", fmt[1:])
             for _ in range(int(n or 1))]
    assert lay.n == len(codes) and lay.size == struct.calcsize(fmt)
    for _ in range(300):
        vals = [value(c) for c in codes]
        buf = fields.new_payload(lay.size)
        for k, (c, v) in enumerate(zip(codes, vals)):
            (fields.put_f if c in "fd" else fields.put_i)(buf, lay, k, v)
        out = fields.done(buf)
        assert out == struct.pack(fmt, *vals), cls
        plen = r.randrange(1, lay.size + 1)
        ref = struct.unpack(fmt, (out[:plen] + bytes(lay.size))[:lay.size])
        data = b"xyz" + out[:plen] + b"tail"
        for k, c in enumerate(codes):
            got = (fields.get_f if c in "fd" else fields.get_i)(data, 3, plen, lay, k)
            assert got == ref[k] or (got != got and ref[k] != ref[k]), (cls, k)
            checked += 1
lay = fields.Layout("<fBbHhIiQq")
for k, v in [(0, 1e39), (0, -1e300), (1, 256), (1, -1), (2, 128), (3, 65536), (4, -32769),
             (5, 2 ** 32), (6, -2 ** 31 - 1), (7, -1)]:
    try:
        (fields.put_f if k == 0 else fields.put_i)(fields.new_payload(lay.size), lay, k, v)
    except (OverflowError, struct.error) as e:
        print(k, type(e).__name__)
for bad in ("<4s", ">f", "<" + "f" * 97):
    try:
        fields.Layout(bad)
    except ValueError:
        print("refused", bad[:4])
print(checked > 10000, sys.modules["mav.fields"].__file__.endswith(".py"))
"""


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_typed_fields_are_structs_bytes_compiled_and_interpreted(compiled):
    env = dict(os.environ, COSIM_COMPILED=compiled)
    p = subprocess.run([sys.executable, "-c", _BOTH_MODES], env=env, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[:10] == ["0 OverflowError", "0 OverflowError", "1 error", "1 error",
                          "2 error", "3 error", "4 error", "5 error", "6 error", "7 error"]
    assert lines[10:13] == ["refused <4s", "refused >f", "refused <fff"]
    assert lines[13] == f"True {compiled == '0'}"       # the mode asked for
