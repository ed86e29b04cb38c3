"""Issue 28, "and it must fly rooms and paths nobody tuned it for": the visual-servo app's
taught poses checked against the world, the homography choice held steady, obstacles kept
clear once out of view, the visibility task bounded, turn keys needing their translation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim.apps.vs import geometry as G
from cosim.apps.vs.choice import HomographyChoice, Refresh
from cosim.apps.vs.features import homographies
from cosim.apps.vs.memory import ObstacleMemory
from cosim.apps.vs.tasks import Obstacle
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set

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


# ------------------------------------------------------------------ the homography choice
def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


M0 = np.array([0.0, 0.0, 1.0])


def test_the_homography_choice_does_not_flip_to_a_model_that_disagrees():
    """The corridor case: the virtual plane comes and goes, the dominant plane (a side wall)
    reads the forward offset as a rotation. The choice keeps the virtual plane's error,
    holds it over short gaps, and takes the other only after `hold_n` cycles without one."""
    good = (np.eye(3) + np.outer([0.0, 0.0, 0.2], [0.0, 0.0, 1.0]), M0)   # forward offset
    side = (_rot_z(0.3), M0)                                              # a "rotation"
    ch = HomographyChoice("virtual_plane", jump=0.15, hold_n=3)
    assert ch.choose({"virtual_plane": good, "dominant_plane": side})[1] == "virtual_plane"
    used = [ch.choose({"virtual_plane": good if i % 2 else None, "dominant_plane": side})[1]
            for i in range(8)]
    assert "dominant_plane" not in used and used.count("held") == 4, used
    e_held, how = ch.choose({"virtual_plane": None, "dominant_plane": side})
    assert how == "held" and np.allclose(e_held, G.homography_error(*good))
    assert [ch.choose({"virtual_plane": None, "dominant_plane": side})[1]
            for _ in range(3)] == ["held", "held", "dominant_plane"]
    assert ch.changes == 1
    # models that agree may alternate: no jump in the error, nothing held
    ch2 = HomographyChoice("virtual_plane", jump=0.15, hold_n=3)
    for i in range(6):
        ch2.choose({"virtual_plane": good if i % 2 else None,
                    "dominant_plane": (good[0] + 0.01, M0)})
    assert ch2.holds == 0


def test_the_dominant_plane_error_is_taken_at_a_point_of_the_plane():
    """A side wall (x = -1.5 m) seen while 0.3 m behind the key: with m* at the principal
    point Eq. 2 has no forward error; at the centroid of the wall's points it has."""
    rng = np.random.default_rng(3)
    K = np.array([[537.0, 0.0, 428.0], [0.0, 537.0, 240.0], [0.0, 0.0, 1.0]])
    X = np.column_stack((np.full(60, -1.5), rng.uniform(-0.8, 0.8, 60),
                         rng.uniform(1.5, 5.0, 60)))          # camera frame, target pose
    def px(P):
        q = (K @ P.T).T
        return (q[:, :2] / q[:, 2:]).astype(np.float32)
    target = px(X)
    current = px(X + np.array([0.0, 0.0, 0.3]))              # 0.3 m behind: points farther
    c = homographies(current, target, K, "dominant_plane", seed=1)
    H, m = c["dominant_plane"]
    assert c["virtual_plane"] is None
    assert abs(G.homography_error(H)[2]) < 0.01               # blind at the principal point
    assert G.homography_error(H, m)[2] < -0.05                # forward error at m* on the wall


# ------------------------------------------------------------------ fresh matches
def test_refresh_bounds_the_visibility_task_and_rematches_thinned_or_stalled_tracks():
    r = Refresh(vis_max_s=3.0, stall_s=4.0, frac=0.3)
    r.matched(0.0, 100)
    t = 0.0
    assert r.due(0.5, 100, 50.0) is None
    for t in np.arange(1.0, 3.9, 0.04):
        assert r.visibility_allowed(t, True)
        assert r.due(t, 100, 50.0 - t) is None
    assert r.due(4.0, 100, 45.0) == "visibility"
    assert not r.visibility_allowed(4.1, True) and not r.visibility_allowed(6.9, True)
    assert r.visibility_allowed(7.1, True) and not r.visibility_allowed(7.2, False)
    r.matched(8.0, 100)
    assert r.due(8.5, 20, 30.0) is None                       # not within min_s
    assert r.due(9.1, 20, 30.0) == "thinned"
    r.matched(10.0, 100)
    assert r.due(10.1, 90, 30.0) is None
    assert r.due(13.0, 90, 28.0) is None                      # not 10 % better: stalling
    assert r.due(14.2, 90, 28.0) == "stalled"
    assert r.count == {"visibility": 1, "thinned": 1, "stalled": 1}


# ------------------------------------------------------------------ obstacle memory
def test_obstacle_memory_places_columns_in_the_local_frame_and_forgets_them_when_passed():
    K = np.array([[537.0, 0.0, 428.0], [0.0, 537.0, 240.0], [0.0, 0.0, 1.0]])
    mem = ObstacleMemory()
    assert mem.see(Obstacle(0.0, 1.0, 240.0, 1), K, 0.1, (0.0, 0.0, -1.0), float("nan"),
                   0.09) is None and mem.columns == []         # no telemetry yet: nothing
    # a 0.1 m column 1.0 m ahead of the camera, 0.2 m right, seen heading east from (1, 2)
    w = 0.1 * 537.0 / 1.0
    xc = 428.0 + 0.2 * 537.0
    ne = mem.see(Obstacle(xc - w / 2, xc + w / 2, 240.0, 1), K, 0.1, (1.0, 2.0, -1.0),
                 np.pi / 2, 0.09)
    assert np.allclose(ne, (1.0 - 0.2, 2.0 + 1.09), atol=1e-9)
    # seen again from 0.3 m closer: the same column, updated; another one 1.5 m further on
    mem.see(Obstacle(xc - w / 2, xc + w / 2, 240.0, 1), K, 0.1, (1.0, 2.3, -1.0), np.pi / 2,
            0.09)
    mem.see(Obstacle(xc - w / 2, xc + w / 2, 240.0, 1), K, 0.1, (1.0, 3.8, -1.0), np.pi / 2,
            0.09)
    assert len(mem.columns) == 2
    # beside the first: 0.2 m to its left, level with it -> in the corridor, push left
    e, J, x = mem.task((1.0, 3.39, -1.0), np.pi / 2, 0.35, 0.1)
    assert np.isclose(e, 0.4 - 0.2) and J.tolist() == [[0.0, 1.0, 0.0, 0.0]] and abs(x) < 1e-9
    # 0.41 m past it: forgotten; the second one is the nearest now
    e, J, x = mem.task((1.0, 3.39 + 0.41, -1.0), np.pi / 2, 0.35, 0.1)
    assert len(mem.columns) == 1 and np.isclose(x, 1.5 - 0.41)


def test_decoupling_takes_the_heading_out_of_e_v_and_keeps_the_equilibrium():
    """A 45 deg turn alone: Eq. 2 asks for a translation (e_v = (0.71, 0, -0.29)); decoupled,
    none. A forward offset with the turn keeps its translation; the parts of e_w a level
    camera cannot turn by are not used; e = 0 stays e = 0."""
    th = np.radians(45.0)
    Ry = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0],
                   [-np.sin(th), 0.0, np.cos(th)]])
    e = G.homography_error(Ry)
    assert e[0] > 0.7 and G.decouple(e)[:3] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)
    e = G.homography_error(Ry + np.outer([0.0, 0.0, 0.2], [0.0, 0.0, 1.0]))
    assert G.decouple(e)[:3] == pytest.approx([0.0, 0.0, 0.2], abs=1e-12)
    e = np.array([0.01, -0.02, 0.03, 0.05, 0.0, 0.04])          # no turn about camera y
    assert np.array_equal(G.decouple(e), e)
    assert np.array_equal(G.decouple(np.zeros(6)), np.zeros(6))


def test_decoupling_is_used_only_while_the_vehicle_is_turned():
    lo, hi = np.radians(10.0), np.radians(20.0)
    for deg, share in ((5.0, 0.0), (15.0, 0.5), (45.0, 1.0)):
        th = np.radians(deg)
        Ry = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0],
                       [-np.sin(th), 0.0, np.cos(th)]])
        e = G.homography_error(Ry)
        assert G.decouple(e, G.M_STAR, lo, hi)[:3] == pytest.approx((1.0 - share) * e[:3],
                                                                     abs=1e-9), deg
