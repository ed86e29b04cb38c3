"""Run a study's jobs (a Monte Carlo study's or a sweep's) and stream the rows into the results
table; the one engine of both, on the executors of cosim/executors.py (`dask`, the default: a
local cluster or `--scheduler`; `serial`: in this process, the reference for tests). A job
whose worker died twice is a failed row (KilledWorker).

Rows come back as runs finish (`as_completed`) and are appended to the table at once, so a
study stopped anywhere (Ctrl-C, a lost worker, a reboot) resumes with the same command and
skips the runs already in the table. A signal stops the study: the runs it cut get no row
(`RunInterrupted`), so the resume flies them. Each finished run also gets a line in `runs.log` (JSON
lines: run id, status, wall time, worker, its resident memory after the run, UTC time): what
changes from one execution to another stays out of the table.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cosim.errors import ScenarioError, output_error
from cosim.executors import EXECUTORS, RunInterrupted, map_jobs
from cosim.studies.jobs import Job, run_job
from cosim.studies.table import ResultsTable


class StudyError(Exception):
    """The study cannot go on (a broken pool); the rows so far are in the table."""


class StudyInterrupted(Exception):
    """Ctrl-C or SIGTERM: the rows so far are in the table, the runs cut by it have none;
    the same command continues."""


@dataclass
class StudyStats:
    total: int = 0          # jobs in the study
    skipped: int = 0        # already in the table
    ran: int = 0            # run now (ok + failed)
    failed: int = 0         # of those, failed
    wall_s: float = 0.0


def run_study(jobs: list[Job], table: ResultsTable, *, executor: str = "dask",
              scheduler: str | None = None, workers: int | None = None,
              limit: int | None = None, retry_failed: bool = False, progress: bool = True,
              log: Path | None = None, fn: Callable[[Job], dict[str, Any]] = run_job,
              ) -> StudyStats:
    """Run the jobs not yet in `table` (at most `limit` of them); rows appended as they finish."""
    if executor not in EXECUTORS:
        raise ScenarioError("--executor", executor, f"one of {', '.join(EXECUTORS)}")
    if workers is not None and workers < 1:
        raise ScenarioError("--workers", workers, "an integer >= 1")
    done = table.finished(retry_failed=retry_failed)
    todo = [j for j in jobs if j.run_id not in done]
    stats = StudyStats(total=len(jobs), skipped=len(jobs) - len(todo))
    if limit is not None:
        todo = todo[:limit]
    t0 = time.perf_counter()
    bar = _bar(len(todo), stats.skipped, progress)

    def record(row: dict[str, Any]) -> None:
        extra = {k: row.pop(k) for k in list(row) if k.startswith("_")}
        try:
            table.append(row)
        except OSError as exc:        # disk full: the table keeps the rows before this one
            raise output_error(exc, table.path, f"run {row['run_id']} just flown is not in it; "
                               "the same command runs it again") from None
        stats.ran += 1
        stats.failed += row["status"] == "failed"
        if log is not None:
            with contextlib.suppress(OSError), open(log, "a") as f:   # a log line: optional
                f.write(json.dumps({"run_id": row["run_id"], "status": row["status"],
                                    "wall_s": extra.get("_wall_s"),
                                    "worker": extra.get("_worker"),
                                    "rss_mb": extra.get("_rss_mb"),
                                    "cpu_s": extra.get("_cpu_s"),
                                    "utc": datetime.now(UTC).isoformat(timespec="seconds")})
                        + "\n")
        bar.set_postfix(done=stats.ran - stats.failed, failed=stats.failed, refresh=False)
        bar.update(1)

    try:
        if todo:
            for row in map_jobs(todo, fn, executor=executor, workers=workers,
                                scheduler=scheduler, lost=lost_row):
                record(row)
    except (KeyboardInterrupt, RunInterrupted):   # the run under way is no row: flown again
        raise StudyInterrupted(f"interrupted after {stats.ran} of {len(todo)} runs") from None
    finally:
        bar.close()
        stats.wall_s = time.perf_counter() - t0
    return stats


def lost_row(job: Job, exc: BaseException) -> dict[str, Any]:
    return {"run_id": job.run_id, **dict(job.params), "seed": job.seed, "status": "failed",
            "exit_reason": "", "passed": False, "app_phase": "", "message": "",
            "error": f"{type(exc).__name__}: {exc}"}


def _bar(total: int, skipped: int, progress: bool):
    from tqdm import tqdm

    quiet = (not progress or not sys.stderr.isatty()
             or os.environ.get("CI", "").lower() in ("1", "true", "yes"))
    return tqdm(total=total, unit="run", disable=quiet, dynamic_ncols=True,
                desc=f"runs ({skipped} already done)" if skipped else "runs")
