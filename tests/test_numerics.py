"""The numerics of a process (cosim/numerics.py): what the portable mode pins, that an
emulated older CPU cannot get past it, and how a run asks for it. Each check runs in a child
process: numerics are fixed when a process starts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cosim import numerics
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set

ROOT = Path(__file__).resolve().parents[1]
SQUARE = ROOT / "scenarios" / "scripted_square.toml"
PY = sys.executable
LEVELS = ("native", "avx2", "baseline")


def child(cmd: list[str], *, level: str = "native", numerics_mode: str | None = None,
          check: bool = True) -> subprocess.CompletedProcess:
    """`cmd` (a python -c or -m command line, without the interpreter) in a process started
    as on a CPU of `level`, then (if given) with the numerics `numerics_mode`."""
    pre = [PY, "-m", "cosim.numerics", "emulate", level, "--"]
    if numerics_mode is not None:
        pre += [PY, "-m", "cosim.numerics", numerics_mode, "--"]
    p = subprocess.run([*pre, PY, *cmd], capture_output=True, text=True, cwd=ROOT,
                       timeout=600, check=False)
    if check and p.returncode != 0:
        raise AssertionError(f"{cmd}: rc {p.returncode}\n{p.stderr[-3000:]}")
    return p


def describe(**kw) -> dict:
    p = child(["-m", "cosim.numerics", "describe"], **kw)
    return json.loads(p.stdout)


@pytest.mark.parametrize("level", LEVELS)
def test_portable_pins_every_library_whatever_the_cpu_looks_like(level):
    d = describe(level=level, numerics_mode="portable")
    assert d["mode"] == "portable" and d["not_portable"] == [], d["not_portable"]
    assert d["numpy"]["dispatched"] == []
    assert set(d["opencv"]["features"]) <= {"SSE4.1", "SSE4.2", "POPCNT"}
    assert d["opencv"]["ipp"] == "off" or "SSE4.2" in d["opencv"]["ipp"]
    assert d["blas"] and all(b["kernel"] == numerics.OPENBLAS_CORE and b["threads"] == 1
                             for b in d["blas"])
    assert set(numerics.GLIBC_OFF) <= set(d["libm"]["masked"])


def test_a_process_started_without_them_is_native_and_says_why():
    d = describe(numerics_mode="native")
    assert d["mode"] == "native"
    # on any CPU at least OpenBLAS's threads and libm's variants are left to the machine
    assert any("libm" in p for p in d["not_portable"]), d["not_portable"]


def test_emulation_takes_features_away():
    """The emulated levels are what the three-CPU flights (test_numerics_levels.py) rest on:
    each library must see the older CPU (features this CPU lacks cannot be taken away)."""
    base = describe(level="baseline")
    assert base["numpy"]["dispatched"] == []
    assert set(base["opencv"]["features"]) <= {"SSE4.1", "SSE4.2", "POPCNT"}
    assert all(b["kernel"] == "Nehalem" for b in base["blas"])
    assert {"FMA", "AVX2"} <= set(base["libm"]["masked"])
    avx2 = describe(level="avx2")
    assert not [f for f in avx2["opencv"]["features"] if "512" in f]
    assert not [f for f in avx2["numpy"]["dispatched"] if "512" in f or f == "X86_V4"]
    assert all(b["kernel"] == "Haswell" for b in avx2["blas"])


LIBM = """
import hashlib, math, random, struct
import numpy as np
r = random.Random(1)
xs = [r.uniform(-4.0, 4.0) for _ in range(20000)]
a = np.array(xs)
h = hashlib.sha256()
for f in (math.sin, math.cos, math.tan, math.atan, math.exp, lambda x: math.log(abs(x) + 1e-3),
          lambda x: math.atan2(x, 1.3), lambda x: math.pow(abs(x), 1.7)):
    h.update(b"".join(struct.pack("<d", f(x)) for x in xs))
for f in (np.sin, np.cos, np.exp, np.arctan2):
    h.update((f(a, a[::-1]) if f is np.arctan2 else f(a)).tobytes())
h.update((np.outer(a[:60], a[60:120]) @ a[120:180]).tobytes())
print(h.hexdigest())
"""


@pytest.mark.flight
def test_libm_numpy_and_blas_give_the_same_bits_at_every_level_when_portable():
    hashes = {lv: child(["-c", LIBM], level=lv, numerics_mode="portable").stdout.strip()
              for lv in LEVELS}
    assert len(set(hashes.values())) == 1, hashes
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if " fma " in flags:
        # the emulation has teeth here: held to SSE4.2 natively, the same code rounds otherwise
        native = child(["-c", LIBM], numerics_mode="native").stdout.strip()
        baseline = child(["-c", LIBM], level="baseline").stdout.strip()
        assert native != baseline


RUN_PORTABLE = ("import sys; from cosim.cli import main; sys.exit(main(['run', {sq!r}, "
                "'--numerics', 'portable', '--no-plots', '--out', {out!r}]))")


def test_a_run_refuses_portable_numerics_its_process_lacks(tmp_path):
    """From Python the process cannot start again: a clear error (exit 2), nothing written."""
    out = tmp_path / "r"
    p = child(["-c", RUN_PORTABLE.format(sq=str(SQUARE), out=str(out))],
              numerics_mode="native", check=False)
    assert p.returncode == 2, p.stderr
    assert "run.numerics" in p.stderr and "python -m cosim.numerics portable" in p.stderr
    assert not (out / "summary.json").exists()


@pytest.mark.flight
def test_the_cosim_command_starts_itself_with_the_numerics_asked_for(tmp_path):
    out = tmp_path / "r"
    child(["-m", "cosim.cli", "run", str(SQUARE), "--numerics", "portable", "--no-plots",
           "--out", str(out)], numerics_mode="native")
    s = json.loads((out / "summary.json").read_text())
    assert s["numerics"]["mode"] == "portable" and s["passed"]
    # and back: --numerics native from a portable shell
    child(["-m", "cosim.cli", "run", str(SQUARE), "--numerics", "native", "--no-plots",
           "--out", str(out)], numerics_mode="portable")
    s = json.loads((out / "summary.json").read_text())
    assert s["numerics"]["mode"] == "native"
    for key in ("cpu", "numpy", "opencv", "blas", "libm"):
        assert key in s["numerics"]


def test_run_numerics_in_the_scenario(tmp_path):
    sc = with_set(load_scenario(SQUARE), {"run.numerics": "portable"})
    assert sc.numerics == "portable"
    assert load_scenario(SQUARE).numerics == "native"
    with pytest.raises(ScenarioError, match="run.numerics"):
        with_set(load_scenario(SQUARE), {"run.numerics": "fast"})
    with pytest.raises(ScenarioError, match="run.speed"):
        with_set(load_scenario(SQUARE), {"run.speed": 1})
    # the scenario's own [run] numerics = "portable" starts the command with them
    f = tmp_path / "sq.toml"
    text = SQUARE.read_text().replace('"worlds/', f'"{SQUARE.parent}/worlds/')
    f.write_text(text + '\n[run]\nnumerics = "portable"\n')
    assert load_scenario(f).numerics == "portable"
    child(["-m", "cosim.cli", "run", str(f), "--no-plots", "--out", str(tmp_path / "o")],
          numerics_mode="native")
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["numerics"]["mode"] == "portable"


@pytest.mark.flight
def test_a_study_says_whether_every_run_was_portable(tmp_path):
    out = tmp_path / "mc"
    child(["-m", "cosim.cli", "montecarlo", str(SQUARE), "-n", "2", "--executor", "serial",
           "--vary", "wind.n_mps=uniform(0,0.2)", "--set", "timing.t_final_s=4",
           "--set", "criteria.must_complete=false", "--numerics", "portable", "--quiet",
           "--out", str(out)], numerics_mode="native")
    rows = (out / "results.csv").read_text().splitlines()
    col = rows[0].split(",").index("numerics")
    assert [r.split(",")[col] for r in rows[1:]] == ["portable", "portable"]
    assert "numerics: portable in every run" in (out / "report.md").read_text()
    rep = json.loads((out / "report.json").read_text())
    assert rep["portable"] is True and rep["numerics"] == {"portable": 2}


def test_the_launcher_refuses_what_it_does_not_know():
    p = subprocess.run([PY, "-m", "cosim.numerics", "fast", "--", "true"], capture_output=True,
                       text=True, check=False)
    assert p.returncode == 2 and "describe, portable, native or emulate" in p.stderr
    p = subprocess.run([PY, "-m", "cosim.numerics", "emulate", "486", "--", "true"],
                       capture_output=True, text=True, check=False)
    assert p.returncode == 2 and "baseline" in p.stderr
    p = subprocess.run([PY, "-m", "cosim.numerics", "portable"], capture_output=True,
                       text=True, check=True, env=numerics.native_env())
    assert "export GLIBC_TUNABLES=" in p.stdout and "OPENBLAS_CORETYPE=Nehalem" in p.stdout
