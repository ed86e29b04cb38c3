"""Result semantics (issue 12): track coverage in order, the path error against the part of
the track the vehicle should be on, and the app's outcome separate from the vehicle's end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim.load import load_scenario, with_set
from cosim.outputs.coverage import track_progress
from cosim.outputs.report import summarize
from cosim.sim.master import ExitReason, RunOptions, run_scenario

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"


def _arc(cx, cy, r, a0, a1, n=200):
    a = np.linspace(a0, a1, n)
    return np.column_stack((cx + r * np.cos(a), cy + r * np.sin(a)))


def _figure_eight():
    """Two circles of radius 0.6 m touching at the origin: the route crosses itself."""
    return [_arc(0.6, 0.0, 0.6, np.pi, -np.pi), _arc(-0.6, 0.0, 0.6, 0.0, 2 * np.pi)]


def test_flying_the_whole_track_covers_it_with_the_true_error():
    parts = _figure_eight()
    route = np.concatenate(parts)
    xy = route + [0.0, 0.03]                      # 3 cm off, all the way
    cov, err = track_progress(parts, xy, 0.15)
    assert cov > 0.99
    assert 0.0 <= err.max() <= 0.031 and np.median(err) > 0.02


def test_skipping_a_loop_at_the_crossing_is_not_coverage():
    """The figure-eight flown as its first loop only: nearest-point metrics call it perfect."""
    parts = _figure_eight()
    xy = parts[0]
    cov, err = track_progress(parts, xy, 0.15)
    assert 0.45 < cov < 0.55 and err.max() < 1e-3     # on the line it flew (chords)


def test_a_gap_that_was_never_crossed_stops_the_coverage():
    parts = [np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[1.5, 0.0], [3.0, 0.0]])]
    xy = np.column_stack((np.linspace(0.0, 1.0, 200), np.zeros(200)))   # stops at the gap
    cov, _ = track_progress(parts, xy, 0.15)
    assert abs(cov - 1.0 / 3.0) < 0.01


def test_a_nearby_leg_does_not_hide_the_error():
    """A hairpin: legs 0.2 m apart. A vehicle that drifts onto the return leg while it should
    be on the outbound one is 0.2 m off, not 0."""
    parts = [np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 0.2], [0.0, 0.2]])]
    xy = np.column_stack((np.linspace(0.0, 1.0, 100), np.r_[np.zeros(50), np.full(50, 0.2)]))
    cov, err = track_progress(parts, xy, 0.15)
    assert err[-1] > 0.19 and cov < 0.3


@pytest.mark.flight
def test_an_app_that_gives_up_is_not_a_completed_mission():
    sc = with_set(load_scenario(SEED), {"app.params.mission_timeout_s": 30.0})
    res = run_scenario(sc, RunOptions(mode="mil"))
    s = summarize(res)
    assert res.exit_reason is ExitReason.APP_ABORTED, res.message
    assert s["metrics"]["outcome"].startswith("aborted: mission_timeout_s")
    assert s["metrics"]["goal_reached"] is False
    assert not s["criteria"]["must_complete"]["passed"] and not s["passed"]
    full = summarize(run_scenario(load_scenario(SEED), RunOptions(mode="mil")))
    assert full["exit_reason"] == "mission_complete" and full["metrics"]["goal_reached"]
    assert full["metrics"]["track_coverage"] > 0.99


def test_a_start_outside_the_arena_is_bad_input_and_a_partial_start_keeps_the_world_s():
    import pytest

    from cosim.errors import ScenarioError

    sc = load_scenario(SEED)
    with pytest.raises(ScenarioError, match="vehicle.start.*inside the world's arena"):
        with_set(sc, {"vehicle.start.n": 0.0})
    part = with_set(sc, {"vehicle.start.yaw_deg": 30.0}).start
    assert (part.n, part.e, part.yaw_deg) == (sc.start.n, sc.start.e, 30.0)


def test_a_bad_line_follower_parameter_is_named_as_the_user_wrote_it():
    import pytest

    from cosim.errors import ScenarioError

    sc = load_scenario(SEED)
    for key, value in (("alpha", -1.0), ("r_min_px", 100.0), ("lost_timeout_s", -2.0),
                       ("arc_width_rad", 10.0), ("k_t", -5.0)):
        with pytest.raises(ScenarioError, match=f"app.params.{key}: got") as e:
            with_set(sc, {f"app.params.{key}": value})
        import re

        for internal in ("gain_track", "r_min", "lost_timeout", "arc_width"):
            assert not re.search(rf"\b{internal}\b", str(e.value)), str(e.value)
