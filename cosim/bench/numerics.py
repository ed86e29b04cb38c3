"""`cosim bench --numerics`: what the portable numerics (cosim/numerics.py) cost.

The seed mission (on the estimate, the default feed) and paper 2's E2 are flown in fresh
processes, native and portable alternately, `rounds` times, on this machine in this one
sitting; each figure is the loop's simulated time over its wall time (set-up excluded), and
the cost is the median over rounds of native / portable (1.15 = portable takes 15 % longer per
simulated second). The two modes fly a camera mission differently in the last bits, so E2's
flights can differ in length: the cost is per simulated second, and both flights are printed.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from typing import Any

from cosim.bench.common import ROOT

MISSIONS = {"seed mission": "mambo_seed_track.toml", "E2": "bebop2_vs_e2.toml"}
_CHILD = """
import json, sys
from cosim.numerics import mode
from cosim.load import load_scenario
from cosim.sim.master import RunOptions, run_scenario
res = run_scenario(load_scenario(sys.argv[1]), RunOptions(mode="mil"))
print(json.dumps({"rtf": res.loop_real_time_factor, "sim_s": res.t_end_s,
                  "exit": res.exit_reason.value, "numerics": mode()}))
"""


def fly(numerics: str, scenario: str) -> dict[str, Any]:
    """One flight in a fresh process started with `numerics`."""
    cmd = [sys.executable, "-m", "cosim.numerics", numerics, "--", sys.executable, "-c",
           _CHILD, str(ROOT / "scenarios" / scenario)]
    p = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=ROOT)
    if p.returncode != 0:
        raise RuntimeError(f"{numerics} {scenario} failed: {p.stderr[-2000:]}")
    d = json.loads(p.stdout.strip().splitlines()[-1])
    if d["numerics"] != numerics:
        raise RuntimeError(f"a {numerics} flight ran {d['numerics']}")
    return d


def bench_numerics(rounds: int = 3) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for label, scenario in MISSIONS.items():
        runs: dict[str, list[dict[str, Any]]] = {"native": [], "portable": []}
        for _ in range(rounds):
            for m in ("native", "portable"):
                runs[m].append(fly(m, scenario))
        cost = [n["rtf"] / p["rtf"] for n, p in zip(runs["native"], runs["portable"], strict=True)]
        out[label] = {"cost": statistics.median(cost), "cost_rounds": cost,
                      **{m: {"rtf": statistics.median(r["rtf"] for r in rs),
                             "sim_s": rs[0]["sim_s"], "exit": rs[0]["exit"]}
                         for m, rs in runs.items()}}
    return out


def format_numerics(res: dict[str, Any]) -> list[str]:
    lines = ["numerics: native against portable (fresh processes, alternately; median of "
             f"{len(next(iter(res.values()))['cost_rounds'])} rounds; target: cost <= 1.15 "
             "for portable to be the default)"]
    for label, d in res.items():
        n, p = d["native"], d["portable"]
        lines.append(f"  {label:<14s} native {n['rtf']:7.2f}x ({n['sim_s']:.1f} s, {n['exit']})"
                     f"  portable {p['rtf']:7.2f}x ({p['sim_s']:.1f} s, {p['exit']})  cost "
                     f"{d['cost']:.3f} (rounds {', '.join(f'{c:.3f}' for c in d['cost_rounds'])})")
    return lines


if __name__ == "__main__":
    r = bench_numerics(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
    print("\n".join(format_numerics(r)))
