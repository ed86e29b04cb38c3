"""Issue 43, item 10: a user's plant FMU runs in a process of its own (cosim/plant/isolated.py).
A segmentation fault in its doStep ended the run (exit 139, no message, no summary, no series,
temporary files left), a doStep that never returned froze it, and Ctrl-C then reported a
component error (exit 1). Now a crash or a hang is `component_error: plant ...` with
everything recorded, and a signal during a hang ends the run as any signal does (130 / 143).

The FMU is the PythonFMU test plant with a fault (tests/plants/FaultyQuad.py), flown by the
scripted square through its map; the runs are real `cosim run` processes and the signals
real ones."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.flight

ROOT = Path(__file__).resolve().parents[1]
PLANTS = Path(__file__).parent / "plants"
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
HANG_S = 120            # hang guards only


@pytest.fixture(scope="module")
def faulty_fmu(tmp_path_factory) -> Path:
    pytest.importorskip("pythonfmu")
    out = tmp_path_factory.mktemp("faulty")
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                    str(PLANTS / "FaultyQuad.py"), str(PLANTS / "EnuQuad.py"), "-d", str(out)],
                   check=True, cwd=out, capture_output=True)
    return out / "FaultyQuad.fmu"


def _toml(v) -> str:
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    if isinstance(v, bool):
        return "true" if v else "false"
    return json.dumps(v)


def _scenario(tmp: Path, fmu: Path, fault: int, **vehicle) -> Path:
    """The scripted square on the faulty plant: `fault` 1 crashes, 2 hangs, at t = 1 s."""
    m = tomllib.loads((PLANTS / "enu_quad_map.toml").read_text())["vehicle"]["fmu_map"]
    m["parameters"].update(fault=fault, fault_at_s=1.0)
    text = SQUARE.read_text().replace('file = "worlds/', f'file = "{ROOT}/scenarios/worlds/')
    extra = "".join(f"{k} = {_toml(v)}\n" for k, v in {"fmu": str(fmu), **vehicle}.items())
    text = text.replace('[vehicle]\npreset = "mambo"\n', f'[vehicle]\npreset = "mambo"\n{extra}')
    text += "\n[vehicle.fmu_map]\n" + "".join(
        f"{k} = {_toml(v)}\n" for k, v in m.items() if not isinstance(v, dict))
    for k, v in m.items():
        if isinstance(v, dict):
            text += f"\n[vehicle.fmu_map.{k}]\n" + "".join(f"{n} = {_toml(x)}\n"
                                                          for n, x in v.items())
    path = tmp / f"faulty{fault}.toml"
    path.write_text(text)
    return path


def _run(tmp_path: Path, scenario: Path, **env) -> subprocess.Popen:
    (tmp_path / "tmp").mkdir(exist_ok=True)
    return subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", str(scenario), "--out",
         str(tmp_path / "out"), "--quiet", "--no-plots"],
        env={**os.environ, "TMPDIR": str(tmp_path / "tmp"), **env}, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, start_new_session=True)


def _finish(proc: subprocess.Popen) -> str:
    try:
        return proc.communicate(timeout=HANG_S)[1]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


def _recorded(tmp_path: Path, exit_reason: str) -> dict:
    """Everything written: the summary, a series row per tick, the flight log; nothing left
    in TMPDIR (the FMU's extraction, the spool)."""
    out = tmp_path / "out"
    s = json.loads((out / "summary.json").read_text())
    assert s["exit_reason"] == exit_reason, s["message"]
    assert s["ticks"] >= 200                                  # flew to t = 1 s at least
    assert (out / "timeseries.csv").read_text().count("\n") - 1 == s["ticks"]
    assert (out / "flight.tlog").stat().st_size > 0
    assert not list((tmp_path / "tmp").iterdir())
    return s


def _workers(pid: int) -> list[int]:
    """The plant workers `pid` started."""
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                ppid = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
                if ppid == pid and "cosim.plant.isolated" in (p / "cmdline").read_text():
                    out.append(int(p.name))
            except (OSError, ValueError, IndexError):
                pass
    return out


def _wait_for(path: Path, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + HANG_S
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the FMU never began to hang"
        time.sleep(0.05)


def test_a_segfault_in_dostep_is_a_component_error_with_everything_recorded(tmp_path,
                                                                            faulty_fmu):
    proc = _run(tmp_path, _scenario(tmp_path, faulty_fmu, 1))
    err = _finish(proc)
    assert proc.returncode == 1, err
    s = _recorded(tmp_path, "component_error")
    assert s["message"].startswith("plant: the FMU's process died of SIGSEGV during DoStep "
                                   "at t = 1 s")
    assert "do_step (FaultyQuad.py:" in s["message"]      # where, from the worker's report
    assert "cosim: run failed: plant:" in err and "Traceback" not in err


def test_a_hang_in_dostep_times_out_as_a_component_error(tmp_path, faulty_fmu):
    proc = _run(tmp_path, _scenario(tmp_path, faulty_fmu, 2, fmu_timeout_s=1.0))
    err = _finish(proc)
    assert proc.returncode == 1, err
    s = _recorded(tmp_path, "component_error")
    assert s["message"].startswith("plant: DoStep did not return within 1 s at t = 1 s")
    assert not _workers(proc.pid)


@pytest.mark.parametrize("sig,group", [(signal.SIGINT, True), (signal.SIGTERM, False)],
                         ids=["ctrl-c", "sigterm"])
def test_a_signal_during_a_hang_ends_the_run_as_any_signal_does(tmp_path, faulty_fmu, sig,
                                                                group):
    hangs = tmp_path / "hangs"
    proc = _run(tmp_path, _scenario(tmp_path, faulty_fmu, 2), FAULTY_QUAD_HANGS=str(hangs))
    _wait_for(hangs, proc)
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    err = _finish(proc)
    assert proc.returncode == 128 + sig, err
    _recorded(tmp_path, "interrupted")
    assert "Traceback" not in err


def test_the_worker_dies_with_a_killed_run(tmp_path, faulty_fmu):
    hangs = tmp_path / "hangs"
    proc = _run(tmp_path, _scenario(tmp_path, faulty_fmu, 2), FAULTY_QUAD_HANGS=str(hangs))
    _wait_for(hangs, proc)
    workers = _workers(proc.pid)
    assert workers
    os.killpg(proc.pid, signal.SIGKILL)            # the worker is in a session of its own
    _finish(proc)
    deadline = time.monotonic() + HANG_S
    while any(Path(f"/proc/{w}").exists() and
              Path(f"/proc/{w}/stat").read_text().split()[2] != "Z" for w in workers):
        assert time.monotonic() < deadline, "the plant worker outlived its run"
        time.sleep(0.05)


def test_the_timeout_is_checked_and_only_for_a_users_fmu(tmp_path, faulty_fmu):
    from cosim.cli import main

    for bad in (0, -1, 1e9, "10"):
        rc = main(["validate", str(_scenario(tmp_path, faulty_fmu, 0, fmu_timeout_s=bad))])
        assert rc == 2
    own = tmp_path / "own.toml"
    own.write_text(SQUARE.read_text().replace('preset = "mambo"\n',
                                              'preset = "mambo"\nfmu_timeout_s = 5\n')
                   .replace('file = "worlds/', f'file = "{ROOT}/scenarios/worlds/'))
    assert main(["validate", str(own)]) == 2
