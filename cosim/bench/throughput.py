"""Study throughput on this machine: missions per minute by executor and worker count.

    python -m cosim.bench.throughput [--runs 40] [--t-final 10]
    python -m cosim.bench.throughput --memory [--runs 1000] [--t-final 10] [--workers 1]

The same small Monte Carlo (the seed mission cut to `--t-final` s, wind and odometry noise
drawn) runs serially and on a local Dask cluster with 1 and 2 workers, each as a user starts
it: `cosim montecarlo` in its own process, its `runs.log` and
`results.csv` read afterwards. Wall times include starting the command and the cluster.
Per-run overhead of an executor = (its wall time - the sum of the runs' own wall times /
workers) / runs; Dask with 1 worker vs serial = (Dask's wall time - serial's) / runs. Run it
on a quiet machine; it prints a Markdown table (and JSON with --json).

`--memory`: one study on a local Dask cluster; the resident memory of each worker after its
runs 1, 100, 500 and 1000 (from `runs.log`) and its growth per run after the 100th: flat
memory per worker is issue 15's target.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "mambo_seed_track.toml"
VARY = ["wind.n_mps=uniform(0,0.3)", "sensors.flow.flow_noise_rad_s=uniform(0.01,0.04)"]


@dataclass
class Stats:
    wall_s: float
    failed: int


def _study(executor: str, workers: int, runs: int, t_final: float):
    """The small Monte Carlo through the CLI; returns its stats and the lines of its runs.log."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "study"
        cmd = [sys.executable, "-m", "cosim.cli", "montecarlo", str(SCENARIO), "-n", str(runs),
               "--set", f"timing.t_final_s={t_final}", "--executor", executor,
               "--workers", str(workers), "--out", str(out), "--quiet"]
        for v in VARY:
            cmd += ["--vary", v]
        t0 = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wall = time.perf_counter() - t0
        if not (out / "runs.log").is_file():
            raise RuntimeError(f"the study did not run: {res.stderr[-2000:]}")
        with open(out / "results.csv", newline="") as f:
            failed = sum(row.get("status") != "ok" for row in csv.DictReader(f))
        return Stats(wall, failed), [json.loads(line) for line in open(out / "runs.log")]


def measure(executor: str, workers: int, runs: int, t_final: float) -> dict:
    stats, log = _study(executor, workers, runs, t_final)
    run_s = sum(r["wall_s"] for r in log)
    ideal = run_s / workers
    return {"executor": executor, "workers": workers, "runs": runs, "failed": stats.failed,
            "wall_s": stats.wall_s, "missions_per_min": 60 * runs / stats.wall_s,
            "run_s_mean": run_s / runs, "overhead_per_run_s": (stats.wall_s - ideal) / runs}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=40)
    p.add_argument("--t-final", type=float, default=10.0, help="s of flight per mission")
    p.add_argument("--json", type=Path)
    p.add_argument("--memory", action="store_true",
                   help="resident memory per Dask worker over one study instead")
    p.add_argument("--workers", type=int, default=1, help="with --memory")
    a = p.parse_args(argv)
    if a.memory:
        return memory(a.runs, a.t_final, a.workers)
    cases = [("serial", 1), ("dask", 1), ("dask", 2)]
    res = [measure(ex, w, a.runs, a.t_final) for ex, w in cases]
    base = res[0]["missions_per_min"]
    print(f"{a.runs} runs of the seed mission cut to {a.t_final:g} s; {os.cpu_count()} cores\n")
    print("| executor | workers | wall (s) | missions/min | vs serial | mean run (s) | "
          "overhead/run (s) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in res:
        print(f"| {r['executor']} | {r['workers']} | {r['wall_s']:.2f} | "
              f"{r['missions_per_min']:.0f} | {r['missions_per_min'] / base:.2f}x | "
              f"{r['run_s_mean']:.3f} | {r['overhead_per_run_s']:.3f} |")
    serial, dk = res[0], res[1]
    print(f"\nDask (1 worker) vs serial: {(dk['wall_s'] - serial['wall_s']) / a.runs:+.3f} s "
          "per run (cluster start-up included)")
    if a.json:
        a.json.write_text(json.dumps(res, indent=2) + "\n")
    return 0


def memory(runs: int, t_final: float, workers: int) -> int:
    stats, log = _study("dask", workers, runs, t_final)
    by_worker: dict[str, list[float]] = {}
    for r in log:                       # finishing order = each worker's order
        by_worker.setdefault(r["worker"], []).append(r["rss_mb"])
    print(f"{runs} runs of the seed mission cut to {t_final:g} s on {workers} Dask worker(s), "
          f"{stats.wall_s:.0f} s; resident memory of each worker after its n-th run (MB)\n")
    print("| worker | runs | n=1 | n=100 | n=500 | n=1000 | last | KB/run after n=100 |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for w, rss in by_worker.items():
        at = [f"{rss[n - 1]:.1f}" if n <= len(rss) else "" for n in (1, 100, 500, 1000)]
        slope = (f"{(rss[-1] - rss[99]) * 1000 / (len(rss) - 100):.1f}" if len(rss) > 100
                 else "")
        print(f"| {w} | {len(rss)} | {' | '.join(at)} | {rss[-1]:.1f} | {slope} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
