"""mav.wire: the fast codec is byte-identical to pymavlink and decodes identically."""

from __future__ import annotations

import math
import random
import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mav import wire

M = mavlink2
FAST = sorted(wire.FAST_BY_ID.values(), key=lambda m: m.id)


def _random_value(rng: random.Random, ftype: str, zero_bias: bool):
    if zero_bias and rng.random() < 0.5:
        return 0
    base = ftype.split("[")[0]
    if base == "float":
        return rng.choice([rng.uniform(-1e4, 1e4), 0.0, -0.0, 1e-30, math.inf, 3.4e38,
                           math.nan, rng.uniform(-1, 1)])
    if base == "double":
        return rng.uniform(-1e6, 1e6)
    if base == "char":
        return bytes(rng.randrange(32, 127) for _ in range(rng.randrange(0, 8)))
    bits = int("".join(c for c in base if c.isdigit()))
    if base.startswith("u"):
        return rng.randrange(0, 1 << bits)
    return rng.randrange(-(1 << (bits - 1)), 1 << (bits - 1))


def _alen(cls, field: str) -> int:
    return cls.array_lengths[cls.ordered_fieldnames.index(field)]     # wire-ordered list


def random_message(cls, rng: random.Random, zero_bias: bool = False):
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = _alen(cls, name)
        if n:
            args.append([_random_value(rng, ftype, zero_bias) for _ in range(n)])
        else:
            args.append(_random_value(rng, ftype, zero_bias))
    return cls(*args)


def wire_values(msg) -> list:
    """The message's fields in wire order, arrays flattened (what wire.pack takes)."""
    out = []
    for f in type(msg).ordered_fieldnames:
        v = getattr(msg, f)
        if isinstance(v, list):
            out.extend(v)
        else:
            out.append(v)
    return out


def pair(sysid=1, compid=1, seq=0):
    a, b = M.MAVLink(None, sysid, compid), M.MAVLink(None, sysid, compid)
    a.seq = b.seq = seq
    return a, b


@pytest.mark.parametrize("fm", FAST, ids=lambda m: m.name)
def test_fast_pack_is_byte_identical(fm):
    rng = random.Random(fm.id)
    for i in range(300):
        a, b = pair(rng.randrange(256), rng.randrange(256), rng.randrange(256))
        msg = random_message(fm.cls, rng, zero_bias=i % 3 == 0)
        ref = msg.pack(a)
        a.seq = (a.seq + 1) % 256
        assert wire.pack(b, fm, *wire_values(msg)) == ref
        assert a.seq == b.seq
    a, b = pair()
    zero = fm.cls(*[[0] * n if n else 0 for n in (_alen(fm.cls, f) for f in fm.cls.fieldnames)])
    ref = zero.pack(a)
    assert wire.pack(b, fm, *wire_values(zero)) == ref
    assert ref[1] == 1                       # MAVLink 2 trims an all-zero payload to one byte


def test_named_encoders_and_sequence_wrap():
    a, b = pair(seq=250)
    cov = [math.nan] + [0.0] * 20
    for k in range(12):                       # seq runs through 255 -> 0 on both
        t = 1_000_000 + k * 5000
        ref = M.MAVLink_odometry_message(t, 1, 1, 0.5, -0.25, -1.0, [1.0, 0.0, 0.0, 0.0],
                                         0.1, 0.0, -0.3, 0.0, 0.01, 0.0, cov, cov, 0, 0, 0)
        r = ref.pack(a)
        a.seq = (a.seq + 1) % 256
        assert wire.encode_odometry(b, t, 0.5, -0.25, -1.0, 1.0, 0.0, 0.0, 0.0, 0.1, 0.0, -0.3,
                                    0.0, 0.01, 0.0) == r
        ref = M.MAVLink_hil_actuator_controls_message(t, [0.5, 0.6, 0.0, 0.7] + [0.0] * 12,
                                                      129, 1)
        r = ref.pack(a)
        a.seq = (a.seq + 1) % 256
        assert wire.encode_hil_actuator_controls(b, t, 0.5, 0.6, 0.0, 0.7, 129) == r
        ref = M.MAVLink_set_position_target_local_ned_message(
            k, 1, 1, 8, 0x05C7, 0, 0, 0, 1.0, 0.0, -0.5, 0, 0, 0, 0, 0.3)
        r = ref.pack(a)
        a.seq = (a.seq + 1) % 256
        assert wire.encode_set_position_target_local_ned(
            b, k, 1, 1, 8, 0x05C7, 0, 0, 0, 1.0, 0.0, -0.5, 0, 0, 0, 0, 0.3) == r
    assert a.seq == b.seq == (250 + 36) % 256


def test_signed_fast_pack_is_byte_identical():
    key = bytes(range(32))
    a, b = pair(1, 191)
    for m in (a, b):
        sg = m.signing
        sg.secret_key, sg.sign_outgoing, sg.link_id, sg.timestamp = key, True, 3, 123456789
    for k in range(5):
        ref = M.MAVLink_attitude_message(k, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
        r = ref.pack(a)
        a.seq = (a.seq + 1) % 256
        f = wire.encode_attitude(b, k, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
        assert f == r and f[2] == wire.IFLAG_SIGNED
    assert a.signing.timestamp == b.signing.timestamp == 123456789 + 5
    checker = M.MAVLink(None, 9, 9)
    checker.signing.secret_key = key
    assert checker.decode(bytearray(f)).get_signed()


@pytest.mark.parametrize("fm", FAST, ids=lambda m: m.name)
def test_fast_decode_matches_pymavlink(fm):
    rng = random.Random(1000 + fm.id)
    a = M.MAVLink(None, 3, 4)
    for i in range(300):
        msg = random_message(fm.cls, rng, zero_bias=i % 3 == 0)
        data = msg.pack(a)
        ref = a.decode(bytearray(data))
        got = wire.decode_fast(fm, data)
        assert got is not None
        # same values, bit for bit (struct round trip of the reference's wire-order fields)
        want = fm.st.unpack(fm.st.pack(*wire_values(ref)))
        assert struct.pack(fm.st.format, *got) == struct.pack(fm.st.format, *want)
        # and inside a longer datagram
        again = wire.decode_fast(fm, data + data, len(data))
        assert struct.pack(fm.st.format, *again) == struct.pack(fm.st.format, *got)


def test_decode_odometry_matches_pymavlink():
    rng = random.Random(7)
    a = M.MAVLink(None, 250, 1)
    for i in range(300):
        msg = random_message(M.MAVLink_odometry_message, rng, zero_bias=i % 2 == 0)
        data = msg.pack(a)
        r = a.decode(bytearray(data))
        got = wire.decode_odometry(data)
        want = (r.time_usec, r.x, r.y, r.z, *r.q, r.vx, r.vy, r.vz, r.rollspeed, r.pitchspeed,
                r.yawspeed, r.frame_id, r.child_frame_id, r.quality)
        assert struct.pack("<Q13dBBb", *got) == struct.pack("<Q13dBBb", *want)


def test_decoders_refuse_bad_frames():
    a = M.MAVLink(None, 1, 1)
    cov = [0.0] * 21
    good = M.MAVLink_odometry_message(5, 1, 1, 1, 2, 3, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, cov,
                                      cov, 0, 0, 50).pack(a)
    assert wire.decode_odometry(good) is not None
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 1
    other = M.MAVLink_heartbeat_message(1, 2, 3, 4, 5, 3).pack(a)
    v1 = M.MAVLink(None, 1, 1)
    for bad in (bytes(bad_crc), good[:-1], good[:11], other, b"",
                b"\xfe" + good[1:], bytes(good[:2]) + b"\x02" + good[3:]):
        assert wire.decode_odometry(bad) is None
        assert wire.decode_fast(wire.ODOMETRY, bad) is None
    # a datagram is one frame for the HIL decoder; decode_fast reads the frame at an offset
    assert wire.decode_odometry(good + b"\x00") is None
    assert wire.decode_fast(wire.ODOMETRY, good + b"\x00") is not None
    assert v1.decode(bytearray(good)).time_usec == 5


def test_frame_end_and_msgid():
    a = M.MAVLink(None, 1, 1)
    hb = M.MAVLink_heartbeat_message(1, 2, 3, 4, 5, 3).pack(a)
    assert wire.frame_end(hb) == len(hb) and wire.msgid_of(hb) == 0
    two = hb + hb
    assert wire.frame_end(two, len(hb)) == len(two)
    assert wire.frame_end(hb[:-1]) == -1 and wire.frame_end(b"\x00abc") == -1
    v1 = M.MAVLink_heartbeat_message(1, 2, 3, 4, 5, 3).pack(a, force_mavlink1=True)
    assert wire.frame_end(v1) == len(v1) and wire.msgid_of(v1) == 0
    assert wire.header_of(hb) == (0, 1, 1)


def test_flat_earth():
    geo = wire.FlatEarth(42.299886, -71.350447, 71.3232)
    assert geo.to_geodetic(0.0, 0.0, 0.0) == (42.299886, -71.350447, 71.3232)
    # 1 degree of latitude at 42.3 deg (WGS-84 series): 111132.954 - 559.822 cos 2phi + ...
    phi = math.radians(42.299886)
    m_per_deg_lat = 111132.954 - 559.822 * math.cos(2 * phi) + 1.175 * math.cos(4 * phi)
    m_per_deg_lon = (math.pi / 180) * 6378137.0 * math.cos(phi) / math.sqrt(
        1 - 0.00669437999014 * math.sin(phi) ** 2)
    lat, lon, alt = geo.to_geodetic(1000.0, 1000.0, -10.0)
    assert (lat - 42.299886) * m_per_deg_lat == pytest.approx(1000.0, abs=0.01)
    assert (lon + 71.350447) * m_per_deg_lon == pytest.approx(1000.0, abs=0.01)
    assert alt == pytest.approx(81.3232)
    for p in ((3.0, -4.0, -2.0), (-250.0, 1234.5, 7.0)):
        assert geo.to_ned(*geo.to_geodetic(*p)) == pytest.approx(p, abs=1e-6)
    lat_e7, lon_e7, alt_mm = geo.to_int(0.0, 0.0, -1.0)
    assert (lat_e7, lon_e7, alt_mm) == (422998860, -713504470, 72323)
    # across the antimeridian
    geo2 = wire.FlatEarth(0.0, 179.99999, 0.0)
    assert geo2.to_geodetic(0.0, 10.0, 0.0)[1] < -179.9


def test_clamp():
    assert wire.clamp_int(1e9, -5, 5) == 5 and wire.clamp_int(math.nan, 0, 9) == 0
    assert wire.clamp_int(-2.6, -5, 5) == -3


def test_hil_codec_odometry_is_pymavlinks():
    """The simulator's ODOMETRY (constant payload tail packed once) is pymavlink's message,
    byte for byte, over a sequence-number wrap."""
    from mav.hil import SIM_COMPID, SIM_SYSID, HilSimulatorCodec

    codec = HilSimulatorCodec()
    pm = mavlink2.MAVLink(None, srcSystem=SIM_SYSID, srcComponent=SIM_COMPID)
    cov = [math.nan] + [0.0] * 20
    r = random.Random(7)
    for k in range(300):
        m = tuple(r.uniform(-3.0, 3.0) for _ in range(13))
        ref = pm.odometry_encode(k * 5000, 1, 1, *m[:3], list(m[3:7]), *m[7:], cov, cov, 0,
                                 1, 100).pack(pm)
        pm.seq = (pm.seq + 1) & 0xFF
        assert codec.encode_odometry(k * 5000, m) == ref, k


def test_decode_hil_actuator_controls_matches_decode_fast():
    """The simulator's per-tick decoder: the same motors as decode_fast (and pymavlink) for
    good frames (trimmed payloads included), None for every corrupted one decode_fast refuses."""
    mav = M.MAVLink(None, 1, 1)
    r = random.Random(11)
    for k in range(2000):
        u = [r.choice([0.0, r.random()]) for _ in range(4)]
        d = wire.encode_hil_actuator_controls(mav, k * 5000, *u, r.choice([129, 1, 0]))
        f = wire.decode_fast(wire.HIL_ACTUATOR_CONTROLS, d)
        assert wire.decode_hil_actuator_controls(d) == (f[0], f[2], f[3], f[4], f[5])
        bad = bytearray(d)
        bad[r.randrange(len(d))] ^= 1 << r.randrange(8)
        if wire.decode_fast(wire.HIL_ACTUATOR_CONTROLS, bytes(bad)) is None:
            assert wire.decode_hil_actuator_controls(bytes(bad)) is None
    assert wire.decode_hil_actuator_controls(d + d) is None      # exactly one frame
    assert wire.decode_hil_actuator_controls(b"") is None


_BOTH_MODES = """
import random, sys
from fastcrc.crc16 import mcrf4xx
from mav import crc, wire
r = random.Random(7)
for n in list(range(0, 300)) * 3:   # every length, at offsets, against fastcrc (pymavlink's)
    d = bytes(r.randrange(256) for _ in range(n + 3))
    i, extra = r.randrange(3), r.randrange(256)
    assert crc.crc_of(d, i, i + n, extra) == mcrf4xx(d[i:i + n] + bytes((extra,))), n
    assert crc._crc16_py(d[:n]) == mcrf4xx(d[:n])
vals = [k / 2 for k in range(-20, 21)] + [k + 0.5 for k in (2**51, -2**51, 2**52 - 1)]
vals += [0.5 + 2**-54 - 1, -0.5 + 2**-54, -2**-60, 0.49999999999999994, -0.0, 1e300, -1e300]
vals += [r.uniform(-1e4, 1e4) for _ in range(20000)] + [r.uniform(-2, 2) for _ in range(20000)]
for v in vals:
    assert int(wire.round_even(v)) == round(v), v
for v in (float("nan"), float("inf")):
    for f in (lambda: round(v), lambda: int(wire.round_even(v))):
        try:
            f()
        except (ValueError, OverflowError) as e:
            print(type(e).__name__)
print(sys.modules["mav.crc"].__file__.endswith(".py"))
"""


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_checksum_and_rounding_are_pythons_compiled_and_interpreted(compiled):
    """crc_of (C over the frame's buffer when compiled) against fastcrc, and round_even (C
    doubles when compiled) against Python's round, halves and NaN/inf included."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, COSIM_COMPILED=compiled)
    p = subprocess.run([sys.executable, "-c", _BOTH_MODES], env=env, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.split()
    assert lines[:4] == ["ValueError", "ValueError", "OverflowError", "OverflowError"]
    assert lines[4] == ("True" if compiled == "0" else "False")   # the mode asked for


def test_one_frame_decoders_read_a_window_of_a_datagram_in_place():
    """decode(data, i, end): the datagram data[i:end] in place, as the same bytes alone."""
    a = M.MAVLink(None, 1, 1)
    cov = [0.0] * 21
    odo = M.MAVLink_odometry_message(5, 1, 1, 1, 2, 3, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, cov,
                                     cov, 0, 0, 50).pack(a)
    hac = wire.encode_hil_actuator_controls(a, 7, 0.1, 0.2, 0.3, 0.4, 129)
    both = hac + odo
    assert wire.decode_hil_actuator_controls(both, 0, len(hac)) == \
        wire.decode_hil_actuator_controls(hac)
    assert wire.decode_odometry(both, len(hac)) == wire.decode_odometry(odo) is not None
    assert wire.decode_odometry(both, len(hac), len(both)) == wire.decode_odometry(odo)
    for i, end in ((0, -1), (len(hac), len(both) - 1), (len(hac) + 1, -1), (-1, -1),
                   (len(hac), len(both) + 1), (len(both), -1)):
        assert wire.decode_odometry(both, i, end) is None
    assert wire.decode_hil_actuator_controls(both) is None     # two frames: not one datagram
