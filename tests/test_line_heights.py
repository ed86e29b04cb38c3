"""The line follower at flight heights other than the seed's (issue 44, item 6): the general
preset scales its default gains (m/px) with the camera height, so the offset per frame in
floor metres, and so the speed, is the seed height's at every height; flights at 0.7-1.5 m
pass within the seed mission's time budget (90 s for its 6.3 m) scaled by the track's length."""

from __future__ import annotations

from pathlib import Path

import pytest

from cosim.apps.line_follower import SEED_CAMERA_HEIGHT_M, LineFollowerApp
from cosim.apps.planner import PlannerParams
from cosim.load import load_scenario, with_set
from cosim.outputs.report import summarize
from cosim.sim.master import run_scenario

ROOT = Path(__file__).resolve().parents[1]
SEED_BUDGET_S_PER_M = 90.0 / 6.3        # mambo_seed_track: mission_time_max_s over its track


def test_the_default_gains_scale_with_the_camera_height():
    seed = PlannerParams.general()
    assert SEED_CAMERA_HEIGHT_M == 1.0
    for params in ({}, {"hover_alt_m": 1.1}):          # the seed height: bit for bit
        p = LineFollowerApp(params).planner_params
        assert (p.gain_track, p.gain_marker, p.deriv_gain) == (
            seed.gain_track, seed.gain_marker, seed.deriv_gain)
    high = LineFollowerApp({"hover_alt_m": 1.5}).planner_params      # camera at 1.4 m
    assert high.gain_track == pytest.approx(1.4 * seed.gain_track)
    assert high.gain_marker == pytest.approx(1.4 * seed.gain_marker)
    assert high.deriv_gain == pytest.approx(1.4 * seed.deriv_gain)
    low = LineFollowerApp({"hover_alt_m": 0.7, "camera_below_cog_m": 0.2}).planner_params
    assert low.gain_track == pytest.approx(0.5 * seed.gain_track)
    # a gain the user gives stays as given; the others still scale
    mine = LineFollowerApp({"hover_alt_m": 1.5, "alpha": 0.005}).planner_params
    assert mine.gain_track == 0.005 and mine.gain_marker == pytest.approx(1.4 * 0.0022)
    # the released and paper presets keep the released code's gains at any height
    rel = LineFollowerApp({"preset": "released", "hover_alt_m": 1.5}).planner_params
    assert rel.gain_track == PlannerParams.released().gain_track


@pytest.mark.flight
@pytest.mark.parametrize("height", [0.7, 1.0, 1.3, 1.5])
@pytest.mark.parametrize("name", ["mambo_seed_track", "mambo_scurve"])
def test_other_heights_pass_within_the_seed_budget(name, height):
    """Measured 2026-11-29 (MIL, seed 0, general preset) before the gains scaled: the seed
    track at 1.3 m in 91.6 s and at 1.5 m not finished in 100 s (0.067 m/s); after: 78-80 s
    at 0.7-1.5 m (0.093-0.096 m/s), the S-curve 64.7-66.3 s (budget 69.9 s)."""
    # on TPL_EST_TYPE 1: the app's law is under test, and paper 1's release (the default)
    # flies ~13 % slower by its flow correction (docs/sensors.md), whatever the height
    sc = with_set(load_scenario(ROOT / "scenarios" / f"{name}.toml"),
                  {"app.params.preset": "general", "app.params.hover_alt_m": height,
                   "onboard.params.TPL_EST_TYPE": 1})
    budget = SEED_BUDGET_S_PER_M * sc.world.track_length()
    s = summarize(run_scenario(sc))
    crit = s["criteria"]
    assert s["exit_reason"] == "mission_complete"
    assert s["metrics"]["landing_reason"] == "marker"
    assert crit["coverage_min"]["passed"] and crit["landing_error_max_m"]["passed"]
    assert crit["mission_time_max_s"]["value"] <= budget
