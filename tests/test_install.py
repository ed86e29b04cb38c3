"""A non-editable install (`pip install .`) carries the compiled build (setup.py), its stale-build
check works in site-packages, and it flies. Slow (a wheel compiles every module: about 1.5 min
on 2 cores) and needs the package index for the build requirements; `pytest -m slow`."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

import cosim  # noqa: F401  (lists its compiled modules)
from onesource import switch as compiled

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.slow


def _run(cmd, cwd, env=None, timeout=900):
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                         timeout=timeout, check=False)
    assert res.returncode == 0, f"{cmd}:\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return res


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A fresh venv with the wheel of this checkout installed (no editable link); its
    third-party dependencies are this environment's (a .pth line), so nothing else is fetched."""
    tmp = tmp_path_factory.mktemp("install")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(tmp / "wheel"), str(ROOT)],
         cwd=tmp)
    wheel, = (tmp / "wheel").glob("cosim-*.whl")
    env_dir = tmp / "venv"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp).stdout.strip())
    (site / "zz_cosim_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", str(wheel)], cwd=tmp)
    env = {k: v for k, v in os.environ.items() if k != compiled.ENV}
    env["COSIM_BUILD_DIR"] = str(tmp / "build")
    return wheel, py, site, env, tmp


PROBE = ("import cosim, mav, onesource.switch as c, mav.wire, cosim.sim.tick; "
         "print(c.describe()); print(mav.wire.__file__); print(cosim.sim.tick.__file__)")


def test_the_wheel_is_tagged_for_this_interpreter_and_runs_compiled(installed):
    wheel, py, site, env, tmp = installed
    assert f"-cp{sys.version_info[0]}{sys.version_info[1]}-" in wheel.name
    assert "linux_x86_64" in wheel.name
    out = _run([str(py), "-c", PROBE], cwd=tmp, env=env).stdout.splitlines()
    assert out[0].startswith("compiled ("), out
    for path in out[1:]:
        assert path.startswith(str(site)) and path.endswith(compiled.SUFFIX), path
    # every .pxd of the checkout is shipped (each is part of a module's source hash)
    for pxd in ROOT.glob("[cm]*/**/*.pxd"):
        assert (site / pxd.relative_to(ROOT)).is_file(), pxd


def test_an_installed_package_flies_and_keeps_its_builds_out_of_site_packages(installed):
    wheel, py, site, env, tmp = installed
    cosim_exe = py.parent / "cosim"
    res = _run([str(cosim_exe), "run", str(ROOT / "scenarios" / "mambo_seed_track.toml"),
                "--out", str(tmp / "run")], cwd=tmp, env=env)
    assert "result    PASSED" in res.stdout
    assert (tmp / "build" / "Quadrotor.fmu").is_file()       # COSIM_BUILD_DIR, not site-packages
    assert not (site / "build").exists()
    assert '"compiled (' in (tmp / "run" / "summary.json").read_text()


def test_the_stale_build_check_and_the_rebuild_work_in_site_packages(installed):
    wheel, py, site, env, tmp = installed
    src = site / "mav" / "battery.py"
    original = src.read_text()
    try:
        src.write_text(original + "# edited after install\n")
        res = _run([str(py), "-c", PROBE], cwd=tmp, env=env)
        assert res.stdout.startswith("interpreted (battery.py (mav.battery) changed"), res.stdout
        # the message names the command that works for an installed package
        assert "python -m onesource.build" in res.stdout
        _run([str(py), "-m", "onesource.build"], cwd=tmp, env=env)
        assert _run([str(py), "-c", PROBE], cwd=tmp, env=env).stdout.startswith("compiled (")
    finally:
        src.write_text(original)
