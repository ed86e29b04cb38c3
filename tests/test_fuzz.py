"""Fuzzing every link of the onboard vehicle: random bytes, mutated valid packets of every
message type, and valid packets with hostile field values. The vehicle must never raise, must
keep answering HIL exactly once per valid ODOMETRY, and must count what it dropped.

Bounded by a wall-clock budget per link (seeded, so a failure can be replayed with the seed).
"""

from __future__ import annotations

import math
import os
import random

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from mav import wire

M = mavlink2
ROUNDS = 500                         # rounds of 20 fuzzed datagrams per link (10000), then a tick
ALL_TYPES = sorted(M.mavlink_map.values(), key=lambda c: c.id)
HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 1e38, -1e38, 1e-45, 21196.0, 1.0,
                  -1.0, 4.0, 6.0)


def _value(rng: random.Random, ftype: str):
    base = ftype.split("[")[0]
    if base in ("float", "double"):
        return rng.choice(HOSTILE_FLOATS) if rng.random() < 0.6 else rng.uniform(-1e3, 1e3)
    if base == "char":
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 17)))
    bits = int("".join(ch for ch in base if ch.isdigit()))
    if rng.random() < 0.3:
        return rng.choice([0, 1, (1 << bits) - 1 if base.startswith("u") else -1])
    if base.startswith("u"):
        return rng.randrange(1 << bits)
    return rng.randrange(-(1 << (bits - 1)), 1 << (bits - 1))


def random_message(rng: random.Random, cls=None):
    cls = cls or rng.choice(ALL_TYPES)
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = cls.array_lengths[cls.ordered_fieldnames.index(name)]
        if n and not ftype.startswith("char"):
            args.append([_value(rng, ftype) for _ in range(n)])
        elif n:
            args.append(bytes(rng.randrange(256) for _ in range(rng.randrange(0, n + 1))))
        else:
            args.append(_value(rng, ftype))
    return cls(*args)


# messages the vehicle acts on: fuzz these more, aimed at our system id
TARGETED = [M.MAVLink_command_long_message, M.MAVLink_command_int_message,
            M.MAVLink_set_position_target_local_ned_message, M.MAVLink_param_set_message,
            M.MAVLink_param_request_read_message, M.MAVLink_param_request_list_message,
            M.MAVLink_set_mode_message, M.MAVLink_request_data_stream_message,
            M.MAVLink_mission_request_list_message, M.MAVLink_timesync_message,
            M.MAVLink_mission_count_message, M.MAVLink_mission_item_int_message,
            M.MAVLink_mission_item_message, M.MAVLink_mission_request_int_message,
            M.MAVLink_mission_request_message, M.MAVLink_mission_ack_message,
            M.MAVLink_mission_clear_all_message, M.MAVLink_mission_set_current_message,
            M.MAVLink_manual_control_message, M.MAVLink_heartbeat_message,
            M.MAVLink_set_position_target_global_int_message,
            M.MAVLink_set_attitude_target_message, M.MAVLink_file_transfer_protocol_message]
COMMANDS = [400, 22, 21, 176, 512, 511, 510, 520, 519, 410, 20, 246, 192, 178, 224, 300, 0,
            65535]


def hostile_valid(rng: random.Random, mav, target: int = 1) -> bytes:
    """A CRC-correct packet with hostile contents (mostly aimed at system 1; with another
    `target`, every targeted message is addressed to that system)."""
    cls = rng.choice(TARGETED) if rng.random() < 0.7 else None
    msg = random_message(rng, cls)
    aim = target != 1 or rng.random() < 0.8
    if hasattr(msg, "target_system") and aim:
        msg.target_system = target
    if hasattr(msg, "target") and aim:                        # MANUAL_CONTROL
        msg.target = target
    if hasattr(msg, "target_component") and rng.random() < 0.8:
        msg.target_component = rng.choice([0, 1])
    if hasattr(msg, "command") and isinstance(msg, (M.MAVLink_command_long_message,
                                                    M.MAVLink_command_int_message)):
        msg.command = rng.choice(COMMANDS)
    if isinstance(msg, M.MAVLink_param_set_message) and rng.random() < 0.5:
        msg.param_id = rng.choice([b"COM_OF_LOSS_T", b"TPL_LAND_SPEED", b"MIS_TAKEOFF_ALT",
                                   b"BAT1_CAPACITY", b"X" * 16])
    if isinstance(msg, M.MAVLink_set_position_target_local_ned_message):
        msg.coordinate_frame = rng.choice([1, 8, 0, 7, 255])
    try:
        return wire.send_msg(mav, msg)
    except Exception:          # pymavlink cannot pack some random values (e.g. char lengths)
        return b""


def mutate(rng: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    op = rng.randrange(8)
    if op == 0 and b:                                   # bit flips
        for _ in range(rng.randrange(1, 4)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif op == 1:                                       # truncate
        del b[rng.randrange(len(b) + 1):]
    elif op == 2:                                       # extend with junk
        b += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
    elif op == 3 and len(b) > 2:                        # length byte
        b[1] = rng.randrange(256)
    elif op == 4 and len(b) > 2:                        # incompat flags (signed / unknown)
        b[2] = rng.choice([1, 2, 0x81, 0xFF])
    elif op == 5 and b:                                 # v1 <-> v2 magic
        b[0] = 0xFE if b[0] == 0xFD else 0xFD
    elif op == 6:                                       # several frames in one datagram
        b = b * rng.randrange(2, 40)
    else:                                               # msg id bytes
        if len(b) > 9:
            b[7], b[8], b[9] = rng.randrange(256), rng.randrange(4), 0
    return bytes(b)


def fuzz_datagram(rng: random.Random, mav, target: int = 1) -> bytes:
    r = rng.random()
    if r < 0.15:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
    valid = hostile_valid(rng, mav, target)
    if r < 0.55:
        return valid
    return mutate(rng, valid)


@pytest.mark.parametrize("target", ["api", "gcs", "hil"])
def test_fuzz_link(target):
    seed = {"api": 1, "gcs": 2, "hil": 3}[target]
    rng = random.Random(seed)
    rig = Rig(decode=False)
    rig.tick()
    mav = M.MAVLink(None, 250 if target == "hil" else 255, 190)
    sent = 0
    for _ in range(ROUNDS):  # a fixed count: the same seed replays the same datagrams
        for _ in range(20):
            d = fuzz_datagram(rng, mav)
            if target == "hil":
                rig.hil.send(d)
                ok = rig.ob.poll()               # a lucky valid ODOMETRY is answered
                ans = rig.hil.recv()
                assert (ans is not None) == ok
                if ok:
                    assert wire.decode_fast(wire.HIL_ACTUATOR_CONTROLS, ans) is not None
            else:
                rig.links[target].send(d)
            sent += 1
        rig.tick()                                # and the real simulator still gets answers
        rig.raw = {"api": [], "gcs": []}
    st = rig.ob.stats
    assert st["handler_errors"] == 0, "a handler raised on fuzzed input"
    assert sent == 20 * ROUNDS
    assert st[f"dropped_bad_{target}"] > sent // 20
    if target != "hil":
        assert st["unknown_msgs"] > 0
        assert st["rx_" + target] == sent
        assert st["rejected_setpoints"] + st["setpoints"] > 0
    # afterwards: a clean vehicle still does its job on this rig
    n = len(rig.answers)
    rig.tick(40)
    assert len(rig.answers) == n + 40
    assert [a[0] for a in rig.answers[-3:]] == [rig.t_us - 15000, rig.t_us - 10000,
                                                rig.t_us - 5000]


def test_flood_is_bounded_per_tick():
    """A flood on one link is handled DRAIN_MAX datagrams at a time; the HIL answer comes."""
    from mav.onboard import DRAIN_MAX

    rig = Rig(decode=False)
    rig.tick()
    mav = M.MAVLink(None, 255, 190)
    hb = wire.send_msg(mav, M.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    for _ in range(3 * DRAIN_MAX):
        rig.send_raw("gcs", hb)
    rig.tick()
    assert rig.ob.stats["rx_gcs"] == DRAIN_MAX and rig.ob.stats["drain_deferred"] == 1
    rig.tick(3)
    assert rig.ob.stats["rx_gcs"] == 3 * DRAIN_MAX


@pytest.mark.skipif(not os.path.exists("/proc/net/udp"), reason="Linux's /proc/net/udp")
def test_kernel_drops_are_counted():
    """What a full socket buffer sheds is counted: every datagram sent to the vehicle is
    either handled (rx_gcs) or dropped by the kernel (dropped_kernel_gcs), none lost
    uncounted; the other links' counters stay 0, a link in memory has none."""
    import socket

    from mav.hil import HilSimulatorCodec
    from mav.links import UdpLink
    from mav.onboard import Onboard, OnboardConfig

    hil, api, gcs = UdpLink(), UdpLink(), UdpLink()
    gcs.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)   # holds a few only
    ob = Onboard(OnboardConfig(), hil, api, gcs)
    sim = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    hb = wire.send_msg(M.MAVLink(None, 2, 1), M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
    codec = HilSimulatorCodec()
    odo = (0.0, 0.0, 0.0, 1.0) + (0.0,) * 9
    n = 3000
    try:
        for i in range(n):
            sim.sendto(hb, gcs.local_address)
            if i % 1000 == 999:              # a tick now and then drains what was queued
                sim.sendto(codec.encode_odometry(i * 5, odo), hil.local_address)
                assert ob.poll()
        sim.sendto(codec.encode_odometry(n * 5, odo), hil.local_address)
        assert ob.poll()
        got = ob.count_kernel_drops()
        st = ob.stats
        assert st["rx_gcs"] + st["dropped_kernel_gcs"] == n
        assert 0 < st["rx_gcs"] < n and st["drain_deferred"] == 0
        assert got == {"dropped_kernel_hil": 0, "dropped_kernel_api": 0,
                       "dropped_kernel_gcs": st["dropped_kernel_gcs"]}
    finally:
        sim.close()
        for link in (hil, api, gcs):
            link.close()
    assert ob.count_kernel_drops() == {}                  # closed sockets: nothing to read
    assert Rig(decode=False).ob.count_kernel_drops() == {}     # links in memory


@pytest.mark.skipif(not os.path.exists("/proc/net/udp"), reason="Linux's /proc/net/udp")
def test_sitl_links_report_kernel_drops(tmp_path):
    """`cosim sitl`'s vehicle (the stack in the master's process on UDP links): its stats,
    read as the run closes its links, say what the GCS socket's full buffer dropped."""
    import socket
    from pathlib import Path

    from cosim.load import load_scenario
    from cosim.outputs.tlog import Tlog
    from cosim.sim.onboard import OnboardHandle
    from cosim.sim.options import RunOptions
    from mav.hil import HilSimulatorCodec
    from mav.links import UdpLink

    sc = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "mambo_hover.toml")
    sinks = {name: UdpLink() for name in ("api", "gcs")}
    ext = {name: (("127.0.0.1", 0), link.local_address) for name, link in sinks.items()}
    h = OnboardHandle(sc, RunOptions(external_links=ext, sitl=True), Tlog(tmp_path / "t.tlog"),
                      tmp_path)
    codec = HilSimulatorCodec()
    meas = (sc.start.n, sc.start.e, 0.0, 1.0) + (0.0,) * 9
    hb = wire.send_msg(M.MAVLink(None, 255, 190), M.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    flood = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    n = 30_000
    try:
        for _ in range(n):
            flood.sendto(hb, h.bound["gcs"])
        for k in range(100):                    # 256 a tick: everything queued is handled
            h.exchange(codec.encode_odometry(k * 5000, meas))
    finally:
        flood.close()
        h.close()
        for link in sinks.values():
            link.close()
    st = h.stats()
    assert st["dropped_kernel_gcs"] > 0 and st["rx_gcs"] + st["dropped_kernel_gcs"] == n
    assert st["dropped_kernel_api"] == 0 and "dropped_kernel_hil" not in st   # HIL: in memory


@pytest.mark.slow
def test_long_fuzz_in_flight_keeps_position_and_rates():
    """Issue 14: >= 100k datagrams per link (random bytes, mutations, CRC-valid packets of
    every message id the vehicle handles with hostile values, all addressed to another
    system so none is a legitimate order) while the vehicle hovers: it keeps its position,
    answers every HIL tick and keeps its 1 Hz heartbeat on both links."""
    from test_onboard_auto import flying_rig, pos

    rng = random.Random(11)
    rig = flying_rig()
    rig.decode = True
    home = pos(rig)
    mav = M.MAVLink(None, 255, 190)
    per_tick, n = 25, 100_000           # within DRAIN_MAX a tick: all handled at once
    from mav.onboard import DRAIN_MAX

    assert per_tick <= DRAIN_MAX

    worst, answers0, t0 = 0.0, len(rig.answers), rig.t_us
    rig.clear()
    api_hb: list[int] = []                 # the app's client owns the api link: count there
    on_hb = rig.client._on_heartbeat

    def count_hb(f, compid):
        api_hb.append(rig.t_us)
        on_hb(f, compid)

    rig.client._fast_handlers[M.MAVLINK_MSG_ID_HEARTBEAT] = count_hb
    for _ in range(n // per_tick):
        for link in ("api", "gcs"):
            for _ in range(per_tick):
                rig.links[link].send(fuzz_datagram(rng, mav, target=7))
        rig.tick()
        worst = max(worst, math.dist(pos(rig), home))
    st = rig.ob.stats
    ticks = (rig.t_us - t0) // 5000
    assert st["handler_errors"] == 0 and len(rig.answers) - answers0 == ticks
    assert st["rx_api"] >= n and st["rx_gcs"] >= n
    assert worst < 0.05 and rig.ob.armed and rig.ob.mode_name == "AUTO.LOITER"
    for link in ("api", "gcs"):
        hbs = api_hb if link == "api" else [
            t for t, m in rig.rx[link] if m is not None and m.get_type() == "HEARTBEAT"]
        gaps = [b - a for a, b in zip(hbs, hbs[1:], strict=False)]
        assert len(hbs) >= ticks * 5000 // 1_000_000 - 1 and max(gaps) <= 1_000_000, link
