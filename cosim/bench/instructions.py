"""`cosim bench --instructions`: the seed mission's work per MIL tick counted in CPU
instructions, compiled ("now") and the same code interpreted ("before") in one run.

Wall-clock figures on a shared 2-core host move by 1.5x within an hour; an instruction count
does not move with the neighbours' load, so it says whether a change made the tick do less
work. Counted by Valgrind's cachegrind (`valgrind --tool=cachegrind --cache-sim=no`), which
is a system tool, not a pip package: install it (`apt-get install valgrind`) to use this
figure; the rest of `cosim bench` does not need it.

Each variant is one Python process under cachegrind flying the seed mission once, and one
flying it twice; the difference over the mission's ticks is the work per tick, without the
imports, the FMU load and the first-run setup. Variants: "now" with `COSIM_COMPILED=1` (the
compiled modules, onesource/switch.py); "before" with `COSIM_COMPILED=0` (the same sources
interpreted, and the plant through ctypes). Four processes, two at a time, for each feed
(`cosim bench --instructions` counts both: truth-fed, the figure's history, and on the
sensors and the onboard estimator, the default): ~8-15 minutes.

Where the compiled tick's instructions go (`parts`): one more process, under callgrind, flies
the mission once; the inclusive count of each part's entry point (its own code and everything
it calls; Cython's function for the method), per tick, is exact where a wall-clock timer
around the part is not: the vehicle's tick with MIL's HIL exchange (`OnboardHandle.exchange`,
`exchange_record` when typed),
the plant (`Stepper.step`), the simulator's ODOMETRY, the client's poll and setpoint, and the
master's tick (`Tick._run`) less the parts it calls. The rest (the app's Python, the camera and
image processing, the master's loop, and the per-run setup the once/twice difference keeps) is
the total less these. Needs `callgrind_annotate` (shipped with Valgrind); skipped without it.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from cosim.bench.common import SEED


class ToolMissing(RuntimeError):
    """Valgrind is not installed."""


VARIANTS: dict[str, dict[str, str]] = {
    "now": {"COSIM_COMPILED": "1"},
    "before": {"COSIM_COMPILED": "0"},
}
# the script each process runs: fly the seed mission `n` times (MIL), print the ticks
_SCRIPT = """
import sys
from cosim.load import load_scenario, with_set
from cosim.sim.master import RunOptions, run_scenario
ticks = 0
sc = with_set(load_scenario(sys.argv[1]), {"sensors.feed": sys.argv[3]})
for _ in range(int(sys.argv[2])):
    ticks = run_scenario(sc, RunOptions(mode="mil")).ticks
print("ticks", ticks)
"""
_IREFS = re.compile(r"I\s+refs:\s+([\d,]+)")
# the entry points: (label, symbol pattern: the C function Cython makes of the method, or the
# FMI binding's; a cpdef method called from compiled code is its __pyx_f_ function, from Python
# its __pyx_pw_ wrapper: the larger counts); "master" is computed (its tick less the others)
PART_SYMBOLS = (
    ("onboard (vehicle tick + MIL HIL exchange)",
     r"__pyx_pw_5cosim_3sim_7onboard_\d+OnboardHandle_\d+exchange(?:_record)?"),
    ("plant (FMI stepper + FMU)", r"Stepper_step"),
    ("ODOMETRY encode (simulator)",
     r"__pyx_pw_3mav_3hil_\d+HilSimulatorCodec_\d+(?:encode|record)_odometry"),
    ("sensor models + their messages (simulator)",
     r"__pyx_pw_5cosim_3sim_8estimate_\d+SensorFeed_\d+(?:encode|record)_odometry"),
    ("camera + app (Python), of which:",
     r"__pyx_(?:pw|f)_5cosim_3sim_4tick_\d+Tick_(?:\d+)?_camera_and_app"),
    ("  app: client poll (telemetry in)",
     r"__pyx_(?:pw|f)_3mav_6client_\d+OffboardClient_(?:\d+)?poll"),
    ("  app: client setpoint out",
     r"__pyx_(?:pw|f)_3mav_6client_\d+OffboardClient_(?:\d+)?_setpoint"),
)
_TAIL = r"__pyx_pw_5cosim_3sim_4tick_\d+Tick_\d+run"   # Tick.run (its _run is a C call)
_INCL = re.compile(r"^\s*([\d,]+)\s+\([\d. ]+%\)\s+\S*?:(\w+)(?:\.\w+)*(?:'\d+)?(?:\s|$)")


def parse_inclusive(text: str) -> dict[str, int]:
    """{function: inclusive instructions} from `callgrind_annotate --inclusive=yes` output
    (the first, largest line per function name)."""
    out: dict[str, int] = {}
    for line in text.splitlines():
        m = _INCL.match(line)
        if m is not None and m.group(2) not in out:
            out[m.group(2)] = int(m.group(1).replace(",", ""))
    return out


def _incl(incl: dict[str, int], pattern: str) -> int:
    """The inclusive count of the function whose name matches `pattern` whole (0 if none)."""
    rx = re.compile(pattern)
    return max((n for name, n in incl.items() if rx.fullmatch(name)), default=0)


def parts_per_tick(incl: dict[str, int], ticks: int, total_per_tick: float) -> dict[str, float]:
    """Instructions per tick of each compiled part, the master's compiled tail less the parts
    it calls, and the rest of the tick."""
    parts = {label: _incl(incl, sym) / ticks for label, sym in PART_SYMBOLS}
    top = sum(n for label, n in parts.items() if not label.startswith(" "))
    # the tick less the parts it calls: the sensor, the HIL answer decode, the GCS tlog tap,
    # the record and the exit test
    parts["master: tick less the above"] = _incl(incl, _TAIL) / ticks - top
    # the master's loop around the tick, and the per-run setup the difference keeps
    parts["the rest (loop, setup)"] = total_per_tick - top - parts["master: tick less the above"]
    return parts


def _callgrind_parts(valgrind: str, annotate: str, scenario: Path, tmp: Path,
                     feed: str = "truth") -> tuple[dict[str, int], int]:
    out = tmp / "callgrind.now"
    cmd = [valgrind, "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable, "-c",
           _SCRIPT, str(scenario), "1", feed]
    p = subprocess.run(cmd, capture_output=True, text=True, check=False)
    m = re.search(r"^ticks (\d+)$", p.stdout, re.M)
    if p.returncode != 0 or m is None:
        raise RuntimeError(f"callgrind run failed ({p.returncode}): {p.stderr[-2000:]}")
    a = subprocess.run([annotate, "--inclusive=yes", "--threshold=100", str(out)],
                       capture_output=True, text=True, check=True)
    return parse_inclusive(a.stdout), int(m.group(1))


def parse_irefs(text: str) -> int:
    """The instruction count ("I refs") of a cachegrind summary."""
    m = _IREFS.search(text)
    if m is None:
        raise ValueError("no 'I refs' line in the cachegrind output")
    return int(m.group(1).replace(",", ""))


def _count(valgrind: str, env_extra: dict[str, str], runs: int, scenario: Path,
           tmp: Path, feed: str = "truth") -> tuple[int, int]:
    """(instructions, ticks of one mission) of a process flying the scenario `runs` times."""
    env = dict(os.environ, **env_extra)
    out = tmp / f"cachegrind.{'-'.join(env_extra) or 'now'}.{runs}"
    cmd = [valgrind, "--tool=cachegrind", "--cache-sim=no", f"--cachegrind-out-file={out}",
           sys.executable, "-c", _SCRIPT, str(scenario), str(runs), feed]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise RuntimeError(f"cachegrind run failed ({p.returncode}): {p.stderr[-2000:]}")
    m = re.search(r"^ticks (\d+)$", p.stdout, re.M)
    if m is None:
        raise RuntimeError(f"the mission printed no tick count: {p.stdout[-500:]}")
    return parse_irefs(p.stderr), int(m.group(1))


def bench_instructions(scenario: Path = SEED, valgrind: str | None = None,
                       workers: int = 2, parts: bool = True, feed: str = "truth"
                       ) -> dict[str, Any]:
    """Instructions per MIL tick for each variant, and before / now; with `parts` (and
    callgrind_annotate on PATH) where the compiled tick's go. `feed`: the scenario's
    `[sensors] feed` (truth-fed by default, the figure's history; "hil": on the sensors)."""
    valgrind = valgrind or shutil.which("valgrind")
    if valgrind is None:
        raise ToolMissing("--instructions counts instructions with Valgrind's cachegrind, and "
                          "valgrind is not on PATH (install it: apt-get install valgrind)")
    jobs = [(name, runs) for name in VARIANTS for runs in (1, 2)]
    with tempfile.TemporaryDirectory(prefix="cosim-instr-") as d, \
            ThreadPoolExecutor(max_workers=workers) as pool:
        futs = {job: pool.submit(_count, valgrind, VARIANTS[job[0]], job[1], scenario, Path(d),
                                 feed) for job in jobs}
        annotate = shutil.which("callgrind_annotate") if parts else None
        cg = (pool.submit(_callgrind_parts, valgrind, annotate, scenario, Path(d), feed)
              if annotate else None)
        got = {job: f.result() for job, f in futs.items()}
        incl = cg.result() if cg is not None else None
    res: dict[str, Any] = {"scenario": str(scenario), "feed": feed}
    for name in VARIANTS:
        (i1, ticks), (i2, ticks2) = got[(name, 1)], got[(name, 2)]
        if ticks != ticks2 or ticks <= 0:
            raise RuntimeError(f"{name}: the two processes flew {ticks} and {ticks2} ticks")
        res[name] = {"ticks": ticks, "instructions_1": i1, "instructions_2": i2,
                     "per_tick": (i2 - i1) / ticks}
    res["before_over_now"] = res["before"]["per_tick"] / res["now"]["per_tick"]
    if incl is not None:
        res["parts_per_tick"] = parts_per_tick(incl[0], incl[1], res["now"]["per_tick"])
    return res


def format_instructions(res: dict[str, Any]) -> list[str]:
    now, before = res["now"], res["before"]
    rows = (("now (compiled)", f"{now['per_tick'] / 1e3:.1f}k"),
            ("before (COSIM_COMPILED=0, interpreted)", f"{before['per_tick'] / 1e3:.1f}k"),
            ("before / now", f"{res['before_over_now']:.2f}x"))
    feed = {"truth": "truth-fed", "hil": "on the sensors and the onboard estimator"}.get(
        res.get("feed", "truth"), res.get("feed", ""))
    lines = [f"instructions per MIL tick, {feed} (cachegrind; seed mission flown twice minus "
             f"once, {now['ticks']} ticks):"] + [f"  {a:<44}{b:>10}" for a, b in rows]
    if "parts_per_tick" in res:
        lines.append("where the compiled tick's go (callgrind, inclusive counts of each entry "
                     "point, per tick; share of the tick):")
        for label, n in res["parts_per_tick"].items():
            lines.append(f"  {label:<44}{n / 1e3:>9.1f}k {n / now['per_tick']:>6.1%}")
    return lines
