"""`cosim bench --instructions`: the seed mission's work per MIL tick counted in CPU
instructions, for the compiled code ("now") and the Python reference ("before") in one run.

Wall-clock figures on a shared 2-core host move by 1.5x within an hour; an instruction count
does not move with the neighbours' load, so it says whether a change made the tick do less
work. Counted by Valgrind's cachegrind (`valgrind --tool=cachegrind --cache-sim=no`), which
is a system tool, not a pip package: install it (`apt-get install valgrind`) to use this
figure; the rest of `cosim bench` does not need it.

Each variant is one Python process under cachegrind flying the seed mission once, and one
flying it twice; the difference over the mission's ticks is the work per tick, without the
imports, the FMU load and the first-run setup. Variants: "now" as installed; "before" with
`MAV_FASTPATH=0` and `COSIM_FMI2STEP=0` (the Python onboard reference, its links and
decoders, and the plant through ctypes). Four processes, two at a time: ~5-8 minutes.
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

from cosim.studies.bench_common import SEED


class ToolMissing(RuntimeError):
    """Valgrind is not installed."""


VARIANTS: dict[str, dict[str, str]] = {
    "now": {},
    "before": {"MAV_FASTPATH": "0", "COSIM_FMI2STEP": "0"},
}
# the script each process runs: fly the seed mission `n` times (MIL), print the ticks
_SCRIPT = """
import sys
from cosim.scenario.parse import load_scenario
from cosim.sim.master import RunOptions, run_scenario
ticks = 0
for _ in range(int(sys.argv[2])):
    ticks = run_scenario(load_scenario(sys.argv[1]), RunOptions(mode="mil")).ticks
print("ticks", ticks)
"""
_IREFS = re.compile(r"I\s+refs:\s+([\d,]+)")


def parse_irefs(text: str) -> int:
    """The instruction count ("I refs") of a cachegrind summary."""
    m = _IREFS.search(text)
    if m is None:
        raise ValueError("no 'I refs' line in the cachegrind output")
    return int(m.group(1).replace(",", ""))


def _count(valgrind: str, env_extra: dict[str, str], runs: int, scenario: Path,
           tmp: Path) -> tuple[int, int]:
    """(instructions, ticks of one mission) of a process flying the scenario `runs` times."""
    env = dict(os.environ, **env_extra)
    out = tmp / f"cachegrind.{'-'.join(env_extra) or 'now'}.{runs}"
    cmd = [valgrind, "--tool=cachegrind", "--cache-sim=no", f"--cachegrind-out-file={out}",
           sys.executable, "-c", _SCRIPT, str(scenario), str(runs)]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise RuntimeError(f"cachegrind run failed ({p.returncode}): {p.stderr[-2000:]}")
    m = re.search(r"^ticks (\d+)$", p.stdout, re.M)
    if m is None:
        raise RuntimeError(f"the mission printed no tick count: {p.stdout[-500:]}")
    return parse_irefs(p.stderr), int(m.group(1))


def bench_instructions(scenario: Path = SEED, valgrind: str | None = None,
                       workers: int = 2) -> dict[str, Any]:
    """Instructions per MIL tick for each variant, and before / now."""
    valgrind = valgrind or shutil.which("valgrind")
    if valgrind is None:
        raise ToolMissing("--instructions counts instructions with Valgrind's cachegrind, and "
                          "valgrind is not on PATH (install it: apt-get install valgrind)")
    jobs = [(name, runs) for name in VARIANTS for runs in (1, 2)]
    with tempfile.TemporaryDirectory(prefix="cosim-instr-") as d, \
            ThreadPoolExecutor(max_workers=workers) as pool:
        futs = {job: pool.submit(_count, valgrind, VARIANTS[job[0]], job[1], scenario, Path(d))
                for job in jobs}
        got = {job: f.result() for job, f in futs.items()}
    res: dict[str, Any] = {"scenario": str(scenario)}
    for name in VARIANTS:
        (i1, ticks), (i2, ticks2) = got[(name, 1)], got[(name, 2)]
        if ticks != ticks2 or ticks <= 0:
            raise RuntimeError(f"{name}: the two processes flew {ticks} and {ticks2} ticks")
        res[name] = {"ticks": ticks, "instructions_1": i1, "instructions_2": i2,
                     "per_tick": (i2 - i1) / ticks}
    res["before_over_now"] = res["before"]["per_tick"] / res["now"]["per_tick"]
    return res


def format_instructions(res: dict[str, Any]) -> list[str]:
    now, before = res["now"], res["before"]
    rows = (("now (compiled)", f"{now['per_tick'] / 1e3:.1f}k"),
            ("before (MAV_FASTPATH=0 COSIM_FMI2STEP=0)", f"{before['per_tick'] / 1e3:.1f}k"),
            ("before / now", f"{res['before_over_now']:.2f}x"))
    return [f"instructions per MIL tick (cachegrind; seed mission flown twice minus once, "
            f"{now['ticks']} ticks):"] + [f"  {a:<44}{b:>10}" for a, b in rows]
