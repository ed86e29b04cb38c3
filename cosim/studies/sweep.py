"""Parameter sweeps: many independent runs of one scenario, in parallel.

`cosim sweep SCENARIO --set app.alpha=0.002,0.003,0.004 --set seed=0,1` runs the Cartesian
product of the values. Each run is a job (scenario path + overrides -> summary dict) that
touches nothing shared and binds its own ports, so any executor can run them: the default
`local` one is a process pool; `serial` runs in this process. A cluster engine plugs in by
implementing `Executor.map(fn, jobs)` (e.g. with `dask.distributed.Client.map` +
`gather`) and registering it in EXECUTORS.
"""

from __future__ import annotations

import csv
import itertools
import json
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from cosim.scenario.sets import parse_sets, split_values  # noqa: F401


class Executor(Protocol):
    def map(self, fn: Callable[[Any], Any], jobs: Iterable[Any]) -> list[Any]: ...


class SerialExecutor:
    def map(self, fn, jobs):
        return [fn(j) for j in jobs]


class LocalPoolExecutor:
    """A local process pool; one run uses one core."""

    def __init__(self, workers: int | None = None) -> None:
        self.workers = workers or max(1, os.cpu_count() or 1)

    def map(self, fn, jobs):
        jobs = list(jobs)
        with ProcessPoolExecutor(max_workers=min(self.workers, max(1, len(jobs)))) as ex:
            return list(ex.map(fn, jobs))


EXECUTORS: dict[str, Callable[[int | None], Executor]] = {
    "local": lambda n: LocalPoolExecutor(n),
    "serial": lambda n: SerialExecutor(),
}


@dataclass(frozen=True)
class Job:
    scenario: str
    overrides: tuple[tuple[str, Any], ...]
    out_dir: str
    mode: str = "mil"


def run_job(job: Job) -> dict[str, Any]:
    from cosim.load import load_scenario, with_set
    from cosim.outputs.report import write_run
    from cosim.sim.master import RunOptions, run_scenario

    sc = with_set(load_scenario(job.scenario), dict(job.overrides))
    out = Path(job.out_dir)
    res = run_scenario(sc, RunOptions(mode=job.mode, out_dir=out))
    summary = write_run(res, out)
    return {"overrides": dict(job.overrides), "out": str(out), **summary}


def make_jobs(scenario: str, grid: dict[str, list[Any]], out: Path, mode: str) -> list[Job]:
    keys = list(grid)
    jobs = []
    for i, combo in enumerate(itertools.product(*(grid[k] for k in keys))):
        tag = "_".join(f"{k.split('.')[-1]}={v}" for k, v in zip(keys, combo, strict=True))
        jobs.append(Job(scenario, tuple(zip(keys, combo, strict=True)),
                        str(out / f"{i:03d}_{tag}"), mode))
    return jobs


TABLE_METRICS = ("mission_time_s", "path_error_rms_m", "path_error_max_m", "landing_error_m",
                 "speed_mean_mps")


def write_table(results: list[dict[str, Any]], keys: list[str], out: Path) -> Path:
    path = out / "sweep.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*keys, "exit_reason", "passed", *TABLE_METRICS, "real_time_factor"])
        for r in results:
            m = r["metrics"]
            w.writerow([*(r["overrides"][k] for k in keys), r["exit_reason"], r["passed"],
                        *(_fmt(m.get(k)) for k in TABLE_METRICS),
                        f"{r['real_time_factor']:.0f}"])
    (out / "sweep.json").write_text(json.dumps(results, indent=2, default=str))
    return path


def _fmt(v: Any) -> str:
    return "" if v is None else f"{v:.4f}"


def plot_sweep(results: list[dict[str, Any]], key: str, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = [r["overrides"][key] for r in results]
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, (metric, label) in zip(axs, [("mission_time_s", "mission time (s)"),
                                         ("path_error_rms_m", "path error RMS (m)"),
                                         ("speed_mean_mps", "mean speed following (m/s)")],
                                   strict=True):
        ys = [r["metrics"].get(metric, float("nan")) for r in results]
        ax.plot(xs, [float("nan") if y is None else y for y in ys], "o-")
        ax.set_xlabel(key)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    path = out / "sweep.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
