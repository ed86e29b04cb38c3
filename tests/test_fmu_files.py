"""Issue 43, item 14: FMU files were trusted too much. An FMU with Windows binaries only passed
validation and the run failed; a 3 GB file inside an FMU was extracted on every run; a
truncated build/Quadrotor3.fmu was reported as the user's bad input (exit 2) and never built
again. Now the platform's binary is checked when the scenario loads, a run extracts only the
description, that binary and the resources, within a size limit (cosim/plant/fmufile.py), and
the build's own FMUs are checked by their SHA-256 and rebuilt (fmus/build.py)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, parse_scenario
from cosim.plant import fmufile
from fmus import build as fb

ROOT = Path(__file__).resolve().parents[1]
PLANTS = Path(__file__).parent / "plants"
SQUARE = ROOT / "scenarios" / "scripted_square.toml"


@pytest.fixture(scope="module")
def enu_fmu(tmp_path_factory) -> Path:
    pytest.importorskip("pythonfmu")
    out = tmp_path_factory.mktemp("enu")
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                    str(PLANTS / "EnuQuad.py"), "-d", str(out)], check=True, cwd=out,
                   capture_output=True)
    return out / "EnuQuad.fmu"


def _rezip(src: Path, dst: Path, drop=(), add: dict[str, bytes] | None = None) -> Path:
    with zipfile.ZipFile(src) as zi, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zo:
        for info in zi.infolist():
            if not info.filename.startswith(tuple(drop)):
                zo.writestr(info, zi.read(info))
        for name, data in (add or {}).items():
            zo.writestr(name, data)
    return dst


def _scenario_on(fmu: Path):
    raw = tomllib.loads(SQUARE.read_text())
    raw["vehicle"].update(fmu=str(fmu), fmu_map=tomllib.loads(
        (PLANTS / "enu_quad_map.toml").read_text())["vehicle"]["fmu_map"])
    return parse_scenario(raw, source=str(SQUARE), base_dir=SQUARE.parent)


def test_an_fmu_without_this_platforms_binary_is_refused_when_it_loads(tmp_path, enu_fmu):
    win = _rezip(enu_fmu, tmp_path / "WinOnly.fmu", drop=("binaries/linux64/",))
    with pytest.raises(ScenarioError, match=r"vehicle\.fmu: .*a binary for this platform "
                       r"\(binaries/linux64/EnuQuad\.so; it has binaries for win64"):
        _scenario_on(win)
    none = _rezip(enu_fmu, tmp_path / "NoBinaries.fmu", drop=("binaries/",))
    with pytest.raises(ScenarioError, match="it has no binaries"):
        _scenario_on(none)
    # through the CLI: exit 2 at `cosim validate`, naming the field
    sc = tmp_path / "win.toml"
    sc.write_text(SQUARE.read_text().replace('preset = "mambo"\n',
                                             f'preset = "mambo"\nfmu = "{win}"\n', 1)
                  .replace('file = "worlds/', f'file = "{ROOT}/scenarios/worlds/')
                  + (PLANTS / "enu_quad_map.toml").read_text())
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "validate", str(sc)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "vehicle.fmu" in r.stderr and "win64" in r.stderr, r.stderr


def test_what_a_run_extracts_is_bounded_and_only_what_it_needs(tmp_path, enu_fmu,
                                                               monkeypatch):
    """A large file where a run reads it (resources/) is refused when the scenario loads; one
    where it does not (documentation/, sources/, another platform's binaries) is never
    extracted. The limit is lowered here to keep the file small: UNPACKED_MAX is 1 GiB."""
    monkeypatch.setattr(fmufile, "UNPACKED_MAX", 2 << 20)
    blob = os.urandom(3 << 20)              # 3 MB that do not compress
    big = _rezip(enu_fmu, tmp_path / "BigResource.fmu", add={"resources/table.bin": blob})
    with pytest.raises(ScenarioError, match=r"vehicle\.fmu: .*at most 2 MB .*"
                                            r"the largest resources/table\.bin, 3 MB"):
        _scenario_on(big)
    doc = _rezip(enu_fmu, tmp_path / "BigDoc.fmu", add={"documentation/manual.bin": blob,
                                                        "sources/model.c": blob})
    sc = _scenario_on(doc)
    folder = fmufile.extract(sc.plant.fmu, 2, "EnuQuad")
    try:
        got = {str(p.relative_to(folder)).split("/")[0] for p in Path(folder).rglob("*")}
        assert got == {"modelDescription.xml", "binaries", "resources"}
        assert [p.name for p in (Path(folder) / "binaries").iterdir()] == ["linux64"]
        assert Path(folder).name.startswith(f"cosim-fmu-{os.getpid()}-")
    finally:
        import shutil

        shutil.rmtree(folder)


def test_a_damaged_build_fmu_is_built_again(tmp_path):
    fb.build(out_dir=tmp_path, fmi=2)
    good = fb.build(out_dir=tmp_path, fmi=3).read_bytes()
    fmu = tmp_path / "Quadrotor3.fmu"
    fmu.write_bytes(good[: len(good) // 2])                 # truncated
    assert fb.build(out_dir=tmp_path, fmi=3).read_bytes() == good
    altered = bytearray(good)
    altered[len(good) // 3] ^= 0xFF                          # one byte changed
    fmu.write_bytes(bytes(altered))
    assert fb.build(out_dir=tmp_path, fmi=3).read_bytes() == good
    lines = (tmp_path / "Quadrotor3.fmu.sha256").read_text().split()
    assert lines == [fb.source_hash(3), hashlib.sha256(good).hexdigest()]


@pytest.mark.flight
def test_a_run_on_a_truncated_build_fmu_flies_on_a_rebuilt_one(tmp_path):
    """Before: `cosim: bad input: vehicle.fmu: ... (BadZipFile ...)`, exit 2, and the next run
    the same."""
    fb.build(out_dir=tmp_path, fmi=2)
    fmu = fb.build(out_dir=tmp_path, fmi=3)
    good = fmu.read_bytes()
    fmu.write_bytes(good[:1000])
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "run",
                        str(ROOT / "scenarios" / "scripted_square_fmi3.toml"), "--set",
                        "timing.t_final_s=1", "--out", str(out), "--quiet", "--no-plots"],
                       capture_output=True, text=True, timeout=300,
                       env={**os.environ, "COSIM_BUILD_DIR": str(tmp_path)})
    assert "bad input" not in r.stderr, r.stderr
    assert json.loads((out / "summary.json").read_text())["exit_reason"] == "time_limit"
    assert fmu.read_bytes() == good


def test_the_default_plant_extracts_only_what_it_needs(tmp_path, monkeypatch):
    """The project's own FMU too (its sources stay in the archive), into a folder named with
    this process (cosim/tempdirs.py)."""
    import tempfile

    from cosim.plant.fmu import Plant
    from cosim.scenario.vehicles import MAMBO

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with Plant(MAMBO) as p:
        [folder] = list(tmp_path.iterdir())
        assert folder.name.startswith(f"cosim-fmu-{os.getpid()}-")
        assert sorted(x.name for x in folder.iterdir()) == ["binaries", "modelDescription.xml"]
        p.step(0.0, 0.0, 0.0, 0.0)
    assert not list(tmp_path.iterdir())


def test_the_shipped_scenarios_still_load():
    for path in sorted((ROOT / "scenarios").glob("*.toml")):
        load_scenario(path)


def test_model_description_parsed_once_per_version_of_the_file(tmp_path, monkeypatch):
    """A study's worker flies one FMU run after run: its model description is parsed once
    (fmufile.model_description), and again when the file at that path is replaced."""
    import fmpy

    calls = []
    real = fmpy.read_model_description

    def counting(path, validate=True):
        calls.append(path)
        return real(path, validate=validate)

    monkeypatch.setattr(fmpy, "read_model_description", counting)
    monkeypatch.setattr(fmufile, "_MD", {})
    fmu = tmp_path / "Quadrotor.fmu"
    fmu.write_bytes(fb.fmu_path().read_bytes())
    first = fmufile.model_description(fmu)
    assert fmufile.model_description(fmu) is first and len(calls) == 1
    assert fmufile.model_description(fmu, validate=False) is not first   # another parse
    assert len(calls) == 2
    st = fmu.stat()
    fmu.unlink()                                   # replaced: a new file at the same path
    fmu.write_bytes(fb.fmu_path().read_bytes())
    os.utime(fmu, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    again = fmufile.model_description(fmu)
    assert again is not first and again.guid == first.guid and len(calls) == 3
    for i in range(fmufile._MD_KEEP + 2):          # the newest kept, memory bounded
        other = tmp_path / f"q{i}.fmu"
        other.write_bytes(fmu.read_bytes())
        fmufile.model_description(other)
    assert len(fmufile._MD) == fmufile._MD_KEEP
    with pytest.raises(FileNotFoundError):
        fmufile.model_description(tmp_path / "missing.fmu")
