"""`cosim bench --instructions` (cosim/bench/instructions.py): the cachegrind summary parse,
the per-tick arithmetic and the variants' environments through a stand-in `valgrind`
executable (the real one is a system tool CI may lack), and the error without Valgrind."""

from __future__ import annotations

import json
import stat
import sys
from pathlib import Path

import pytest

from cosim.bench import command as bench
from cosim.bench import instructions as bench_instr

FAKE = """#!{python}
# a stand-in for valgrind: checks the arguments cosim passes, answers like cachegrind
import os, sys
args = sys.argv[1:]
assert args[0] == "--tool=cachegrind" and args[1] == "--cache-sim=no", args
assert args[2].startswith("--cachegrind-out-file="), args
assert args[3] == {python!r} and args[4] == "-c", args
runs, feed = int(args[-2]), args[-1]
assert feed == "truth", args           # the figure's history: the seed mission truth-fed
before = os.environ["COSIM_COMPILED"] == "0"
assert os.environ["COSIM_COMPILED"] in ("0", "1")
per_tick = 600 if before else 250
print("ticks 1000")
print(f"==42== I   refs:      {{1_000_000 + runs * 1000 * per_tick:,}}", file=sys.stderr)
"""


def test_parse_irefs():
    text = "==1== \n==1== I   refs:      4,395,895,132\n==1== other\n"
    assert bench_instr.parse_irefs(text) == 4_395_895_132
    with pytest.raises(ValueError):
        bench_instr.parse_irefs("no summary here")


def test_instructions_per_tick_from_two_processes_per_variant(tmp_path, monkeypatch):
    fake = tmp_path / "valgrind"
    fake.write_text(FAKE.format(python=sys.executable))
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    res = bench_instr.bench_instructions(valgrind=str(fake), parts=False)
    assert res["now"]["per_tick"] == 250 and res["before"]["per_tick"] == 600
    assert res["before_over_now"] == pytest.approx(2.4)
    assert res["now"]["ticks"] == 1000
    lines = bench_instr.format_instructions(res)
    assert "0.2k" in lines[1] and "0.6k" in lines[2] and "2.40x" in lines[3]


def test_a_failing_count_is_reported(tmp_path):
    fake = tmp_path / "valgrind"
    fake.write_text(f"#!{sys.executable}\nimport sys\nprint('boom', file=sys.stderr)\n"
                    "sys.exit(3)\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    with pytest.raises(RuntimeError, match="boom"):
        bench_instr.bench_instructions(valgrind=str(fake), parts=False)


def test_without_valgrind_the_bench_says_what_to_install(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(bench_instr.shutil, "which", lambda name: None)
    rc = bench.main(instructions=True, json_path=Path(tmp_path) / "i.json")
    assert rc == 2
    err = capsys.readouterr().err
    assert "valgrind is not on PATH" in err and "apt-get install valgrind" in err
    assert not (tmp_path / "i.json").exists()


def test_instructions_and_flood_together_are_refused(capsys):
    from cosim.cli import main

    assert main(["bench", "--instructions", "--flood"]) == 2
    assert "--instructions --flood" in capsys.readouterr().err


ANNOTATE = """\
--------------------------------------------------------------------------------
Ir
--------------------------------------------------------------------------------
3,121,409,499 (100.0%)  PROGRAM TOTALS
11,495,308,473 (368.2%)  /tmp/Python-3.11.7/Python/ceval.c:_PyEval_EvalFrameDefault'2 [/lib/x]
 2,000,000,000 (64.07%)  ???:__pyx_pw_5cosim_3sim_4tick_4Tick_3run [/w/cosim/sim/tick.so]
   518,703,574 (16.62%)  ???:__pyx_pw_5cosim_3sim_7onboard_13OnboardHandle_9exchange [/w/x.so]
   214,704,656 ( 6.88%)  ???:Stepper_step [/work/main/cosim/plant/_fmi2step.so]
    55,000,000 ( 1.76%)  ???:__pyx_pw_3mav_3hil_17HilSimulatorCodec_3encode_odometry [/w/h.so]
   900,000,000 (28.83%)  ???:__pyx_pw_5cosim_3sim_4tick_4Tick_7_camera_and_app [/w/t.so]
    84,917,734 ( 2.72%)  ???:__pyx_pw_3mav_6client_14OffboardClient_5poll.constprop.0 [/w/c.so]
     1,000,000 ( 0.03%)  ???:__pyx_pw_5cosim_3sim_7onboard_13OnboardHandle_9exchange'2 [/w/x.so]
"""


def test_parts_from_callgrind_inclusive_counts():
    incl = bench_instr.parse_inclusive(ANNOTATE)
    tick = "__pyx_pw_5cosim_3sim_4tick_4Tick_3run"
    assert incl[tick] == 2_000_000_000
    assert incl["__pyx_pw_3mav_6client_14OffboardClient_5poll"] == 84_917_734
    assert incl["_PyEval_EvalFrameDefault"] == 11_495_308_473 and "PROGRAM" not in incl
    parts = bench_instr.parts_per_tick(incl, 1000, 3_000_000.0)
    labels = list(parts)
    assert parts[labels[0]] == 518_703.574 and parts[labels[6]] == 0.0   # no setpoint symbol
    assert labels[3].startswith("sensor models") and parts[labels[3]] == 0.0   # truth-fed
    assert parts[labels[5]] == 84_917.734
    master = (2_000_000_000 - 518_703_574 - 214_704_656 - 55_000_000 - 900_000_000) / 1000
    assert parts[labels[7]] == pytest.approx(master)
    top = sum(v for k, v in parts.items() if not k.startswith(" "))
    assert top == pytest.approx(3_000_000.0)              # the rest closes it
    res = {"now": {"per_tick": 3e6, "ticks": 1000}, "before": {"per_tick": 6e6},
           "before_over_now": 2.0, "parts_per_tick": parts}
    text = "\n".join(bench_instr.format_instructions(res))
    assert "518.7k" in text and "17.3%" in text and "the rest" in text


def test_the_bench_counts_both_feeds(monkeypatch, capsys, tmp_path):
    """Truth-fed (the figure's history) and on the sensors and the onboard estimator (the
    default's), each with its own heading and its own entry in the JSON."""
    def fake(feed: str = "truth", **_kw):
        n = 130_000.0 if feed == "truth" else 150_000.0
        return {"feed": feed, "now": {"per_tick": n, "ticks": 10},
                "before": {"per_tick": 3 * n}, "before_over_now": 3.0}

    monkeypatch.setattr(bench_instr, "bench_instructions", fake)
    rc = bench.main(instructions=True, json_path=Path(tmp_path) / "i.json")
    assert rc == 0
    out = capsys.readouterr().out
    assert "per MIL tick, truth-fed" in out and "130.0k" in out
    assert "per MIL tick, on the sensors and the onboard estimator" in out and "150.0k" in out
    res = json.loads((tmp_path / "i.json").read_text())
    assert res["instructions"]["feed"] == "truth"
    assert res["instructions_estimate"]["feed"] == "hil"
