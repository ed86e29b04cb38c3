"""Results that travel: flights under three emulated CPUs (this one; AVX2 without AVX-512;
SSE4.2 only: cosim/numerics.py LEVELS).

- portable numerics: the seed mission on its sensors and truth-fed, paper 2's E1 and E2 write
  byte-identical timeseries.csv and flight.tlog at every level;
- native numerics: E2 does what it must at every level (its flight may differ in the last
  bits, and so in its times), with margins, not one CPU's exact times.

Each flight is a `cosim run` in its own process (numerics are fixed when a process starts),
two at a time on a 2-core machine.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

pytestmark = pytest.mark.flight     # whole flights (make test-fast leaves them out)

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
LEVELS = ("native", "avx2", "baseline")
E2 = "bebop2_vs_e2.toml"
PORTABLE = {                      # label: (scenario, --set ...)
    "seed": ("mambo_seed_track.toml", []),
    "seed truth-fed": ("mambo_seed_track.toml", ["sensors.feed=truth"]),
    "E1": ("bebop2_vs_e1.toml", []),
    "E2": (E2, ["timing.t_final_s=30"]),      # take-off, the cylinder, the first key
}


def fly(out: Path, level: str, scenario: str, sets: list[str], numerics: str) -> dict:
    cmd = [PY, "-m", "cosim.numerics", "emulate", level, "--", PY, "-m", "cosim.cli", "run",
           str(ROOT / "scenarios" / scenario), "--numerics", numerics, "--no-plots",
           "--out", str(out)]
    for s in sets:
        cmd += ["--set", s]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=900, check=False)
    assert (out / "summary.json").exists(), p.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["numerics"]["mode"] == numerics, s["numerics"]["not_portable"]
    s["_hash"] = {f: hashlib.sha256((out / f).read_bytes()).hexdigest()
                  for f in ("timeseries.csv", "flight.tlog")}
    return s


def fly_all(tmp_path: Path, cases: list[tuple[str, str, str, list[str], str]]) -> dict:
    with ThreadPoolExecutor(2) as pool:
        futs = {(label, lv): pool.submit(fly, tmp_path / f"{label}-{lv}".replace(" ", "_"), lv,
                                         sc, sets, num)
                for label, lv, sc, sets, num in cases}
        return {k: f.result() for k, f in futs.items()}


def test_portable_flights_are_the_same_bytes_on_every_cpu(tmp_path):
    cases = [(label, lv, sc, sets, "portable") for label, (sc, sets) in PORTABLE.items()
             for lv in LEVELS]
    got = fly_all(tmp_path, cases)
    for label in PORTABLE:
        hashes = {lv: got[label, lv]["_hash"] for lv in LEVELS}
        assert hashes["avx2"] == hashes["native"] == hashes["baseline"], (label, hashes)
        assert got[label, "native"]["sim_time_s"] > 5.0      # a flight, not an early error
    assert got["seed", "native"]["passed"] and got["E1", "native"]["passed"]


@pytest.fixture(scope="module")
def native_e2(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("e2native")
    return fly_all(tmp, [("E2", lv, E2, [], "native") for lv in LEVELS])


@pytest.mark.parametrize("level", LEVELS)
def test_native_e2_does_what_it_must_at_every_level(native_e2, level):
    s = native_e2["E2", level]
    m = s["metrics"]
    assert s["exit_reason"] == "mission_complete" and s["passed"], s["message"]
    assert m["keys_reached"] == 4 and m["outcome"] == "goal_reached"
    assert m["final_pose_error_m"] < 0.15 and m["final_yaw_error_deg"] < 3.0
    assert m["min_clearance_m"] > 0.02
    assert len(m["avoidance_active_s"]) >= 2          # the cylinder, then the bar
    assert m["goal_time_s"] < 60.0
