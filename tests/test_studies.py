"""Studies (cosim/studies): statistics, the `--vary` syntax and draws, executors that agree bit
for bit, resuming an interrupted study, failed runs as rows, and the replay command."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cosim.errors import ScenarioError
from cosim.studies.deps import load_scenario
from cosim.studies.dists import parse_varies, parse_vary, run_draws
from cosim.studies.engine import run_study
from cosim.studies.jobs import Job, run_job, self_contained
from cosim.studies.report import wilson
from cosim.studies.study import montecarlo_jobs, run_in_folder
from cosim.studies.table import ResultsTable

ROOT = Path(__file__).resolve().parent.parent
SEED_TRACK = str(ROOT / "scenarios" / "mambo_seed_track.toml")
SQUARE = str(ROOT / "scenarios" / "scripted_square.toml")
COSIM = [sys.executable, "-m", "cosim.cli"]
# a short seed-track study: 7 s (arming, take-off, the first metres of following)
VARY = ["wind.n_mps=uniform(0,0.6)", "sensors.flow.flow_noise_rad_s=truncnormal(0.02,0.01,0,0.05)",
        "vehicle.start.yaw_deg=normal(0,15)"]
SHORT = {"timing.t_final_s": 7.0}     # the vehicle arms after its 0.5 s tilt alignment, 1 s in


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "CI": "true"}
    return subprocess.run([*COSIM, *args], capture_output=True, text=True, timeout=600, env=env)


def _mc_args(out: Path, n: int, *extra: str) -> list[str]:
    args = ["montecarlo", SEED_TRACK, "-n", str(n), "--seed", "7", "--set",
            "timing.t_final_s=7.0", "--out", str(out), *extra]
    for v in VARY:
        args += ["--vary", v]
    return args


# ------------------------------------------------------------------ statistics
def test_wilson_interval_against_hand_computed_values():
    # 8 of 10, z = 1.96: centre (0.8 + 1.9208/10) / 1.38416 = 0.71674,
    # half 1.96 / 1.38416 * sqrt(0.016 + 0.009604) = 0.22658 -> [0.4902, 0.9433]
    lo, hi = wilson(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-4) and hi == pytest.approx(0.9433, abs=1e-4)
    lo, hi = wilson(0, 10)                      # [0, z^2 / (n + z^2)] = [0, 0.2775]
    assert lo == 0.0 and hi == pytest.approx(3.8415 / 13.8415, abs=1e-4)
    lo, hi = wilson(10, 10)
    assert hi == pytest.approx(1.0) and lo == pytest.approx(1 - 0.2775, abs=1e-4)


# ------------------------------------------------------------------ --vary
def test_distribution_parser_forms_and_errors():
    d = parse_vary("wind.n_mps=uniform(0,1.5)")
    assert (d.key, d.kind, d.args) == ("wind.n_mps", "uniform", (0.0, 1.5))
    assert parse_vary("a.b = normal(0, 0.01)").args == (0.0, 0.01)
    assert parse_vary("app.preset=choice(released, 'x', 3)").args == ("released", "x", 3)
    assert parse_vary("k=loguniform(1e-3,1)").kind == "loguniform"
    bad = ["wind.n_mps", "wind.n_mps=uniform(1,0)", "wind.n_mps=gauss(0,1)",
           "wind.n_mps=normal(0)", "wind.n_mps=normal(0,-1)", "wind.n_mps=loguniform(0,1)",
           "wind.n_mps=uniform(a,1)", "wind.n_mps=choice()", "wind.n_mps=truncnormal(0,1,2,1)"]
    for text in bad:
        with pytest.raises(ScenarioError) as e:
            parse_vary(text)
        assert e.value.field == f"--vary {text}", text
    with pytest.raises(ScenarioError, match="each key varied once"):
        parse_varies(["wind.n_mps=uniform(0,1)", "wind.n_mps=normal(0,1)"])


def test_bad_vary_and_out_of_range_draws_exit_2_naming_them(tmp_path):
    r = _cli("montecarlo", SQUARE, "-n", "3", "--vary", "wind.n_mps=gauss(0,1)",
             "--out", str(tmp_path / "a"))
    assert r.returncode == 2 and "--vary wind.n_mps=gauss(0,1)" in r.stderr, r.stderr
    # half of normal(0, 0.01) is negative: no clipping, an error naming the field
    r = _cli("montecarlo", SQUARE, "-n", "20", "--vary",
             "sensors.odometry_noise.pos_std_m=normal(0,0.01)", "--out", str(tmp_path / "b"))
    assert r.returncode == 2, r.stderr
    assert "sensors.odometry_noise.pos_std_m" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "b" / "results.csv").exists()


def test_same_study_seed_same_draws():
    dists = parse_varies(VARY + ["app.preset=choice(released,tuned)"])
    a = [run_draws(7, i, dists) for i in range(50)]
    assert a == [run_draws(7, i, dists) for i in range(50)]
    assert a != [run_draws(8, i, dists) for i in range(50)]
    assert len({s for s, _ in a}) == 50                       # each run its own scenario seed
    # run i depends on (seed, i) only, and each key has its own stream
    only_wind = parse_varies(VARY[:1])
    assert [v["wind.n_mps"] for _, v in a] == [run_draws(7, i, only_wind)[1]["wind.n_mps"]
                                               for i in range(50)]
    w = np.array([v["wind.n_mps"] for _, v in a])
    p = np.array([v["sensors.flow.flow_noise_rad_s"] for _, v in a])
    assert w.min() >= 0 and w.max() < 0.6 and p.min() >= 0 and p.max() <= 0.05
    assert {v["app.preset"] for _, v in a} == {"released", "tuned"}


# ------------------------------------------------------------------ executors
def _study(out: Path, executor: str, n: int = 4, **kw):
    sc = load_scenario(SEED_TRACK)
    jobs, manifest = montecarlo_jobs(sc, parse_varies(VARY), n, 7, dict(SHORT), out)
    manifest["command"] = "test"
    return run_in_folder(jobs, manifest, out, executor=executor, progress=False, **kw)


@pytest.mark.flight
def test_serial_and_local_dask_cluster_give_the_same_rows(tmp_path):
    s_stats, s_rows, _ = _study(tmp_path / "serial", "serial")
    d_stats, _, _ = _study(tmp_path / "dask", "dask", workers=2)
    assert s_stats.ran == d_stats.ran == 4 and s_stats.failed == d_stats.failed == 0
    serial = (tmp_path / "serial" / "results.csv").read_bytes()
    assert serial == (tmp_path / "dask" / "results.csv").read_bytes()
    # the runs really differ (seeds, draws), and two worker processes shared them
    assert len({r["path_error_rms_m"] for r in s_rows}) == 4
    workers = {json.loads(line)["worker"] for line in open(tmp_path / "dask" / "runs.log")}
    assert len(workers) == 2


# ------------------------------------------------------------------ resume
@pytest.mark.flight
def test_interrupted_study_resumes_without_redoing_runs(tmp_path):
    out = tmp_path / "mc"
    r = _cli(*_mc_args(out, 5, "--executor", "serial", "--limit", "2"))
    assert r.returncode == 0, r.stderr
    first = (out / "results.csv").read_text().splitlines()
    assert len(first) == 3 and not (out / "report.md").exists()
    with open(out / "results.csv", "a") as f:           # a row torn by the interruption
        f.write("2,0.1,0.0")
    r = _cli(*_mc_args(out, 5, "--executor", "serial"))
    assert r.returncode == 0, r.stderr
    assert "3 runs now (0 failed), 2 already done" in r.stderr
    rows = (out / "results.csv").read_text().splitlines()
    assert rows[:3] == first and len(rows) == 6
    log = [json.loads(line)["run_id"] for line in open(out / "runs.log")]
    assert sorted(log) == [0, 1, 2, 3, 4]                # every run flown exactly once
    # same bytes as the study run in one go
    whole = tmp_path / "whole"
    assert _cli(*_mc_args(whole, 5, "--executor", "serial")).returncode == 0
    assert (whole / "results.csv").read_bytes() == (out / "results.csv").read_bytes()
    rep = json.loads((out / "report.json").read_text())
    assert rep["runs"] == 5 and set(rep["metrics"]["path_error_rms_m"]) >= {"p5", "p50", "p95"}
    # other settings in the same folder: refused, naming what differs
    r = _cli(*_mc_args(out, 5, "--executor", "serial", "--vary", "wind.e_mps=uniform(0,1)"))
    assert r.returncode == 2 and "a new folder, or the same settings" in r.stderr
    assert "wind.e_mps" in r.stderr and len((out / "results.csv").read_text().splitlines()) == 6


@pytest.mark.flight
def test_replay_command_flies_the_same_run_kept_with_keep_runs(tmp_path):
    out = tmp_path / "mc"
    assert _cli(*_mc_args(out, 3, "--executor", "serial", "--keep-runs")).returncode == 0
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["000000", "000001", "000002"]
    rep = json.loads((out / "report.json").read_text())
    worst = rep["worst"][0]
    args = shlex.split(worst["replay"])
    args[args.index("--out") + 1] = str(tmp_path / "replay")
    r = _cli(*args[1:], "--no-plots")
    assert r.returncode in (0, 1), r.stderr
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())
    row = next(r for r in (out / "results.csv").read_text().splitlines()[1:]
               if r.startswith(f"{worst['run_id']},"))
    assert repr(summary["metrics"]["path_error_rms_m"]) == worst["main_metric"]
    assert str(summary["seed"]) == worst["seed"] and worst["main_metric"] in row
    kept = out / "runs" / f"{worst['run_id']:06d}" / "timeseries.csv"     # --keep-runs
    assert kept.read_bytes() == (tmp_path / "replay" / "timeseries.csv").read_bytes()


# ------------------------------------------------------------------ failed runs
class CrashingApp:
    """A user app that raises 0.5 s into the flight."""

    def __init__(self, params):
        self.phase, self.done, self.events, self.setpoint = "wait", False, [], [0.0] * 3

    def on_start(self, ctx):
        pass

    def on_frame(self, t, image):
        pass

    def on_tick(self, t):
        if t > 0.5:
            raise RuntimeError("boom at 0.5 s")

    def metrics(self):
        return {}


@pytest.mark.flight
def test_crashing_runs_are_failed_rows_and_the_study_goes_on(tmp_path):
    sc = load_scenario(SQUARE)
    raw = self_contained(sc)
    crash = dict(raw, app={"name": f"{__name__}:CrashingApp"})
    short = (("timing.t_final_s", 2.0),)
    jobs = [Job(0, raw, sc.source, short, (("wind.n_mps", 0.0),)),
            Job(1, raw, sc.source, short, (("wind.n_mps", -99.0),)),    # raises: out of range
            Job(2, crash, sc.source, short, (("wind.n_mps", 0.0),)),    # the app raises
            Job(3, raw, sc.source, short, (("wind.n_mps", 0.2),))]
    table = ResultsTable(tmp_path / "results.csv", ["wind.n_mps"])
    stats = run_study(jobs, table, executor="serial", progress=False)
    rows = table.finish()
    assert stats.ran == 4 and stats.failed == 2
    assert [r["status"] for r in rows] == ["ok", "failed", "failed", "ok"]
    assert "ScenarioError" in rows[1]["error"] and "wind.n_mps" in rows[1]["error"]
    assert rows[2]["exit_reason"] == "component_error" and "boom at 0.5 s" in rows[2]["error"]
    # failed rows count as finished; --retry-failed runs them again (one row per run at the end)
    again = ResultsTable(tmp_path / "results.csv", ["wind.n_mps"])
    assert run_study(jobs, again, executor="serial", progress=False).ran == 0
    assert run_study(jobs, again, executor="serial", progress=False,
                     retry_failed=True).ran == 2
    assert [r["run_id"] for r in again.finish()] == ["0", "1", "2", "3"]


def _dies_once(job: Job) -> dict:
    """Run 1 kills its worker process the first time (a marker file remembers); run 2 always."""
    marker = Path(job.keep_dir) / f"died-{job.run_id}"
    if job.run_id == 2 or (job.run_id == 1 and not marker.exists()):
        marker.touch()
        os._exit(1)
    return run_job(job)


@pytest.mark.flight
def test_a_job_whose_worker_dies_runs_again_or_is_a_failed_row(tmp_path):
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])   # workers cannot import tests
    sc = load_scenario(SQUARE)
    raw = self_contained(sc)
    jobs = [Job(i, raw, sc.source, (("timing.t_final_s", 2.0),), (("wind.n_mps", 0.1 * i),),
                keep_dir=str(tmp_path)) for i in range(3)]
    table = ResultsTable(tmp_path / "results.csv", ["wind.n_mps"])
    stats = run_study(jobs, table, executor="dask", workers=2, progress=False, fn=_dies_once)
    rows = table.finish()
    assert stats.ran == 3 and [r["status"] for r in rows] == ["ok", "ok", "failed"]
    assert "KilledWorker" in rows[2]["error"] and (tmp_path / "died-1").exists()


@pytest.mark.flight
def test_a_study_on_an_existing_cluster_via_scheduler(tmp_path):
    """`dask scheduler` + `dask worker` (the README's two commands, port 0), then --scheduler."""
    dask_cli = str(Path(sys.executable).parent / "dask")
    sfile = tmp_path / "scheduler.json"
    logs = open(tmp_path / "dask.log", "w")
    procs = [subprocess.Popen([dask_cli, "scheduler", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sfile)], stdout=logs, stderr=logs)]
    try:
        # no nanny: the worker is this test's child with its environment as it is (a nanny
        # would set OPENBLAS_NUM_THREADS=1 where none is set, and under an emulated CPU that
        # turns the worker portable, which check_workers then rightly refuses)
        procs.append(subprocess.Popen([dask_cli, "worker", "--scheduler-file", str(sfile),
                                       "--no-nanny", "--nthreads", "1", "--no-dashboard"],
                                      stdout=logs, stderr=logs))
        for _ in range(1200):                  # the scheduler writes its address when up
            if sfile.is_file() and sfile.stat().st_size:
                break
            assert procs[0].poll() is None, (tmp_path / "dask.log").read_text()
            time.sleep(0.05)
        addr = json.loads(sfile.read_text())["address"]
        out = tmp_path / "mc"
        r = _cli(*_mc_args(out, 3, "--scheduler", addr))
        assert r.returncode == 0, r.stderr
        assert f"on {addr}" in r.stderr
        serial = tmp_path / "serial"
        assert _cli(*_mc_args(serial, 3, "--executor", "serial")).returncode == 0
        assert (out / "results.csv").read_bytes() == (serial / "results.csv").read_bytes()
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=30)
        logs.close()


@pytest.mark.flight
def test_sweep_through_the_study_engine(tmp_path):
    """`cosim sweep`: streamed table, one seed column, report, same bytes from a local Dask
    cluster and serially."""
    base = ["sweep", SEED_TRACK, "--set", "seed=0,1", "--set", "wind.n_mps=0,0.3",
            "--set", "sensors.flow.flow_noise_rad_s=0.03", "--set", "timing.t_final_s=5"]
    r = _cli(*base, "--executor", "dask", "--workers", "2", "--resume",
             "--out", str(tmp_path / "pool"))
    assert r.returncode in (0, 1), r.stderr
    assert _cli(*base, "--executor", "serial", "--resume",
                "--out", str(tmp_path / "serial")).returncode in (0, 1)
    table = (tmp_path / "pool" / "results.csv").read_text()
    assert table == (tmp_path / "serial" / "results.csv").read_text()
    header, *rows = table.splitlines()
    assert header.startswith("run_id,wind.n_mps,seed,status,") and len(rows) == 4
    assert [r.split(",")[1:3] for r in rows] == [["0", "0"], ["0.3", "0"], ["0", "1"],
                                                 ["0.3", "1"]]
    rep = json.loads((tmp_path / "pool" / "report.json").read_text())
    assert rep["study"]["kind"] == "sweep" and rep["study"]["params"] == ["seed", "wind.n_mps"]
    for w in rep["worst"]:            # the replay pins the fixed sets, the seed, the swept value
        assert "--set timing.t_final_s=5 " in w["replay"] and f"--seed {w['seed']} " in w["replay"]
        assert f"--set wind.n_mps={w['params']['wind.n_mps']} " in w["replay"]
    md = (tmp_path / "pool" / "report.md").read_text()   # 5 s: none completes, and it says so
    assert rep["failed_criteria"]["must_complete"] == 4 and "must_complete 4" in md


def test_the_report_says_why_runs_failed_and_ranks_each_main_metric():
    from cosim.studies.report import build_report, markdown

    rows = []
    for i, (clear, err, why) in enumerate([(0.30, 0.02, ""), (0.01, 0.03, "clearance_min"),
                                           (0.20, 0.09, "final_error mission_time"),
                                           (0.05, 0.01, "")]):
        rows.append({"run_id": str(i), "seed": str(i), "status": "ok",
                     "exit_reason": "mission_complete", "passed": str(not why),
                     "app_phase": "done", "message": "", "error": "", "x": str(i / 10),
                     "min_clearance_m": repr(clear), "final_pose_error_m": repr(err),
                     "failed_criteria": why})
    man = {"kind": "montecarlo", "scenario": "s.toml", "params": ["x"], "sets": {},
           "command": "cosim montecarlo s.toml", "program": ".venv/bin/cosim"}
    rep = build_report(rows, man)
    assert rep["failed_criteria"] == {"clearance_min": 1, "final_error": 1, "mission_time": 1}
    by = rep["worst_by_metric"]
    assert [w["run_id"] for w in by["min_clearance_m"]] == [1, 3, 2]        # smallest first
    assert [w["run_id"] for w in by["final_pose_error_m"]] == [2, 1, 0]     # largest first
    assert by["min_clearance_m"][0]["replay"].startswith(".venv/bin/cosim run s.toml --seed 1")
    assert rep["worst"][0]["failed_criteria"] in ("clearance_min", "final_error mission_time")
    md = markdown({**rep, "plots": []})
    assert "failed criteria (runs): clearance_min 1, final_error 1, mission_time 1" in md
    assert "## the smallest min_clearance_m" in md and "(clearance_min failed)" in md


@pytest.mark.slow
def test_the_documented_200_run_monte_carlo_of_the_seed_mission(tmp_path):
    """The README's command (cosim/studies/README.md) on a local Dask cluster, ~5 min on 2
    cores: every run has a row, none raised, and the report holds the statistics."""
    out = tmp_path / "mc-200"
    args = ["montecarlo", SEED_TRACK, "-n", "200", "--seed", "1", "--out", str(out),
            "--vary", "wind.n_mps=uniform(0,1.5)",
            "--vary", "sensors.flow.flow_noise_rad_s=truncnormal(0.02,0.01,0,0.05)",
            "--vary", "vehicle.start.yaw_deg=normal(0,15)"]
    r = _cli(*args)
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["runs"] == 200 and rep["failed"] == 0
    lo, hi = rep["success"]["wilson95"]
    assert lo <= rep["success"]["rate"] <= hi
    assert {"report_hist.png", "report_vs_params.png"} <= {p.name for p in out.iterdir()}
    assert len(rep["worst"]) == 5 and all("--seed" in w["replay"] for w in rep["worst"])


def test_local_workers_run_this_process_numerics(monkeypatch):
    """Dask's nanny starts a worker with OMP/MKL/OPENBLAS_NUM_THREADS=1 where this process has
    none set; a study's workers keep this process's environment (their BLAS sums as the serial
    engine's) and its numerics mode, which check_workers compares."""
    from dask.distributed import Client

    from cosim import executors as engine
    from cosim import numerics

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)   # neither changes the mode
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    with engine.local_cluster(1) as cluster, Client(cluster) as client:
        engine.check_workers(client)
        (info,) = client.run(engine.worker_info).values()
    assert info["threads"] == {k: os.environ.get(k) for k in engine.THREAD_VARIABLES}
    assert info["threads"]["OMP_NUM_THREADS"] is None      # Dask's default would be "1"
    assert info["numerics"] == numerics.mode()
