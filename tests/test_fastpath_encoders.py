"""The compiled per-tick encoders (mav/csrc/telemetry.c) against their Python references:
ATTITUDE and LOCAL_POSITION_NED from a VehicleState (mav/onboard/telemetry.py), and framing
on a link's MAVLink object in one call (`wire.frame`), byte for byte, seq for seq."""

from __future__ import annotations

import functools
import math
import random

import pytest
from pymavlink.dialects.v20 import common as M

from mav import fastpath, reference, wire
from mav.onboard.telemetry import Telemetry
from mav.types import Setpoint, VehicleState

F32_MAX = 3.4028234663852886e38


class _Chan:
    """The part of a Chan the emitters use."""

    def __init__(self, mav) -> None:
        self.mav = mav
        self.sent: list[bytes] = []

    def send(self, data: bytes) -> None:
        self.sent.append(data)


class _Status:
    def __init__(self, s: VehicleState, t_us: int) -> None:
        self.state, self.t_us = s, t_us
        self.setpoint = Setpoint()


def test_compiled_position_target_is_the_reference_bytes():
    """POSITION_TARGET_LOCAL_NED from the setpoint in use (telemetry.c kind 2) against
    Telemetry.emit_position_target: NaN fields masked and sent as 0, ints, overflow."""
    rng = random.Random(4)
    for k in range(3000):
        sp = Setpoint()
        for name in ("x", "y", "z", "vx", "vy", "vz", "yaw", "yaw_rate"):
            r = rng.random()
            setattr(sp, name, math.nan if r < 0.3 else (rng.randrange(-5, 5) if r < 0.35
                                                          else _value(rng)))
        t_us = rng.randrange(0, 1 << 45)
        out = []
        for compiled in (True, False):
            tel = Telemetry.__new__(Telemetry)
            tel.vs = _Status(VehicleState(), t_us)
            tel.vs.setpoint = sp
            ch = _Chan(M.MAVLink(None, 1, 1))
            emit = functools.partial(fastpath.lib.emit_state, 2, wire.POSITION_TARGET_LOCAL_NED.id,
                                     wire.POSITION_TARGET_LOCAL_NED.crc_extra,
                                     tel.emit_position_target, tel.vs)
            ch.stats, ch.tx_key, ch.link = {"tx": 0}, "tx", ch
            try:
                if compiled:
                    emit(ch)
                else:
                    with reference.python():
                        tel.emit_position_target(ch)
            except OverflowError as exc:
                ch.sent.append(str(exc))
            out.append((ch.sent, ch.mav.seq))
        assert out[0] == out[1], (k, [getattr(sp, n) for n in Setpoint.__slots__])


def _value(rng: random.Random) -> float:
    r = rng.random()
    if r < 0.04:
        return math.nan
    if r < 0.07:
        return rng.choice([math.inf, -math.inf, 0.0, -0.0, F32_MAX, -F32_MAX, 1e-45])
    if r < 0.12:
        return rng.uniform(-1.5, 1.5)               # |2(qw qy - qz qx)| past 1: asin clamp
    return rng.uniform(-50.0, 50.0)


def _emit_both(kind: str, s: VehicleState, t_us: int, sysid: int, compid: int, seq: int):
    out = []
    for compiled in (True, False):
        tel = Telemetry.__new__(Telemetry)      # only the state and clock are read
        tel.vs = _Status(s, t_us)
        ch = _Chan(M.MAVLink(None, sysid, compid))
        ch.mav.seq = seq
        emit = getattr(tel, kind)
        if compiled:
            emit(ch)
        else:
            with reference.python():
                emit(ch)
        out.append((ch.sent, ch.mav.seq))
    return out


@pytest.mark.parametrize("kind", ["emit_attitude", "emit_local_position"])
def test_compiled_state_messages_are_the_reference_bytes(kind):
    assert fastpath.lib is not None
    rng = random.Random(kind)
    for k in range(3000):
        s = VehicleState()
        for name in VehicleState.__slots__[1:]:
            setattr(s, name, _value(rng))
        if k % 3 == 0:   # a unit quaternion, as the estimate gives
            a, b, c = (rng.uniform(-math.pi, math.pi) for _ in range(3))
            s.qw, s.qx, s.qy, s.qz = (math.cos(a), math.sin(a) * math.cos(b),
                                      math.sin(a) * math.sin(b) * math.cos(c),
                                      math.sin(a) * math.sin(b) * math.sin(c))
        t_us = rng.randrange(0, 1 << 45) if k % 10 else rng.randrange(-(1 << 20), 1 << 70)
        got, want = _emit_both(kind, s, t_us, rng.randrange(256), rng.randrange(256),
                               rng.randrange(256))
        assert got == want, (k, vars(s) if hasattr(s, "__dict__") else None)


def test_compiled_state_message_overflow_is_the_references_error():
    """A value too large for a float32 field: struct.pack's OverflowError, nothing sent and
    the sequence number untouched, compiled or not."""
    s = VehicleState()
    s.x = 1e39
    for ctx in (None, reference.python):
        tel = Telemetry.__new__(Telemetry)
        tel.vs = _Status(s, 0)
        ch = _Chan(M.MAVLink(None, 1, 1))
        if ctx is None:
            with pytest.raises(OverflowError):
                tel.emit_local_position(ch)
        else:
            with ctx(), pytest.raises(OverflowError):
                tel.emit_local_position(ch)
        assert ch.sent == [] and ch.mav.seq == 0


def test_frame_on_is_wire_frame_and_declines_a_signing_link():
    lib = fastpath.lib
    rng = random.Random(3)
    for k in range(3000):
        n = rng.randint(1, 255)
        payload = bytes(rng.randrange(256) if rng.random() < 0.6 else 0 for _ in range(n))
        m = wire.FAST_BY_ID[rng.choice(sorted(wire.FAST_BY_ID))]
        a = M.MAVLink(None, rng.randrange(256), rng.randrange(256))
        b = M.MAVLink(None, a.srcSystem, a.srcComponent)
        a.seq = b.seq = rng.randrange(256)
        got = lib.frame_on(a, m.id, m.crc_extra, payload)
        with reference.python():
            want = wire.frame(b, m, payload)
        assert got == want and a.seq == b.seq, k
    signed = M.MAVLink(None, 1, 1)
    signed.signing.secret_key = bytes(32)
    signed.signing.sign_outgoing = True
    assert lib.frame_on(signed, 30, 39, b"\x01") is None and signed.seq == 0
    with pytest.raises(ValueError):
        lib.frame_on(M.MAVLink(None, 1, 1), 30, 39, b"")
    with pytest.raises(TypeError):
        lib.frame_on(M.MAVLink(None, 1, 1), 30, 39, "text")


def test_compiled_hil_decoders_are_the_reference(monkeypatch):
    """decode_odometry / decode_hil_actuator_controls as one C call (decode.c) against the
    Python decoder: trimmed payloads (zero motors: MAVLink 2 drops trailing zeros), corrupted,
    truncated, padded and signed frames, and a bytearray (the Python fallback)."""
    import struct

    from mav.hil import HilSimulatorCodec

    assert isinstance(wire.decode_hil_actuator_controls, functools.partial)
    with monkeypatch.context() as mp:
        mp.setattr(wire, "_fp_check", None)
        py = {"odo": wire.one_frame_decoder(wire.ODOMETRY, wire.ODOMETRY_USED),
              "act": wire.one_frame_decoder(wire.HIL_ACTUATOR_CONTROLS,
                                             wire.HIL_ACTUATOR_CONTROLS_USED)}
    c = {"odo": wire.decode_odometry, "act": wire.decode_hil_actuator_controls}
    rng = random.Random(5)
    hil = HilSimulatorCodec()
    mav = M.MAVLink(None, 1, 1)
    for k in range(3000):
        u = [0.0 if rng.random() < 0.4 else rng.uniform(0, 1) for _ in range(4)]
        t = 0 if k % 7 == 0 else rng.randrange(1 << 40)
        frames = {"act": wire.encode_hil_actuator_controls(mav, t, *u, rng.choice([0, 1])),
                  "odo": hil.encode_odometry(t, tuple(rng.uniform(-5, 5) for _ in range(13)))}
        for kind, f in frames.items():
            b = bytearray(f)
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
            s = bytearray(f)
            s[2] = 1
            for data in (f, bytes(b), f[:rng.randrange(len(f))], f + b"\x00", bytes(s),
                         bytes(s) + bytes(13), bytearray(f), frames["odo" if kind == "act"
                                                                   else "act"]):
                assert c[kind](data) == py[kind](data), (k, kind, data)
    assert struct.calcsize("<Q8x4f") == wire.HIL_ACTUATOR_CONTROLS_USED.size


def test_compiled_battery_step_is_the_reference():
    from mav.battery import BATTERIES, Battery

    rng = random.Random(9)
    for name, p in BATTERIES.items():
        a, b = Battery(p, 0.55), Battery(p, 0.55)
        for k in range(5000):
            dt = rng.choice([0.005, 0.0025, rng.uniform(1e-6, 0.1)])
            u = [rng.uniform(0.0, 1.0) if rng.random() > 0.1 else 0.0 for _ in range(4)]
            if k % 500 == 0:
                u[0] = 1                               # an int: the reference's arithmetic
            fastpath.lib.battery_step(a, dt, *u)
            b.step(dt, *u)
            if k % 97 == 0:                            # telemetry refreshes _v_last
                assert a.voltage == b.voltage
            if k % 1000 == 0:
                a.sag(2.0, 0.1)
                b.sag(2.0, 0.1)
            for f in ("current", "consumed_mah", "energy_j", "_v_last"):
                assert getattr(a, f) == getattr(b, f), (name, k, f)


def test_compiled_stream_emit_sends_and_counts_as_the_reference():
    """The streams' compiled emit (emit_state through Telemetry.stream_emitter): the same
    bytes on the link and the same tx counter as the Python emitter plus Chan.send; on a
    signing link it hands over to the Python emitter, which signs."""
    from mav.links import MemoryLink
    from mav.onboard.links import Chan

    rng = random.Random(2)
    for msgid in (wire.ATTITUDE.id, wire.LOCAL_POSITION_NED.id):
        for signed in (False, True):
            out = []
            for compiled in (True, False):
                s = VehicleState()
                rng.seed(msgid * 2 + signed)          # the same state both times
                for name in VehicleState.__slots__[1:]:
                    setattr(s, name, rng.uniform(-3, 3))
                tel = Telemetry.__new__(Telemetry)
                tel.vs = _Status(s, 123_456_789)
                tel._emitters = {wire.ATTITUDE.id: tel.emit_attitude,
                                 wire.LOCAL_POSITION_NED.id: tel.emit_local_position}
                a, b = MemoryLink.pair()
                mav = M.MAVLink(None, 1, 1)
                if signed:
                    mav.signing.secret_key = bytes(range(32))
                    mav.signing.sign_outgoing = True
                    mav.signing.link_id = 0
                    mav.signing.timestamp = 1
                ch = Chan("api", a, mav, {"tx_api": 3})
                if compiled:
                    emit = tel.stream_emitter(msgid)
                    assert isinstance(emit, functools.partial)
                    emit(ch)
                    emit(ch)
                else:
                    with reference.python():
                        assert not isinstance(tel.stream_emitter(msgid), functools.partial)
                        tel._emitters[msgid](ch)
                        tel._emitters[msgid](ch)
                out.append((b.recv(), b.recv(), b.recv(), ch.stats, mav.seq))
            assert out[0] == out[1] and out[0][0] is not None and out[0][3] == {"tx_api": 5}


def _odometry_both(fast, ref, t_us, m) -> bool:
    """Both codecs' answer (bytes, or the error's type and text) is the same."""
    got = []
    for codec in (fast, ref):
        try:
            got.append(codec.encode_odometry(t_us, m))
        except Exception as exc:
            got.append((type(exc), str(exc)))
    return got[0] == got[1]


def test_compiled_odometry_encoder_is_the_reference():
    """The simulator's ODOMETRY (mav/csrc/hilsim.c) against HilSimulatorCodec's Python
    encoder: same bytes and seq on random values; the reference's answer (or error) for what
    the compiled path hands back (not a tuple of 13 floats, a clock out of range, signing)."""
    import numpy as np

    from mav.hil import HilSimulatorCodec

    fast = HilSimulatorCodec()
    assert isinstance(fast.encode_odometry, functools.partial)
    with reference.python():
        ref = HilSimulatorCodec()
    assert not isinstance(ref.encode_odometry, functools.partial)
    rng = random.Random(11)
    for k in range(3000):
        t_us = rng.choice([0, k * 5000, (1 << 64) - 1, rng.randrange(1 << 64)])
        m = tuple(_value(rng) for _ in range(13))
        if rng.random() < 0.05:
            m = m[:12] + (F32_MAX * 2,)       # too large for a float: struct's OverflowError
        assert _odometry_both(fast, ref, t_us, m)
        assert fast.mav.seq == ref.mav.seq
    odd = [(-1, (0.0,) * 13), (1 << 64, (0.0,) * 13), (5, [0.5] * 13), (5, (1,) * 13),
           (5, tuple(np.float32(0.25) for _ in range(13))), (5, (0.0,) * 12), (5.0, (0.0,) * 13)]
    for t_us, m in odd:
        assert _odometry_both(fast, ref, t_us, m)
    sg = fast.mav.signing                # a signing simulator: the reference frames it
    sg.secret_key, sg.sign_outgoing, sg.link_id, sg.timestamp = b"s" * 32, True, 1, 1
    rsg = ref.mav.signing
    rsg.secret_key, rsg.sign_outgoing, rsg.link_id, rsg.timestamp = b"s" * 32, True, 1, 1
    m = (0.5,) * 13
    assert fast.encode_odometry(7, m) == ref.encode_odometry(7, m)


class _Link:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send(self, data: bytes) -> None:
        self.sent.append(data)


def test_compiled_client_setpoint_is_the_reference():
    """OffboardClient.set_position_target compiled (mav/csrc/client.c) against its Python
    method: the same bytes, seq and tx count on random setpoints, and the reference's answer
    (or error, with nothing sent) for what the compiled path hands back: keywords, ints,
    numpy floats, a clock that is not finite, targets out of range, a signing client."""
    import numpy as np

    from mav.client import OffboardClient

    fast = OffboardClient(_Link())
    assert isinstance(fast.set_position_target, functools.partial)
    with reference.python():
        ref = OffboardClient(_Link())
    assert "set_position_target" not in ref.__dict__

    def both(args, kw, t):
        got = []
        for c in (fast, ref):
            c.t = t
            try:
                c.set_position_target(*args, **kw)
                got.append(c.link.sent[-1])
            except Exception as exc:
                got.append((type(exc), str(exc)))
            got.append((c.mav.seq, c.stats["tx"], len(c.link.sent)))
        return got[:2] == got[2:]

    rng = random.Random(5)
    for k in range(3000):
        args = tuple(_value(rng) for _ in range(rng.randrange(3, 9)))
        if rng.random() < 0.03:
            args = args[:2] + (F32_MAX * 4,) + args[3:]
        t = rng.choice([k * 0.005, -k * 0.005, 5e6, rng.uniform(0, 1e7)])
        assert both(args, {}, t), (args, t)
    odd = [((1.0, 2.0, -1.0), {"yaw": 0.5}, 1.0), ((1, 2, -1), {}, 1.0),
           ((np.float64(1.5), 2.0, -1.0, np.float64(0.1)), {}, 1.0),
           ((np.float32(1.5), 2.0, -1.0), {}, 1.0), ((1.0, 2.0, -1.0), {}, math.nan),
           ((1.0, 2.0, -1.0), {}, math.inf), ((1.0, 2.0, -1.0), {}, 3),
           ((1.0, 2.0, -1.0), {}, 1e17), ((1.0, 2.0), {}, 1.0)]
    for args, kw, t in odd:
        assert both(args, kw, t), (args, kw, t)
    for name, bad in (("target_system", 300), ("target_component", -1),
                      ("target_system", 1.0)):
        for c in (fast, ref):
            setattr(c, name, bad)
        assert both((1.0, 2.0, -1.0), {}, 1.0), (name, bad)
        for c in (fast, ref):
            setattr(c, name, 1)
    for c in (fast, ref):                   # a signing client: the reference frames it
        sg = c.mav.signing
        sg.secret_key, sg.sign_outgoing, sg.link_id, sg.timestamp = b"s" * 32, True, 1, 1
    assert both((1.0, 2.0, -1.0, 0.3), {}, 1.0)


def test_compiled_global_position_is_the_reference():
    """GLOBAL_POSITION_INT (mav/csrc/globalpos.c) against Telemetry.emit_global_position on
    random states, homes and origins (the date line included): same bytes, seq and counts;
    the reference's error, nothing sent, for a position that does not fit (or NaN)."""
    from mav.onboard.commander import Commander

    rng = random.Random(9)
    for k in range(3000):
        geo = wire.FlatEarth(rng.uniform(-80, 80), rng.choice([rng.uniform(-180, 180), 179.9999]),
                             rng.uniform(-100, 3000))
        s = VehicleState()
        for name in VehicleState.__slots__[1:]:
            setattr(s, name, _value(rng) if rng.random() < 0.3 else rng.uniform(-30, 30))
        if k % 50 == 0:
            s.x = rng.choice([1e12, -1e12, math.nan, math.inf])
        if k % 7 == 0:     # ties: cm/s that round half to even (12.5 -> 12, -37.5 -> -38)
            s.vx, s.vy, s.vz = 0.125, -0.375, 0.625
        status = _Status(s, rng.randrange(0, 1 << 45))
        status.home = rng.choice([None, (0.0, 0.0, rng.uniform(-5, 5)), (0, 0, 1)])
        out = []
        for compiled in (True, False):
            tel = Telemetry.__new__(Telemetry)
            tel.vs, tel.geo = status, geo
            tel.cmd = Commander.__new__(Commander)
            tel.cmd.vs = status
            ch = _Chan(M.MAVLink(None, 1, 1))
            ch.stats, ch.tx_key, ch.link = {"tx": 0}, "tx", ch
            try:
                if compiled:
                    m = wire.GLOBAL_POSITION_INT
                    fastpath.lib.emit_global(tel.emit_global_position, geo, status, m.id,
                                             m.crc_extra, ch)
                else:
                    tel.emit_global_position(ch)
            except Exception as exc:
                ch.sent.append((type(exc), str(exc)))
            out.append((ch.sent, ch.mav.seq))
        assert out[0] == out[1], (k, [getattr(s, n) for n in VehicleState.__slots__])
