"""The line follower app's parameters map onto the IPS and planner presets; bad ones are named."""

from __future__ import annotations

import pytest

from cosim.apps.line_follower import LineFollowerApp


def test_presets_and_overrides_map_to_ips_and_planner():
    rel = LineFollowerApp({})
    assert rel.ips_params.k_t == 100 and rel.planner_params.gain_track == 0.0038
    assert rel.planner_params.z_hover == -1.1 and rel.every == 1
    pap = LineFollowerApp({"preset": "paper"})
    assert pap.ips_params.k_t == 150 and pap.ips_params.r_min == 26
    assert pap.planner_params.gain_marker == 0.018 and pap.planner_params.z_hover == -1.0
    app = LineFollowerApp({"alpha": 0.008, "beta": 0.003, "hover_alt_m": 1.3, "k_t": 120,
                           "search_on_loss": False, "search_nearest": False,
                           "lost_timeout_s": 2.0, "setpoint_every": 4})
    pp, ip = app.planner_params, app.ips_params
    assert (pp.gain_track, pp.gain_marker, pp.z_hover) == (0.008, 0.003, -1.3)
    assert (pp.search_on_loss, pp.lost_timeout) == (False, 2.0)
    assert (ip.k_t, ip.search_nearest, app.every) == (120, False, 4)
    assert app.seq.takeoff_alt_m == 1.3        # takes off to the hover height


@pytest.mark.parametrize("params, match", [
    ({"alhpa": 0.1}, "app.params.alhpa: unknown parameter"),
    ({"alpha": "fast"}, "app.params.alpha"),
    ({"alpha": float("inf")}, "app.params.alpha"),
    ({"preset": "matlab"}, "app.params.preset"),
    ({"hover_alt_m": -1.0}, "app.params"),
    ({"setpoint_every": 0}, "app.params.setpoint_every"),
    ({"r_min_px": 40, "r_max_px": 30}, "app.params"),
])
def test_bad_parameters_are_named(params, match):
    with pytest.raises(ValueError, match=match):
        LineFollowerApp(params)
