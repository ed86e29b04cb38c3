"""`cosim bench` rows for paper 2's vision pipeline (called by cosim/bench/command.py with
its timing helpers)."""

from __future__ import annotations

from typing import Any

from cosim.bench.common import ROOT


def bench_vision(n: int, repeats: int, per_call_us, stat) -> dict[str, Any]:
    """Paper 2's pipeline on 856 x 480 frames of the E1 room approaching the key: matching
    (SIFT detect + ratio test + seeded RANSAC, at each key change) and one servo cycle (LK
    tracking, outlier filter, homography, visual error, control law, hierarchy)."""
    import numpy as np

    from cosim.apps.vs import geometry as G
    from cosim.apps.vs.features import (
        Detector,
        Tracker,
        gray_of,
        homography,
        match,
        robust_inliers,
        sort_points,
    )
    from cosim.apps.vs.presets import DEFAULTS
    from cosim.load import load_scenario
    from cosim.sensors.front import FrontCamera

    sc = load_scenario(ROOT / "scenarios" / "bebop2_vs_e1.toml")
    cam = FrontCamera(sc.world, sc.camera)
    K = sc.camera.K()
    frames = [gray_of(cam.render((0.6 * i / n, 0.3 * i / n, -1.0 + 0.4 * i / n),
                                 (1.0, 0.0, 0.0, 0.0))) for i in range(n + 1)]
    key = gray_of(cam.render((1.5, 0.0, -0.5), (1.0, 0.0, 0.0, 0.0)))
    det, tracker = Detector("sift", 800), Tracker(win=DEFAULTS["lk_win_px"])
    kp, kd = det.detect(key)
    S = G.body_from_camera_matrix(sc.camera.mount_B)
    it = iter(())

    def matching() -> None:
        pts, desc = det.detect(frames[0])
        match(det, kp, kd, pts, desc, 0)

    pts, desc = det.detect(frames[0])
    tgt0, cur0 = sort_points(*match(det, kp, kd, pts, desc, 0))
    state = {}

    def cycle() -> None:
        nonlocal it
        try:
            i = next(it)
        except StopIteration:
            it = iter(range(1, n + 1))
            state.update(cur=cur0, tgt=tgt0)
            i = next(it)
        new, keep = tracker.track(frames[i - 1], frames[i], state["cur"])
        cur, tgt = new[keep], state["tgt"][keep]
        inl = robust_inliers(cur, tgt, i, 2.0)
        cur, tgt = cur[inl], tgt[inl]
        r = homography(cur, tgt, K, "virtual_plane", i)
        e = G.homography_error(r.H)
        lam = G.adaptive_gain(float(np.linalg.norm(e)), 2.8, 0.1, 5.0)
        G.hierarchy(S @ G.control_law(e, lam, 2.5), None, 0.0, 0.0, None, None, 0.0)
        state.update(cur=cur, tgt=tgt)

    return {"match_sift_856x480": stat(per_call_us(matching, max(3, n // 10), repeats),
                                        "us/match"),
            "servo_cycle_856x480": stat(per_call_us(cycle, n, repeats), "us/frame")}
