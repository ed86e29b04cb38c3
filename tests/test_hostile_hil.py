"""A hostile HIL link (issue 43): datagrams the simulator never sent, put on the vehicle's HIL
link between its own. None may step the vehicle's clock, its estimate, its battery or its
timers; each is dropped and counted by its reason (`mav.hil.tick_refusal`): another system's
(`dropped_foreign_hil`), a stamp not later than the last tick (`dropped_stale_hil`: repeats,
replays, a clock gone back) or more than HIL_MAX_STEP_US ahead (`dropped_jump_hil`). A
sensor stream whose IMU readings are all rejected is an IMU failure: a blind descent, no
landing declared on a frozen estimate."""

from __future__ import annotations

import math
import random
import socket
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from cosim.load import load_scenario, with_set
from cosim.sim import onboard as onboard_mod
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from mav import hil_sensors as hs
from mav.hil import HIL_MAX_STEP_US, SIM_SYSID, tick_refusal

ROOT = Path(__file__).resolve().parent.parent
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
HOVER = ROOT / "scenarios" / "mambo_hover.toml"
NAN = math.nan
DROPS = ("dropped_stale_hil", "dropped_jump_hil", "dropped_foreign_hil")
_SOCKETS: list[socket.socket] = []


def _imu(mav, t_us: int, nan: bool = False) -> bytes:
    """A HIL_SENSOR at rest (or every reading NaN), stamped t_us."""
    if nan:
        return hs.encode_hil_sensor(mav, t_us, (NAN,) * 3, (NAN,) * 3, (NAN,) * 3, NAN, NAN,
                                    NAN, 0x1FFF)
    return hs.encode_hil_sensor(mav, t_us, (0.0, 0.0, -9.81), (0.0, 0.0, 0.0), (0.2, 0.0, 0.4),
                                1012.0, 0.0, 25.0, 0x1FFF)


# datagrams on the HIL link: MIL's framed exchange (the typed one has no link to put them
# on), SIL's; each clean run they are compared with is MIL's default, typed
def framed() -> RunOptions:
    return RunOptions(hil_exchange="framed")


class Injector:
    """Wraps OnboardHandle.exchange: `before(k, t_us, data)` returns the datagrams to put on
    the vehicle's HIL link before the tick's own (MIL: in memory; SIL: from a socket of its
    own to the vehicle's HIL port), and `replace(k, t_us, data)` the tick's own datagram. The
    run must use the framed exchange (`framed()`, or SIL)."""

    def __init__(self, monkeypatch, before=None, replace=None) -> None:
        self.k = 0
        self.sent = 0
        orig = onboard_mod.OnboardHandle.exchange
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        _SOCKETS.append(sock)

        def exchange(handle, data: bytes) -> bytes:
            k, t_us = self.k, self.k * 5000
            self.k += 1
            for d in (before(k, t_us, data) if before else ()):
                self.sent += 1
                if handle.proc is None:
                    handle.hil.send(d)
                else:
                    sock.sendto(d, ("127.0.0.1", handle.proc.ports["hil"]))
            if replace is not None:
                data = replace(k, t_us, data)
            return orig(handle, data)

        monkeypatch.setattr(onboard_mod.OnboardHandle, "exchange", exchange)


@pytest.fixture(autouse=True)
def _close_sockets():
    yield
    while _SOCKETS:
        _SOCKETS.pop().close()


def _texts(res) -> list[str]:
    from test_faults import _statustexts

    return _statustexts(res)[::2]          # each text is sent on both links


def test_the_tick_refusals():
    assert tick_refusal(SIM_SYSID, 123, -1) is None               # the first starts the clock
    assert tick_refusal(SIM_SYSID, 5000, 0) is None
    assert tick_refusal(SIM_SYSID, HIL_MAX_STEP_US, 0) is None
    assert tick_refusal(SIM_SYSID, HIL_MAX_STEP_US + 1, 0) == "dropped_jump_hil"
    assert tick_refusal(SIM_SYSID, 0, 0) == "dropped_stale_hil"
    assert tick_refusal(SIM_SYSID, 0, 5000) == "dropped_stale_hil"
    assert tick_refusal(SIM_SYSID + 1, 5000, 0) == "dropped_foreign_hil"


@pytest.mark.flight
def test_seeded_hostile_datagrams_change_nothing_and_each_is_counted(monkeypatch):
    """Stamps gone back, repeated, replayed, far ahead; other systems; floods of them: the
    flight is the clean one bit for bit (no failsafe, no battery step, no tick), and every
    one is counted by its reason."""
    sc = with_set(load_scenario(SQUARE), {"timing.t_final_s": 10.0})
    clean = run_scenario(sc, RunOptions())
    rng = random.Random(43)
    sim = M.MAVLink(None, SIM_SYSID, M.MAV_COMP_ID_SYSTEM_CONTROL)
    other = M.MAVLink(None, 77, M.MAV_COMP_ID_SYSTEM_CONTROL)
    want = dict.fromkeys(DROPS, 0)
    last: list[bytes] = []

    def before(k: int, t_us: int, data: bytes) -> list[bytes]:
        last.append(data)
        out: list[tuple[str, bytes]] = []
        if k < 400 or rng.random() > 0.2:              # from 2 s, on a fifth of the ticks
            return []
        for _ in range(rng.choice((1, 1, 1, 3, 40))):  # sometimes a flood
            kind = rng.randrange(8)
            if kind == 0:                              # the last tick's datagram again
                out.append(("dropped_stale_hil", last[-2]))
            elif kind == 1:                            # an old one, replayed
                out.append(("dropped_stale_hil", last[rng.randrange(len(last) - 1)]))
            elif kind == 2:                            # the clock back to 0
                out.append(("dropped_stale_hil", _imu(sim, 0)))
            elif kind == 3:                            # the one-off 1e12 us of the issue
                out.append(("dropped_jump_hil", _imu(sim, 10**12)))
            elif kind == 4:                            # just beyond the step
                out.append(("dropped_jump_hil", _imu(sim, t_us - 5000 + HIL_MAX_STEP_US + 1)))
            elif kind == 5:                            # NaN readings, stamp far ahead
                out.append(("dropped_jump_hil", _imu(sim, t_us + 10**6, nan=True)))
            elif kind == 6:                            # another system, a plausible stamp
                out.append(("dropped_foreign_hil", _imu(other, t_us - 2500)))
            else:                                      # this tick's own, another system's
                out.append(("dropped_foreign_hil", _imu(other, t_us)))
        for why, _ in out:
            want[why] += 1
        return [d for _, d in out]

    inj = Injector(monkeypatch, before=before)
    res = run_scenario(sc, framed())
    assert res.exit_reason is clean.exit_reason, res.message
    assert inj.sent > 200 and all(want.values()), want
    assert res.series.tobytes() == clean.series.tobytes()
    assert res.estimate.tobytes() == clean.estimate.tobytes()
    assert res.tlog.read() == clean.tlog.read()        # no STATUSTEXT, no battery step
    st = res.onboard_stats
    assert {k: st[k] for k in DROPS} == want
    assert st["rx_hil"] == clean.onboard_stats["rx_hil"] + inj.sent
    assert st["ticks"] == clean.onboard_stats["ticks"]


@pytest.mark.flight
def test_sil_a_datagram_stamped_1e12_from_another_socket_is_dropped(monkeypatch):
    """The issue's SIL case: one HIL_SENSOR stamped 1e12 us drained the battery to 0 % and
    fired the offboard-loss failsafe. Now it is dropped and counted; the flight is MIL's."""
    sc = with_set(load_scenario(SQUARE), {"timing.t_final_s": 6.0})
    clean = run_scenario(sc, RunOptions())
    sim = M.MAVLink(None, SIM_SYSID, M.MAV_COMP_ID_SYSTEM_CONTROL)
    Injector(monkeypatch, before=lambda k, t, d: [_imu(sim, 10**12)] if k == 600 else [])
    res = run_scenario(sc, RunOptions(mode="sil"))
    assert res.series.tobytes() == clean.series.tobytes(), res.message
    assert res.onboard_stats["dropped_jump_hil"] == 1


@pytest.mark.flight
def test_single_nan_datagrams_step_nothing(monkeypatch):
    """A tick whose every reading is NaN (once a second): rejected and counted; the estimate
    and the motors' torque wait for the next reading; no failsafe, and the battery within a
    tick's draw of the clean flight's."""
    sc = with_set(load_scenario(SQUARE), {"timing.t_final_s": 10.0})
    clean = run_scenario(sc, RunOptions())
    sim = M.MAVLink(None, SIM_SYSID, M.MAV_COMP_ID_SYSTEM_CONTROL)
    res_k: list[int] = []

    def replace(k: int, t_us: int, data: bytes) -> bytes:
        if k >= 400 and k % 200 == 0:
            res_k.append(k)
            return _imu(sim, t_us, nan=True)
        return data

    Injector(monkeypatch, replace=replace)
    res = run_scenario(sc, framed())
    assert res.exit_reason is clean.exit_reason, res.message
    st = res.onboard_stats
    assert st["est_rej_imu"] == len(res_k) and st["failsafe_imu"] == 0
    assert not [x for x in _texts(res) if "ailsafe" in x]
    d = abs(res.series[:, 1:4] - clean.series[:, 1:4]).max()
    assert d < 0.05, d                                  # m: the flight barely moved


@pytest.mark.flight
def test_a_stream_of_nan_readings_is_an_imu_failure_and_a_blind_descent(monkeypatch):
    """Every reading NaN from 3 s on, hovering at 1 m (the issue: "Landing detected,
    disarmed" at 1 m on the frozen estimate, then a 4.3 m/s touchdown): the vehicle declares
    an IMU failure after IMU_FAIL_US, descends blind at PX4's 0.15 m/s^2 and disarms on the
    floor; no landing is detected in the air."""
    from mav.onboard.failsafe import IMU_FAIL_US

    sc = with_set(load_scenario(HOVER), {"timing.t_final_s": 12.0})
    sim = M.MAVLink(None, SIM_SYSID, M.MAV_COMP_ID_SYSTEM_CONTROL)
    Injector(monkeypatch, replace=lambda k, t, d: _imu(sim, t, nan=True) if k >= 600 else d)
    res = run_scenario(sc, framed())
    texts = _texts(res)
    assert "Failsafe: no valid IMU data, landing" in texts, texts
    assert "Landing detected, disarmed" not in texts
    assert texts[-1] == "Blind descent over, disarmed"
    assert res.onboard_stats["failsafe_imu"] == 1
    t, z, vz = res.series[:, 0], res.series[:, 3], res.series[:, 6]
    assert res.exit_reason is ExitReason.LANDED, res.message
    assert z[-1] > -0.01 and t[-1] < 10.0              # on the floor, disarmed
    # m/s: no hard touchdown (0.44-0.48), the descent's speed while airborne (the ground
    # contact's own transient is not a touchdown speed)
    assert vz[z < -0.005].max() < 0.6
    assert abs(z[t < 3.0 + IMU_FAIL_US * 1e-6][-1] - z[t < 3.0][-1]) < 0.02
