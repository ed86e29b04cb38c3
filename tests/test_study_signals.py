"""Issue 43, items 2 and 16: a signal during a study. The study stops at the signal, the run
under way is no row (the same command flies it again), the exit status is 130 after Ctrl-C
and 143 after SIGTERM, on every executor; a local Dask cluster shuts down without its
workers' tracebacks.

The studies here are sweeps of the hover scenario over its duration: run 0 lasts 1 s, the
others an hour, so a run is surely under way when the signal comes; real processes, real
signals (Ctrl-C is SIGINT to the whole process group, as a terminal sends it)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cosim.studies.table import ResultsTable

pytestmark = pytest.mark.flight

ROOT = Path(__file__).resolve().parents[1]
HOVER = str(ROOT / "scenarios" / "mambo_hover.toml")
HANG_S = 180            # a hang guard only: every wait below normally ends in seconds


def _study(out: Path, tmp: Path, executor: str, durations: str, *extra: str
           ) -> subprocess.Popen:
    tmp.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "CI": "true", "TMPDIR": str(tmp)}
    return subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sweep", HOVER, "--set",
         f"timing.t_final_s={durations}", "--executor", executor, "--out", str(out), *extra],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)          # its own process group: a Ctrl-C reaches it all


def _rows(out: Path) -> list[dict[str, str]]:
    f = out / "results.csv"
    if not f.is_file():
        return []
    text = f.read_text()
    return list(csv.DictReader(text[: text.rfind("\n") + 1].splitlines()))


def _flying(tmp: Path) -> bool:
    """A run of the study is under way: its temporary folder has a flight log with data."""
    return any(p.stat().st_size > 0 for p in tmp.glob("cosim-run-*/flight.tlog"))


def _signal_when_run_1_flies(proc: subprocess.Popen, out: Path, tmp: Path, sig: int,
                             group: bool) -> tuple[str, str]:
    deadline = time.monotonic() + HANG_S
    try:
        while not (len(_rows(out)) >= 1 and _flying(tmp)):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the study never got under way"
            time.sleep(0.05)
        time.sleep(0.5)                          # well into the hour-long run
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        return proc.communicate(timeout=HANG_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


@pytest.mark.parametrize("sig,group", [(signal.SIGINT, True), (signal.SIGTERM, False)],
                         ids=["ctrl-c", "sigterm"])
def test_a_signal_stops_a_serial_study_and_keeps_no_cut_run(tmp_path, sig, group):
    """Before: the cut run was a row (status ok, exit_reason interrupted, passed False), the
    study flew on, Ctrl-C exited 0 (or 1 by the cut run's failure), and the resume skipped
    the cut run."""
    out, tmp = tmp_path / "study", tmp_path / "tmp"
    proc = _study(out, tmp, "serial", "1,36000,36001")
    _, err = _signal_when_run_1_flies(proc, out, tmp, sig, group)
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and "the same command continues the study" in err
    rows = _rows(out)
    assert [r["run_id"] for r in rows] == ["0"] and rows[0]["exit_reason"] == "time_limit"
    assert [json.loads(x)["run_id"] for x in (out / "runs.log").read_text().splitlines()] == [0]
    assert not (out / "report.md").exists()
    # the resume flies runs 1 and 2 (the cut one included), skips run 0
    assert ResultsTable(out / "results.csv", ["timing.t_final_s"]).finished() == {0}
    assert not list(tmp.glob("cosim-*"))                # the run's temporary folders removed


@pytest.mark.parametrize("sig,group", [(signal.SIGINT, True), (signal.SIGTERM, False)],
                         ids=["ctrl-c", "sigterm"])
def test_a_signal_stops_a_dask_study_quietly_and_keeps_no_cut_run(tmp_path, sig, group):
    """Item 16 too: Ctrl-C reached the workers of the local cluster, and each printed the
    tracebacks of its broken connections while the client closed the cluster."""
    out, tmp = tmp_path / "study", tmp_path / "tmp"
    proc = _study(out, tmp, "dask", "1,36000,36001,36002", "--workers", "2")
    _, err = _signal_when_run_1_flies(proc, out, tmp, sig, group)
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and "ERROR" not in err and "Warning" not in err, err
    assert "the same command continues the study" in err
    assert [r["run_id"] for r in _rows(out)] == ["0"]
    assert ResultsTable(out / "results.csv", ["timing.t_final_s"]).finished() == {0}
    # the workers were stopped in their runs: what those left in TMPDIR is removed once the
    # cluster is closed (cosim/tempdirs.py; item 15)
    assert not list(tmp.glob("cosim-*")), list(tmp.iterdir())


def test_a_cut_run_an_older_cosim_kept_as_a_row_is_flown_again(tmp_path):
    """A table written before this fix holds the cut run as a row (exit_reason interrupted):
    the same command flies it again and its new row replaces it."""
    out = tmp_path / "study"
    args = [sys.executable, "-m", "cosim.cli", "sweep", HOVER, "--set",
            "timing.t_final_s=1,1.5", "--executor", "serial", "--out", str(out)]
    env = {**os.environ, "CI": "true"}
    r = subprocess.run(args, capture_output=True, text=True, timeout=HANG_S, env=env)
    assert r.returncode == 0, r.stderr
    table = out / "results.csv"
    lines = table.read_text().splitlines()
    head = lines[0].split(",")
    cut = lines[2].split(",")
    cut[head.index("exit_reason")], cut[head.index("passed")] = "interrupted", "False"
    table.write_text("\n".join([*lines[:2], ",".join(cut)]) + "\n")
    r = subprocess.run(args, capture_output=True, text=True, timeout=HANG_S, env=env)
    assert r.returncode == 0, r.stderr
    assert "1 runs now (0 failed), 1 already done" in r.stderr
    assert [x["exit_reason"] for x in _rows(out)] == ["time_limit", "time_limit"]
    assert table.read_text().splitlines() == lines


def _ignores_sigint() -> bool:
    return signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def _dies(_x: int) -> None:
    os._exit(1)


def test_local_workers_ignore_ctrl_c_even_when_started_again():
    """The client alone answers Ctrl-C; a worker the nanny starts again after one died (the
    preload) ignores it too."""
    import cloudpickle
    from dask.distributed import Client

    from cosim.executors import local_cluster

    cloudpickle.register_pickle_by_value(sys.modules[__name__])   # workers cannot import tests
    ours = signal.getsignal(signal.SIGINT)
    cluster = local_cluster(2)
    try:
        with Client(cluster) as client:
            assert set(client.run(_ignores_sigint).values()) == {True}
            before = set(client.scheduler_info()["workers"])
            fut = client.submit(_dies, 0, pure=False)
            with pytest.raises(Exception):       # noqa: B017 (KilledWorker or a lost worker)
                fut.result(timeout=HANG_S)
            deadline = time.monotonic() + HANG_S
            while set(client.scheduler_info()["workers"]) == before or \
                    len(client.scheduler_info()["workers"]) < 2:
                assert time.monotonic() < deadline
                time.sleep(0.1)
            assert set(client.run(_ignores_sigint).values()) == {True}
    finally:
        cluster.close()
    assert signal.getsignal(signal.SIGINT) is ours      # this process answers Ctrl-C again


def test_a_ctrl_c_while_the_local_cluster_starts_closes_it(monkeypatch):
    """Ctrl-C is held while the workers start (so they are born ignoring it) and raised as
    the start ends (`_ctrl_c_held`): the cluster made meanwhile must be closed, not left
    behind."""
    import contextlib

    import dask.distributed

    from cosim import executors

    made = []

    class Cluster:
        def __init__(self, **_kw) -> None:
            self.closed = False
            made.append(self)

        def close(self) -> None:
            self.closed = True

    @contextlib.contextmanager
    def held():                 # the held Ctrl-C, delivered as the start ends
        yield
        raise KeyboardInterrupt

    monkeypatch.setattr(dask.distributed, "LocalCluster", Cluster)
    monkeypatch.setattr(executors, "_ctrl_c_held", held)
    with pytest.raises(KeyboardInterrupt):
        executors.local_cluster(1)
    assert len(made) == 1 and made[0].closed
