"""The master's compiled tick tail (cosim/plant/csrc/tail.c: HIL exchange, record, plant step,
exit test) against its reference, the Python loop of cosim/sim/master.py: whole missions and
every way a run ends, flown both ways, compared bit for bit (series, tlog, exit, counters)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from cosim.scenario.parse import load_scenario, with_set
from cosim.sim import master
from cosim.sim.master import ExitReason, RunOptions, run_scenario
from cosim.sim.recorder import COL

pytest.importorskip("cosim.plant._fmi2step", reason="the compiled simulator side is not built")

SCEN = Path(__file__).resolve().parent.parent / "scenarios"


def _fly(monkeypatch, compiled: bool, sc, opts: RunOptions | None = None):
    monkeypatch.setattr(master, "COMPILED_TAIL", compiled)
    seen = []
    real = master.make_tail

    def spy(*a, **kw):
        tail = real(*a, **kw)
        seen.append(tail)
        return tail

    monkeypatch.setattr(master, "make_tail", spy)
    res = run_scenario(sc, opts or RunOptions())
    assert (seen[0] is not None) == compiled      # the path asked for is the one flown
    return res


def _outcome(res) -> tuple:
    return (res.exit_reason, res.message, res.ticks, res.series.tobytes(), res.tlog.read(),
            res.phases, res.touchdown, res.min_clearance, res.onboard_stats)


def _both(monkeypatch, sc, opts: RunOptions | None = None):
    c = _fly(monkeypatch, True, sc, opts)
    p = _fly(monkeypatch, False, sc, opts)
    assert _outcome(c) == _outcome(p)
    return c


@pytest.mark.parametrize("name, sets", [
    ("mambo_seed_track", {}),                                       # camera, line follower
    ("mambo_seed_wind", {"timing.t_final_s": 20.0}),                # turbulence and gust
    ("scripted_square", {}),                                        # scripted, lands
    ("mambo_hover", {"app.name": "none", "timing.t_final_s": 5.0}),  # no app at all
    ("bebop2_room_e1", {"timing.t_final_s": 3.0}),                  # a 3D scene: clearance
])
def test_missions_fly_the_same_both_ways(monkeypatch, name, sets):
    res = _both(monkeypatch, with_set(load_scenario(SCEN / f"{name}.toml"), sets))
    assert res.ticks > 500


def test_sitl_option_flies_the_same_both_ways(monkeypatch):
    sc = with_set(load_scenario(SCEN / "scripted_square.toml"), {"timing.t_final_s": 8.0})
    res = _both(monkeypatch, sc, RunOptions(sitl=True))
    assert res.exit_reason is ExitReason.TIME_LIMIT


def test_leaving_the_arena_ends_the_same_both_ways(monkeypatch):
    sc = with_set(load_scenario(SCEN / "scripted_square.toml"),
                  {"app.waypoints": [[57.0, 95.0, -1.0, 0.5]],
                   "app.velocity_legs": [[1.5, 0.0, 0.0, 30.0]]})
    res = _both(monkeypatch, sc)
    assert res.exit_reason is ExitReason.LEFT_ARENA, res.message


def _poison(monkeypatch, change):
    """The master's decoder of the HIL answer, changed from 2 s on by `change(t, u)`."""
    from mav import wire

    orig = wire.decode_hil_actuator_controls

    def poisoned(data):
        got = orig(data)
        if got is None or got[0] < 2_000_000:
            return got
        return change(got[0], got[1:])

    monkeypatch.setattr(wire, "decode_hil_actuator_controls", poisoned)


@pytest.mark.parametrize("change, reason, text", [
    (lambda t, u: (t, 0.0, 0.0, 0.0, 0.0), ExitReason.CRASHED, "hard touchdown"),
    (lambda t, u: (t, 1.0, 0.0, 1.0, 0.0), ExitReason.CRASHED, "flipped over"),
    (lambda t, u: (t, math.nan, *u[1:]), ExitReason.COMPONENT_ERROR, "plant:"),
    (lambda t, u: None, ExitReason.COMPONENT_ERROR,
     "onboard: ValueError: not a valid HIL_ACTUATOR_CONTROLS frame"),
    (lambda t, u: (t + 5000, *u), ExitReason.COMPONENT_ERROR, "onboard: HIL answer stamped"),
    (lambda t, u: (t, *u[:3]), ExitReason.COMPONENT_ERROR,
     "onboard: ValueError: not enough values to unpack (expected 5, got 4)"),
])
def test_every_ending_is_the_same_both_ways(monkeypatch, change, reason, text):
    _poison(monkeypatch, change)
    res = _both(monkeypatch, load_scenario(SCEN / "scripted_square.toml"))
    assert res.exit_reason is reason and text in res.message, res.message
    assert res.t_end_s >= 2.0 and res.ticks == len(res.series)   # what ran is recorded


def test_a_vehicle_that_stops_answering_is_named_both_ways(monkeypatch):
    from cosim.sim.onboard import OnboardHandle

    orig = OnboardHandle.exchange_call

    def silent_after_1s(self):
        ex = orig(self)
        n = [0]

        def call(data):
            n[0] += 1
            return ex(data) if n[0] <= 200 else None
        return call

    monkeypatch.setattr(OnboardHandle, "exchange_call", silent_after_1s)
    res = _both(monkeypatch, load_scenario(SCEN / "scripted_square.toml"))
    assert res.message == "onboard: no HIL_ACTUATOR_CONTROLS answer" and res.ticks == 200


def test_a_failing_recorder_is_named_both_ways(monkeypatch):
    """A phase name that is not hashable: the reference's dict lookup raises in the onboard
    stage; so does the compiled one's."""
    from cosim.apps.scripted import ScriptedApp

    class OddPhase(ScriptedApp):
        def on_tick(self, t: float) -> None:
            super().on_tick(t)
            if t >= 1.0:
                self.phase = ["not", "hashable"]

    sc = load_scenario(SCEN / "scripted_square.toml")
    outs = [_fly(monkeypatch, c, sc, RunOptions(app_override=OddPhase(sc.app.params)))
            for c in (True, False)]
    assert _outcome(outs[0]) == _outcome(outs[1])
    assert outs[0].message.startswith("onboard: TypeError: unhashable type")


def test_a_touch_and_go_then_landing_is_the_same_both_ways(monkeypatch):
    """Down on the floor, up again, then the landing: the touchdown bookkeeping restarts."""
    sc = with_set(load_scenario(SCEN / "scripted_square.toml"),
                  {"app.waypoints": [[57.0, 95.0, -1.0, 0.5], [57.0, 95.0, 0.05, 1.0],
                                     [57.5, 95.0, -1.0, 1.0]],
                   "app.velocity_legs": [[0.0, 0.0, 0.0, 0.5]]})
    res = _both(monkeypatch, sc)
    og = res.series[:, COL["on_ground"]]
    assert (og[1:] != og[:-1]).sum() >= 3                   # down, up, down at least
    assert res.exit_reason is ExitReason.MISSION_COMPLETE
    assert res.touchdown[1] > 57.4                          # the final touchdown, not the first


def test_cosim_fmi2step_0_flies_the_python_reference(monkeypatch):
    """The simulator's compiled side off (as `cosim bench --instructions` "before" runs it)."""
    monkeypatch.setenv("COSIM_FMI2STEP", "0")
    got = []
    real = master.make_tail
    monkeypatch.setattr(master, "make_tail", lambda *a: got.append(real(*a)) or got[-1])
    sc = with_set(load_scenario(SCEN / "scripted_square.toml"), {"timing.t_final_s": 1.0})
    assert run_scenario(sc, RunOptions()).ticks == 200 and got == [None]


def test_a_tail_never_set_up_refuses_to_run():
    from cosim.plant._fmi2step import Tail

    bare = Tail.__new__(Tail)
    with pytest.raises(TypeError, match="not initialised"):
        bare.run(0, 0, 0.0, (0.0,) * 13, [0.0] * 20)


def test_an_answer_decoder_that_fails_while_unpacked_is_named_the_same(monkeypatch):
    def odd(t, u):
        def gen():
            yield t
            raise TypeError("inner bug")
        return gen()
    _poison(monkeypatch, odd)
    res = _both(monkeypatch, load_scenario(SCEN / "scripted_square.toml"))
    assert res.message == "onboard: TypeError: inner bug"
