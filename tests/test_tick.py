"""The compiled tick (mav/csrc/tick.c) against its reference, `Onboard.poll` in Python.

Back to back, the Simulink model-vs-generated-code way: whole missions (recorded series, tlog
bytes, counters), and a random session played into two vehicles at once, one per tick
implementation, comparing every byte each sends on every link, what each `poll` returns and
the records it keeps, tick by tick. The session covers the rare branches the compiled tick
hands to Python: datagrams that are not ODOMETRY on the HIL link (garbage, a battery fault,
other messages), ODOMETRY with unusable values, a lost estimate, body-frame velocity, bursts
past the drain bound, setpoints mixed with commands and garbage, mode changes through every
mode, GCS heartbeats that stop, and a signed link.
"""

from __future__ import annotations

import hashlib
import math
import random

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_fuzz import fuzz_datagram
from test_onboard_rig import TICK_US, Rig

from cosim.scenario.parse import load_scenario
from cosim.sim.master import RunOptions, run_scenario
from mav import fastpath, wire
from mav.hil import INJECT_COMPID, SIM_SYSID, encode_inject_failure
from mav.onboard import vehicle as vehicle_mod

M = mavlink2
pytestmark = pytest.mark.skipif(fastpath.lib is None, reason="mav/_fastpath not built")


def _fingerprint(r) -> tuple:
    nan_safe = r.series.tobytes()
    return (r.exit_reason, r.ticks, hashlib.sha256(r.tlog.read()).hexdigest(),
            hashlib.sha256(nan_safe).hexdigest(), sorted(r.onboard_stats.items()))


@pytest.mark.parametrize("name", ["mambo_seed_battery", "mambo_seed_dropout",
                                  "mambo_seed_outage", "scripted_square"])
def test_missions_identical_compiled_tick_and_reference(name, monkeypatch):
    sc = load_scenario(f"scenarios/{name}.toml")
    got = {}
    for compiled in (True, False):
        monkeypatch.setattr(vehicle_mod.Onboard, "compiled_tick", compiled)
        got[compiled] = _fingerprint(run_scenario(sc, RunOptions(mode="mil")))
    assert got[True] == got[False]
    assert got[True][1] > 900


def test_the_compiled_tick_is_in_use_and_can_be_turned_off(monkeypatch):
    rig = Rig()
    assert type(rig.ob.poll.__self__) is fastpath.lib.Tick
    monkeypatch.setattr(vehicle_mod.Onboard, "compiled_tick", False)
    rig = Rig()
    assert rig.ob.poll.__func__ is vehicle_mod.Onboard.poll


# ------------------------------------------------------------------ a random session, twice
STATE = ("t", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r")
STATUS = ("t_us", "dt_us", "v_prev", "have_state", "armed", "mode", "landed_state", "home",
          "of_last_us", "fs_active", "gcs_last_us", "gcs_lost", "pos_lost_us", "u",
          "ground_since", "bat_warned", "fence_breached")


def _snapshot(ob) -> tuple:
    vs = ob.status
    b = vs.battery
    chans = tuple((ch.next_due, list(ch.param_queue), ch.peer,
                   [(st.msgid, st.interval_us, st.next_us) for st in ch.streams])
                  for ch in (ob._api, ob._gcs))
    return (chans, tuple(getattr(vs.state, k) for k in STATE),
            tuple(repr(getattr(vs, k)) for k in STATUS),
            repr((b.consumed_mah, b.energy_j, b.current)), ob.origin, dict(ob.stats))


class Twin:
    """Two rigs, one vehicle per tick implementation, fed the same bytes."""

    def __init__(self, monkeypatch, **kw) -> None:
        self.rigs = []
        for compiled in (True, False):
            monkeypatch.setattr(vehicle_mod.Onboard, "compiled_tick", compiled)
            self.rigs.append(Rig(plant=True, decode=False, failsafe_land_s=1.0, **kw))
        assert type(self.rigs[0].ob.poll.__self__) is fastpath.lib.Tick
        assert self.rigs[1].ob.poll.__func__ is vehicle_mod.Onboard.poll
        self.modes: set[tuple] = set()       # (mode, armed, fs_active) seen
        self.sim = M.MAVLink(None, SIM_SYSID, M.MAV_COMP_ID_SYSTEM_CONTROL)
        self.inject = M.MAVLink(None, SIM_SYSID, INJECT_COMPID)

    def send(self, link: str, data: bytes) -> None:
        for rig in self.rigs:
            (rig.hil if link == "hil" else rig.links[link]).send(data)

    def tick(self, odo_kw: dict | None = None, pre_hil: list[bytes] = ()) -> None:
        """One tick: HIL datagrams `pre_hil`, then an ODOMETRY of rig 0's plant state (with
        `odo_kw` overriding frame ids, quality or values); poll until the HIL link is empty;
        compare everything."""
        from cosim.plant.fmu import Y_P, Y_QW, Y_VX, Y_X

        r0 = self.rigs[0]
        y = r0.plant.y
        o = list(y[Y_X:Y_X + 3] + y[Y_QW:Y_QW + 4] + y[Y_VX:Y_VX + 3] + y[Y_P:Y_P + 3])
        kw = dict(odo_kw or {})
        for i, v in kw.pop("values", {}).items():
            o[i] = v
        t_us = r0.k * TICK_US
        odo = wire.encode_odometry(self.sim, t_us, *o, **kw)
        for d in (*pre_hil, odo):
            self.send("hil", d)
        outs = []
        for rig in self.rigs:
            got = []
            while True:      # one poll per datagram, as the master's exchange
                got.append(rig.ob.poll())
                if rig.hil_v_pending() == 0:
                    break
            answers = []
            while (a := rig.hil.recv()) is not None:
                answers.append(a)
            sent = {}
            for name, link in rig.links.items():
                sent[name] = []
                while (d := link.recv()) is not None:
                    sent[name].append(d)
            if answers:
                f = wire.decode_fast(wire.HIL_ACTUATOR_CONTROLS, answers[-1])
                rig.plant.step(*f[2:6])
            rig.k += 1
            outs.append((got, answers, sent, _snapshot(rig.ob)))
        a, b = outs
        vs = r0.ob.status
        self.modes.add((vs.mode, vs.armed, vs.fs_active))
        assert a[0] == b[0], f"poll results differ at k={r0.k - 1}"
        assert a[1] == b[1], f"HIL answers differ at k={r0.k - 1}"
        assert a[2] == b[2], f"link output differs at k={r0.k - 1}"
        assert a[3] == b[3], f"vehicle records differ at k={r0.k - 1}"


def _pending_factory(rig):
    inner = rig.ob._hil
    return lambda: inner.pending()


def _script(twin: Twin, rng: random.Random, n_ticks: int, key: bytes | None) -> None:
    r0 = twin.rigs[0]
    mav = {"api": M.MAVLink(None, 1, 191), "gcs": M.MAVLink(None, 255, 190)}
    if key is not None:         # as the rig's own ends sign (test_onboard_rig.Rig)
        for m in mav.values():
            sg = m.signing
            sg.secret_key, sg.sign_outgoing, sg.link_id = key, True, 7
            sg.timestamp = 283996800 * 100000 + 1
    for rig in twin.rigs:
        rig.hil_v_pending = _pending_factory(rig)

    def cmd(link, command, *p, target=1):
        p = list(p) + [0.0] * (7 - len(p))
        twin.send(link, wire.send_msg(mav[link], M.MAVLink_command_long_message(
            target, 1, command, 0, *p)))

    def setpoint(link="api", frame=M.MAV_FRAME_LOCAL_NED, mask=0b110111111000, target=1,
                 xyz=(0.0, 0.0, -1.0)):
        twin.send(link, wire.encode_set_position_target_local_ned(
            mav[link], r0.k * 5, target, 1, frame, mask, *xyz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            rng.uniform(-4, 4), 0.0))

    modes = [(4, 2), (4, 3), (4, 4), (4, 5), (4, 6), (1, 0), (2, 0), (3, 0), (6, 0), (4, 4)]
    gcs_beat = True
    for k in range(n_ticks):
        pre_hil, odo_kw = [], None
        # the app streams offboard setpoints most ticks; sometimes bursts past the bound
        quiet = 1800 <= k < 2300    # no setpoints: the offboard loss failsafe
        if rng.random() < 0.8 and not quiet:
            for _ in range(40 if rng.random() < 0.02 else 1):
                setpoint(xyz=(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1.5, -0.3)))
        if rng.random() < 0.03 and not quiet:   # setpoints the C path hands on, then a good one
            setpoint(frame=M.MAV_FRAME_BODY_NED, mask=0b110111000111)
            setpoint(target=9)
            setpoint(mask=0b110111111011)
            setpoint()
        if rng.random() < 0.04:
            twin.send(rng.choice(["api", "gcs"]), fuzz_datagram(rng, mav["api"]))
        if k == 5:
            cmd("gcs", M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        if k == 8:
            cmd("gcs", M.MAV_CMD_DO_SET_MODE, 1.0, 4.0, 2.0)      # takeoff
        if 300 < k < 1700 and rng.random() < 0.01:
            main, sub = rng.choice(modes)
            cmd(rng.choice(["api", "gcs"]), M.MAV_CMD_DO_SET_MODE, 1.0, float(main), float(sub))
        if k > 300 and rng.random() < 0.003:
            cmd("gcs", M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        if rng.random() < 0.01:     # stream rates changed, streams off and back, params
            msgid = rng.choice([30, 32, 33, 24, 1, 74, 85, 147, 245, 105])
            hz = rng.choice([-1.0, 0.0, 1.0, 7.0, 50.0, 400.0])
            cmd(rng.choice(["api", "gcs"]), M.MAV_CMD_SET_MESSAGE_INTERVAL, float(msgid),
                1e6 / hz if hz > 0 else hz)
        if rng.random() < 0.002:
            twin.send("gcs", wire.send_msg(mav["gcs"], M.MAVLink_param_request_list_message(
                1, 1)))
        if gcs_beat and k % 200 == 0:
            twin.send("gcs", wire.send_msg(mav["gcs"], M.MAVLink_heartbeat_message(
                M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3)))
        if k in (1700, 1790):   # into OFFBOARD (armed first) before the setpoints stop
            cmd("gcs", M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            cmd("gcs", M.MAV_CMD_DO_SET_MODE, 1.0, 6.0, 0.0)
        if k == 1500:
            gcs_beat = False        # the ground station goes quiet
        if rng.random() < 0.02:     # the HIL link: garbage, a HEARTBEAT, a battery fault
            pre_hil.append(rng.choice([
                b"\xfd\x01\x00", bytes(rng.randrange(256) for _ in range(30)),
                wire.send_msg(twin.sim, M.MAVLink_heartbeat_message(2, 8, 0, 0, 4, 3)),
                encode_inject_failure(twin.inject, 4, rng.uniform(1.0, 3.0), 0.1)]))
        r = rng.random()
        if r < 0.01:
            odo_kw = {"quality": -1}                   # the estimate failed
        elif r < 0.02:
            odo_kw = {"child_frame_id": M.MAV_FRAME_BODY_FRD, "quality": 100}
        elif r < 0.025:
            odo_kw = {"values": {rng.randrange(13): rng.choice([math.nan, math.inf])}}
        elif r < 0.03:
            odo_kw = {"frame_id": M.MAV_FRAME_BODY_FRD}
        twin.tick(odo_kw, pre_hil)


@pytest.mark.parametrize("seed,gcs_key", [(1, None), (2, None), (3, b"k" * 32)])
def test_random_sessions_identical_compiled_tick_and_reference(seed, gcs_key, monkeypatch):
    """Signed links (seed 3) go through the Python drain from the compiled tick."""
    kw = {"app_key": gcs_key, "gcs_key": gcs_key, "signing_key": gcs_key} if gcs_key else {}
    twin = Twin(monkeypatch, **kw)
    _script(twin, random.Random(seed), 2500, gcs_key)
    ob = twin.rigs[0].ob
    st = ob.stats
    # the session reached the branches it is for
    assert st["setpoints"] > 1000 and st["drain_deferred"] > 0 and st["dropped_bad_hil"] > 0
    assert st["hil_bad_values"] > 0 and st["commands"] > 5
    assert st["hil_ignored"] + st["faults_injected"] > 0
    assert len({m for m, armed, fs in twin.modes if armed}) >= 4, twin.modes
    assert any(fs for m, armed, fs in twin.modes), twin.modes
    if gcs_key:
        assert ob._gcs.signed and ob._api.signed


# ------------------------------------------------------------------ MIL's exchange in one call
class _Sim:
    def __init__(self, answers):
        self.sent, self.answers = [], list(answers)

    def send(self, data):
        self.sent.append(data)

    def recv(self):
        return self.answers.pop(0) if self.answers else None


def _reference_exchange(sim, poll, pending, data):
    """cosim.sim.onboard.OnboardHandle.exchange's MIL loop, unwrapped."""
    sim.send(data)
    while not poll() and pending():
        pass
    return sim.recv()


@pytest.mark.parametrize("polls,queued", [([True], []), ([False, False, True], [1, 1]),
                                          ([False, 0, None], [2, True, 0]), ([False], [0])])
def test_mil_exchange_is_the_reference_loop(polls, queued):
    got = []
    for ex in (fastpath.lib.mil_exchange, _reference_exchange):
        calls = []
        p, q = list(polls), list(queued)

        def poll(p=p, calls=calls):
            calls.append("poll")
            return p.pop(0)

        def pending(q=q, calls=calls):
            calls.append("pending")
            return q.pop(0)
        sim = _Sim([b"answer"])
        got.append((ex(sim, poll, pending, b"odo"), sim.sent, calls))
    assert got[0] == got[1]


def test_mil_exchange_passes_a_failure_on_and_the_master_names_it(monkeypatch):
    def boom():
        raise RuntimeError("boom")
    with pytest.raises(RuntimeError, match="boom"):
        fastpath.lib.mil_exchange(_Sim([]), boom, lambda: 0, b"odo")
    sc = load_scenario("scenarios/scripted_square.toml")
    messages = []
    for compiled in (True, False):     # the C exchange, and the handle's Python exchange
        if not compiled:
            monkeypatch.setattr(fastpath, "lib", None)
        monkeypatch.setattr(vehicle_mod.Onboard, "compiled_tick", False)
        monkeypatch.setattr(vehicle_mod.Onboard, "poll", lambda self: boom())
        r1 = run_scenario(sc, RunOptions(mode="mil"))
        monkeypatch.setattr(vehicle_mod.Onboard, "poll", lambda self: self._hil.recv() and False)
        r2 = run_scenario(sc, RunOptions(mode="mil"))
        messages.append((r1.exit_reason, r1.message, r2.exit_reason, r2.message))
    assert messages[0] == messages[1]
    assert messages[0][1] == "onboard: RuntimeError: boom"
    assert messages[0][3] == "onboard: no HIL_ACTUATOR_CONTROLS answer"
