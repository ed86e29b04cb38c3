"""Frames nobody looks at are not rendered (cosim/sensors/stream.py, ``FrontCamera.skip``): the
camera takes their draws all the same, so every frame that is rendered, early or late, and
every flight, is the same to the byte as when every frame is rendered."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim.apps.base import FrameStage
from cosim.load import load_scenario, with_set
from cosim.plant.fmu import Y_P, Y_QW, Y_VX, Y_X, Y_Z
from cosim.sensors.front import FrontCamera, FrontCameraConfig
from cosim.sensors.stream import FrameStream, StreamSpec
from cosim.sim.master import run_scenario
from cosim.sim.options import RunOptions
from cosim.world.floor import World

ROOT = Path(__file__).resolve().parents[1]
H_US = 5000
EVERY = 8                 # ticks between captures
LATENCY = 0.05            # s: 10 ticks, so frames captured unwanted arrive wanted


def _camera() -> FrontCamera:
    w = World.from_dict({"arena": {"n_min": -1.5, "n_max": 4.5, "e_min": -2.0, "e_max": 2.0},
                         "room": {"height": 2.6}})
    cfg = FrontCameraConfig.from_dict({"width": 107, "height": 60, "exposure_s": 0.02,
                                       "noise_std": 3.0, "lighting_noise": 0.02,
                                       "offset_noise": 1.0})
    return FrontCamera(w, cfg, seed=7)


def _y(k: int) -> list[float]:
    """A moving pose (so each frame has a blur streak of its own)."""
    y = [0.0] * 21
    y[Y_X], y[Y_Z], y[Y_QW] = 0.01 * k, -1.0, 1.0
    y[Y_VX] = 0.5 + 0.01 * (k % 7)
    y[Y_P + 2] = 0.3 * np.sin(0.05 * k)          # yaw rate
    return y


def _wanted_at(k: int) -> bool:
    return (k // 40) % 2 == 1                     # five frames wanted, five not, ...


def _work(img):
    """An app's per-frame image work (a FrameStage function)."""
    return img.astype(np.int32).sum(axis=2)


def _fly(skip: bool, pipelined: bool, n: int = 400, camera=None):
    """[(capture tick, delivery tick, frame or None)], the stream's times, its skip count and
    worker; pipelined, with a FrameStage whose offered results are checked as they come."""
    st = FrameStream(camera or _camera(), StreamSpec(latency_s=LATENCY), H_US, 0,
                     pipelined=pipelined)
    now = {"k": 0}
    stage = FrameStage(_work)
    st.prepare_with(stage, (lambda: _wanted_at(now["k"])) if skip else None)
    got = []
    try:
        for k in range(n):
            now["k"] = k
            if k % EVERY == 0:
                st.capture(k, _y(k))
            while st.due(k):
                kc, _, img = st.pop()
                got.append((kc, k, None if img is None else img.copy()))
                if img is not None and pipelined:   # its work came with it, and is right
                    assert stage._image is img and np.array_equal(stage(img), _work(img))
    finally:
        st.close()
    return got, st.times, st.skipped, st.worker


@pytest.mark.parametrize("worker", ["", "thread", "process"])
def test_skipped_frames_leave_the_others_the_same_bytes(worker, monkeypatch):
    if worker == "thread":
        monkeypatch.setenv("COSIM_RENDER_PROCESS", "0")
    every, times_all, none, _ = _fly(skip=False, pipelined=False)
    got, times, skipped, ran_on = _fly(skip=True, pipelined=bool(worker))
    if worker != "process" or ran_on == "process":          # (a fork is not always safe)
        assert ran_on == worker
    assert none == 0 and all(img is not None for *_, img in every)
    assert [g[:2] for g in got] == [e[:2] for e in every]   # the same frames, same ticks
    assert times == times_all                               # blur streaks included
    late = 0
    for (kc, kd, img), (_, _, ref) in zip(got, every, strict=True):
        if img is None:          # neither captured nor delivered while wanted
            assert not _wanted_at(kc) and not _wanted_at(kd)
        else:
            assert np.array_equal(img, ref), kc             # noise and blur included
            late += not _wanted_at(kc)                      # skipped, then made at delivery
    assert skipped == sum(img is None for *_, img in got) > 10
    assert late > 3


def test_the_exact_renderer_skips_the_same_way():
    cam = lambda: FrontCamera(                                          # noqa: E731
        World.from_dict({"arena": {"n_min": -1.5, "n_max": 4.5, "e_min": -2.0, "e_max": 2.0},
                         "room": {"height": 2.6}}),
        FrontCameraConfig.from_dict({"width": 32, "height": 18, "exact": True,
                                     "supersample": 1, "exposure_s": 0.02, "noise_std": 3.0,
                                     "lighting_noise": 0.02}), seed=3)
    every = _fly(skip=False, pipelined=False, n=160, camera=cam())[0]
    got, _, skipped, _ = _fly(skip=True, pipelined=False, n=160, camera=cam())
    assert skipped > 0
    for (_, _, img), (_, _, ref) in zip(got, every, strict=True):
        assert img is None or np.array_equal(img, ref)


def test_a_camera_that_cannot_skip_renders_every_frame():
    class Plain:
        def render(self, p_W, q_WB):
            return np.full((2, 2, 3), int(p_W[0]) % 256, np.uint8)

    st = FrameStream(Plain(), StreamSpec(), H_US, 0)
    st.prepare_with(None, lambda: False)
    st.capture(0, _y(300))
    assert st.pop()[2][0, 0, 0] == 3 and st.skipped == 0


@pytest.mark.flight
def test_e1_flies_the_same_when_every_frame_is_rendered(tmp_path):
    """E1's first 10 s (take-off, matching, servo): the app's frames_wanted skips the frames
    of the take-off; a sink that sees every frame (PNGs) makes the stream render them all.
    The same flight, bit for bit."""
    sc = with_set(load_scenario(ROOT / "scenarios/bebop2_vs_e1.toml"),
                  {"timing.t_final_s": 10.0, "camera.width": 428, "camera.height": 240})
    a = run_scenario(sc, RunOptions(out_dir=tmp_path / "a"))
    b = run_scenario(sc, RunOptions(out_dir=tmp_path / "b", png_every=1000))
    assert a.camera_stream["skipped"] > 50 and b.camera_stream["skipped"] == 0
    assert np.asarray(a.series).tobytes() == np.asarray(b.series).tobytes()
    assert a.frame_log == b.frame_log and len(a.frame_log) > 20
    assert a.frame_times == b.frame_times


def test_frames_wanted_is_the_apps_own_not_a_wrappers_borrowed_one():
    from cosim.apps.registry import make_app
    from cosim.sim.master import frames_wanted

    app = make_app(load_scenario(ROOT / "scenarios/bebop2_vs_e1.toml").app)
    assert frames_wanted(app)() is False                 # on the ground: no frames wanted

    class Wrapper:                  # hands everything on, but looks at every frame itself
        def __init__(self, inner):
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

    assert Wrapper(app).frames_wanted() is False and frames_wanted(Wrapper(app)) is None
