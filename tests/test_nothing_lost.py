"""Issue 31: nothing lost and nothing silently wrong in the run and study folders: a run never
clears its inputs, two studies never share a folder, a full disk ends in one line, and the
outputs are strict JSON."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.apps.vs import visual_path as VP
from cosim.cli import main
from cosim.load import load_scenario, with_set

ROOT = Path(__file__).resolve().parents[1]
E1 = ROOT / "scenarios" / "bebop2_vs_e1.toml"


def _small_path(folder: Path) -> Path:
    sc = load_scenario(E1)
    return VP.teach_by_render(sc, [(1.5, 0.0, -1.0, 0.0)], folder, "orb", 200)


def test_a_run_never_clears_the_visual_path_it_reads(tmp_path, capsys):
    """Defect 1: `--out R` with `visual_path=R/visual_path` emptied the taught folder before
    the app read it. Now refused at once (exit 2, naming the field and --out), nothing
    deleted."""
    out = tmp_path / "R"
    vp = _small_path(out / "visual_path")
    before = sorted(p.name for p in vp.iterdir())
    rc = main(["run", str(E1), "--set", f"app.params.visual_path={vp}", "--out", str(out),
               "--quiet", "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "app.params.visual_path" in err and "--out" in err
    assert sorted(p.name for p in vp.iterdir()) == before
    VP.load(vp)                                   # still a whole visual path


HOVER = ROOT / "scenarios" / "mambo_hover.toml"


def test_a_second_study_into_the_same_folder_fails_at_once(tmp_path, capsys):
    """Defect 2: two studies started together into one --out both 'succeeded' and the table
    lost rows. The folder is locked for a study: the second fails at once, exit 2, naming
    --out, and writes nothing there."""
    from cosim.outputs.folder import claim_run_folder

    out = tmp_path / "mc"
    with claim_run_folder(out, "--out", what="study"):       # a study running there now
        for argv in (["montecarlo", str(HOVER), "-n", "2", "--vary",
                      "timing.t_final_s=uniform(1,2)", "--limit", "0"],
                     ["sweep", str(HOVER), "--set", "timing.t_final_s=1,2", "--limit", "0"],
                     ["sweep", str(HOVER), "--set", "timing.t_final_s=1,2"]):   # plain sweep
            argv = argv + ["--out", str(out), "--executor", "serial"]
            rc = main(argv)
            err = capsys.readouterr().err
            assert rc == 2 and "--out" in err and "study" in err, (argv, err)
    assert sorted(p.name for p in out.iterdir()) == [".study.lock"]


# ---------------------------------------------------------------- defect 6: a full disk
def full_disk(monkeypatch, root: Path, free: int) -> None:
    """Files opened for writing under `root` share `free` bytes: a write beyond them writes
    what fits and raises ENOSPC, and so does closing such a file (its last flush), as on a
    full device. (Simulated: mounting a small tmpfs needs privileges a test must not need.)"""
    import builtins
    import errno
    import io

    real = builtins.open
    left = [free]

    def enospc():
        return OSError(errno.ENOSPC, "No space left on device")

    class Full:
        def __init__(self, f):
            self._f, self._hit = f, False

        def write(self, b):
            if len(b) > left[0]:
                k, left[0] = left[0], 0
                if k:
                    self._f.write(b[:k])
                self._hit = True
                raise enospc()
            left[0] -= len(b)
            return self._f.write(b)

        def close(self):
            self._f.close()
            if self._hit:
                raise enospc()

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.close()

        def __getattr__(self, name):
            return getattr(self._f, name)

    def fake_open(file, mode="r", *a, **kw):
        f = real(file, mode, *a, **kw)
        if isinstance(file, int) or not any(m in mode for m in "wax+"):
            return f
        return Full(f) if str(Path(file).resolve()).startswith(str(root)) else f

    monkeypatch.setattr(builtins, "open", fake_open)
    monkeypatch.setattr(io, "open", fake_open)


def _whole_outputs(out: Path) -> None:
    """What a run left is consistent: no part files, a summary that parses, whole records."""
    import json

    from cosim.outputs.tlog import read_tlog

    assert not [p.name for p in out.iterdir() if p.suffix in (".part", ".tmp")]
    if (out / "summary.json").exists():
        json.loads((out / "summary.json").read_text())
    if (out / "flight.tlog").exists():
        from mav import wire

        for _, frame in read_tlog(out / "flight.tlog"):
            assert wire.decode_fast is not None and len(frame) >= 12


@pytest.mark.flight
@pytest.mark.parametrize("free", [5_000, 40_000, 147_000])
def test_a_full_disk_ends_a_run_in_one_line_and_keeps_outputs_whole(tmp_path, monkeypatch,
                                                                   capsys, free):
    """Defect 6: ENOSPC gave a traceback at the tlog's close and no summary. Now: one line
    `cosim: disk full writing ...`, exit 1, and every file left is whole."""
    out = tmp_path / "r"
    full_disk(monkeypatch, tmp_path.resolve(), free)
    rc = main(["run", str(HOVER), "--set", "timing.t_final_s=2", "--out", str(out), "--quiet",
               "--no-plots"])
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert rc == 1, err
    assert "Traceback" not in err
    assert "cosim: disk full writing" in err.strip().splitlines()[-1], err
    _whole_outputs(out)


@pytest.mark.flight
def test_a_full_disk_ends_a_study_in_one_line_and_keeps_its_table(tmp_path, monkeypatch,
                                                                   capsys):
    """Defect 6, studies: tracebacks and a stray results.csv.tmp. Now one line, exit 1, the
    table holds the rows written before, and the same command then finishes the study."""
    import csv

    def argv_for(out):
        return ["montecarlo", str(HOVER), "-n", "3", "--vary",
                "timing.t_final_s=uniform(0.2,0.3)", "--executor", "serial", "--quiet",
                "--out", str(out)]

    # the same study once with room, into a folder of the same name length: the bytes it
    # writes up to its first row (study.json records the command line, whose length is this
    # machine's paths'); the full disk then leaves room for that and not for the second row
    probe = tmp_path / "m0"
    monkeypatch.setattr("sys.argv", ["cosim", *argv_for(probe)])
    assert main(argv_for(probe)) == 0
    capsys.readouterr()
    header, first, *_ = (probe / "results.csv").read_text().splitlines(keepends=True)
    log_first = (probe / "runs.log").read_text().splitlines(keepends=True)[0]
    free = ((probe / "study.json").stat().st_size + len(header) + len(first)
            + len(log_first) + 8)
    out = tmp_path / "mc"
    argv = argv_for(out)
    monkeypatch.setattr("sys.argv", ["cosim", *argv])
    full_disk(monkeypatch, tmp_path.resolve(), free)
    rc = main(argv)
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith("cosim: disk full writing"), err
    assert not list(out.glob("*.tmp"))
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) < 3
    assert main(argv) == 0                                   # room again: the study finishes
    assert len(list(csv.DictReader((out / "results.csv").open()))) == 3


# ---------------------------------------------------------------- defect 7: strict outputs
def _strict_load(text: str):
    import json

    def refuse(name):
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.flight
def test_summary_json_is_strict_json(tmp_path, monkeypatch):
    """Defect 7: summary.json held bare NaN and criteria `"passed": "True"` (a numpy bool
    through default=str). Now null for a missing number, true/false as booleans."""
    import numpy as np

    from cosim.outputs import report
    from cosim.sim.master import RunOptions, run_scenario

    sc = with_set(load_scenario(HOVER), {"timing.t_final_s": 1.0})
    res = run_scenario(sc, RunOptions(out_dir=tmp_path / "a"))
    real = report.summarize

    def with_numpy(r):
        s = real(r)
        s["metrics"]["x_nan"] = np.float64("nan")
        s["metrics"]["x_inf"] = float("inf")
        s["metrics"]["x_list"] = [np.float32(1.5), float("nan"), (1, np.int64(2))]
        s["criteria"]["x"] = {"value": np.float64(0.1), "limit": 0.2,
                              "passed": np.float64(0.1) <= 0.2}
        return s

    monkeypatch.setattr(report, "summarize", with_numpy)
    report.write_run(res, tmp_path / "a", plots=False)
    s = _strict_load((tmp_path / "a" / "summary.json").read_text())
    assert s["metrics"]["x_nan"] is None and s["metrics"]["x_inf"] is None
    assert s["metrics"]["x_list"] == [1.5, None, [1, 2]]
    assert s["criteria"]["x"]["passed"] is True
    assert all(isinstance(c["passed"], bool) for c in s["criteria"].values())
    assert isinstance(s["passed"], bool)


def test_montecarlo_runs_are_bounded(tmp_path, capsys):
    """Defect 7: `-n 100000000 --limit 1` made 1.6 GB of draws before its one run. -n and
    the sweep grid are bounded (MAX_RUNS) and refused at once."""
    from cosim.studies.study import MAX_RUNS

    rc = main(["montecarlo", str(HOVER), "-n", str(100_000_000), "--limit", "1", "--vary",
               "timing.t_final_s=uniform(1,2)", "--out", str(tmp_path / "m"),
               "--executor", "serial"])
    err = capsys.readouterr().err
    assert rc == 2 and "-n" in err and f"{MAX_RUNS}" in err.replace(",", ""), err
    vals = ",".join(str(1 + i / 1000) for i in range(400))
    rc = main(["sweep", str(HOVER), "--set", f"timing.t_final_s={vals}", "--set",
               f"timing.camera_every={','.join(str(i) for i in range(1, 401))}",
               "--out", str(tmp_path / "s"), "--executor", "serial", "--limit", "1"])
    assert rc == 2 and "runs" in capsys.readouterr().err
