"""Issue 29: what makes paper 2's missions cheaper must not change them. Caches give back the
same bytes, the column detector labels within the colour's box exactly as over the frame,
OpenCV's thread count and the pipelined stream change no result, and a study's runs share
what one world makes; the pixel thresholds scale with the image's width."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cosim import cache, cvthreads
from cosim.apps.vs import visual_path as VP
from cosim.apps.vs.tasks import Obstacle, find_obstacle
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set
from cosim.sensors.camera import make_camera
from cosim.sensors.noise import FrameNoise
from cosim.sensors.pinhole import world_surfaces
from cosim.sensors.tiles import tile_set
from cosim.world.textures import TextureSpec, cached_texture, make_texture

ROOT = Path(__file__).resolve().parents[1]
E1 = ROOT / "scenarios" / "bebop2_vs_e1.toml"
E2 = ROOT / "scenarios" / "bebop2_vs_e2.toml"


@pytest.fixture
def fresh_cache(tmp_path):
    """An empty memory cache and `tmp_path/cache` on disk; restored afterwards."""
    saved = cache.get_dir()
    cache.clear_memory()
    cache.set_dir(tmp_path / "cache")
    yield tmp_path / "cache"
    cache.clear_memory()
    cache.set_dir(saved)


# ------------------------------------------------------------------ the cache
def test_cache_keeps_arrays_in_memory_and_on_disk_and_remakes_a_bad_file(fresh_cache):
    made = []

    def make():
        made.append(1)
        return {"a": np.arange(5.0), "b": np.array(2.5)}

    k = cache.key("x", (1, 2.0))
    assert k == cache.key("x", (1, 2.0)) and k != cache.key("x", (1, 2.000001))
    with pytest.raises(ValueError, match="does not say"):
        cache.key(np.zeros(5000))                # its repr is cut: not a key
    first = cache.arrays("kind", k, make)
    again = cache.arrays("kind", k, make)
    assert again is first and len(made) == 1                 # memory
    cache.clear_memory()
    disk = cache.arrays("kind", k, make)
    assert len(made) == 1 and np.array_equal(disk["a"], first["a"]) and float(disk["b"]) == 2.5
    (fresh_cache / "kind" / f"{k}.npz").write_bytes(b"torn")
    cache.clear_memory()
    assert np.array_equal(cache.arrays("kind", k, make)["a"], first["a"]) and len(made) == 2


def test_memory_cache_is_bounded(fresh_cache):
    for i in range(cache.MEMO_MAX + 3):
        cache.memo("bounded", str(i), lambda i=i: i)
    assert len(cache._memo["bounded"]) == cache.MEMO_MAX
    assert "0" not in cache._memo["bounded"] and str(cache.MEMO_MAX + 2) in cache._memo["bounded"]


def test_cached_textures_are_the_generated_bytes_and_read_only(fresh_cache):
    spec = TextureSpec("posters", 5)
    img, s = make_texture(spec, 1.3, 0.7, 120, salt=3)
    got, s2 = cached_texture(spec, 1.3, 0.7, 120, salt=3)
    cache.clear_memory()
    disk, s3 = cached_texture(spec, 1.3, 0.7, 120, salt=3)
    assert np.array_equal(img, got) and np.array_equal(img, disk) and s == s2 == s3
    assert not disk.flags.writeable
    other, _ = cached_texture(spec, 1.3, 0.7, 120, salt=4)
    assert not np.array_equal(other, img)


def test_a_world_is_built_once_per_scene_in_a_process(fresh_cache):
    a, b = load_scenario(E2), load_scenario(E2)
    assert a.world is not b.world
    assert world_surfaces(a.world) is world_surfaces(b.world)
    assert tile_set(a.world, world_surfaces(a.world), 2.0) is tile_set(
        b.world, world_surfaces(b.world), 2.0)
    c = with_set(load_scenario(E2), {"world.room.walls.seed": 99})
    assert world_surfaces(c.world) is not world_surfaces(a.world)


# ------------------------------------------------------------------ column detection
def _find_obstacle_full_frame(rgb, min_height_frac=0.15):
    """The detector as it was: labelled over the whole frame."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    mask = cv2.inRange(hsv, np.array([35, 90, 40], np.uint8), np.array([85, 255, 255], np.uint8))
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    best = None
    for i in range(1, n):
        x, y, w, h, area = (int(v) for v in stats[i])
        if h < min_height_frac * rgb.shape[0]:
            continue
        if best is None or area > best[4]:
            best = (x, y, w, h, area)
    if best is None:
        return None
    x, y, w, h, area = best
    if x <= 0 or x + w >= rgb.shape[1]:
        return None
    return Obstacle(float(x), float(x + w), y + 0.5 * h, area)


def test_column_detection_in_the_colour_box_equals_the_full_frame():
    rng = np.random.default_rng(3)
    found = 0
    for trial in range(150):
        img = rng.integers(0, 256, (120, 200, 3), dtype=np.uint8)
        img[:, :, 1] //= 2                                   # little green in the noise
        for _ in range(int(rng.integers(0, 5))):
            x, y = int(rng.integers(-5, 195)), int(rng.integers(-5, 110))
            w, h = int(rng.integers(1, 30)), int(rng.integers(1, 90))
            img[max(y, 0):y + h, max(x, 0):x + w] = (0, 170, 0)
        if trial % 10 == 0:                  # equal areas: the first in raster order wins
            img[:] = 0
            top = 30 if trial % 20 else 10       # the same top row, or a lower one
            img[30:80, 120:124] = (0, 170, 0)
            img[top:top + 50, 20:24] = (0, 170, 0)
            if trial % 30 == 0:                  # and one of them 8-connected across a corner
                img[top + 50, 24] = (0, 170, 0)
                img[top + 51:top + 60, 25:27] = (0, 170, 0)
        got, ref = find_obstacle(img), _find_obstacle_full_frame(img)
        assert got == ref, trial
        found += ref is not None
    assert found > 30


def test_column_detection_on_rendered_e2_frames():
    sc = load_scenario(E2)
    cam = make_camera(sc.camera, sc.world, seed=0)
    seen = 0
    for i in range(12):
        yaw = 0.05 * (i - 6)
        img = cam.render(np.array([0.3 * i, 0.1 * math.sin(i), -1.0]),
                         (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)))
        got = find_obstacle(img)
        assert got == _find_obstacle_full_frame(img)
        seen += got is not None
    assert seen >= 3


# ------------------------------------------------------------------ taught keys
def test_taught_keys_are_made_once_and_written_the_same(fresh_cache, tmp_path, monkeypatch):
    sc = with_set(load_scenario(E1), {"camera.width": 428, "camera.height": 240})
    poses = [(1.5, 0.0, -0.5, 0.0), (1.0, 0.2, -1.0, 10.0)]
    a = VP.load(VP.teach_by_render(sc, poses, tmp_path / "a", "sift", 300))

    def no_detection(*_a, **_k):
        raise AssertionError("detected again")
    monkeypatch.setattr(VP.Detector, "detect", no_detection)
    cache.clear_memory()                              # from disk this time
    darker = with_set(sc, {"camera.brightness": 0.5})   # the repeat's lighting, not the keys'
    b = VP.load(VP.teach_by_render(darker, poses, tmp_path / "b", "sift", 300))
    for ka, kb in zip(a.keys, b.keys, strict=True):
        assert np.array_equal(ka.image, kb.image) and np.array_equal(ka.pts, kb.pts)
        assert np.array_equal(ka.desc, kb.desc)
    assert (tmp_path / "b" / "000.png").read_bytes() == (tmp_path / "a" / "000.png").read_bytes()


# ------------------------------------------------------------------ brightness
def test_brightness_scales_frames_and_is_checked():
    img = np.full((4, 4, 3), 200, np.uint8)
    rng = np.random.default_rng(0)
    assert FrameNoise(rng, 0.0, 0.0, img.size).apply(img) is img
    assert (FrameNoise(rng, 0.0, 0.0, img.size, 0.5).apply(img) == 100).all()
    assert (FrameNoise(rng, 0.0, 0.0, img.size, 1.5).apply(img) == 255).all()
    with pytest.raises(ScenarioError, match="camera.brightness"):
        with_set(load_scenario(E2), {"camera.brightness": 0.0})


def test_exposure_noise_by_table_is_the_per_pixel_formula():
    """Without pixel noise the exposure's gain and offset are looked up per value (noise.py):
    the same bytes as the formula applied to each pixel, for any gain and offset."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (48, 86, 3), dtype=np.uint8)
    noise = FrameNoise(rng, 0.0, 0.01, img.size, 1.0, 1.0)
    for gain, offset in ((1.0, 0.3), (0.97, -1.2), (1.3, 0.0), (0.7, 0.0), (-0.1, 2.0),
                         (2.5, -300.0), (1.0001, 0.49999), (1.0, -0.5), (-0.5, 0.0)):
        if offset:
            ref = img.astype(np.float32) * np.float32(max(gain, 0.0)) + np.float32(offset + 0.5)
            ref = np.clip(ref, 0.0, 255.0).astype(np.uint8)
        else:
            ref = cv2.convertScaleAbs(img, alpha=max(gain, 0.0))
        assert np.array_equal(noise.apply(img, (gain, offset, 0)), ref), (gain, offset)
    assert noise.apply(img[:, :, :1], (1.2, 0.3, 0)).shape == (48, 86, 1)
    with pytest.raises(TypeError, match="uint8"):
        noise.apply(img.astype(np.float32), (1.2, 0.3, 0))


# ------------------------------------------------------------------ OpenCV threads
def test_thread_count_setting(monkeypatch):
    saved = cvthreads._run_threads
    try:
        cvthreads.set_run_threads(None)
        monkeypatch.setenv("COSIM_CV_THREADS", "3")
        assert cvthreads.run_threads() == 3
        cvthreads.set_run_threads(1)
        assert cvthreads.run_threads() == 1
    finally:
        cvthreads.set_run_threads(saved)
    cv2.setNumThreads(2)
    with cvthreads.single_thread():
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == 2


def _fly_e1(threads: int, seconds: float, sets: dict | None = None, where: list | None = None):
    """E1 cut to `seconds`; `where` collects the thread names the app's frame work ran on."""
    import threading

    from cosim.apps import visual_servo
    from cosim.sim.master import run_scenario
    from cosim.sim.options import RunOptions

    sc = with_set(load_scenario(E1), {"timing.t_final_s": seconds, **(sets or {})})
    saved = cvthreads._run_threads
    work = visual_servo.frame_work

    def traced(image, avoidance):
        where.append(threading.current_thread().name)
        return work(image, avoidance)
    cvthreads.set_run_threads(threads)
    if where is not None:
        visual_servo.frame_work = traced
    try:
        return run_scenario(sc, RunOptions(mode="mil"))
    finally:
        cvthreads.set_run_threads(saved)
        visual_servo.frame_work = work


@pytest.mark.flight
def test_e1_is_the_same_sequential_and_pipelined_and_from_the_cache(fresh_cache, monkeypatch):
    """Take-off, matching, tracking and the column in view (the first 7 s of E1): one
    thread, sequential, with everything made afresh; then on two cores with the world and
    keys cached, the stream rendering and computing the app's frame work (grey, column) on
    a worker thread, then in a render process; OpenCV on one thread in each."""
    from cosim.sensors.render_proc import fork_is_safe

    on_a: list[str] = []
    on_b: list[str] = []
    on_c: list[str] = []
    a = _fly_e1(1, 7.0, where=on_a)
    monkeypatch.setenv("COSIM_RENDER_PROCESS", "0")
    b = _fly_e1(2, 7.0, where=on_b)
    monkeypatch.delenv("COSIM_RENDER_PROCESS")
    forkable = fork_is_safe()
    c = _fly_e1(2, 7.0, where=on_c)
    assert any((fresh_cache / k).is_dir() for k in ("texture", "visual-path"))
    assert a.series.shape == b.series.shape == c.series.shape
    for r in (b, c):                                                        # bit for bit
        assert np.asarray(a.series).tobytes() == np.asarray(r.series).tobytes()
        assert a.frame_log == r.frame_log and len(a.frame_log) > 20
    assert a.camera_stream["worker"] == "" and b.camera_stream["worker"] == "thread"
    assert on_a and not any(n.startswith("cosim-render") for n in on_a)
    # all on the worker, the frames rendered late (captured before the app's mission began,
    # delivered after) too; none for the frames nobody wanted (frames_wanted)
    assert on_b and all(n.startswith("cosim-render") for n in on_b), on_b
    assert b.camera_stream["skipped"] > 20
    assert len(on_a) <= len(on_b) < b.camera_stream["frames"]
    if forkable:                                 # (pytest alone: one thread)
        assert c.camera_stream["worker"] == "process"
        assert not on_c                          # the frame work ran in the child


def _job(ys):
    """A render process's job: an image and a FrameStage-like tuple from the request."""
    if ys[0] < 0:
        raise ValueError("a bad pose")
    img = np.full((24, 32, 3), ys[0] % 256, np.uint8)
    return img, 0.5 * ys[0], (img[:, :, 0].copy(), {"n": ys[0]}, None)


def test_render_process_hands_back_each_frame_in_order_and_raises_its_errors():
    from cosim.sensors.render_proc import RenderProcess

    rp = RenderProcess(_job, 24 * 32 * 3, n_slots=3)
    try:
        tickets = [rp.submit([float(i)]) for i in range(10)]   # more than its slots
        for i, t in enumerate(tickets):
            img, blur, (grey, meta, none) = rp.result(t)
            assert img.shape == (24, 32, 3) and int(img[0, 0, 0]) == i and blur == 0.5 * i
            assert grey.shape == (24, 32) and int(grey[5, 5]) == i
            assert meta == {"n": float(i)} and none is None
            img[:] = 0                                          # the parent's own copy
        bad = rp.submit([-1.0])
        with pytest.raises(RuntimeError, match="a bad pose"):
            rp.result(bad)
        assert int(rp.result(rp.submit([7.0]))[0][0, 0, 0]) == 7   # still serving
    finally:
        rp.close()
    assert rp.proc is None


@pytest.mark.flight
def test_render_process_ends_when_its_parent_is_killed(tmp_path):
    """The child holds no copy of the parent's end of the pipe: a parent killed outright
    (SIGKILL, no clean-up) leaves no render process behind."""
    import os
    import signal
    import subprocess
    import sys
    import time

    code = ("import os, signal, sys\n"
            "sys.path.insert(0, sys.argv[1])\n"
            "from test_paper2_speed import _job\n"
            "from cosim.sensors.render_proc import RenderProcess\n"
            "rp = RenderProcess(_job, 24 * 32 * 3)\n"
            "rp.result(rp.submit([1.0]))\n"
            "print(rp.proc.pid, flush=True)\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    r = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent)],
                       capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert r.returncode == -signal.SIGKILL, r.stderr
    child = int(r.stdout.split()[0])
    for _ in range(100):                 # it reads the closed pipe and exits (init reaps it)
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(child, signal.SIGKILL)
        raise AssertionError("the render process outlived its parent")


def _stuck(ys):
    import time
    time.sleep(120)


@pytest.mark.flight
def test_a_stuck_render_process_is_killed_at_close():
    """The child ignores SIGTERM (a TERM to the process group is its run's to handle), so
    close() kills one that does not answer, rather than waiting for it (also at exit)."""
    from cosim.sensors.render_proc import RenderProcess

    rp = RenderProcess(_stuck, 24 * 32 * 3)
    rp.submit([1.0])
    proc = rp.proc
    rp.close()                         # ~10 s: its answer, then its end, waited for in vain
    assert not proc.is_alive() and proc.exitcode == -9


def test_render_process_gone_is_an_error_not_a_hang():
    from cosim.sensors.render_proc import RenderProcess

    rp = RenderProcess(_job, 24 * 32 * 3)
    try:
        t = rp.submit([1.0])
        assert rp.result(t)[1] == 0.5
        rp.proc.kill()
        rp.proc.join(5.0)
        with pytest.raises(RuntimeError, match="render process ended"):
            rp.result(rp.submit([2.0]))
    finally:
        rp.close()


@pytest.mark.flight
def test_a_frame_a_camera_fault_replaces_is_worked_on_afresh_when_pipelined(fresh_cache):
    """A frozen or black frame is not the frame the worker prepared: the app works on the
    frame it gets, as a sequential run does (E1 with both faults while it tracks)."""
    faults = {"faults.camera": [{"kind": "freeze", "start_s": 5.0, "end_s": 5.4},
                                {"kind": "black", "start_s": 5.4, "end_s": 5.6}]}
    where: list[str] = []
    a = _fly_e1(1, 6.5, faults)
    b = _fly_e1(2, 6.5, faults, where)
    assert np.asarray(a.series).tobytes() == np.asarray(b.series).tobytes()
    assert a.frame_log == b.frame_log
    assert "MainThread" in where                 # the replaced frames, worked on here


def test_frame_stage_hands_out_what_was_computed_for_that_frame_once():
    from cosim.apps.base import FrameStage

    calls = []
    stage = FrameStage(lambda img: calls.append(1) or float(img.sum()))
    a, b = np.ones((2, 2)), np.ones((2, 2))
    stage.offer(a, -1.0)                         # what the worker computed for a
    assert stage(a) == -1.0 and not calls
    assert stage(a) == 4.0 and len(calls) == 1   # handed out once, then computed
    stage.offer(a, -1.0)
    assert stage(b) == 4.0 and len(calls) == 2   # another frame (a fault's): computed


def test_pixel_thresholds_scale_with_the_width():
    from cosim.apps.vs.features import Detector, Tracker, px_scale

    assert px_scale(856) == 1.0 and px_scale(428) == 0.5
    t = Tracker(win=21)
    img = np.zeros((480, 856), np.uint8)
    t.track(img, img, np.zeros((1, 2), np.float32))
    assert t.params["winSize"] == (21, 21) and t.params["maxLevel"] == 3 and t.fb_px == 1.0
    t.track(img[::2, ::2], img[::2, ::2], np.zeros((1, 2), np.float32))
    assert t.params["winSize"] == (11, 11) and t.params["maxLevel"] == 2 and t.fb_px == 0.5
    t = Tracker(win=15)                   # the default: 15 px at 856, not below 11 px
    t.track(img, img, np.zeros((1, 2), np.float32))
    assert t.params["winSize"] == (15, 15)
    t.track(img[::2, ::2], img[::2, ::2], np.zeros((1, 2), np.float32))
    assert t.params["winSize"] == (11, 11)
    t = Tracker(win=7)                    # a smaller window asked for is kept
    t.track(img[::2, ::2], img[::2, ::2], np.zeros((1, 2), np.float32))
    assert t.params["winSize"] == (7, 7)
    rng = np.random.default_rng(0)
    noise = cv2.GaussianBlur(rng.integers(0, 255, (240, 428), dtype=np.uint8), (0, 0), 1.0)
    pts, desc = Detector("gftt", 300).detect(noise)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2) + np.eye(len(pts)) * 99
    assert len(pts) > 50 and d.min() >= 3.5 - 1e-6    # 7 px at 856 wide: 3.5 px here


@pytest.mark.flight
def test_e1_at_half_resolution_matches_and_tracks(fresh_cache):
    """428 x 240 (the documented fast choice): the keys are taught at that size, the points
    matched and tracked with the scaled thresholds (the first 7 s of E1)."""
    r = _fly_e1(1, 7.0, {"camera.width": 428, "camera.height": 240})
    rows = [f for f in r.frame_log if f[3] >= 8]      # n_points
    assert len(rows) > 20
    assert max(f[2] for f in rows) < 240               # eps (px) within the smaller frame


def test_centre_depth_is_the_nearest_surface_hit():
    """blur.centre_depth (nearest first, one outline test) against every plane tested."""
    from cosim.sensors.blur import centre_depth
    from cosim.sensors.raycast import _inside

    sc = load_scenario(E2)
    surfaces = world_surfaces(sc.world)
    rng = np.random.default_rng(3)
    for _ in range(300):
        c = rng.uniform((-0.5, -2.0, -2.5), (4.5, 2.0, -0.1))
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        best = math.inf
        for s in surfaces:
            den = float(axis @ s.normal)
            if den >= -1e-12:
                continue
            lam = float(s.normal @ (s.O - c)) / den
            X = c + lam * axis - s.O
            if 0.05 <= lam < best and _inside(np.array([[X @ s.U, X @ s.V]]), s.outline())[0]:
                best = lam
        assert centre_depth(surfaces, c, axis, 0.05) == best


def test_a_numpy_float_metric_is_written_as_a_number():
    """E2's final_yaw_error_deg is a numpy float: the study table wrote 'np.float64(...)',
    which the report could not read (the metric was missing from it)."""
    from cosim.studies.table import fmt

    assert fmt(np.float64(0.46793366282014404)) == "0.46793366282014404"
    assert float(fmt(np.float64(0.1))) == 0.1
