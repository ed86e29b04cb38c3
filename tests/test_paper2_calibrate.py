"""The paper-2 calibration's arithmetic (cosim/apps/vs/calibrate.py) on hand-made sweeps."""

from __future__ import annotations

import json
import math

from cosim.apps.vs import calibrate as C

PARAMS = ["app.params.low_level", "camera.latency_s"]


def _study(folder, runs):
    """A sweep's study folder as `cosim sweep` writes it: study.json and results.csv."""
    folder.mkdir()
    (folder / "study.json").write_text(json.dumps({"kind": "sweep", "params": PARAMS}))
    cols = ["run_id", *PARAMS, "seed", "status", "exit_reason", "passed", *C.METRICS]
    lines = [",".join(cols)]
    for i, r in enumerate(runs):
        m = r["metrics"]
        cells = [str(i), *(str(r["overrides"][k]) for k in PARAMS), "0", "ok", r["exit_reason"],
                 str(r["passed"]), str(m["goal_reached"]), repr(m["goal_time_s"]),
                 repr(m["repeat_time_s"]), '"' + json.dumps(m["switch_times_s"]) + '"']
        lines.append(",".join(cells))
    (folder / "results.csv").write_text("\n".join(lines) + "\n")


def _run(lat, goal, rep, switches, passed=True, exit_reason="mission_complete"):
    return {"overrides": {"app.params.low_level": "moveby", "camera.latency_s": lat},
            "passed": passed, "exit_reason": exit_reason,
            "metrics": {"goal_reached": True, "goal_time_s": goal, "repeat_time_s": rep,
                        "switch_times_s": switches}}


def test_times_count_from_the_repeat_start_and_failures_cost_infinity():
    e1 = [_run(0.1, 20.0, 12.0, [20.0]), _run(0.2, 30.0, 24.0, [30.0]),
          _run(0.3, 30.0, 20.0, [30.0], exit_reason="collision")]
    # repeat starts at 10 s: switches 12, 15, 26 s after it -> exact
    e2 = [_run(0.1, 46.0, 36.0, [22.0, 25.0, 36.0, 46.0]),
          _run(0.2, 46.0, 36.0, [22.0, 25.0, 36.0, 46.0]),
          _run(0.3, 46.0, 36.0, [22.0, 25.0, 36.0, 46.0])]
    rows = C.fit_rows(e1, e2)
    assert [r["grid"]["camera.latency_s"] for r in rows][:2] == [0.1, 0.2]
    assert rows[0]["e2_s"] == [12.0, 15.0, 26.0] and rows[0]["cost"] == 0.0
    assert math.isclose(rows[1]["max_rel_err"], 1.0)               # E1 24 s against 12 s
    assert rows[2]["cost"] == math.inf                              # the collision


def test_fit_and_ratio_commands(tmp_path, capsys):
    for name, runs in (("e1", [_run(0.1, 20.0, 12.0, [20.0])]),
                       ("e2", [_run(0.1, 46.0, 36.0, [22.0, 25.0, 36.0, 46.0])]),
                       ("e3", [_run(0.1, 110.0, 100.0, []), _run(0.2, 110.0, 100.0, [])]),
                       ("e4", [_run(0.1, 60.0, 40.0, []), _run(0.2, 60.0, 50.0, [])])):
        _study(tmp_path / name, runs)
    assert C.main(["fit", str(tmp_path / "e1"), str(tmp_path / "e2")]) == 0
    assert "within 30%" in capsys.readouterr().out
    assert C.main(["fit", str(tmp_path / "e1"), str(tmp_path / "e2"),
                   "--where", "camera.latency_s=0.2"]) == 1          # no such grid point
    assert "no grid point passes" in capsys.readouterr().out
    assert C.main(["ratio", str(tmp_path / "e3"), str(tmp_path / "e4"), "--plot",
                   str(tmp_path / "r.png")]) == 0
    out = capsys.readouterr().out
    assert "E4/E3    0.4" in out and (tmp_path / "r.png").stat().st_size > 1000
