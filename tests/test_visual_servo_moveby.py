"""Paper 2's low level as flown (issue 28): the visual servo's command sent as ViSP's
setVelocity(v, dt) sends it, a relative move of the twist's exponential map over dt
(`cosim/apps/vs/lowlevel.py`), and E1 on it, the same in MIL and SIL bit for bit."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from cosim.apps.visual_servo import VisualServoApp
from cosim.apps.vs.lowlevel import LowLevel, twist_displacement
from cosim.cli import main as cli
from cosim.load import load_scenario
from cosim.outputs.report import summarize
from cosim.sim.master import run_scenario
from cosim.sim.options import RunOptions

ROOT = Path(__file__).resolve().parents[1]
E1M = ROOT / "scenarios" / "bebop2_vs_e1.toml"


def se3(vx, vy, vz, wz, dt):
    """exp of the twist (vx, vy, vz, 0, 0, wz) * dt as a 4x4 matrix (scipy's expm)."""
    xi = np.zeros((4, 4))
    xi[0, 1], xi[1, 0] = -wz, wz
    xi[:3, 3] = (vx, vy, vz)
    return expm(xi * dt)


@pytest.mark.parametrize("v", [(0.3, -0.1, 0.05, 0.4), (0.0, 0.2, -0.1, -1.5),
                               (0.25, 0.0, 0.0, 3.0), (0.1, 0.1, 0.0, 1e-7)])
@pytest.mark.parametrize("dt", [0.04, 1.0])
def test_displacement_is_the_exponential_map_of_the_twist(v, dt):
    d = twist_displacement(*v, dt)
    m = se3(*v, dt)
    assert d[:3] == pytest.approx(tuple(m[:3, 3]), abs=1e-12)
    assert d[3] == pytest.approx(v[3] * dt, abs=1e-15)
    assert math.atan2(m[1, 0], m[0, 0]) == pytest.approx(math.remainder(v[3] * dt, math.tau))


def test_displacement_limits_straight_line_and_small_dt():
    # no yaw rate: v * dt exactly
    assert twist_displacement(0.3, -0.2, 0.1, 0.0, 0.04) == (0.3 * 0.04, -0.2 * 0.04,
                                                              0.1 * 0.04, 0.0)
    # small dt: v dt to first order, the arc's sideways offset is v wz dt^2 / 2
    for dt in (1e-2, 1e-3, 1e-4):
        dx, dy, _, _ = twist_displacement(0.3, 0.0, 0.0, 0.5, dt)
        assert dx == pytest.approx(0.3 * dt, rel=dt)
        assert dy == pytest.approx(0.3 * 0.5 * dt * dt / 2.0, rel=dt)
    # both sides of the series' switch (|wz dt| = 1e-4) are the exponential map
    for wz in (0.99e-4, 1.01e-4):
        d = twist_displacement(0.3, 0.1, 0.0, wz, 1.0)
        assert d[:2] == pytest.approx(tuple(se3(0.3, 0.1, 0.0, wz, 1.0)[:2, 3]), abs=1e-12)
    # a half turn at 1 rad/s: the arc of radius v / wz ends 2 v / wz to the side
    dx, dy, _, dpsi = twist_displacement(0.2, 0.0, 0.0, 1.0, math.pi)
    assert (dx, dy, dpsi) == pytest.approx((0.0, 0.4, math.pi), abs=1e-12)


class _Client:
    def __init__(self):
        self.sent = []

    def set_relative_move(self, *a):
        self.sent.append(("move", a))

    def set_velocity_target(self, *a, **k):
        self.sent.append(("vel", a, k))


def test_the_low_level_sends_one_move_per_new_command_or_velocities_at_least_at_10_hz():
    c = _Client()
    mb = LowLevel("moveby", 0.0, 0.04)
    assert mb.send(c, 0.0, (0.2, 0.0, 0.0, 0.0), True)
    assert not mb.send(c, 0.5, (0.2, 0.0, 0.0, 0.0), False)   # nothing new: nothing sent
    assert c.sent == [("move", (0.2 * 0.04, 0.0, 0.0, 0.0))]
    assert LowLevel("moveby", 1.0, 0.04).dt == 1.0             # ViSP's example: dt = 1 s
    c = _Client()
    vel = LowLevel("velocity", 0.0, 0.04)
    assert vel.send(c, 0.0, (0.2, 0.0, 0.0, 0.1), True)
    assert not vel.send(c, 0.05, (0.2, 0.0, 0.0, 0.1), False)
    assert vel.send(c, 0.1, (0.2, 0.0, 0.0, 0.1), False)     # re-sent: the offboard stream
    assert c.sent[0] == ("vel", (0.2, 0.0, 0.0), {"yaw_rate": 0.1, "frame": "body"})


def test_a_bad_low_level_names_the_field(tmp_path, capsys):
    for params, name in [({"low_level": "pcmd"}, "low_level"),
                         ({"moveby_dt_s": -0.1}, "moveby_dt_s")]:
        with pytest.raises(ValueError, match=f"app.params.{name}"):
            VisualServoApp({"keys": [[1, 0, -1, 0]], **params})
    bad = tmp_path / "bad.toml"
    bad.write_text(E1M.read_text().replace('low_level = "moveby"', 'low_level = "pcmd"')
                   .replace('file = "worlds/', f'file = "{ROOT / "scenarios" / "worlds"}/'))
    assert cli(["validate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "app.params.low_level" in err and "velocity, moveby" in err


@pytest.fixture(scope="module")
def e1_moveby(tmp_path_factory):
    sc = load_scenario(E1M)
    out = {}
    for mode in ("mil", "sil"):
        res = run_scenario(sc, RunOptions(mode=mode, out_dir=tmp_path_factory.mktemp(mode)))
        out[mode] = (res, summarize(res))
    return out


@pytest.mark.flight
def test_e1_on_relative_moves_is_the_same_in_mil_and_sil_bit_for_bit(e1_moveby):
    (a, sa), (b, _) = e1_moveby["mil"], e1_moveby["sil"]
    assert a.exit_reason == b.exit_reason
    assert np.array_equal(a.series, b.series, equal_nan=True)
    assert a.frame_log == b.frame_log and len(a.frame_log) > 100
    assert sa["metrics"]["outcome"] == "goal_reached", sa["message"]
