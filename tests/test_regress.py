"""`cosim test` as a user runs it: real `cosim run` processes, baselines written and read back,
a change caught with the signal and time it left its tube, equivalence of modes, JUnit and
Markdown reports, the pytest plugin, and bad input."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import junitparser
import pytest

from cosim.regress import check_baseline, fly

pytestmark = pytest.mark.flight

ROOT = Path(__file__).resolve().parent.parent
SCEN = ROOT / "scenarios"


def cosim(*args: str, cwd: Path | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)


def copy_scenario(name: str, dest: Path, stem: str | None = None) -> Path:
    """A shipped scenario in a user's folder (its world file by absolute path)."""
    text = (SCEN / f"{name}.toml").read_text()
    text = text.replace('file = "worlds/', f'file = "{SCEN}/worlds/')
    out = dest / f"{stem or name}.toml"
    out.write_text(text)
    return out


@pytest.fixture(scope="module")
def seed_dir(tmp_path_factory):
    """The seed mission with its baseline, written by `cosim test --update`."""
    d = tmp_path_factory.mktemp("seed")
    copy_scenario("mambo_seed_track", d)
    r = cosim("test", str(d), "--update", "--executor", "serial", "--out", str(d / "runs"))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "update: new baseline" in r.stdout
    return d


def test_update_writes_small_readable_baseline_files(seed_dir):
    meta = json.loads((seed_dir / "baselines" / "mambo_seed_track.json").read_text())
    assert meta["exit_reason"] == "mission_complete" and meta["passed"] is True
    assert meta["metrics"]["landing_reason"] == "marker"
    assert len(meta["series_sha256"]) == 64 and meta["numerics"] in ("native", "portable")
    csv = (seed_dir / "baselines" / "mambo_seed_track.csv").read_text().splitlines()
    assert csv[0] == "t,n,e,alt,yaw"
    t_end = float(csv[-1].split(",")[0])            # the flight at 10 Hz, ~80 s
    assert 60.0 < t_end < 120.0 and abs(len(csv) - 1 - 10 * t_end) <= 2
    assert (seed_dir / "baselines" / "mambo_seed_track.csv").stat().st_size < 100_000


def test_the_unchanged_mission_passes_bit_for_bit(seed_dir):
    r = cosim("test", str(seed_dir / "mambo_seed_track.toml"), "--executor", "serial",
              "--out", str(seed_dir / "runs"))
    assert r.returncode == 0, r.stdout
    assert "1 passed, 0 failed" in r.stdout
    (v,) = json.loads((seed_dir / "runs" / "verdicts.json").read_text())
    assert v["exact"] == "identical" and v["status"] == "passed"


def test_a_change_that_matters_is_caught_and_an_update_accepts_it(seed_dir, tmp_path):
    scen = seed_dir / "mambo_seed_track.toml"
    rep, xml = tmp_path / "report", tmp_path / "j.xml"
    r = cosim("test", str(scen), "--set", "app.alpha=0.006", "--executor", "serial",
              "--out", str(tmp_path / "runs"), "--report", str(rep), "--junit", str(xml))
    assert r.returncode == 1, r.stdout
    assert "[FAIL] cosim/mambo_seed_track" in r.stdout
    assert "left its tube at t=" in r.stdout          # the signal and the time it left
    page = (rep / "index.md").read_text()
    assert "left its tube" in page and "-overlay.png" in page
    assert "metric mission_time_s: " in page            # every failure on the page
    pngs = sorted(p.name for p in rep.glob("*.png"))
    assert "cosim-mambo_seed_track-overlay.png" in pngs and len(pngs) >= 2
    assert all(p.stat().st_size > 5000 for p in rep.glob("*.png"))
    suite = junitparser.JUnitXml.fromfile(str(xml))
    assert (suite.tests, suite.failures, suite.errors) == (1, 1, 0)
    # the intended change, accepted: the update says what changed, the files show it
    base = seed_dir / "baselines" / "mambo_seed_track.json"
    before = base.read_text()
    r = cosim("test", str(scen), "--set", "app.alpha=0.006", "--update", "--executor", "serial",
              "--out", str(tmp_path / "runs"), "--baselines", str(tmp_path / "b2"))
    assert r.returncode == 0 and "update: new baseline" in r.stdout
    shutil_copy(base, tmp_path / "b2")
    r = cosim("test", str(scen), "--set", "app.alpha=0.006", "--update", "--executor", "serial",
              "--out", str(tmp_path / "runs"), "--baselines", str(tmp_path / "b2"))
    assert "update: metric mission_time_s: " in r.stdout, r.stdout
    assert "update: signal n: max change" in r.stdout
    assert base.read_text() == before                 # the other folder's is untouched


def shutil_copy(base: Path, dest: Path) -> None:
    for suffix in (".json", ".csv"):
        (dest / base.with_suffix(suffix).name).write_bytes(base.with_suffix(suffix).read_bytes())


def test_a_late_but_right_flight_passes_when_the_user_allows_the_lag(tmp_path):
    """The scripted square with its take-off held 0.3 s longer: outside a 5 cm tube in time,
    inside it with time_s = 0.4."""
    scen = copy_scenario("scripted_square", tmp_path)
    assert cosim("test", str(scen), "--update", "--executor", "serial",
                 "--out", str(tmp_path / "r")).returncode == 0
    text = scen.read_text()
    scen.write_text(text.replace("[56.0, 95.0, -1.0, 1.0]", "[56.0, 95.0, -1.0, 1.3]"))
    suite = tmp_path / "suite.toml"
    for lag, rc in ((0.0, 1), (0.4, 0)):
        suite.write_text(f'[tolerance]\nposition_m = 0.05\naltitude_m = 0.05\ntime_s = {lag}\n'
                         f'metric_abs = 0.5\n'
                         f'[[case]]\nscenario = "scripted_square.toml"\n'
                         f'name = "scripted_square"\n')
        r = cosim("test", str(suite), "--executor", "serial", "--out", str(tmp_path / "r"),
                  "--baselines", str(tmp_path / "baselines"))
        assert r.returncode == rc, (lag, r.stdout)
    assert "left its tube" not in r.stdout


def test_equivalence_mil_sil_is_exact_on_the_seed_mission(seed_dir):
    r = cosim("test", str(seed_dir / "mambo_seed_track.toml"), "--equivalence", "mil,sil",
              "--executor", "serial", "--out", str(seed_dir / "eq"))
    assert r.returncode == 0, r.stdout
    (v,) = json.loads((seed_dir / "eq" / "verdicts.json").read_text())
    assert v["equivalence"] == "identical"
    modes = {k: json.loads((Path(d) / "summary.json").read_text())["mode"]
             for k, d in v["runs"].items()}
    assert modes == {"mil": "mil", "sil": "sil"}


def test_equivalence_mil_sil_is_exact_on_paper2_e1(tmp_path):
    scen = copy_scenario("bebop2_vs_e1", tmp_path)
    r = cosim("test", str(scen), "--equivalence", "mil,sil", "--out", str(tmp_path / "eq"))
    assert r.returncode == 0, r.stdout
    (v,) = json.loads((tmp_path / "eq" / "verdicts.json").read_text())
    assert v["equivalence"] == "identical" and v["status"] == "passed"


def test_equivalence_interpreted_compiled_and_a_difference_is_named(tmp_path):
    scen = copy_scenario("scripted_square", tmp_path)
    r = cosim("test", str(scen), "--equivalence", "interpreted,compiled", "--executor",
              "serial", "--out", str(tmp_path / "eq"))
    assert r.returncode == 0, r.stdout
    (v,) = json.loads((tmp_path / "eq" / "verdicts.json").read_text())
    impl = {k: json.loads((Path(d) / "summary.json").read_text())["implementation"]
            for k, d in v["runs"].items()}
    assert impl["interpreted"].startswith("interpreted") and impl["compiled"].startswith(
        "compiled")
    # native vs portable differ in their last bits (or not, on an old CPU): within the tubes
    r = cosim("test", str(scen), "--equivalence", "native,portable", "--executor", "serial",
              "--out", str(tmp_path / "np"))
    assert r.returncode == 0, r.stdout
    (v,) = json.loads((tmp_path / "np" / "verdicts.json").read_text())
    nums = {k: json.loads((Path(d) / "summary.json").read_text())["numerics"]["mode"]
            for k, d in v["runs"].items()}
    assert nums == {"native": "native", "portable": "portable"}


def test_a_suite_on_dask_gives_the_serial_verdicts_and_errors_are_errors(tmp_path):
    copy_scenario("scripted_square", tmp_path)
    suite = tmp_path / "suite.toml"
    suite.write_text('[[case]]\nscenario = "scripted_square.toml"\n'
                     '[[case]]\nscenario = "scripted_square.toml"\nname = "tight"\n'
                     'set = ["criteria.position_error_max_m=0.01"]\n'
                     '[[case]]\nscenario = "scripted_square.toml"\nname = "broken"\n'
                     'set = ["vehicle.mass_kg=-1"]\n')
    out = {}
    for ex in ("serial", "dask"):
        xml = tmp_path / f"{ex}.xml"
        r = cosim("test", str(suite), "--executor", ex, "--workers", "2",
                  "--out", str(tmp_path / ex), "--junit", str(xml))
        assert r.returncode == 1, r.stdout + r.stderr
        out[ex] = {v["id"]: (v["status"], v["failures"][:1]) for v in json.loads(
            (tmp_path / ex / "verdicts.json").read_text())}
        x = junitparser.JUnitXml.fromfile(str(xml))
        assert (x.tests, x.failures, x.errors) == (3, 1, 1)
    assert out["serial"] == out["dask"]
    assert out["serial"]["scripted_square"][0] == "new"
    assert out["serial"]["tight"][1][0].startswith("criterion position_error_max_m")
    assert out["serial"]["broken"][0] == "error"
    assert "vehicle.mass_kg" in out["serial"]["broken"][1][0]


def test_the_pytest_plugin_collects_scenarios_and_fails_with_cosim_tests_words(tmp_path):
    copy_scenario("scripted_square", tmp_path, stem="test_square")
    tight = copy_scenario("scripted_square", tmp_path, stem="test_tight")
    tight.write_text(tight.read_text().replace("position_error_max_m = 0.15",
                                               "position_error_max_m = 0.01"))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        "--cosim-out", str(tmp_path / "runs"), str(tmp_path)],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert "1 failed, 1 passed" in r.stdout, r.stdout
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("criterion "))
    c = cosim("test", str(tight), "--executor", "serial", "--out", str(tmp_path / "c"))
    assert line in c.stdout                              # the same words as cosim test
    # --cosim collects any scenario file in the folder, not only test_*.toml
    (tmp_path / "more").mkdir()
    copy_scenario("scripted_square", tmp_path / "more")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        "--collect-only", str(tmp_path / "more")], capture_output=True,
                       text=True, cwd=tmp_path, env=env)
    assert "no tests collected" in r.stdout
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        "--cosim", "--collect-only", str(tmp_path / "more")],
                       capture_output=True, text=True, cwd=tmp_path, env=env)
    assert "1 test collected" in r.stdout, r.stdout


def test_the_python_api_flies_and_compares(tmp_path):
    scen = copy_scenario("scripted_square", tmp_path)
    f = fly(scen, out=tmp_path / "a", signals=("vz",))
    assert f.ok and f.summary["passed"] and set(f.trajectory) >= {"t", "n", "alt", "vz"}
    assert f.metrics["mission_time_s"] > 10
    v = check_baseline(scen, f, update=True)
    assert v["status"] == "passed" and v["exact"] == "identical"
    g = fly(scen, sets=["app.params.tolerance_m=0.2"], out=tmp_path / "b")
    v = check_baseline(scen, g)
    assert v["status"] == "failed" and any("left its tube" in x for x in v["failures"])


def test_bad_input_is_named_and_a_hung_or_interrupted_run_is_handled(tmp_path):
    scen = copy_scenario("scripted_square", tmp_path)
    r = cosim("test", str(scen), "--equivalence", "mil,hil")
    assert r.returncode == 2 and "--equivalence" in r.stderr
    r = cosim("test", str(tmp_path / "none.toml"))
    assert r.returncode == 2 and "none.toml" in r.stderr
    (tmp_path / "baselines").mkdir()
    (tmp_path / "baselines" / "scripted_square.json").write_text("{not json")
    r = cosim("test", str(scen), "--executor", "serial", "--out", str(tmp_path / "r"))
    assert r.returncode == 1 and "scripted_square.json" in r.stdout
    assert "--update" in r.stdout
    (tmp_path / "baselines" / "scripted_square.json").unlink()
    r = cosim("test", str(scen), "--executor", "serial", "--timeout", "0.5",
              "--out", str(tmp_path / "r"))
    assert r.returncode == 1 and "[ERROR]" in r.stdout
    log = (tmp_path / "r" / "cosim" / "scripted_square" / "run" / "cosim-run.log").read_text()
    assert "stopped after 0.5 s" in log
    # Ctrl-C: the cases so far are reported, the flight in the air is stopped, 130
    long = copy_scenario("mambo_hover", tmp_path)
    p = subprocess.Popen([sys.executable, "-m", "cosim.cli", "test", str(long), "--set",
                          "timing.t_final_s=80000", "--executor", "serial",
                          "--out", str(tmp_path / "h")], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    run_dir = tmp_path / "h" / "cosim" / "mambo_hover" / "run"
    deadline = time.monotonic() + 120
    while not (run_dir / "cosim-run.log").exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(2.0)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 130, out + err
    assert "interrupted after 0 of 1 cases" in err
    assert (tmp_path / "h" / "verdicts.json").exists()
