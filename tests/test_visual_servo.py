"""Paper 2's teach-and-repeat visual servoing (issue 11): the maths with known answers, the
image pipeline on synthetic views, the visual path format, and E1/E2 flown in the loop."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.linalg import expm

from cosim.apps.visual_servo import VisualServoApp
from cosim.apps.vs import geometry as G
from cosim.apps.vs import visual_path as VP
from cosim.apps.vs.features import homography, sort_points, spread
from cosim.apps.vs.tasks import Obstacle, corridor_task, find_obstacle
from cosim.cli import main as cli
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set
from cosim.outputs.report import summarize
from cosim.sim.master import run_scenario
from cosim.sim.options import RunOptions

ROOT = Path(__file__).resolve().parents[1]
E1 = ROOT / "scenarios" / "bebop2_vs_e1.toml"
E2 = ROOT / "scenarios" / "bebop2_vs_e2.toml"
K = np.array([[537.3, 0.0, 428.0], [0.0, 527.0, 240.0], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------ maths, known answers
def test_error_is_zero_when_current_is_target():
    assert np.array_equal(G.homography_error(np.eye(3)), np.zeros(6))


def test_translation_along_the_normal_gives_no_rotation_error_and_rotation_no_e_v():
    n = np.array([0.0, 0.0, 1.0])
    H = np.eye(3) + np.outer([0.0, 0.0, 0.2], n) / 2.0      # 0.2 m along the normal, d 2 m
    e = G.homography_error(H / np.cbrt(np.linalg.det(H)))
    assert np.allclose(e[3:], 0.0, atol=1e-15) and e[2] != 0.0
    # a lateral translation couples into e_w by design (Benhimane & Malis 2007): the issue's
    # "a pure translation gives e_w = 0" holds only along the plane normal
    H = np.eye(3) + np.outer([0.2, 0.0, 0.0], n) / 2.0
    assert abs(G.homography_error(H)[4]) > 0.05
    R = expm(G.skew([0.0, 0.1, 0.0]))            # pure rotation: e_v = (R - I) m*, e_w ~ 2 w
    e = G.homography_error(R)
    assert np.allclose(e[:3], (R - np.eye(3)) @ G.M_STAR)
    assert np.isclose(e[4], 2 * math.sin(0.1), rtol=1e-12)


def test_twist_transform_matches_a_hand_computation():
    S = G.body_from_camera_matrix((0.09, 0.0, 0.0))
    # forward along the optical axis -> body vx; camera x (right) -> body vy; y (down) -> vz
    assert np.allclose(S @ [0, 0, 1, 0, 0, 0], [1, 0, 0, 0])
    assert np.allclose(S @ [1, 0, 0, 0, 0, 0], [0, 1, 0, 0])
    assert np.allclose(S @ [0, 1, 0, 0, 0, 0], [0, 0, 1, 0])
    # turning about the camera's y axis at 1 rad/s in place: the CoG 0.09 m behind moves
    # t x w = (0.09, 0, 0) x (0, 0, 1) = (0, -0.09, 0) and the body yaws at 1 rad/s
    assert np.allclose(S @ [0, 0, 0, 0, 1, 0], [0, -0.09, 0, 1])
    # camera_from_body is its inverse on the 4 controllable velocities
    assert np.allclose(S @ G.camera_from_body_matrix((0.09, 0.0, 0.0)), np.eye(4))


def test_adaptive_gain_has_the_paper_shape():
    assert G.adaptive_gain(0.0, 2.8, 0.1, 5.0) == pytest.approx(2.8)
    assert G.adaptive_gain(1e3, 2.8, 0.1, 5.0) == pytest.approx(0.1)
    h = 1e-7       # slope at 0 is -l0'
    assert (G.adaptive_gain(h, 2.8, 0.1, 5.0) - 2.8) / h == pytest.approx(-5.0, rel=1e-5)


def test_activation_ramps_are_continuous_and_reach_their_levels():
    r = G.Ramp(3.0)
    r.set(0.0, 1.0)
    vals = []
    for k in range(800):
        t = k * 0.01
        if k == 150:
            r.set(t, 0.0)          # switched off half-way up
        if k == 250:
            r.set(t, 1.0)          # and on again
        vals.append(r.value(t))
    vals = np.array(vals)
    assert np.abs(np.diff(vals)).max() < 0.01        # no jump anywhere
    assert vals[0] == 0.0 and vals[-1] == 1.0
    assert vals[249] < vals[150] and 0.0 < vals[150] < 1.0
    sm = G.Ramp(1.6, 1.0)
    sm.restart(10.0, 0.2)
    assert sm.value(10.0) == pytest.approx(0.2) and sm.value(11.6) == 1.0


def test_the_lower_task_does_not_disturb_the_higher_ones():
    rng = np.random.default_rng(4)
    for _ in range(50):
        J_a = rng.normal(size=(1, 4))
        J_m = rng.normal(size=(2, 4))
        ed_a = rng.normal(size=1)
        ed_m = rng.normal(size=2)
        nu_v = rng.normal(size=4)
        nu, _, _ = G.hierarchy(nu_v, J_a, ed_a, 1.0, J_m, ed_m, 1.0)
        assert np.allclose(J_a @ nu, ed_a)                     # avoidance exactly
        # visibility as far as avoidance leaves room (least squares in N_a), whatever nu_v
        nu2, _, _ = G.hierarchy(nu_v + rng.normal(size=4), J_a, ed_a, 1.0, J_m, ed_m, 1.0)
        assert np.allclose(J_m @ nu, J_m @ nu2) and np.allclose(J_a @ nu2, ed_a)
        # inactive upper tasks: the servo's velocity passes unchanged
        nu0, _, _ = G.hierarchy(nu_v, J_a, ed_a, 0.0, J_m, ed_m, 0.0)
        assert np.allclose(nu0, nu_v)


# ------------------------------------------------------------------ the image side
def _scene(seed: int = 1, n: int = 80):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1, 1, n),
                            rng.uniform(2.5, 5, n)])


def _project(X, R, c):
    Xc = (X - c) @ R
    return ((Xc / Xc[:, 2:3]) @ K.T)[:, :2]


@pytest.mark.flight
@pytest.mark.parametrize("method", ["virtual_plane", "dominant_plane"])
def test_the_control_law_converges_in_closed_loop_on_a_3d_scene(method):
    """Camera kinematics with the law v = -lambda e: the error direction (m* ~ H m) and the
    signs are right when the camera returns to the taught pose from an offset."""
    X = _scene()
    target = _project(X, np.eye(3), np.zeros(3))
    R, c = expm(G.skew([0.0, 0.25, 0.0])), np.array([0.4, -0.2, -0.8])
    d0 = np.linalg.norm(c)
    for k in range(300):
        cur = _project(X, R, c)
        t_s, c_s = sort_points(target, cur)
        r = homography(c_s, t_s, K, method, seed=k)
        v = -0.5 * G.homography_error(r.H)
        c = c + R @ v[:3] * 0.1
        R = R @ expm(G.skew(v[3:]) * 0.1)
    limit = 0.1 if method == "virtual_plane" else 0.25   # one plane fits a 3-D scene badly
    assert np.linalg.norm(c) < limit * d0 and np.linalg.norm(R - np.eye(3)) < 0.05


def test_virtual_plane_homography_is_the_plane_through_the_three_points():
    X = _scene(2)
    R, c = expm(G.skew([0.02, -0.15, 0.01])), np.array([0.3, 0.1, -0.5])
    target = _project(X, np.eye(3), np.zeros(3))
    cur = _project(X, R, c)
    t_s, c_s = sort_points(target, cur)
    r = homography(c_s, t_s, K, "virtual_plane", seed=0, gate=10.0)
    assert r.method == "virtual_plane"
    # the plane through the 3 sorted points (target frame): m* ~ H m for all its points
    idx = [int(np.where((target == p).all(axis=1))[0][0]) for p in t_s[:3]]
    P = X[idx]
    n = np.cross(P[1] - P[0], P[2] - P[0])
    n /= np.linalg.norm(n)
    on_plane = P[0] + 0.3 * (P[1] - P[0]) + 0.4 * (P[2] - P[0])
    m_cur = np.linalg.inv(K) @ np.append(_project(on_plane[None], R, c)[0], 1.0)
    want = on_plane[:2] / on_plane[2]

    def miss(H):
        m = H @ m_cur
        return float(np.abs(m[:2] / m[2] - want).max())

    # F comes from a seeded RANSAC fit (a minimal sample's model): within 1e-3 (~0.5 px);
    # one plane fitted to all the points misses the virtual plane's point far more
    assert miss(r.H) < 1e-3
    assert miss(homography(c_s, t_s, K, "dominant_plane", seed=0).H) > 10 * miss(r.H)


def test_obstacle_segmentation_and_the_corridor_task():
    img = np.full((240, 428, 3), 120, np.uint8)
    img[20:220, 250:270] = (20, 200, 40)                  # a green column right of centre
    ob = find_obstacle(img)
    assert ob is not None and (ob.x_left_px, ob.x_right_px) == (250.0, 270.0)
    img[20:220, 0:10] = (20, 200, 40)                     # cut by the border: not measured
    img[20:220, 250:270] = 120
    assert find_obstacle(img) is None
    Kh = np.array([[268.6, 0, 214.0], [0, 263.5, 120.0], [0, 0, 1.0]])
    e_c, J = corridor_task(Obstacle(224.0, 244.0, 120.0, 4000), Kh, 0.05, 0.35,
                           G.camera_from_body_matrix((0.09, 0.0, 0.0)))
    assert e_c > 0          # ahead, slightly right: in the corridor
    # moving left (body -y) takes it out (e_c falls), forward brings it nearer (e_c rises);
    # turning is not a way out (yaw column zeroed)
    assert J[0, 1] > 0 and J[0, 0] > 0 and J[0, 3] == 0.0


# ------------------------------------------------------------------ the visual path folder
def test_visual_path_round_trip_and_bad_folders(tmp_path):
    sc = with_set(load_scenario(E1), {"camera.width": 428, "camera.height": 240,
                                       "camera.fx": 268.65, "camera.fy": 263.5,
                                       "camera.cx": 214.0, "camera.cy": 120.0})
    folder = VP.teach_by_render(sc, [(1.5, 0.0, -0.5, 0.0), (1.0, 0.2, -1.0, 10.0)],
                                tmp_path / "vp", "orb", 300)
    vp = VP.load(folder)
    assert vp.size == (428, 240) and len(vp.keys) == 2 and vp.detector == "orb"
    assert vp.poses[1] == (1.0, 0.2, -1.0, 10.0) and len(vp.keys[0].pts) > 50
    meta = json.loads((folder / "path.json").read_text())
    assert meta["taught_by"] == "render" and meta["keys"][0]["image"] == "000.png"
    (folder / "001.png").unlink()
    with pytest.raises(ValueError, match="001.png"):
        VP.load(folder)
    (folder / "path.json").write_text("{")
    with pytest.raises(ValueError, match="not JSON"):
        VP.load(folder)
    with pytest.raises(ValueError, match="cosim teach"):
        VP.load(tmp_path / "nowhere")


def test_a_capped_point_set_is_spread_over_the_image_best_matches_first():
    rng = np.random.default_rng(5)
    W, H = 856, 480
    pts = np.column_stack([rng.uniform(0, 60, 300), rng.uniform(0, 40, 300)])  # one corner
    far = np.array([[800.0, 450.0], [430.0, 250.0], [20.0, 470.0]])            # 3 loners
    pts = np.vstack([pts, far])
    score = rng.uniform(0.1, 0.8, len(pts))
    assert np.array_equal(spread(pts, 0, W, H, score), np.arange(len(pts)))
    assert np.array_equal(spread(pts, 400, W, H, score), np.arange(len(pts)))
    keep = spread(pts, 48, W, H, score)
    assert len(keep) == 48 and np.all(np.diff(keep) > 0)
    assert {300, 301, 302} <= set(keep.tolist())        # every covered cell is kept
    corner = keep[keep < 300]
    assert set(corner.tolist()) == set(np.argsort(score[:300])[:45].tolist())  # its best 45
    assert np.array_equal(spread(pts, 48, W, H, score), keep)                # deterministic
    # a cap below the cells that hold points: a round's best points, not the top rows'
    grid = np.array([[(i + 0.5) * W / 8, (j + 0.5) * H / 6] for j in range(6) for i in range(8)])
    pts2 = np.repeat(grid, 2, axis=0)                        # 2 points in each of 48 cells
    score2 = np.tile([0.5, 0.6], 48)
    score2[-2] = 0.1                                         # the bottom-right cell's best
    keep2 = spread(pts2, 16, W, H, score2)
    assert len(keep2) == 16 and 94 in keep2 and pts2[keep2, 1].max() > H / 2


def test_the_app_servos_on_the_capped_set_and_counts_it_as_matched():
    """`track_max` caps the matched points the app tracks, and the thinning rule (a fresh
    match when fewer than `refresh_frac` of the matched points are left) counts the capped
    set: counted against all the matches, 64 of 200 is thin after 5 points are lost."""
    from cosim.apps.vs.choice import HomographyChoice, Refresh

    app = VisualServoApp({"keys": [[1, 0, -1, 0]], "track_max": 64})
    app.W, app.H = 856, 480
    app.hchoice = HomographyChoice("virtual_plane", 0.15, 5, True, 0.3)
    app.refresh = Refresh(3.0, 4.0, 0.3)
    rng = np.random.default_rng(2)
    cur = np.column_stack([rng.uniform(0, 856, 200), rng.uniform(0, 480, 200)])
    app._use_points(1.0, cur + 3.0, cur, rng.uniform(0.2, 0.8, 200))
    assert len(app.cur) == len(app.tgt) == 64 and np.allclose(app.tgt - app.cur, 3.0)
    assert app.refresh.n_match == 64
    assert app.refresh.due(3.0, 59, 5.0) is None          # 59 of 64 left: not thin


def test_bad_parameters_name_the_parameter():
    for params, name in [({"preset": "e9"}, "preset"), ({"keys": [[1, 2, 3]]}, "keys"),
                         ({"keys": [[1, 0, -1, 0]], "sigma": [0.1, -1]}, "sigma"),
                         ({"keys": [[1, 0, -1, 0]], "detector": "akaze"}, "detector"),
                         ({"keys": [[1, 0, -1, 0]], "min_tracked": 4}, "min_tracked"),
                         ({"keys": [[1, 0, -1, 0]], "p": 1.5}, "p"), ({}, "keys"),
                         ({"keys": [[1, 0, -1, 0]], "lk_win_px": 14}, "lk_win_px"),
                         ({"keys": [[1, 0, -1, 0]], "lk_win_px": 9}, "lk_win_px"),
                         ({"keys": [[1, 0, -1, 0]], "lk_win_px": 15.0}, "lk_win_px"),
                         ({"keys": [[1, 0, -1, 0]], "track_max": 10}, "track_max"),
                         ({"keys": [[1, 0, -1, 0]], "track_max": -1}, "track_max")]:
        with pytest.raises(ValueError, match=f"app.params.{name}"):
            VisualServoApp(params)


# ------------------------------------------------------------------ in the loop
@pytest.fixture(scope="module")
def e1_runs(tmp_path_factory):
    sc = load_scenario(E1)
    out = {}
    for mode in ("mil", "sil"):
        d = tmp_path_factory.mktemp(f"e1-{mode}")
        res = run_scenario(sc, RunOptions(mode=mode, out_dir=d))
        out[mode] = (res, summarize(res), d)
    return out


@pytest.mark.flight
def test_e1_converges_past_the_bar(e1_runs):
    res, s, _ = e1_runs["mil"]
    m = s["metrics"]
    assert s["exit_reason"] == "mission_complete" and s["passed"], s["message"]
    assert m["outcome"] == "goal_reached" and m["keys_reached"] == 1
    # eps < 6 px with the wall 3 m ahead leaves a lateral / yaw ambiguity of ~0.1 m / 2 deg
    assert m["final_pose_error_m"] < 0.15 and m["final_yaw_error_deg"] < 3.0
    assert m["min_clearance_m"] > 0.05 and m["min_clearance_to"] == "column 'bar'"
    (on, off), = m["avoidance_active_s"]            # one activation, then off
    assert math.isfinite(off) and off > on
    assert m["goal_time_s"] - [t for t, n in res.events if n == "repeat"][0] < 20.0
    cols = res.frame_columns
    t, eps, h_m = (np.array([r[cols.index(c)] for r in res.frame_log])
                   for c in ("t", "eps_px", "h_m"))
    assert eps[0] > 50.0 and eps[-1] < 6.0
    # Visibility, paper Sec. 5.1 (Figs. 7, 10, 11): the points stay in the safety area for the
    # whole visual task, which ends at eps < T_eps; h_m stays 0. Here that is the first
    # eps < 6 px: no activation before it. The goal confirmation that follows (ours: a fresh
    # match, adopted when it disagrees) can bring in points matched just inside the
    # rectangle's border and already a little past it, which switches the task on in the
    # last cycles (the shipped key: 16.52 s, goal 16.64 s, h_m 0.06; over 25 key placements
    # within 6 cm: 8 runs, at most 0.2 s before the goal, h_m <= 0.14; with the renderer
    # before the poster-frame fix 5, and a 6th at the start of the repeat, which this test
    # rejects); there it must not gain any authority.
    t_task = t[np.argmax(eps < 6.0)]
    assert all(on > t_task for on, _ in m["visibility_active_s"]), m["visibility_active_s"]
    assert h_m.max() < 0.25


@pytest.mark.flight
def test_e1_is_the_same_in_mil_and_sil_bit_for_bit(e1_runs):
    a, b = e1_runs["mil"][0], e1_runs["sil"][0]
    assert a.exit_reason == b.exit_reason
    assert np.array_equal(a.series, b.series, equal_nan=True)
    assert a.frame_log == b.frame_log and len(a.frame_log) > 100


@pytest.mark.flight
def test_e2_follows_four_keys_past_two_obstacles():
    res = run_scenario(load_scenario(E2))
    s = summarize(res)
    m = s["metrics"]
    assert s["exit_reason"] == "mission_complete" and s["passed"], s["message"]
    assert m["keys_reached"] == 4 and m["outcome"] == "goal_reached"
    act = m["avoidance_active_s"]                   # the cylinder, then (after 10 s) the bar
    # the cylinder's activation lasts until the vehicle has passed it, in its own estimate
    # (issue 28: the obstacle memory; before, it ended at 8.1 s, paper ~5 s): by then the
    # body is at least the corridor's half-width past the cylinder (N 0.75 m)
    ts, xs = res.recorded.columns("t", "x")
    n_off = float(xs[min(int(np.searchsorted(ts, act[0][1])), len(ts) - 1)])
    # ... and it ends before key 1 (1.5 m) is reached; the bar's activation comes after it
    t_key1 = m["switch_times_s"][0]
    assert n_off > 0.75 + 0.3 and act[0][1] < t_key1, (act, n_off, t_key1)
    assert any(on > act[0][1] for on, _ in act[1:])
    assert m["final_pose_error_m"] < 0.15 and m["final_yaw_error_deg"] < 3.0
    assert m["min_clearance_m"] > 0.0
    # smoothing at target changes: the command right after a switch is a fraction h0 of it
    cols = res.frame_columns
    ht = [r[cols.index("h_t")] for r in res.frame_log]
    assert min(ht) == pytest.approx(0.2, abs=0.01)
    assert m["goal_time_s"] < 60.0


@pytest.mark.flight
def test_lost_view_hovers_then_aborts_with_a_reason():
    """A key the vehicle cannot see from where it is (taught facing backwards): the app
    hovers, re-matches, gives up after lost_timeout_s, lands; must_complete fails."""
    sc = with_set(load_scenario(E1), {"app.params.keys": [[-1.0, 0.0, -1.0, 180.0]],
                                      "app.params.lost_timeout_s": 2.0,
                                      "timing.t_final_s": 30.0})
    s = summarize(run_scenario(sc))
    m = s["metrics"]
    assert m["outcome"].startswith("aborted: few matches"), m["outcome"]
    assert s["exit_reason"] == "app_aborted"
    assert m["goal_reached"] is False and m["rematches"] > 10
    assert s["criteria"]["must_complete"]["passed"] is False and not s["passed"]
    assert "app: aborted" in s["criteria"]["must_complete"]["value"]


def test_teach_command_renders_a_folder_a_run_can_use(tmp_path, capsys):
    out = tmp_path / "vp"
    assert cli(["teach", str(E1), "--out", str(out), "--set", "camera.width=428",
                "--set", "camera.height=240", "--set", "camera.fx=268.65",
                "--set", "camera.fy=263.5", "--set", "camera.cx=214",
                "--set", "camera.cy=120"]) == 0
    vp = VP.load(out)
    assert len(vp.keys) == 1 and vp.size == (428, 240)
    img = cv2.imread(str(out / "000.png"))
    assert img.shape == (240, 428, 3) and img.std() > 20
    assert cli(["teach", str(E1), "--fly", "--via", "9:1,1,1"]) == 2   # bad key number
    assert "--via" in capsys.readouterr().err


def test_presets_fill_in_and_every_parameter_can_be_set_from_the_command_line():
    sc = load_scenario(E2)
    app = VisualServoApp(sc.app.params)
    assert app.p["smoothing"] is True and app.p["t_eps_px"] == 12.0   # the e2 preset
    sc2 = with_set(sc, {"app.params.smoothing": False, "app.params.avoidance": False,
                        "app.params.rising_n": 7, "app.params.preset": "e3",
                        "app.params.t_eps_px": 9})
    p = VisualServoApp(sc2.app.params).p
    assert (p["smoothing"], p["avoidance"], p["rising_n"], p["t_eps_px"]) == (
        False, False, 7, 9)
    # feed-forward flies E2's taught legs blind through its bar: refused, the field named
    with pytest.raises(ScenarioError) as e:
        with_set(sc, {"app.params.feedforward": True})
    assert e.value.field == "app.params.feedforward"
    assert p["detector"] == "gftt" and p["l0"] == 2.1                  # the rest from e3
