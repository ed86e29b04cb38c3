"""Model against generated code (onesource/switch.py): the same sources run interpreted
(COSIM_COMPILED=0) and compiled by Cython (COSIM_COMPILED=1) fly the same flight bit for bit,
and the switch refuses a compiled module that does not match its source.

Each flight is a real `cosim run` process per implementation (a process runs one or the other):
the recorded series, the MAVLink log and the summary less its wall-clock fields must be equal.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SC = ROOT / "scenarios"
WALL = ("wall_time_s", "real_time_factor", "implementation", "realtime_stalls",
        "realtime_lost_s")


def cosim(*args: str, compiled: str, cwd: Path = ROOT, check: bool = True
          ) -> subprocess.CompletedProcess:
    env = dict(os.environ, COSIM_COMPILED=compiled)
    p = subprocess.run([sys.executable, "-m", "cosim.cli", *args], env=env, cwd=cwd,
                       capture_output=True, text=True, timeout=600, check=False)
    if check and p.returncode not in (0, 1):
        raise AssertionError(f"cosim {' '.join(args)} ({compiled}) exit {p.returncode}:\n"
                             f"{p.stderr[-3000:]}")
    return p


def fly(tmp: Path, scenario: str, compiled: str, *extra: str) -> dict:
    out = tmp / f"{Path(scenario).stem}-{compiled}"
    cosim("run", str(SC / scenario), "--out", str(out), *extra, compiled=compiled)
    summary = json.loads((out / "summary.json").read_text())
    return {"dir": out, "summary": summary}


@pytest.mark.flight
@pytest.mark.parametrize(("scenario", "extra"), [
    ("mambo_seed_track.toml", ()),                  # the seed mission (paper 1)
    ("mambo_seed_track.toml", ("--mode", "sil")),   # SIL: the flight stack in its own process
    ("bebop2_scripted_square.toml", ()),            # the Bebop 2 square
    ("mambo_seed_dropout.toml", ()),                # a [faults] scenario (the fault hooks)
    ("bebop2_vs_e1.toml", ()),                      # paper 2's E1 (front camera, teach)
    ("mambo_seed_estimate.toml", ()),               # sensor-fed: sensor models, HIL_SENSOR &
                                                    # co., the onboard estimator (issue 27)
    ("bebop2_room_e1.toml", ("--set", "camera.stream=bebop2", "--set",   # delayed, blurred
                             "timing.t_final_s=6")),                     # frames (issue 28)
], ids=["seed", "seed-sil", "bebop2-square", "faults", "paper2-e1", "seed-estimate",
        "camera-stream"])
def test_interpreted_and_compiled_fly_bit_for_bit(tmp_path, scenario, extra):
    i = fly(tmp_path, scenario, "0", *extra)
    c = fly(tmp_path, scenario, "1", *extra)
    assert i["summary"]["implementation"].startswith("interpreted")
    assert c["summary"]["implementation"].startswith("compiled")
    for name in ("timeseries.csv", "flight.tlog"):
        a, b = (i["dir"] / name).read_bytes(), (c["dir"] / name).read_bytes()
        assert len(a) > 1000 and a == b, name
    si, sc = ({k: v for k, v in r["summary"].items() if k not in WALL} for r in (i, c))
    for s in (si, sc):   # whether the render worker ran depends on the host's load, not the
        if s.get("camera_stream"):          # flight (the same bytes either way, above)
            s["camera_stream"] = {k: v for k, v in s["camera_stream"].items()
                                  if k not in ("pipelined", "worker", "worker_cpu_s")}
    assert si == sc
    assert si["ticks"] > 100


def _package(tmp: Path, body: str = "def f(x):\n    return 2 * x\n") -> Path:
    pkg = tmp / "pkgx"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "mod.py").write_text(body)
    return pkg


_PROBE = """
import sys
sys.path.insert(0, {root!r})
from onesource import switch as compiled
compiled.register(__import__('pathlib').Path({pkg!r}), ["pkgx.mod"])
import pkgx.mod
print("LOADED", type(pkgx.mod.f).__name__, compiled.describe())
"""


def _probe(tmp: Path, pkg: Path, env_value: str | None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.pop("COSIM_COMPILED", None)
    if env_value is not None:
        env["COSIM_COMPILED"] = env_value
    return subprocess.run([sys.executable, "-c", _PROBE.format(root=str(tmp), pkg=str(pkg))],
                          env=env, capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.flight
def test_the_switch_uses_fresh_builds_and_refuses_stale_ones(tmp_path):
    """A module built from its source loads compiled; after the source changes it is never
    used: COSIM_COMPILED=1 fails with one line naming the rebuild command, unset runs
    interpreted and says why on stderr, 0 runs interpreted."""
    from onesource import switch as compiled
    from onesource.build import build_modules

    pkg = _package(tmp_path)
    py = pkg / "mod.py"
    so = compiled.extension_path(py)
    assert compiled.module_status(py) == "missing"
    p = _probe(tmp_path, pkg, None)
    assert "LOADED function" in p.stdout and "not built" in p.stdout   # nothing built: Python
    p = _probe(tmp_path, pkg, "1")
    assert p.returncode != 0 and "make build" in p.stderr and "is not built" in p.stderr
    build_modules({"pkgx.mod": (py, so)}, build_dir=tmp_path / "b", echo=lambda s: None)
    assert compiled.module_status(py) == "fresh"
    for env in (None, "1"):
        p = _probe(tmp_path, pkg, env)
        assert "LOADED cython_function_or_method compiled" in p.stdout, (env, p.stderr)
    p = _probe(tmp_path, pkg, "0")
    assert "LOADED function interpreted (COSIM_COMPILED=0)" in p.stdout
    py.write_text(py.read_text() + "\ng = 1\n")                         # the source moves on
    assert compiled.module_status(py) == "stale"
    p = _probe(tmp_path, pkg, None)
    assert "LOADED function interpreted" in p.stdout
    assert "changed since it was compiled" in p.stderr and "make build" in p.stderr
    p = _probe(tmp_path, pkg, "1")
    assert p.returncode != 0 and "changed since it was compiled" in p.stderr
    assert len(p.stderr.strip().splitlines()[-1]) < 300               # one line, not a dump
    p = _probe(tmp_path, pkg, "yes")
    assert p.returncode != 0 and "allowed values are 0" in p.stderr


def test_the_cli_names_the_rebuild_command_when_compiled_is_demanded_but_stale(tmp_path):
    """COSIM_COMPILED=1 with a module out of date: `cosim` ends with one line and exit 1."""
    pkg = _package(tmp_path)
    env = dict(os.environ, COSIM_COMPILED="1",
               PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    code = ("import sys; from onesource import switch as compiled; from pathlib import Path; "
            f"compiled.register(Path({str(pkg)!r}), ['pkgx.mod']); "
            "from cosim.cli import main; sys.exit(main(['validate', "
            f"{str(SC / 'mambo_hover.toml')!r}]))")
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=120, check=False)
    assert p.returncode == 1, p.stderr
    assert "Traceback" not in p.stderr and "make build" in p.stderr


def test_this_test_run_is_compiled():
    """The suite runs on the build the install step made (a missing or stale build would
    quietly test the interpreter only)."""
    from onesource import switch as compiled

    assert compiled.mode() == "compiled", compiled.describe()
    assert all(compiled.module_status(src, so) == "fresh"
               for src, so in compiled.compiled_modules().values())


def test_a_changed_record_layout_makes_every_module_that_cimports_it_stale(tmp_path):
    """A field added to a .pxd changes the C code of every module that cimports it (they read
    the fields at fixed offsets): such modules count as changed too, so a stale build is
    never loaded with the new layout (it corrupted memory once: tick.so with an old tlog.pxd)."""
    from onesource import switch as compiled

    pkg = tmp_path / "pkgy"
    (pkg / "sub").mkdir(parents=True)
    for f in (pkg / "__init__.py", pkg / "sub" / "__init__.py"):
        f.write_text("")
    (pkg / "rec.py").write_text("class R:\n    pass\n")
    (pkg / "rec.pxd").write_text("cdef class R:\n    cdef public double x\n")
    (pkg / "sub" / "user.py").write_text("def f(r):\n    return r.x\n")
    (pkg / "sub" / "user.pxd").write_text("from pkgy.rec cimport R\n")
    (pkg / "other.py").write_text("def g():\n    return 1\n")
    user, other = pkg / "sub" / "user.py", pkg / "other.py"
    before = compiled.source_hash(user), compiled.source_hash(other)
    (pkg / "rec.pxd").write_text("cdef class R:\n    cdef public double x, y\n")
    assert compiled.source_hash(user) != before[0]        # cimports rec: changed
    assert compiled.source_hash(other) == before[1]       # does not: unchanged
    # the module cimported by name from its package (`from pkgy cimport rec as r`) counts too
    (pkg / "sub" / "user.pxd").write_text("from pkgy cimport other, rec as r\n")
    before = compiled.source_hash(user)
    (pkg / "rec.pxd").write_text("cdef class R:\n    cdef public double x, y, z\n")
    assert compiled.source_hash(user) != before
