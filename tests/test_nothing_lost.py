"""Issue 31: nothing lost and nothing silently wrong in the run and study folders: a run never
clears its inputs, two studies never share a folder, a full disk ends in one line, and the
outputs are strict JSON."""

from __future__ import annotations

from pathlib import Path

from cosim.apps.vs import visual_path as VP
from cosim.cli import main
from cosim.scenario.parse import load_scenario

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
