"""Issue 28, "and it must fly rooms and paths nobody tuned it for": the visual-servo app's
taught poses checked against the world, the homography choice held steady, obstacles kept
clear once out of view, the visibility task bounded, turn keys needing their translation."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.errors import ScenarioError
from cosim.scenario.parse import load_scenario, with_set

ROOT = Path(__file__).resolve().parents[1]
E2 = ROOT / "scenarios" / "bebop2_vs_e2.toml"


@pytest.mark.parametrize("key,why", [
    ([0.75, 0.05, -1.0, 0.0], "inside the column 'cylinder'"),
    ([0.75, 0.25, -1.0, 0.0], "closer than the body radius to the column 'cylinder'"),
    ([1.5, 1.6, -0.5, 0.0], "box 'crate'"),
    ([1.5, 1.9, -1.0, 0.0], "east wall"),
    ([1.5, 0.0, -2.5, 0.0], "ceiling"),
    ([1.5, 0.0, -0.1, 0.0], "under the body radius"),
])
def test_a_taught_pose_the_vehicle_cannot_hold_is_refused_naming_the_key(key, why):
    sc = load_scenario(E2)
    keys = [list(k) for k in sc.app.params["keys"]]
    keys[2] = key
    with pytest.raises(ScenarioError) as ei:
        with_set(sc, {"app.params.keys": keys})
    assert ei.value.field == "app.params.keys[2]", str(ei.value)
    assert why in str(ei.value), str(ei.value)


def test_the_shipped_and_robustness_missions_have_poses_the_vehicle_can_hold():
    for path in [*ROOT.glob("scenarios/bebop2_vs_*.toml"),
                 *ROOT.glob("scenarios/robustness/*.toml")]:
        load_scenario(path)
