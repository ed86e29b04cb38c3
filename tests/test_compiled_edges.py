# ruff: noqa: E501  (the edge cases are lines of data, one call each)
"""The compiled core raises where the interpreted one does, and never crashes or writes into
memory it does not own (issue 39): the same edge inputs (empty, 255/256 bytes, negative and
huge indices and offsets, the wrong buffer type) go to every function behind an
`if cython.compiled:` branch in both builds, each build in a child process, and must give the
same answer or the same exception; then a seeded fuzz of 10,000 such calls per build ends with
no signal. A compiled module with a check removed crashes or answers where the interpreted one
raises, and these tests fail."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# each case: a Python expression over the names below; its result (repr) or its exception type
CASES = r"""
from mav import crc, fields, hil_sensors, wire
from mav.fields import Layout, copy_of, done, get_f, get_i, new_payload, put_f, put_i
from pymavlink.dialects.v20 import common as mavlink2
F = Layout('<f')
D90 = Layout('<' + 'd' * 90)
B = Layout('<B')
Q = Layout('<Qhb')
mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
ODO = wire.ODOMETRY
HB = wire.HEARTBEAT
one = b'\x00'
CASES = [
    "get_f(b'abcd', 0, 4, F, 0)", "get_f(b'abcd', 0, 4, F, 10**6)", "get_f(b'abcd', 0, 4, F, -1)",
    "get_f(b'abcd', 10**12, 4, F, 0)", "get_f(b'abcd', -1, 4, F, 0)", "get_f(b'abcd', 0, 5, F, 0)",
    "get_f(b'abcd', 0, -1, F, 0)", "get_f(b'', 0, 0, F, 0)", "get_f(b'ab', 0, 2, F, 0)",
    "get_f(b'abcd', 2**62, 2**62, F, 0)", "get_f(bytearray(4), 0, 4, F, 0)",
    "get_i(b'abcd', 0, 4, F, 0)", "get_i(b'\xff' * 11, 0, 11, Q, 1)",
    "get_i(b'\xff' * 11, 0, 11, Q, 2)", "get_i(b'\xff' * 11, 0, 11, Q, 3)",
    "get_i(b'\xff' * 11, 3, 8, Q, 0)", "get_i(b'\xff' * 11, 4, 8, Q, 0)",
    "get_i(b'x', 0, 1, B, 0)", "get_i(b'x', 0, 1, B, 1)", "get_i(b'x', 1, 0, B, 0)",
    "get_i(b'x', 2, 0, B, 0)",
    "put_i(one, B, 0, 65)", "put_f(b'\x00' * 4, F, 0, 1.0)", "put_f(b'', D90, 89, 1e300)",
    "put_f(bytearray(720), D90, 89, 1e300)", "put_f(bytearray(719), D90, 89, 1.0)",
    "put_f(bytearray(4), F, 1, 1.0)", "put_f(bytearray(4), F, -1, 1.0)",
    "put_f(bytearray(4), F, 0, 1e300)", "put_f(bytearray(4), F, 0, float('nan'))",
    "put_i(bytearray(1), B, 0, 256)", "put_i(bytearray(1), B, 0, -1)", "put_i(bytearray(1), B, 0, 255)",
    "put_i(bytearray(0), B, 0, 1)", "put_i(bytearray(4), F, 0, 1)", "put_f(bytearray(1), B, 0, 1.0)",
    "put_i(bytearray(11), Q, 0, 2**63 - 1)", "put_i(bytearray(11), Q, 1, -32769)",
    "done(bytearray(b'ab'))", "done(b'ab')", "new_payload(3)", "new_payload(-1)", "copy_of(b'ab')",
    "crc.crc_of(b'abc', 0, 3, 300)", "crc.crc_of(b'abc', 0, 3, -1)", "crc.crc_of(b'abc', 0, 3, 255)",
    "crc.crc_of(b'abc', 0, 4, 0)", "crc.crc_of(b'abc', -1, 3, 0)", "crc.crc_of(b'abc', 2, 1, 0)",
    "crc.crc_of(bytearray(b'abc'), 0, 3, 7)", "crc.crc_of('abc', 0, 3, 7)", "crc.crc_of(b'', 0, 0, 0)",
    "wire.frame(mav, ODO, bytes(range(1, 256)))", "wire.frame(mav, ODO, bytes([1]) * 256)",
    "wire.frame(mav, ODO, bytes([1]) * 300)", "wire.frame(mav, ODO, bytes(300))",
    "wire.frame(mav, HB, b'')", "wire.frame(mav, HB, b'\x01')",
    "wire.frame_end(b'', 0)", "wire.frame_end(b'\xfd', 0)", "wire.frame_end(b'\xfd\xff\x00', 0)",
    "wire.frame_end(b'\xfd' * 300, 10**6)", "wire.frame_end(b'\xfd' * 300, -1)",
    "wire.msgid_of(b'\xfd', 0)", "wire.msgid_of(b'', 0)", "wire.msgid_of(b'\xfe' * 6, 0)",
    "wire.frame_ok(HB, b'\xfd' * 30, 0, 30)", "wire.frame_ok(HB, b'', 0, 0)",
    "wire.frame_ok(HB, b'\xfd' * 30, -5, 30)", "wire.frame_ok(HB, b'\xfd' * 30, 0, 10**9)",
    "wire.decode_fast(HB, b'\xfd' * 30, 0, 30)", "wire.decode_fast(HB, b'', 0, -1)",
    "wire.decode_fast(HB, wire.frame(mav, HB, bytes(9)), 0, -1)",
    "hil_sensors.decode_bundle(b'')", "hil_sensors.decode_bundle(b'\xfd' * 255)",
    "hil_sensors.decode_bundle(b'\xfd\x00\x00\x00\x00\x01\x01\x6b\x00\x00\x00\x00')",
    "hil_sensors.is_sensor_bundle(b'\xfd' * 11)",
    "hil_sensors.stamp(ODO, 2**64, b'')", "hil_sensors.stamp(ODO, -1, b'')",
    "hil_sensors.frames(mav, [HB, bytes(300)])", "hil_sensors.frames(mav, [HB, b'\x01' * 255])",
    "hil_sensors.distance_rest(2**40, 0, 0, 0, 0)", "hil_sensors.flow_rest(-1, 0., 0., 0., 0., 0., 300)",
]
"""

PAYLOAD = r"""
P = hil_sensors.Payload(hil_sensors.HIL_SENSOR)
def payload(data, p0, plen, k, kind):
    P.data, P.p0, P.plen = data, p0, plen
    return P.f(k) if kind == 'f' else P.i(k)
CASES += [
    "payload(b'abc', 2**40, 3, 0, 'i')", "payload(b'abc', 0, 10**9, 3, 'f')",
    "payload(b'abc', 0, 3, 1, 'f')", "payload(b'abc', 0, 3, 0, 'i')", "payload(b'abc', 0, 3, 99, 'f')",
    "payload(None, 0, 0, 1, 'f')", "payload(bytes(64), 0, 64, 13, 'f')", "payload(bytes(64), 0, 64, 14, 'i')",
]
"""

RUN = r"""
import json, sys
out = []
for expr in CASES:
    try:
        v = eval(expr)
        out.append(["ok", repr(v)])
    except Exception as exc:
        out.append(["raised", type(exc).__name__])
# nothing a call did may have changed what Python shares: the cached one-byte bytes, literals
out.append(["bytes intact", repr((b'\x00' == b'A', one, bytes(1)))])
print(json.dumps(out))
"""


def run_build(compiled: str, code: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, COSIM_COMPILED=compiled)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=300, check=False)


def test_both_builds_answer_every_edge_case_alike():
    code = CASES + PAYLOAD + RUN
    got = {}
    for c in ("0", "1"):
        p = run_build(c, code)
        assert p.returncode == 0, f"COSIM_COMPILED={c}: rc {p.returncode} {p.stderr[-2000:]}"
        got[c] = json.loads(p.stdout.strip().splitlines()[-1])
    exprs = [e for e in eval(CASES.split("CASES = ", 1)[1].split("]\n", 1)[0] + "]")]
    assert len(got["0"]) == len(got["1"]) > 80
    for i, (a, b) in enumerate(zip(got["0"], got["1"], strict=True)):
        what = exprs[i] if i < len(exprs) else f"case {i}"
        assert a == b, (what, a, b)
    # the crashers raise now (a removed check would segfault or answer instead)
    named = dict(zip(exprs, got["1"], strict=False))
    for expr in ("get_f(b'abcd', 0, 4, F, 10**6)", "get_f(b'abcd', 10**12, 4, F, 0)",
                 "put_i(one, B, 0, 65)", "put_f(b'', D90, 89, 1e300)",
                 "crc.crc_of(b'abc', 0, 3, 300)", "wire.frame(mav, ODO, bytes([1]) * 300)"):
        assert named[expr][0] == "raised", (expr, named[expr])
    assert got["1"][-1] == ["bytes intact", repr((False, b"\x00", b"\x00"))]


FUZZ = r"""
import random, struct, json
r = random.Random(int(sys.argv[1]))
LAYS = [F, D90, B, Q, Layout('<Q13fIB'), Layout('<H')]
def num():
    return r.choice([0, 1, -1, 2, 3, 4, 7, 8, 11, 255, 256, 719, 720, 2**31, 2**40, -2**40,
                     2**62, r.randrange(-1000, 1000)])
def buf():
    n = r.choice([0, 1, 3, 4, 8, 11, 64, 255, 256, 720])
    return bytes(r.randrange(256) for _ in range(n))
def one_call():
    k = r.randrange(8)
    lay = r.choice(LAYS)
    if k == 0:
        return get_f(buf(), num(), num(), lay, num())
    if k == 1:
        return get_i(buf(), num(), num(), lay, num())
    if k == 2:
        return put_f(bytearray(buf()), lay, num(), r.choice([0.0, 1e300, -1e-300, float('nan')]))
    if k == 3:
        return put_i(bytearray(buf()), lay, num(), num())
    if k == 4:
        return crc.crc_of(buf(), num(), num(), num())
    if k == 5:
        return wire.frame(mav, r.choice([ODO, HB]), buf())
    if k == 6:
        d = buf()
        return (wire.frame_end(d, num()), wire.decode_fast(HB, d, num(), num()))
    return payload(buf(), num(), num(), num(), r.choice('fi'))
kinds = {}
for _ in range(10000):
    try:
        one_call()
        kinds['ok'] = kinds.get('ok', 0) + 1
    except (IndexError, TypeError, ValueError, OverflowError, struct.error) as exc:
        kinds[type(exc).__name__] = kinds.get(type(exc).__name__, 0) + 1
print(json.dumps(kinds))
"""


@pytest.mark.parametrize("compiled", ["0", "1"])
def test_a_seeded_fuzz_of_10000_calls_ends_with_no_signal(compiled):
    p = subprocess.run([sys.executable, "-c", "import sys\n" + CASES + PAYLOAD + FUZZ, "7"],
                       capture_output=True, text=True, cwd=ROOT, timeout=300, check=False,
                       env=dict(os.environ, COSIM_COMPILED=compiled))
    assert p.returncode == 0, f"rc {p.returncode} (a negative rc is a signal): {p.stderr[-2000:]}"
    kinds = json.loads(p.stdout.strip().splitlines()[-1])
    assert sum(kinds.values()) == 10000 and kinds.get("ok", 0) > 100 and kinds.get("IndexError")
