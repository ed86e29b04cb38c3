"""The fast paths against their references: the compiled onboard code (mav/csrc/*.c)
against its Python reference (mav/cascade.py, mav/wire.py), bit-identical tick by tick on
random inputs and on closed-loop missions (the Simulink model-vs-generated-code check); the
SIL lockstep's spin-then-sleep HIL wait against sleeping at once."""

from __future__ import annotations

import math
import os
import random
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from cosim.outputs.report import summarize
from cosim.scenario.parse import load_scenario
from cosim.sim.master import RunOptions, run_scenario
from mav import fastpath, reference, wire
from mav.airframe import BEBOP2, MAMBO
from mav.control import make_controller
from mav.types import Setpoint, VehicleState

SCEN = Path(__file__).resolve().parents[1] / "scenarios"
NAN = math.nan


def bits(v: float) -> bytes:
    return struct.pack("<d", v)


def test_the_fast_path_is_built_and_used():
    """The install step builds it, so the suite exercises the compiled path (a silent fallback
    to Python would hide a broken build)."""
    assert fastpath.lib is not None, fastpath.describe()
    assert make_controller(MAMBO)._c is not None
    assert make_controller(MAMBO, fast=False)._c is None


def _random_tick(rng: random.Random, s: VehicleState, sp: Setpoint) -> None:
    """A state and setpoint drawn to reach every branch: saturations, NaN fields, yaw wrap,
    tilts beyond 60 deg, disarm/re-arm."""
    u = rng.uniform
    s.x, s.y, s.z = u(-5, 5), u(-5, 5), u(-3, 0.1)
    s.vx, s.vy, s.vz = u(-3, 3), u(-3, 3), u(-2, 2)
    ang = [u(-1.2, 1.2), u(-1.2, 1.2), u(-math.pi, math.pi)]
    if rng.random() < 0.05:
        ang[0] = u(1.2, 3.1)                    # upside down: r33 < 0.5
    cr, sr = math.cos(ang[0] / 2), math.sin(ang[0] / 2)
    cp, spt = math.cos(ang[1] / 2), math.sin(ang[1] / 2)
    cy, sy = math.cos(ang[2] / 2), math.sin(ang[2] / 2)
    s.qw = cr * cp * cy + sr * spt * sy
    s.qx = sr * cp * cy - cr * spt * sy
    s.qy = cr * spt * cy + sr * cp * sy
    s.qz = cr * cp * sy - sr * spt * cy
    s.p, s.q, s.r = u(-4, 4), u(-4, 4), u(-4, 4)

    def maybe(lo, hi, p_nan=0.3):
        return NAN if rng.random() < p_nan else u(lo, hi)
    sp.x, sp.y = maybe(-8, 8), maybe(-8, 8)
    sp.z = maybe(-4, 0)
    sp.vx, sp.vy, sp.vz = maybe(-4, 4), maybe(-4, 4), maybe(-3, 3)
    sp.yaw = maybe(-4, 4, 0.5)
    sp.yaw_rate = maybe(-5, 5)
    sp.ax = maybe(-6, 6, 0.5)
    sp.ay = u(-6, 6)
    sp.armed = rng.random() > 0.02


@pytest.mark.parametrize("vehicle", [MAMBO, BEBOP2], ids=["mambo", "bebop2"])
def test_compiled_controller_is_bit_identical_to_the_reference(vehicle):
    rng = random.Random(16)
    ref, fast = make_controller(vehicle, fast=False), make_controller(vehicle, fast=True)
    s, sp = VehicleState(), Setpoint()
    out_r, out_f = [0.0] * 4, [0.0] * 4
    for k in range(20_000):
        if k % 2000 == 0:   # a parameter change mid-run rebuilds both gain sets
            for c in (ref, fast):
                c.set_param("MPC_XY_VEL_MAX", 0.5 + k / 4000)
        _random_tick(rng, s, sp)
        ref.update(s, sp, out_r)
        fast.update(s, sp, out_f)
        assert list(map(bits, out_r)) == list(map(bits, out_f)), (k, out_r, out_f)
        state = (ref._i_p, ref._i_r, ref._i_z, ref._i_n, ref._i_e, ref._yaw_ref, ref._n)
        assert list(map(bits, state[:6])) == list(map(bits, fast._c.integrators()[:6])), k
        assert state[6] == fast._c.integrators()[6]
    ref.reset()
    fast.reset()
    assert fast._c.integrators() == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0)


def test_compiled_controller_rejects_bad_arguments():
    c = make_controller(MAMBO, fast=True)
    with pytest.raises(TypeError):
        c.update(VehicleState(), Setpoint())
    with pytest.raises(ValueError, match="47 values"):
        c._c.set_gains((1.0,) * 3)
    sp = Setpoint()
    sp.armed = True
    with pytest.raises(AttributeError):
        c.update(object(), sp, [0.0] * 4)


def _fly(name: str, fast: bool, mode: str = "mil"):
    sc = load_scenario(SCEN / f"{name}.toml")
    if fast:
        res = run_scenario(sc, RunOptions(mode=mode))
    else:
        with reference.python():
            assert fastpath.lib is None
            res = run_scenario(sc, RunOptions(mode=mode))
        assert fastpath.lib is not None
    return res, summarize(res)


@pytest.mark.parametrize("name,mode", [("mambo_seed_track", "mil"),
                                       ("bebop2_scripted_square", "mil"),
                                       ("mambo_seed_track", "sil")])
def test_closed_loop_missions_identical_compiled_and_reference(name, mode):
    """The whole onboard stack compiled vs its Python reference (in SIL, the onboard process
    runs the reference: MAV_FASTPATH=0): the same run, bit for bit, and the same MAVLink
    bytes (telemetry, setpoints) in the tlog."""
    ref, s_ref = _fly(name, fast=False, mode=mode)
    fast, s_fast = _fly(name, fast=True, mode=mode)
    assert ref.exit_reason == fast.exit_reason and ref.ticks == fast.ticks
    assert np.array_equal(ref.series, fast.series, equal_nan=True)
    assert ref.tlog.read() == fast.tlog.read()       # every MAVLink byte on api and gcs
    def same(s):   # everything but the wall-clock figures
        return {k: v for k, v in s.items() if "wall" not in k and "real_time" not in k}
    assert same(s_ref) == same(s_fast)


# ------------------------------------------------------------------ MAVLink framing
class _Layout:
    """A FastMsg stand-in for an arbitrary message id and CRC_EXTRA."""

    def __init__(self, msgid: int, crc_extra: int) -> None:
        self.id = msgid
        self.crc_extra = crc_extra
        self.extra = bytes((crc_extra,))
        self.id3 = struct.pack("<I", msgid)[:3]


def test_compiled_framing_gives_the_same_bytes(monkeypatch):
    from pymavlink.dialects.v20 import common as M

    from mav import wire

    assert wire._fp_frame is not None
    rng = random.Random(7)
    for k in range(5000):
        n = rng.randint(1, 255)
        payload = bytes(rng.randrange(256) if rng.random() < 0.6 else 0 for _ in range(n))
        if k % 50 == 0:
            payload = bytes(n)                      # all zeros: one byte stays
        m = _Layout(rng.randrange(1 << 24), rng.randrange(256))
        mav_c = M.MAVLink(None, rng.randrange(256), rng.randrange(256))
        mav_p = M.MAVLink(None, mav_c.srcSystem, mav_c.srcComponent)
        mav_c.seq = mav_p.seq = k & 0xFF
        got = wire.frame(mav_c, m, payload)
        with monkeypatch.context() as mp:
            mp.setattr(wire, "_fp_frame", None)
            want = wire.frame(mav_p, m, payload)
        assert got == want and mav_c.seq == mav_p.seq, k
    # and pymavlink agrees on a real message
    mav_c, mav_p = M.MAVLink(None, 1, 1), M.MAVLink(None, 1, 1)
    msg = M.MAVLink_attitude_message(1234, 0.1, -0.2, 3.0, 0.0, 0.5, 0.0)
    assert wire.encode_attitude(mav_c, 1234, 0.1, -0.2, 3.0, 0.0, 0.5, 0.0) == msg.pack(mav_p)


def _mutations(rng: random.Random, frame: bytes):
    yield frame
    b = bytearray(frame)
    b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    yield bytes(b)
    yield frame[:rng.randrange(len(frame))]
    yield frame + bytes(rng.randint(1, 20))
    s = bytearray(frame)
    s[2] = 1                                         # "signed" without a signature
    yield bytes(s)
    yield bytes(s) + bytes(13)                       # signed: the signature is not checked here
    s[2] = 2                                         # an unknown incompat flag
    yield bytes(s)


def test_compiled_frame_checks_give_the_same_verdicts(monkeypatch):
    from mav import wire
    from mav.hil import HilSimulatorCodec

    assert wire._fp_check is not None
    rng = random.Random(3)
    hil = HilSimulatorCodec()
    with monkeypatch.context() as mp:
        mp.setattr(wire, "_fp_check", None)
        py_odo = wire.one_frame_decoder(wire.ODOMETRY, struct.Struct("<Q13f168xBB2xb"))
    c_odo = wire.decode_odometry
    for k in range(3000):
        vals = tuple(rng.uniform(-5, 5) for _ in range(13))
        if k % 10 == 0:
            vals = (0.0,) * 13
        odo = hil.encode_odometry(rng.randrange(1 << 40), vals)
        sp = wire.encode_set_position_target_local_ned(
            hil.mav, k, 1, 1, 1, rng.randrange(1 << 16), *(rng.uniform(-9, 9) for _ in range(11)))
        for data in (*_mutations(rng, odo), *_mutations(rng, sp), sp + odo):
            assert c_odo(data) == py_odo(data), k
            for m in (wire.ODOMETRY, wire.SET_POSITION_TARGET_LOCAL_NED):
                got = wire.decode_fast(m, data)
                with monkeypatch.context() as mp:
                    mp.setattr(wire, "_fp_check", None)
                    want = wire.decode_fast(m, data)
                assert got == want or _same_nan(got, want), k


def _same_nan(a, b) -> bool:
    return a is not None and b is not None and len(a) == len(b) and all(
        x == y or (x != x and y != y) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("spin_us", [0.0, 50.0])
def test_sil_hil_wait_spinning_or_not_gives_the_same_run(spin_us):
    """How the SIL processes wait for each other's HIL datagram (poll for a while, or sleep in
    the kernel at once) changes the wall time only: the run equals the MIL one bit for bit."""
    sc = load_scenario(SCEN / "mambo_seed_track.toml")
    mil = run_scenario(sc, RunOptions(mode="mil"))
    sil = run_scenario(sc, RunOptions(mode="sil", hil_spin_us=spin_us))
    assert sil.exit_reason == mil.exit_reason and sil.ticks == mil.ticks
    assert np.array_equal(mil.series, sil.series, equal_nan=True)


def test_sil_over_a_unix_domain_hil_link_gives_the_same_run():
    """Issue 16: the simulator link over a Unix-domain datagram socket (the api and gcs links
    stay UDP): the same run as MIL bit for bit, every MAVLink byte of the tlog too, and the
    socket files are gone afterwards."""
    import glob
    import tempfile

    sc = load_scenario(SCEN / "mambo_seed_track.toml")
    before = set(glob.glob(os.path.join(tempfile.gettempdir(), "cosim-hil-*")))
    mil = run_scenario(sc, RunOptions(mode="mil"))
    sil = run_scenario(sc, RunOptions(mode="sil", hil_transport="unix"))
    assert sil.exit_reason == mil.exit_reason and sil.ticks == mil.ticks
    assert np.array_equal(mil.series, sil.series, equal_nan=True)
    assert mil.tlog.read() == sil.tlog.read()
    assert sil.onboard_stats["rx_hil"] == sil.ticks >= 14000
    assert set(glob.glob(os.path.join(tempfile.gettempdir(), "cosim-hil-*"))) == before
    with pytest.raises(ValueError, match="hil_transport: got 'tcp'"):
        run_scenario(sc, RunOptions(mode="sil", hil_transport="tcp"))


def test_unix_link_behaves_as_the_udp_link(tmp_path):
    """UnixLink: datagrams both ways, replies go to the last sender when no remote is fixed,
    a send to nobody is a counted drop, recv_spin waits, close removes the socket file."""
    from mav.links import UnixLink

    a_path, b_path = str(tmp_path / "a"), str(tmp_path / "b")
    b = UnixLink(b_path)                       # answers whoever sent last
    a = UnixLink(a_path, remote=b_path)
    assert b.recv() is None and a.local_address == a_path
    b.send(b"early")                           # nobody has sent yet: dropped, counted
    assert b.dropped_sends == 1
    a.send(b"\xfd" * 300)
    assert b.recv_spin(10_000_000, 1.0) == b"\xfd" * 300 and b.remote == a_path
    b.send(b"back")
    assert a.recv_spin(0, 1.0) == b"back"
    a.close()
    b.send(b"to a closed peer")                # the peer's file is gone: a counted drop
    assert b.dropped_sends == 2 and not os.path.exists(a_path)
    b.close()
    b.close()                                  # idempotent
    assert not os.path.exists(b_path)


def _setpoint_datagrams(rng: random.Random, n: int) -> list[bytes]:
    """SET_POSITION_TARGET_LOCAL_NED datagrams a client or an attacker may send: valid streams
    of every kind (position, velocity, both, yaw or rate), masks PX4 refuses, wrong targets,
    BODY_NED and unknown frames, NaN / inf / huge values, trimmed, corrupted and signed-flag
    frames."""
    mav = M.MAVLink(None, 1, 191)
    masks = [0x0DF8, 0x0DC7, 0x0DC0, 0x09F8, 0x05F8, 0x0DFB, 0x0DE7, 0x0FFF, 0x0DF9, 0x0000,
             0x0DC4, 0x0DE0, 0x0C38, rng.randrange(65536)]
    specials = [math.nan, math.inf, -math.inf, 1e30, 1e4, 1.00001e4, 20.0, 20.001, -12.57,
                12.566, 3.3, -0.0, 7.5]

    def val(scale: float) -> float:
        return rng.choice(specials) if rng.random() < 0.08 else rng.uniform(-scale, scale)

    out = []
    for _ in range(n):
        tsys = 1 if rng.random() < 0.9 else rng.choice([0, 2, 255])
        tcomp = rng.choice([1, 1, 1, 0, 0, 191, 2])
        frame = rng.choice([1] * 8 + [8, 8, 7, 9, 0])
        data = wire.encode_set_position_target_local_ned(
            mav, rng.randrange(1 << 32), tsys, tcomp, frame, rng.choice(masks), val(50), val(50),
            val(10), val(5), val(5), val(3), val(1), val(1), val(1), val(8), val(5))
        r = rng.random()
        if r < 0.04:          # a corrupted byte
            i = rng.randrange(len(data))
            data = data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1:]
        elif r < 0.06:        # the signed flag without a signature, or with 13 junk bytes
            data = data[:2] + b"\x01" + data[3:] + (b"\x00" * 13 if rng.random() < 0.5 else b"")
        elif r < 0.08:        # a second frame in the datagram
            data += data
        out.append(data)
    return out


def test_compiled_setpoint_path_equals_the_python_one():
    """Issue 16: mav/csrc/setpoint.c applies the offboard setpoints the Python path accepts,
    and hands every other datagram back to it: two vehicles, one compiled and one the Python
    reference, fed the same 6000 datagrams on the api link, have the same offboard setpoint
    (bit for bit, NaN where not commanded), the same time of the last one and the same
    counters after every tick."""
    from test_onboard_rig import Rig

    from mav.onboard.links import LinkInput

    assert fastpath.lib is not None, "mav/_fastpath not built: python -m mav.build"
    fast = Rig(decode=False)
    with reference.python():
        slow = Rig(decode=False)
    assert fast.ob.input._fast_sp is not None and slow.ob.input._fast_sp is None
    assert isinstance(fast.ob.input, LinkInput)
    rng = random.Random(16)
    pack = struct.Struct("<8d").pack
    for k, data in enumerate(_setpoint_datagrams(rng, 6000)):
        for rig in (fast, slow):
            rig.send_raw("api", data)
            if k % 3 == 0:                   # sometimes several per tick
                rig.tick()
        if k % 3:
            continue
        a, b = fast.ob.status, slow.ob.status
        fa = [getattr(a.of, f) for f in ("x", "y", "z", "vx", "vy", "vz", "yaw", "yaw_rate")]
        fb = [getattr(b.of, f) for f in ("x", "y", "z", "vx", "vy", "vz", "yaw", "yaw_rate")]
        assert pack(*fa) == pack(*fb), (k, data.hex())
        assert a.of_last_us == b.of_last_us and a.stats == b.stats, k
    assert fast.ob.stats["setpoints"] > 1000 and fast.ob.stats["rejected_setpoints"] > 500



def test_spin_policy_stops_spinning_while_it_does_not_pay():
    """SIL waits: spinning continues while most answers come within it; a window of mostly
    misses (CPUs shared with other jobs) stops it for `backoff` waits, then it is tried
    again; no spin asked, none ever."""
    from mav.links import SpinPolicy

    sp = SpinPolicy(200_000, window=10, backoff=30)
    for _ in range(50):
        sp.record(True)
    assert sp.ns == 200_000
    for k in range(10):                  # 4 hits of 10: under half
        sp.record(k < 4)
    assert sp.ns == 0
    for _ in range(29):
        sp.record(False)
    assert sp.ns == 0
    sp.record(False)
    assert sp.ns == 200_000              # tried again
    for k in range(10):                  # 5 of 10: keeps spinning
        sp.record(k % 2 == 0)
    assert sp.ns == 200_000
    off = SpinPolicy(0)
    for _ in range(500):
        off.record(False)
    assert off.ns == 0
