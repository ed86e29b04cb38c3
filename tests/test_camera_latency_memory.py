"""Issue 43, item 13: delayed frames were held as images. `camera.latency_s = 5` with a frame
every tick held 1000 rendered frames (1.35 GB at 856 x 480, 5.4 GB at 1920 x 1080: OpenCV ran
out of memory), and both validated. Now a frame waits for its delivery as its pose, and is
rendered at its delivery (or by the render worker at most LOOKAHEAD frames before): the
memory is a few frames whatever the latency, and the frames are the same bytes
(cosim/sensors/stream.py; the flights: tests/test_camera_stream.py, tests/test_paper2_speed.py).

The choice over refusing such a camera at validation: nothing that flies today is refused,
the bound holds for every latency, rate and size, and it costs nothing: frames are delivered
in capture order and the camera draws its noise in that order either way."""

from __future__ import annotations

import gc
import subprocess
import sys
import tomllib
import weakref
from pathlib import Path

import pytest

from cosim.load import parse_scenario
from cosim.sensors.camera import make_camera
from cosim.sensors.stream import LOOKAHEAD, FrameStream

ROOT = Path(__file__).resolve().parents[1]
H_US = 5000
TICKS = 1600                     # 8 s, a frame every tick; 5 s of latency: 1000 in flight


def _camera(latency_s: float, seed: int = 3):
    raw = tomllib.loads((ROOT / "scenarios" / "mambo_hover.toml").read_text())
    raw["camera"] = {"width": 160, "height": 120, "latency_s": latency_s, "jitter_s": 0.002}
    sc = parse_scenario(raw, source=str(ROOT / "scenarios" / "mambo_hover.toml"),
                        base_dir=ROOT / "scenarios")
    return make_camera(sc.camera, sc.world, seed=seed), sc.camera.stream


def _pose(k: int) -> list[float]:
    y = [0.0] * 21
    y[0], y[1], y[2] = 57.0 + 1e-3 * k, 95.0 - 5e-4 * k, -1.0 - 1e-4 * k
    y[6] = 1.0
    return y


def _fly(stream: FrameStream, held: list) -> tuple[list[bytes], int]:
    """Capture every tick, deliver what is due; the frames delivered, and the most images
    alive at once that were rendered but not yet delivered."""
    cam = stream.camera
    render = cam.render
    alive: list[weakref.ref] = []

    def counted(*a, **kw):
        img = render(*a, **kw)
        alive.append(weakref.ref(img))
        return img

    cam.render = counted
    out, most = [], 0
    try:
        for k in range(TICKS):
            stream.capture(k, _pose(k))
            while stream.due(k):
                _, _, img = stream.pop()
                out.append(img.tobytes())
                del img
            gc.collect() if k % 100 == 0 else None
            most = max(most, sum(r() is not None for r in alive))
            held.append(len(stream.queue))
    finally:
        stream.close()
    return out, most


@pytest.mark.parametrize("worker", ["none", "thread"])
def test_frames_in_flight_are_held_as_poses_not_images(monkeypatch, worker):
    cam, spec = _camera(5.0)
    monkeypatch.setenv("COSIM_RENDER_PROCESS", "0")        # the thread: images in this process
    stream = FrameStream(cam, spec, H_US, seed=3, pipelined=worker == "thread")
    queued: list[int] = []
    frames, most = _fly(stream, queued)
    assert max(queued) > 990                 # ~1000 frames waited for their delivery at once
    assert len(frames) > 500
    assert most <= (LOOKAHEAD + 1 if worker == "thread" else 1), most   # before: ~1000


def test_the_frames_are_the_ones_a_render_at_capture_makes():
    """The reference: each frame rendered at its capture, in capture order, by the same
    camera (seed), and handed out on the same delivery ticks."""
    cam, spec = _camera(5.0)
    stream = FrameStream(cam, spec, H_US, seed=3)
    got, _ = _fly(stream, [])
    ref_cam, _ = _camera(5.0)
    ref = FrameStream(ref_cam, spec, H_US, seed=3)       # only for its delivery ticks
    want, pending = [], []
    for k in range(TICKS):
        kd = ref.delivery_tick(k)
        pending.append((kd, ref_cam.render(_pose(k)[0:3], (1.0, 0.0, 0.0, 0.0)).tobytes()))
        while pending and pending[0][0] <= k:
            want.append(pending.pop(0)[1])
    assert got == want


def _process_most() -> tuple[str, int]:
    """The most frames the render process path held at once (received and not delivered,
    or sent and not received); run in a fresh process, where a fork is safe."""
    cam, spec = _camera(5.0)
    stream = FrameStream(cam, spec, H_US, seed=3, pipelined=True)
    most = 0
    try:
        for k in range(TICKS):
            stream.capture(k, _pose(k))
            proc = stream.proc
            if proc is not None:
                most = max(most, len(proc.done) + proc.sent - proc.received)
            while stream.due(k):
                stream.pop()
    finally:
        worker = stream.worker
        stream.close()
    return worker, most


def test_the_render_process_holds_at_most_lookahead_frames():
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import test_camera_latency_memory "
            "as t; print(*t._process_most())")
    r = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    worker, most = r.stdout.split()
    assert worker == "process" and int(most) <= LOOKAHEAD, r.stdout     # before: ~1000
