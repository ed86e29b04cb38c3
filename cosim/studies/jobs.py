"""One run of a study: the job record a worker receives and the flat row it sends back.

A job carries the scenario itself (the TOML table with its world file already merged in), not
a path, so a worker on another machine needs no copy of the scenarios folder; it does need the
same `cosim` install (the code, and the FMU that `fmus.build.fmu_path()` finds or builds next to
it; see README.md of this package). `run_job` never raises for a failed run: a run that raises
is a row with status 'failed' and the error text, and the study goes on. A run cut by a signal
(Ctrl-C, SIGTERM) is no result: `run_job` raises `RunInterrupted`, the engine keeps no row for
it and stops the study, and the same command flies it again.
"""

from __future__ import annotations

import copy
import ctypes
import ctypes.util
import gc
import os
import shutil
import socket
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cosim import cache, cvthreads, tempdirs
from cosim.executors import RunInterrupted
from cosim.outputs.metrics import flat_metrics
from cosim.studies import deps

# columns every row has, in this order; then the varied parameters, then the metrics
HEAD = ("run_id",)
TAIL = ("seed", "status", "exit_reason", "passed", "app_phase", "message", "error")


@dataclass(frozen=True)
class Job:
    run_id: int
    raw: dict[str, Any]                         # the scenario table, world merged in
    source: str                                 # the scenario file (name, messages)
    sets: tuple[tuple[str, Any], ...]           # fixed --set assignments, every run
    params: tuple[tuple[str, Any], ...]         # this run's varied parameters (table columns)
    seed: int | None = None                     # scenario seed (None: the file's / a param's)
    mode: str = "mil"
    keep_dir: str | None = None                 # keep the run folder here (None: a temp dir)
    mcap: bool = False                          # the kept run folder also gets run.mcap
    cache_dir: str | None = None                # textures, taught keys (cosim/cache.py)


def self_contained(sc) -> dict[str, Any]:
    """The scenario's raw table with the world file merged in (ships to remote workers)."""
    raw = copy.deepcopy(sc.raw)
    raw["world"] = copy.deepcopy(sc.world_table)
    return raw


def start_sets(sc, keys: list[str]) -> dict[str, Any]:
    """Varying one field of vehicle.start in a scenario that takes the world's start pose would
    drop the other two fields to 0: pin them to the pose the scenario resolves to."""
    if not any(k.startswith("vehicle.start.") for k in keys) or "start" in sc.raw["vehicle"]:
        return {}
    return {f"vehicle.start.{f}": getattr(sc.start, f) for f in ("n", "e", "yaw_deg")
            if f"vehicle.start.{f}" not in keys}


def scenario_of(job: Job):
    src = Path(job.source)
    sc = deps.parse_scenario(copy.deepcopy(job.raw), source=job.source, base_dir=src.parent)
    assign = {**dict(job.sets), **dict(job.params)}
    if job.seed is not None:
        assign["seed"] = job.seed
    return deps.with_set(sc, assign) if assign else sc


def run_job(job: Job) -> dict[str, Any]:
    """Fly one mission; return its row. Never raises for a failed run (a run cut by a signal
    raises RunInterrupted: it is not a result). A worker runs one
    mission per core: OpenCV on one thread; what is made once per world is kept in the
    study's cache folder (the same results bit for bit: cosim/cvthreads.py, cosim/cache.py)."""
    cvthreads.set_run_threads(1)
    cache.set_dir(job.cache_dir)
    heap_for_frames()
    row: dict[str, Any] = {"run_id": job.run_id, **dict(job.params), "seed": job.seed}
    t0, c0 = time.perf_counter(), time.process_time()
    tmp = None
    try:
        sc = scenario_of(job)
        row["seed"] = sc.seed
        if job.keep_dir is None:
            tmp = tempdirs.make("run")
        out = Path(job.keep_dir or tmp)
        res = deps.run_mission(sc, mode=job.mode, out_dir=out,
                               mcap=job.mcap and job.keep_dir is not None)
        if deps.interrupted(res):
            raise RunInterrupted(f"run {job.run_id} cut at t = {res.t_end_s:.2f} s")
        summary = deps.write_run(res, out) if job.keep_dir else deps.summarize(res)
        failed = deps.component_error(res)
        row.update(status="failed" if failed else "ok", exit_reason=res.exit_reason.value,
                   passed=bool(summary["passed"]), app_phase=_last_phase(res),
                   message=res.message, error=res.message if failed else "")
        row.update(flat_metrics(summary["metrics"]))
        # why a run that ended well did not pass (a metric column of text)
        row["failed_criteria"] = " ".join(n for n, c in summary.get("criteria", {}).items()
                                          if not c["passed"])
        # the worker's numerics: "portable" runs give the same bits on any x86-64 CPU
        row["numerics"] = summary["numerics"]["mode"]
    except RunInterrupted:
        raise
    except Exception as exc:  # a crashed run is a row, the study goes on
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
        row.update(status="failed", exit_reason="", passed=False, app_phase="", message="",
                   error=f"{type(exc).__name__}: {exc}{where}")
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        release_memory()
    # '_' keys go to the study's run log, not the table (they differ from one execution to another)
    row["_wall_s"] = time.perf_counter() - t0
    row["_cpu_s"] = time.process_time() - c0   # busy host: the run's cost, better than wall
    row["_worker"] = f"{socket.gethostname()}:{os.getpid()}"
    row["_rss_mb"] = _rss_mb()
    return row


def _libc(fn_name: str, argtypes: list):
    """A glibc function, or None on another C library (macOS, musl)."""
    name = ctypes.util.find_library("c")
    try:
        fn = getattr(ctypes.CDLL(name), fn_name) if name else None
    except (OSError, AttributeError):
        return None
    if fn is not None:
        fn.argtypes, fn.restype = argtypes, ctypes.c_int
    return fn


_TRIM = _libc("malloc_trim", [ctypes.c_size_t])
_MALLOPT = _libc("mallopt", [ctypes.c_int, ctypes.c_int])
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3        # glibc's malloc.h
HEAP_FRAMES = 32 << 20       # glibc's largest mmap threshold (64-bit): frames from the heap
HEAP_TRIM = 256 << 20        # the heap is trimmed after each run (release_memory), not within


def heap_for_frames() -> None:
    """Frames from the heap, not a fresh mmap each: Dask's nanny starts its workers with
    MALLOC_TRIM_THRESHOLD_=65536, and a trim threshold set by hand turns off glibc's moving
    mmap threshold, so each 1.6 MB frame of a front-camera run was mapped, faulted in page by
    page and unmapped (E2: 4.6 million page faults and 9.8 s of system time a run, 29.5 s
    instead of 18.5 s). Set again before each run (it is the worker's, whoever started it);
    the memory stays flat because `release_memory` trims after each run."""
    if _MALLOPT is not None:
        _MALLOPT(_M_MMAP_THRESHOLD, HEAP_FRAMES)
        _MALLOPT(_M_TRIM_THRESHOLD, HEAP_TRIM)


def release_memory() -> None:
    """Give the memory a finished run freed back to the system. A front-camera run allocates
    ~1 GB in 1.2 MB frames; glibc's malloc raises its mmap threshold after the first such
    frame is freed, so later frames come from the heap and its freed pages stay resident: a
    paper-2 worker held ~265 MB and grew by ~0.1 MB a run. `malloc_trim(0)` after each run
    returns them (measured: 145 MB, flat; docs/performance-paper2.md)."""
    gc.collect()
    if _TRIM is not None:
        _TRIM(0)


def _rss_mb() -> float | None:
    """Resident memory of this worker process after the run (MB), to see it stay flat."""
    try:
        import psutil  # a dependency of dask.distributed
    except ImportError:
        return None
    return round(psutil.Process().memory_info().rss / 1e6, 1)


def _last_phase(res) -> str:
    if res.scenario.app.name == "none" or not len(res.series):
        return ""
    i = int(res.series[-1, deps.phase_column()])
    return res.phases[i] if 0 <= i < len(res.phases) else ""
