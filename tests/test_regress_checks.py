"""cosim test's checks without flying: tolerance tubes (with a time tolerance), metric
tolerances, suite files and their errors, JUnit XML read by an independent parser."""

from __future__ import annotations

import math
from pathlib import Path

import junitparser
import numpy as np
import pytest

from cosim.errors import ScenarioError
from cosim.regress.cases import Tol, Tolerances, collect
from cosim.regress.compare import first_difference, metric_checks, tube
from cosim.regress.report import junit

ROOT = Path(__file__).resolve().parent.parent
SQUARE = ROOT / "scenarios" / "scripted_square.toml"


def traj(fn, seconds: float = 10.0, rate: float = 10.0) -> dict[str, np.ndarray]:
    t = np.arange(int(seconds * rate) + 1) / rate
    return {"t": t, "n": fn(t)}


def step(delay: float):
    return lambda t: np.where(t >= 3.0 + delay, 1.0, 0.0) + 0.1 * np.sin(t)


def test_a_late_flight_leaves_its_tube_unless_the_time_tolerance_allows_it():
    ref, late = traj(step(0.0)), traj(step(0.2))
    c = tube(ref, late, "n", Tol(0.05))
    assert not c["passed"]
    assert c["first_exit_t"] == pytest.approx(3.0)          # where the step should have been
    assert c["value"] < c["lo"]
    assert tube(ref, late, "n", Tol(0.05, time_s=0.2))["passed"]
    assert not tube(ref, late, "n", Tol(0.05, time_s=0.1))["passed"]
    early = traj(step(-0.2))                                  # leading, the same way
    assert not tube(ref, early, "n", Tol(0.05, time_s=0.1))["passed"]
    assert tube(ref, early, "n", Tol(0.05, time_s=0.2))["passed"]


def test_a_tube_has_absolute_and_relative_width():
    ref = traj(lambda t: 10.0 + 0 * t)
    off = traj(lambda t: 10.4 + 0 * t)
    assert not tube(ref, off, "n", Tol(0.3))["passed"]
    assert tube(ref, off, "n", Tol(0.3, rel=0.05))["passed"]   # 5 % of 10 = 0.5 m
    assert tube(ref, off, "n", Tol(0.5))["passed"]


def test_a_shorter_flight_holds_its_last_value_and_nan_fails_unless_both_are():
    ref = traj(lambda t: np.minimum(t, 5.0))
    short = traj(lambda t: np.minimum(t, 5.0), seconds=7.0)   # landed, then ended earlier
    assert tube(ref, short, "n", Tol(0.01))["passed"]
    bad = traj(lambda t: np.where(t > 4, np.nan, np.minimum(t, 5.0)))
    c = tube(ref, bad, "n", Tol(0.01))
    assert not c["passed"] and c["first_exit_t"] == pytest.approx(4.1)
    assert tube(bad, bad, "n", Tol(0.01))["passed"]


def test_metrics_within_abs_or_rel_tolerance_and_exact_for_text():
    tol = Tolerances().refined({"metric_rel": 0.02, "metrics": {"t_s": {"abs": 0.5}}}, "t")
    ref = {"t_s": 70.0, "err": 0.10, "reason": "marker", "span": "[5.2, 62.6]", "x": "nan"}
    ok = {"t_s": 70.4, "err": 0.1019, "reason": "marker", "span": "[5.2, 62.7]", "x": math.nan}
    assert metric_checks(ref, ok, tol) == ([], [])
    bad = {"t_s": 70.6, "err": 0.103, "reason": "timeout", "span": "[5.2]", "x": 1.0,
           "extra": 1}
    fails, notes = metric_checks(ref, bad, tol)
    assert [f.split(":")[0] for f in fails] == [
        "metric err", "metric reason", "metric span", "metric t_s", "metric x"]
    assert notes == ["metric extra: new in this run (1), not in the baseline"]


def test_first_difference_names_the_time_and_signal():
    a = traj(lambda t: t)
    b = {k: v.copy() for k, v in a.items()}
    b["n"][37] = np.nextafter(b["n"][37], 10.0)                # one bit
    assert first_difference(a, b).startswith("first difference at t=3.70 s in n")


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_suite_cases_seeds_sets_and_tolerances(tmp_path):
    suite = write(tmp_path / "s.toml", f'''
[suite]
name = "mine"
baselines = "base"
[tolerance]
position_m = 0.2
time_s = 0.5
[[case]]
scenario = "{SQUARE}"
seeds = [1, 2]
set = {{ "app.params.tolerance_m" = 0.12 }}
tolerance = {{ signals = {{ alt = {{ abs = 0.03, time_s = 0.1 }}, vx = 0.2 }} }}
[[case]]
scenario = "{SQUARE}"
name = "plain"
''')
    a, b, c = collect([suite])
    assert (a.seed, b.seed, c.seed) == (1, 2, None)
    assert a.sets == ("app.params.tolerance_m=0.12",)
    assert a.id.startswith("scripted_square-seed1-") and c.id == "plain"
    assert a.baselines == tmp_path / "base" and a.suite == "mine"
    sig = a.tolerance.signals
    assert sig["n"] == Tol(0.2, 0.0, 0.5) and sig["alt"] == Tol(0.03, 0.0, 0.1)
    assert sig["vx"] == Tol(0.2, 0.0, 0.5)
    assert c.tolerance.signals["alt"] == Tol(0.10, 0.0, 0.5)
    # the command line's assignments are the change under test: the case keeps its id
    (d,) = collect([SQUARE], sets=("app.params.tolerance_m=0.2",), seed=4)
    assert (d.id, d.seed, d.sets) == ("scripted_square", 4, ("app.params.tolerance_m=0.2",))


@pytest.mark.parametrize("body, field", [
    ('[tolerance]\nposition = 0.1\n', "tolerance.position"),
    ('[tolerance]\nposition_m = -1\n', "tolerance.position_m"),
    ('[tolerance]\nexact = "yes"\n', "tolerance.exact"),
    ('[tolerance.signals]\nalt = {{ abs = 0.1, lag = 2 }}\n', "tolerance.signals.alt.lag"),
    ('[suite]\nbaseline = "b"\n', "suite.baseline"),
    ('[[case]]\nscenario = "nope.toml"\n', "case[1].scenario"),
    ('[[case]]\nscenario = "{sq}"\nseeds = [-1]\n', "case[1].seeds"),
    ('[[case]]\nscenario = "{sq}"\nmode = "hil"\n', "case[1].mode"),
    ('[[case]]\nscenario = "{sq}"\nname = "../x"\n', "case[1].name"),
    ('[[case]]\nscenario = "{sq}"\nset = ["a"]\n', "case[1].set"),
    ('[[case]]\nscenario = "{sq}"\nwhat = 1\n', "case[1].what"),
])
def test_a_bad_suite_names_the_field(tmp_path, body, field):
    suite = write(tmp_path / "s.toml", f'[[case]]\nscenario = "{SQUARE}"\n'
                  + body.format(sq=SQUARE))
    with pytest.raises(ScenarioError) as e:
        collect([suite])
    assert e.value.field == field


def test_two_cases_of_one_id_are_refused(tmp_path):
    suite = write(tmp_path / "s.toml", f'[[case]]\nscenario = "{SQUARE}"\n'
                  f'[[case]]\nscenario = "{SQUARE}"\n')
    with pytest.raises(ScenarioError, match="one case of that id"):
        collect([suite])


def test_a_folder_gives_its_scenarios_and_skips_worlds_and_baselines(tmp_path):
    (tmp_path / "worlds").mkdir()
    (tmp_path / "baselines").mkdir()
    write(tmp_path / "worlds" / "w.toml", '[world]\nname = "w"\n')
    write(tmp_path / "baselines" / "x.toml", "[vehicle]\n")
    write(tmp_path / "notes.toml", 'title = "not a scenario"\n')
    write(tmp_path / "a.toml", SQUARE.read_text().replace(
        "worlds/empty.toml", str(SQUARE.parent / "worlds" / "empty.toml")))
    assert [c.id for c in collect([tmp_path])] == ["a"]
    with pytest.raises(ScenarioError, match="a scenario"):
        collect([tmp_path / "notes.toml"])


def test_junit_xml_is_read_by_a_junit_parser(tmp_path):
    def v(i, status, failures=()):
        return {"id": f"c{i}", "suite": "s1" if i < 3 else "s2", "scenario": "x.toml",
                "status": status, "failures": list(failures), "notes": ["a\x01note"],
                "runs": {"run": "/r"}, "wall_s": 1.5}
    verdicts = [v(0, "passed"), v(1, "failed", ["n left its tube at t=3.00 s", "metric x"]),
                v(2, "error", ["run: component_error: plant <boom> & \x07"]), v(3, "new"),
                v(4, "failed", ["criterion y"])]
    path = tmp_path / "j.xml"
    junit(verdicts, path, 9.0)
    xml = junitparser.JUnitXml.fromfile(str(path))
    suites = {s.name: s for s in xml}
    assert (suites["s1"].tests, suites["s1"].failures, suites["s1"].errors) == (3, 1, 1)
    assert (suites["s2"].tests, suites["s2"].failures, suites["s2"].errors) == (2, 1, 0)
    cases = {c.name: c for s in xml for c in s}
    assert cases["c0"].is_passed and cases["c3"].is_passed
    (res,) = cases["c1"].result
    assert isinstance(res, junitparser.Failure)
    assert res.message == "n left its tube at t=3.00 s"
    assert "metric x" in res.text
    (err,) = cases["c2"].result
    assert isinstance(err, junitparser.Error) and "<boom> &" in err.message


def test_the_longest_cases_are_flown_first(tmp_path):
    """A suite on n workers ends near its runs spread over them: the last run's wall times
    in --out order the jobs, else the baselines' simulated times."""
    from cosim.regress.cases import Case
    from cosim.regress.runner import jobs_for

    base = tmp_path / "b"
    base.mkdir()
    cases = [Case(id=n, scenario=SQUARE, baselines=base) for n in ("a", "b", "c", "d")]
    for n, sim in (("a", 10.0), ("b", 80.0), ("c", 30.0)):
        (base / f"{n}.json").write_text(f'{{"sim_time_s": {sim}}}')
    out = tmp_path / "out"
    assert [j.case.id for j in jobs_for(cases, out)] == ["b", "c", "a", "d"]
    assert [j.run_id for j in jobs_for(cases, out)] == [1, 2, 0, 3]
    out.mkdir()
    (out / "verdicts.json").write_text(
        '[{"suite": "cosim", "id": "a", "wall_s": 50.0}, {"suite": "cosim", "id": "d", '
        '"wall_s": 1.0}]')
    assert [j.case.id for j in jobs_for(cases, out)] == ["a", "b", "c", "d"]


def test_exact_true_fails_on_a_bit_where_bits_can_be_expected(tmp_path):
    """exact = true: a portable baseline with the same versions must be met bit for bit;
    with other versions (or natively) the tubes decide and a note says why. By default the
    tubes decide and the verdict only reports the bits."""
    from cosim.regress.baseline import Baseline
    from cosim.regress.cases import Case
    from cosim.regress.compare import check
    from cosim.regress.flight import Flight

    t = traj(lambda t: 0.01 * t)
    t = {**t, "e": t["n"], "alt": t["n"], "yaw": t["n"]}
    versions = {"numpy": "2.4.6"}

    def flight(sha, v=versions):
        return Flight(tmp_path, 0, {"passed": True, "exit_reason": "mission_complete",
                                    "numerics": {"mode": "portable"}, "versions": v},
                      metrics={"m": 1.0}, trajectory=t, series_sha256=sha)
    base = Baseline(tmp_path / "c.json", {"exit_reason": "mission_complete", "rate_hz": 10.0,
                                          "numerics": "portable", "versions": versions,
                                          "series_sha256": "a", "metrics": {"m": 1.0}}, t)
    strict = Case(id="c", scenario=SQUARE, tolerance=Tolerances().refined({"exact": True}, "t"))
    plain = Case(id="c", scenario=SQUARE)
    v = check(strict, {"run": flight("b")}, base)
    assert v["status"] == "failed" and v["failures"][0].startswith("not bit for bit")
    assert check(strict, {"run": flight("a")}, base)["status"] == "passed"
    v = check(strict, {"run": flight("b", {"numpy": "2.5.0"})}, base)
    assert v["status"] == "passed" and "numpy 2.4.6 -> 2.5.0" in v["notes"][0]
    v = check(plain, {"run": flight("b")}, base)
    assert v["status"] == "passed" and v["exact"] == "differs" and not v["notes"]
