"""`cosim sweep` (a study: cosim/studies): a local Dask cluster gives the same results as
running serially, with a sweep figure, and (slow) the alpha trade-off of paper 1 on the seed
track."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
COSIM = [sys.executable, "-m", "cosim.cli"]


def _sweep(tmp: Path, scenario: str, sets: list[str], executor: str,
           *extra: str) -> list[dict[str, str]]:
    args = [*COSIM, "sweep", str(ROOT / "scenarios" / scenario), "--executor", executor,
            "--out", str(tmp), "--quiet", *extra]
    for s in sets:
        args += ["--set", s]
    r = subprocess.run(args, capture_output=True, text=True, timeout=1200)
    assert r.returncode in (0, 1), r.stderr
    if len([s for s in sets if "," in s]) == 1:       # one swept key: the figure
        assert (tmp / "sweep.png").stat().st_size > 0
    return list(csv.DictReader(open(tmp / "results.csv")))


@pytest.mark.flight
def test_dask_and_serial_agree(tmp_path):
    # flow noise makes the seed matter; each run's whole time series must agree bit for bit
    sets = ["seed=0,1", "sensors.flow.flow_noise_rad_s=0.03", "timing.t_final_s=6.0"]
    a = _sweep(tmp_path / "dask", "scripted_square.toml", sets, "dask", "--keep-runs")
    b = _sweep(tmp_path / "serial", "scripted_square.toml", sets, "serial", "--keep-runs")
    assert len(a) == len(b) == 2 and a == b
    series = {}
    for name in ("dask", "serial"):
        dirs = sorted((tmp_path / name / "runs").iterdir())
        assert len(dirs) == 2
        series[name] = [(d / "timeseries.csv").read_bytes() for d in dirs]
    assert series["dask"] == series["serial"]
    assert series["dask"][0] != series["dask"][1]     # seed 0 and seed 1 differ
    assert {r["exit_reason"] for r in a} == {"time_limit"}


@pytest.mark.slow
def test_alpha_trade_off_on_the_seed_track(tmp_path):
    alphas = [0.0038, 0.006, 0.008, 0.010, 0.012]
    rows = _sweep(tmp_path, "mambo_seed_track.toml",
                  ["app.alpha=" + ",".join(map(str, alphas))], "dask")
    assert [float(r["app.alpha"]) for r in rows] == alphas
    assert all(r["exit_reason"] == "mission_complete" for r in rows)
    times = [float(r["mission_time_s"]) for r in rows]
    speeds = [float(r["speed_mean_mps"]) for r in rows]
    assert times == sorted(times, reverse=True)         # larger alpha, shorter mission
    assert speeds == sorted(speeds)                     # ... and faster
    for a, v in zip(alphas, speeds, strict=True):       # speed ~ proportional to alpha
        assert v / a == pytest.approx(speeds[0] / alphas[0], rel=0.2)
    rms = [float(r["path_error_rms_m"]) for r in rows]
    assert rms[-1] == max(rms) > min(rms) * 1.5         # the fastest is the least accurate


@pytest.mark.slow
def test_monte_carlo_on_the_textured_floor(tmp_path):
    """8 seeds: odometry noise, camera pixel and lighting noise, distractors. Every run lands
    on the marker, and the seeds really differ."""
    rows = _sweep(tmp_path, "mambo_textured.toml",
                  ["seed=0,1,2,3,4,5,6,7", "sensors.flow.flow_noise_rad_s=0.03",
                   "sensors.baro.baro_noise_pa=3.0"], "dask")
    assert len(rows) == 8
    assert all(r["exit_reason"] == "mission_complete" and r["passed"] == "True" for r in rows)
    assert max(float(r["landing_error_m"]) for r in rows) < 0.05
    assert len({r["mission_time_s"] for r in rows}) > 1
