"""One flight of a case, as `cosim test` and the Python API see it: flown by the `cosim run`
command in a process of its own (so a case can run interpreted or compiled, native or portable,
and a crash or a hang of the user's code is a failed case, not a lost suite), then read back
from its run folder (summary.json, timeseries.csv).

    from cosim.regress import fly
    f = fly("scenarios/mambo_seed_track.toml", seed=1, sets=["app.alpha=0.005"])
    f.metrics["mission_time_s"], f.trajectory["alt"]
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.outputs.metrics import flat_metrics
from cosim.regress.cases import DEFAULT_SIGNALS, RATE_HZ
from mav.rotations import yaw_from_quat

# a side of an equivalence test: what differs between the two flights of one case
SIDES: dict[str, dict[str, Any]] = {
    "mil": {"mode": "mil"}, "sil": {"mode": "sil"},
    "interpreted": {"env": {"COSIM_COMPILED": "0"}},
    "compiled": {"env": {"COSIM_COMPILED": "1"}},
    "native": {"numerics": "native"}, "portable": {"numerics": "portable"},
}
LOG = "cosim-run.log"          # the run command's own output, beside its files


@dataclass
class Flight:
    """A flown case: its summary, flat metrics and trajectory sampled at `rate_hz`."""
    run_dir: Path
    returncode: int
    summary: dict[str, Any] | None
    metrics: dict[str, Any] = field(default_factory=dict)
    trajectory: dict[str, np.ndarray] = field(default_factory=dict)   # "t" and the signals
    series_sha256: str = ""
    wall_s: float = 0.0
    error: str = ""                      # why the run gave no result ("" when it did)

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def numerics(self) -> str:
        return (self.summary or {}).get("numerics", {}).get("mode", "")

    @property
    def versions(self) -> dict[str, Any]:
        return (self.summary or {}).get("versions", {})


def command(scenario: Path, out: Path, *, seed: int | None = None, sets=(), mode: str = "mil",
            numerics: str | None = None) -> list[str]:
    cmd = [sys.executable, "-m", "cosim.cli", "run", str(scenario), "--out", str(out),
           "--mode", mode, "--no-plots", "--quiet"]
    if seed is not None:
        cmd += ["--seed", str(seed)]
    for s in sets:
        cmd += ["--set", s]
    if numerics is not None:
        cmd += ["--numerics", numerics]
    return cmd


def fly(scenario: str | Path, *, seed: int | None = None, sets=(), mode: str = "mil",
        numerics: str | None = None, env: dict[str, str] | None = None,
        out: str | Path | None = None, signals: tuple[str, ...] = (),
        rate_hz: float = RATE_HZ, timeout_s: float | None = None) -> Flight:
    """Fly `scenario` with `cosim run` in a process of its own and read the run back. `out`:
    the run folder (default: a new temporary one, kept); `signals`: series columns to sample
    besides n, e, alt, yaw. Never raises for a run that failed: `Flight.error` says why."""
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="cosim-test-"))
    clear_run_folder(out)
    cmd = command(Path(scenario), out, seed=seed, sets=tuple(sets), mode=mode,
                  numerics=numerics)
    t0 = time.perf_counter()
    rc = _run(cmd, out, {**os.environ, **(env or {})}, timeout_s)
    flight = read_run(out, rc, signals=signals, rate_hz=rate_hz)
    flight.wall_s = time.perf_counter() - t0
    return flight


def _run(cmd: list[str], out: Path, env: dict[str, str], timeout_s: float | None) -> int:
    """The run command's exit status; its output goes to `out/cosim-run.log`. A run past
    `timeout_s` is stopped as Ctrl-C stops it (it writes what it recorded), killed if it does
    not end, and gets status -9. The run stays in our process group: Ctrl-C at the terminal
    reaches it too."""
    with open(out / LOG, "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                preexec_fn=_child_setup)
        try:
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _stop(proc)
            log.write(f"\ncosim test: stopped after {timeout_s:g} s (--timeout)\n".encode())
            return -9
        except BaseException:            # Ctrl-C / SIGTERM of `cosim test`: the run ends too
            _stop(proc)
            raise


def _child_setup() -> None:
    """In the run's process before it starts: Ctrl-C stops it even where our process ignores
    it (a study worker of a local Dask cluster does: cosim/studies/engine.py), and it is sent
    SIGTERM (a normal stop: it writes what it recorded) if the thread that started it dies,
    e.g. a worker closed with its cluster, instead of flying on as an orphan (Linux)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


def _prctl():
    import ctypes
    import ctypes.util

    try:
        fn = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_int
    return fn


_PRCTL = _prctl() if sys.platform.startswith("linux") else None
_PR_SET_PDEATHSIG = 1        # linux/prctl.h


def _stop(proc: subprocess.Popen) -> None:
    for sig, wait in ((signal.SIGINT, 15.0), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            return
        proc.send_signal(sig)
        try:
            proc.wait(timeout=wait)
            return
        except subprocess.TimeoutExpired:
            continue


def clear_run_folder(out: Path) -> None:
    """A fresh run folder: the files of an earlier run of this case are removed (only a
    folder that holds a run, or nothing, is touched)."""
    if out.is_dir() and any(out.iterdir()):
        if not ((out / "summary.json").exists() or (out / LOG).exists()
                or (out / ".run.lock").exists()):
            raise FileExistsError(f"{out} holds files that are not a run's; not overwritten")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)


def read_run(out: Path, returncode: int = 0, *, signals: tuple[str, ...] = (),
             rate_hz: float = RATE_HZ) -> Flight:
    """A run folder as a Flight (what `cosim run` wrote there)."""
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return Flight(out, returncode, None, error=f"the run wrote no summary.json (exit "
                      f"{returncode}): {log_tail(out)}")
    f = Flight(out, returncode, summary, metrics=flat_metrics(summary.get("metrics", {})))
    if summary.get("exit_reason") == "component_error":
        f.error = f"component_error: {summary.get('message', '')}"
    elif returncode not in (0, 1):
        f.error = f"the run ended with exit status {returncode}: {log_tail(out)}"
    series = out / "timeseries.csv"
    try:
        f.series_sha256 = sha256_file(series)
        f.trajectory = sample(series, signals, rate_hz)
    except (OSError, ValueError) as exc:
        f.error = f.error or f"timeseries.csv unreadable: {exc}"
    return f


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def log_tail(out: Path, n: int = 400) -> str:
    try:
        text = (out / LOG).read_text(errors="replace").strip()
    except OSError:
        return "(no output)"
    return ("..." + text[-n:] if len(text) > n else text).replace("\n", " | ") or "(no output)"


def sample(series: Path, signals: tuple[str, ...] = (), rate_hz: float = RATE_HZ
           ) -> dict[str, np.ndarray]:
    """The run's signals at `rate_hz` (linear between ticks): n, e (m), alt (m, up), yaw (deg,
    unwrapped) and any other numeric column of timeseries.csv named in `signals`."""
    with open(series) as fh:
        header = fh.readline().strip().split(",")
    col = {name: i for i, name in enumerate(header)}
    extra = [s for s in signals if s not in DEFAULT_SIGNALS]
    missing = [s for s in extra if s not in col or s == "phase_name"]
    if missing:
        raise ValueError(f"no numeric column {', '.join(missing)} in timeseries.csv "
                         f"(its columns: {', '.join(header)})")
    names = ["t", "x", "y", "z", "qw", "qx", "qy", "qz", *extra]
    data = np.loadtxt(series, delimiter=",", skiprows=1, usecols=[col[c] for c in names],
                      ndmin=2)
    if not len(data):
        raise ValueError("timeseries.csv has no rows")
    d = dict(zip(names, data.T, strict=True))
    yaw = np.degrees(np.unwrap(np.fromiter(
        map(yaw_from_quat, d["qw"], d["qx"], d["qy"], d["qz"]), float, len(data))))
    raw = {"n": d["x"], "e": d["y"], "alt": -d["z"], "yaw": yaw,
           **{s: d[s] for s in extra}}
    t = d["t"]
    grid = np.arange(0, math.floor(t[-1] * rate_hz + 1e-9) + 1) / rate_hz
    return {"t": grid, **{k: np.interp(grid, t, v) for k, v in raw.items()}}
