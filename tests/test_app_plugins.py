"""A scenario names its app; a plugin is checked against the app contract before anything of
it is called (issue 14, item 1: `app.name = "subprocess:Popen"` used to run a command during
`cosim validate`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, parse_scenario, with_set

ROOT = Path(__file__).resolve().parents[1]
SQUARE = ROOT / "scenarios" / "scripted_square.toml"


def _scenario(app: dict) -> dict:
    return {"vehicle": {"preset": "mambo"},
            "world": {"arena": {"n_min": 0, "n_max": 4, "e_min": 0, "e_max": 4}}, "app": app}


@pytest.mark.parametrize("name", ["subprocess:Popen", "os:system", "antigravity:x"])
def test_a_callable_that_is_not_an_app_is_refused_and_never_called(tmp_path, name):
    # Popen(params) iterates the dict: its keys are the command line ('touch', path)
    marker = tmp_path / "ran"
    params = {"touch": 1, str(marker): 1}
    before = set(sys.modules)
    with pytest.raises(ScenarioError, match="app.name"):
        parse_scenario(_scenario({"name": name, "params": params}))
    assert not marker.exists()
    assert "antigravity" not in set(sys.modules) - before      # not even imported


def test_cosim_validate_runs_no_command(tmp_path):
    marker = tmp_path / "ran"
    sc = tmp_path / "evil.toml"
    sc.write_text(f'''
[vehicle]
preset = "mambo"
[world]
arena = {{ n_min = 0, n_max = 4, e_min = 0, e_max = 4 }}
[app]
name = "subprocess:Popen"
[app.params]
touch = 1
"{marker}" = 1
''')
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "validate", str(sc)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "app.name" in r.stderr
    assert not marker.exists()


def test_a_class_without_the_contract_is_refused(tmp_path, monkeypatch):
    (tmp_path / "notapp.py").write_text(
        "CALLS = []\n"
        "class Half:\n"
        "    def __init__(self, params):\n"
        "        CALLS.append(params)\n"
        "    def on_tick(self, t):\n"
        "        pass\n"
        "def factory(params):\n"
        "    CALLS.append(params)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import notapp

    for name in ("notapp:Half", "notapp:factory", "notapp:Missing", "notapp:CALLS"):
        with pytest.raises(ScenarioError, match="app contract"):
            parse_scenario(_scenario({"name": name}))
    assert notapp.CALLS == []


@pytest.mark.flight
def test_a_plugin_app_is_checked_at_load_and_built_only_at_run(tmp_path, monkeypatch):
    (tmp_path / "myapp.py").write_text(
        "from cosim.apps.scripted import ScriptedApp\n"
        "BUILT = []\n"
        "class Mine(ScriptedApp):\n"
        "    def __init__(self, params):\n"
        "        BUILT.append(1)\n"
        "        super().__init__(params)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import myapp

    from cosim.sim.master import RunOptions, run_scenario

    sc = with_set(load_scenario(SQUARE), {"app.name": "myapp:Mine", "timing.t_final_s": 1.0})
    assert myapp.BUILT == []                    # validation did not construct it
    res = run_scenario(sc, RunOptions())
    assert myapp.BUILT == [1] and res.ticks == 200


def test_bad_names_are_named():
    for name in ("nosuch.module:App", "a b:C", "mod:", "no_colon", "mod:1x"):
        with pytest.raises(ScenarioError, match="app.name"):
            parse_scenario(_scenario({"name": name}))
