"""Where a batch of jobs runs: in this process one after the other (`serial`), or on Dask
(`dask`): a `LocalCluster` of one single-threaded worker process per core (or `workers`), or,
with `--scheduler tcp://HOST:8786` or the environment variable COSIM_DASK_SCHEDULER, the
existing cluster behind that scheduler. A job whose worker dies is re-run on another worker
by the scheduler (Dask's `distributed.scheduler.allowed-failures`: 1 on our local cluster, the
scheduler's own setting on a remote one); when it has killed more workers than that, `lost`
makes its row. A task that raises outside the job's function is retried once (`retries=1`).

The engine of studies (cosim/studies/engine.py) and of `cosim test` (cosim/regress/): rows
come back as jobs finish (`map_jobs`). Every worker must run this process's FMU and numerics
(`check_workers`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from cosim.errors import ScenarioError


class RunInterrupted(Exception):
    """A run cut by a signal: not a result (no row); the batch stops, its resume re-flies it."""


EXECUTORS = ("dask", "serial")
SCHEDULER_ENV = "COSIM_DASK_SCHEDULER"


def scheduler_address(option: str | None) -> str | None:
    """--scheduler, else $COSIM_DASK_SCHEDULER, else None (a local cluster)."""
    addr = option or os.environ.get(SCHEDULER_ENV) or None
    if addr is not None and not _ADDRESS.fullmatch(addr):
        raise ScenarioError("--scheduler", addr, "a scheduler address like tcp://HOST:8786 "
                            "(HOST a name, an IPv4 address or [IPv6])")
    return addr


# [protocol://]host:port, the forms Dask's `Client(address)` takes
_ADDRESS = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx|inproc)://)?"
                      r"(?:[A-Za-z0-9_.-]+|\[[0-9A-Fa-f:.]+\]):[0-9]{1,5}")


def map_jobs(jobs: list, fn: Callable[[Any], dict[str, Any]], *, executor: str = "dask",
             workers: int | None = None, scheduler: str | None = None,
             lost: Callable[[Any, BaseException], dict[str, Any]],
             ) -> Iterator[dict[str, Any]]:
    """`fn(job)` of each job (each has a `run_id`), as they finish, on the executor; `lost`
    makes the row of a job whose worker died."""
    if executor not in EXECUTORS:
        raise ScenarioError("--executor", executor, f"one of {', '.join(EXECUTORS)}")
    runner = {"serial": _serial, "dask": _dask}[executor]
    return runner(jobs, fn, workers=workers, scheduler=scheduler, lost=lost)


def _serial(jobs, fn, **_) -> Iterator[dict[str, Any]]:
    for j in jobs:
        yield fn(j)


# the variables Dask's nanny sets in a worker that change how its libraries compute
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def local_cluster(n: int):
    """A LocalCluster of `n` single-threaded worker processes that run this process's
    numerics."""
    import dask
    from dask.distributed import LocalCluster

    # The workers' numerics are this process's (cosim/numerics.py): Dask's nanny would set
    # OMP/MKL/OPENBLAS_NUM_THREADS=1 in each worker before it starts, so a worker's BLAS
    # would sum in another order than the serial engine's, and a portable study could get
    # native workers or the reverse; they inherit this environment instead.
    spawn = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ").items()
             if k not in THREAD_VARIABLES}
    # worker-saturation 1.0: a worker holds only the task it runs (none queued behind it), so
    # a job that kills its worker does not take queued innocent jobs with it. No statistical
    # profiler in the workers: it feeds the dashboard (none here) and keeps a call tree per
    # second of work, 1000 of them, tens of MB per worker (issue 15).
    # Workers ignore Ctrl-C (worker_ignores_ctrl_c): the preload for a worker the nanny
    # starts again later, `_ctrl_c_held` for the first ones.
    cluster = None
    try:
        with dask.config.set({"distributed.scheduler.allowed-failures": 1,
                              "distributed.scheduler.worker-saturation": 1.0,
                              "distributed.worker.profile.enabled": False,
                              "distributed.worker.preload": [__name__],
                              "distributed.nanny.pre-spawn-environ": spawn}), _ctrl_c_held():
            # no dashboard; the scheduler's HTTP endpoints on a free port (not 8787, which
            # another study may hold: a warning)
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.ERROR,
                                   scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    except BaseException:
        # a Ctrl-C held while the workers started is raised as it ends: the cluster made
        # meanwhile is closed, not left running behind the interrupted study
        if cluster is not None:
            cluster.close()
        raise
    return cluster


# Ctrl-C in a terminal signals every process of its group, the workers of a local cluster too.
# A worker that takes it as KeyboardInterrupt closes itself while the client closes the
# cluster, and each prints tracebacks of the broken connections (issue 43, item 16). The
# client alone answers Ctrl-C (the study stops, the cluster is closed in order): the workers
# ignore it.
def dask_setup(worker) -> None:
    """Dask's preload hook, run in each worker of our local cluster as it starts."""
    worker_ignores_ctrl_c()
    logging.getLogger("distributed.worker").addFilter(_ClosingHeartbeat(worker))


class _ClosingHeartbeat(logging.Filter):
    """Drops the one error a worker logs when the cluster is closed under its running task:
    its heartbeat finds the scheduler gone while the worker itself is already closing (the
    close waits for the task; the scheduler does not). Measured: 1 stop in 2 printed it with
    its traceback. A failed heartbeat of a worker that is not closing is still logged."""

    MESSAGE = "Failed to communicate with scheduler during heartbeat."

    def __init__(self, worker) -> None:
        super().__init__()
        self.worker = worker

    def filter(self, record: logging.LogRecord) -> bool:
        from distributed.core import Status

        return not (record.msg == self.MESSAGE
                    and self.worker.status in (Status.closing, Status.closed,
                                               Status.closing_gracefully))


def worker_ignores_ctrl_c() -> None:
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _ctrl_c_held():
    """While the first workers start, SIGINT is ignored (a disposition a child inherits, so a
    worker ignores it from its first instruction on, before the preload runs) and blocked in
    this process's threads (a blocked signal is kept pending, not dropped: a Ctrl-C in the
    meantime is delivered when this ends, as KeyboardInterrupt)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})   # threads made now too
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def _dask(jobs, fn, *, workers, scheduler, lost, **_) -> Iterator[dict[str, Any]]:
    from dask.distributed import Client, as_completed

    addr = scheduler_address(scheduler)
    cluster = None
    if addr is None:
        cluster = local_cluster(workers or os.cpu_count() or 1)
        client = Client(cluster)
    else:
        try:
            client = Client(addr, timeout="20s")
        except (OSError, ValueError) as exc:
            raise ScenarioError("--scheduler", addr, f"a reachable Dask scheduler ({exc})"
                                ) from None
    try:
        check_workers(client)
        keys = [f"cosim-run-{j.run_id}-{id(jobs)}" for j in jobs]
        by_key = dict(zip(keys, jobs, strict=True))
        # no list of the futures: a future held by the client keeps its result (and its task
        # record) in the worker's memory until the study ends, a few tens of KB per run
        # (issue 15). Each one is released as soon as its row is taken.
        for f in as_completed(client.map(fn, jobs, key=keys, retries=1, pure=False)):
            job = by_key.pop(f.key)
            try:
                row = f.result()
            except RunInterrupted:    # a signal on the worker: no result, the study stops
                raise
            except Exception as exc:  # the worker died twice (KilledWorker) or the task broke
                row = lost(job, exc)
            f.release()
            del f
            yield row
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
            from cosim import tempdirs

            tempdirs.sweep()     # what the workers stopped in a run left (issue 43, item 15)


def worker_info() -> dict[str, Any]:
    """What a worker has: its cosim install and FMU (built there if needed), and its numerics
    (the mode, and the thread counts its BLAS was started with)."""
    import cosim
    from cosim import numerics
    from fmus.build import fmu_path, source_hash

    return {"cosim": str(Path(cosim.__file__).parent), "fmu_source": source_hash(),
            "fmu": str(fmu_path()), "numerics": numerics.mode(),
            "threads": {k: os.environ.get(k) for k in THREAD_VARIABLES}}


def check_workers(client) -> None:
    """Every worker must run the same model and the same numerics as this process: compare
    its FMU source hash and its numerics mode with ours."""
    from cosim import numerics
    from fmus.build import source_hash

    client.wait_for_workers(1, timeout=120)
    ours, mode = source_hash(), numerics.mode()
    for addr, info in client.run(worker_info).items():
        if info["fmu_source"] != ours:
            raise ScenarioError("--scheduler", addr,
                                f"workers with the same cosim install (its FMU source "
                                f"{info['fmu_source'][:12]} != ours {ours[:12]}, {info['cosim']})")
        if info["numerics"] != mode:
            raise ScenarioError("--scheduler", addr,
                                f"workers with this process's numerics ({mode}; this worker "
                                f"runs {info['numerics']}: start it with `python -m "
                                f"cosim.numerics {mode} -- dask worker ...`)")
