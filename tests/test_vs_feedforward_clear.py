"""Feed-forward that cannot fly into the room (issue 44, item 5): paper 2's feed-forward
(Eqs. 31-32) pushes the vehicle along the taught legs whatever it sees, and the avoidance task
sees columns only; a taught path whose poses or legs come closer than `ff_clearance_m` to a
wall, the ceiling, a box or a column is refused at load, naming `app.params.feedforward`."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.apps.registry import _check_feedforward_clear
from cosim.cli import main
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set

ROOT = Path(__file__).resolve().parents[1]
LROOM_FF = ROOT / "scenarios" / "robustness" / "lroom_turn_ff.toml"
# the L room's path turning right 0.45 m from the north wall (N 3.6): the body (radius 0.25 m)
# 0.20 m from it (flown without feed-forward it hit the wall), and 0.6 m from it: 0.35 m
# (flown with feed-forward it hit the shelving). docs/papers/visual-servoing.md, "Feed-forward
# near the room"
NEAR_WALL = [[1.0, 0.0, -1.0, 0.0], [2.0, 0.0, -1.0, 0.0], [2.9, 0.0, -1.0, 0.0],
             [3.1, 0.3, -1.0, 45.0], [3.15, 0.8, -1.0, 90.0], [3.15, 1.8, -1.0, 90.0],
             [3.15, 2.6, -1.0, 90.0]]
NEAR_WALL_060 = [[1.0, 0.0, -1.0, 0.0], [2.0, 0.0, -1.0, 0.0], [2.75, 0.0, -1.0, 0.0],
                 [2.95, 0.3, -1.0, 45.0], [3.0, 0.8, -1.0, 90.0], [3.0, 1.8, -1.0, 90.0],
                 [3.0, 2.6, -1.0, 90.0]]


def test_feedforward_on_a_path_that_turns_near_a_wall_is_refused_naming_the_field():
    sc = load_scenario(LROOM_FF)
    with pytest.raises(ScenarioError) as ei:
        with_set(sc, {"app.params.keys": NEAR_WALL})
    assert ei.value.field == "app.params.feedforward"
    msg = str(ei.value)
    assert "north wall" in msg and "0.20 m" in msg and "ff_clearance_m = 0.4 m" in msg, msg
    with pytest.raises(ScenarioError, match=r"passes 0\.35 m from the north wall"):
        with_set(sc, {"app.params.keys": NEAR_WALL_060})
    # the same path without feed-forward loads (its poses are ones the vehicle can hold), and
    # so does feed-forward with a clearance the user states (theirs to answer for)
    with_set(sc, {"app.params.keys": NEAR_WALL, "app.params.feedforward": False})
    with_set(sc, {"app.params.keys": NEAR_WALL, "app.params.ff_clearance_m": 0.15})
    with pytest.raises(ScenarioError, match="ff_clearance_m"):
        with_set(sc, {"app.params.ff_clearance_m": -0.1})


def test_a_leg_between_clear_poses_that_cuts_a_corner_is_refused():
    """Both poses keep 0.45 m or more from the L room's shelving (N 0.2-1.8, E 0.9-2.3);
    the straight leg between them cuts its corner."""
    scene = load_scenario(LROOM_FF).world.scene
    poses = [("app.params.keys[0]", (2.6, 1.2, -1.0)), ("app.params.keys[1]", (1.5, 0.2, -1.0))]
    for _, ned in poses:
        assert scene.clearance(*ned, 0.25)[0] >= 0.4
    with pytest.raises(ScenarioError) as ei:
        _check_feedforward_clear(poses, scene, 0.25, 0.4)
    assert "the leg app.params.keys[0] -> app.params.keys[1]" in str(ei.value)
    assert "box 'shelving'" in str(ei.value)
    _check_feedforward_clear(poses, scene, 0.25, 0.0)    # the body itself stays clear


def test_the_cli_exits_2_on_it(tmp_path, capsys):
    text = LROOM_FF.read_text().replace('file = "worlds/lroom.toml"',
                                        f'file = "{LROOM_FF.parent / "worlds/lroom.toml"}"')
    keys = [line for line in text.splitlines() if line.startswith("keys = ")][0]
    bad = tmp_path / "near_wall_ff.toml"
    bad.write_text(text.replace(keys, f"keys = {NEAR_WALL}"))
    assert main(["validate", str(bad)]) == 2
    assert "app.params.feedforward" in capsys.readouterr().err


def test_every_shipped_feedforward_path_keeps_the_clearance():
    for path in [*ROOT.glob("scenarios/bebop2_vs_*.toml"),
                 *ROOT.glob("scenarios/robustness/*.toml")]:
        sc = load_scenario(path)
        if sc.app.params.get("feedforward") or sc.app.params.get("preset") == "e4":
            assert "ff_clearance_m" not in sc.app.params, path     # the default, 0.4 m
