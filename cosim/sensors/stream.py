"""The camera's video stream: when a frame captured at tick k reaches the app (issue 28).

A frame is captured on a camera tick k (the pose at t_k is rendered) and delivered to the app
at ``t_k + latency_s + jitter`` on the first tick at or after that instant, in capture order:
a frame delayed more than the next one holds it back (the stream is FIFO, as a decoder's
output; none is dropped or reordered). The jitter is ``jitter_s * N(0, 1)`` per frame from its
own seeded stream (``[scenario seed, 12]``), drawn only when ``jitter_s > 0``; the delay is
never below zero. With both zero (the default, ``stream = "ideal"``) every frame is delivered
on the tick it is captured, exactly as before the stream existed.

``[camera] stream = "bebop2"`` takes the Bebop 2 preset below for every stream and exposure
key the table does not set (front camera only); the keys themselves can be set with any
stream. docs/cameras.md, "The video stream", gives the sources of the preset.

``FrameStream`` renders a frame when it is delivered (below). With a delay it may instead
render ``pipelined``: the render of frame k is a pure function of the pose at capture (the
renderer's own seeded noise is drawn in capture order, one job at a time), so it runs while
the plant and the flight stack step on, and is joined at delivery; with it runs the app's
per-frame image work (``FrameStage``: cosim/apps/base.py). The worker is a forked render
process where a fork is safe (cosim/sensors/render_proc.py: its own interpreter, so the
render's Python does not take turns with the loop's), else a thread
(``COSIM_RENDER_PROCESS=0`` forces the thread). The flight is the same, bit for bit, either
way. A render process that does not answer within ``[camera] render_timeout_s`` (default
30 s; stopped, stuck) is ended, and the run with ``component_error: camera``.

A frame waits for its delivery as its pose (and the app's wish for it, taken at capture), not
as an image: it is rendered at its delivery, or by the worker at most ``LOOKAHEAD`` frames
before it. Frames are delivered in capture order and the camera draws its noise in that order
either way, so the images are the ones a render at capture makes, and the memory held stays
a few frames whatever the latency and the frame rate (issue 43, item 13: ``latency_s = 5``
with a frame every tick held 1000 images, 5.4 GB at 1920 x 1080).
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosim.errors import ScenarioError
from cosim.plant.fmu import Y_P, Y_QW, Y_QZ, Y_R, Y_VX, Y_VZ, Y_X, Y_Z
from cosim.scenario.validate import number, string
from cosim.sensors.render_proc import TIMEOUT_S as RENDER_TIMEOUT_S

OFF = ("0", "false", "no", "off")   # COSIM_RENDER_PROCESS values that keep the thread
STREAM_SEED = 12          # the jitter's stream: default_rng([scenario seed, STREAM_SEED])

# The Bebop 2 preset (docs/cameras.md, "The video stream", has the sources). No measurement of
# the Bebop 2's own stream latency was found; these are chosen within the published ranges:
# - latency_s 0.12: H.264 encode on the vehicle 30-80 ms + Wi-Fi + decode 30-80 ms (glass-to-
#   glass budget of a drone stream), and "the latency of wifi-based transmission systems can
#   exceed 100 ms" (Int. J. Micro Air Vehicles 2019, doi:10.1177/1756829319869645); the
#   stream in ARSDK mode 0, "low latency" (as ViSP's vpRobotBebop2 sets it);
# - jitter_s 0.01: the Bebop 2's 30 fps frames reach a laptop at 25-50 Hz instantaneous rate
#   (bebop_autonomy issue 184), arrival times spread by ~+-10 ms around the 33 ms period;
# - exposure_s 0.01 (1/100 s, indoor auto-exposure of a small fixed-aperture sensor at
#   30 fps), lighting_noise 0.01 (1 % frame-to-frame gain of the auto-exposure), offset_noise
#   1.0 (0-255 units): chosen, no source.
PRESETS: dict[str, dict[str, float]] = {
    "ideal": {},
    "bebop2": {"latency_s": 0.12, "jitter_s": 0.01, "exposure_s": 0.01,
               "lighting_noise": 0.01, "offset_noise": 1.0},
}
STREAM_KEYS = ("stream", "latency_s", "jitter_s", "render_timeout_s")
LATENCY_MAX_S = 5.0
JITTER_MAX_S = 1.0
RENDER_TIMEOUT_MAX_S = 3600.0
LOOKAHEAD = 8                 # frames the worker renders ahead of their delivery, at most


@dataclass(frozen=True)
class StreamSpec:
    """The stream of a camera (``[camera]`` keys ``stream``, ``latency_s``, ``jitter_s``)."""

    preset: str = "ideal"
    latency_s: float = 0.0        # s, capture to delivery
    jitter_s: float = 0.0         # s, std of the per-frame delay around latency_s
    render_timeout_s: float = RENDER_TIMEOUT_S   # s, a frame from the render process

    @property
    def delayed(self) -> bool:
        return self.latency_s > 0.0 or self.jitter_s > 0.0


def split_stream(d: Mapping[str, Any], where: str, kind: str) -> tuple[dict, StreamSpec]:
    """The ``[camera]`` table with its preset's values filled in and the stream keys taken
    out, and the parsed ``StreamSpec``."""
    name = string(d, "stream", where, "ideal", tuple(PRESETS))
    rest = {k: v for k, v in d.items() if k not in STREAM_KEYS}
    preset = PRESETS[name]
    if preset and kind != "front":
        raise ScenarioError(f"{where}.stream", name, "a preset of the front camera "
                            "(kind = 'front'); 'ideal' for this camera")
    filled = {**preset, **{k: d[k] for k in STREAM_KEYS[1:] if k in d}}
    spec = StreamSpec(
        preset=name,
        latency_s=number(filled, "latency_s", where, 0.0, lo=0.0, hi=LATENCY_MAX_S),
        jitter_s=number(filled, "jitter_s", where, 0.0, lo=0.0, hi=JITTER_MAX_S),
        render_timeout_s=number(d, "render_timeout_s", where, RENDER_TIMEOUT_S, lo=0.0,
                                hi=RENDER_TIMEOUT_MAX_S, lo_open=True))
    for k, v in preset.items():
        if k not in STREAM_KEYS:
            rest.setdefault(k, v)
    return rest, spec


@dataclass(frozen=True)
class Later:
    """A captured frame not handed to a renderer yet: what was decided at its capture."""

    work: bool                    # the app's FrameStage of it, on the worker
    render: bool                  # the app wanted it at capture (else: its draws only)


@dataclass(frozen=True)
class Skipped:
    """A frame not rendered at its capture: the camera's draws for it (``FrontCamera.skip``),
    from which it is rendered if it is wanted by its delivery."""

    drawn: Any


class FrameStream:
    """A renderer's frames, captured on camera ticks and handed out on their delivery ticks.

    ``capture(k, y)`` on a camera tick (``y`` the plant outputs at t_k); then, every tick,
    ``due(k)`` says whether the oldest frame is to be delivered at tick k and ``pop()`` gives
    it as (capture tick, plant outputs at capture, image). ``times`` holds, per delivered
    frame, (capture tick, delivery tick, motion blur in px).
    """

    def __init__(self, camera, spec: StreamSpec, h_us: int, seed: int,
                 pipelined: bool = False) -> None:
        self.camera = camera
        self.spec = spec
        self.h_us = int(h_us)
        self.latency_us = int(round(spec.latency_s * 1e6))
        self.jitter_us = spec.jitter_s * 1e6
        self.rng = (np.random.default_rng([seed, STREAM_SEED]) if spec.jitter_s > 0.0
                    else None)
        self.moving = bool(getattr(camera, "wants_motion", False))
        self.queue: deque = deque()      # (delivery tick, capture tick, y, Later or its job)
        self.in_flight = 0               # the first entries of the queue handed to a renderer
        self.last_k = -1                 # delivery tick of the frame captured last
        self.times: list[tuple[int, int, float]] = []
        self.pipelined = bool(pipelined and spec.delayed)
        self.pool = None                 # the worker thread, or
        self.proc = None                 # the render process (render_proc.py)
        self.worker = ""                 # which of the two, once the first frame is captured
        self.stage = None                # the app's FrameStage (pipelined: run on the worker)
        self.wanted = None               # the app's frames_wanted, where frames may be skipped
        self.skipped = 0                 # frames delivered without an image (nobody wanted it)
        self.worker_cpu_s: float | None = None

    def prepare_with(self, stage, wanted=None, render_all: bool = False) -> None:
        """The app's `FrameStage` and `frames_wanted` (cosim/apps/base.py).

        - The stage is computed for each frame on the worker, after its render; only when
          pipelined (else the app computes it when it needs it).
        - A frame captured while `wanted()` says False is not rendered: the camera takes its
          draws (`skip`), and the frame is delivered without an image. If the app wants it
          by its delivery, it is rendered then, from its pose and draws. The same frames
          either way, bit for bit.
        - `render_all` (a video, PNG, MCAP or live sink, camera faults) renders every
          frame, as does a camera that cannot skip or keeps a depth image."""
        self.stage = stage if self.pipelined else None
        cam = self.camera
        can_skip = hasattr(cam, "skip") and not getattr(getattr(cam, "config", None), "depth",
                                                         False)
        self.wanted = wanted if can_skip and not render_all else None

    def delivery_tick(self, k: int) -> int:
        """The tick a frame captured at tick k is delivered on (one jitter draw), never
        before the frame captured before it."""
        d = self.latency_us
        if self.rng is not None:
            d = max(0, int(round(d + self.jitter_us * float(self.rng.standard_normal()))))
        kd = k + -(-d // self.h_us)      # the first tick at or after t_k + delay
        if kd < self.last_k:
            kd = self.last_k
        self.last_k = kd
        return kd

    def _start_worker(self) -> None:
        """At the first capture (the app and OpenCV's threads are set by then): a render
        process where a fork is safe, else a worker thread."""
        from cosim.sensors.render_proc import RenderProcess, fork_is_safe

        cfg = getattr(self.camera, "config", None)
        frame_bytes = 3 * int(getattr(cfg, "width", 0)) * int(getattr(cfg, "height", 0))
        wanted = os.environ.get("COSIM_RENDER_PROCESS", "1").strip().lower() not in OFF
        if wanted and frame_bytes > 0 and fork_is_safe():
            self.proc = RenderProcess(self._render, frame_bytes,
                                      timeout_s=self.spec.render_timeout_s)
            self.worker = "process"
        else:
            self.pool = ThreadPoolExecutor(1, thread_name_prefix="cosim-render")
            self.worker = "thread"

    def capture(self, k: int, y) -> None:
        kd = self.delivery_tick(k)
        ys = list(y)                      # the pose at capture, kept as it was
        if self.pipelined and not self.worker:
            self._start_worker()
        render = self.wanted is None or bool(self.wanted())
        self.queue.append((kd, k, ys, Later(render and self.stage is not None, render)))
        self._hand_out()

    def _hand_out(self) -> None:
        """The worker gets the next frames, in capture order, up to LOOKAHEAD undelivered
        (without a worker a frame is rendered when it is delivered)."""
        q = self.queue
        ahead = LOOKAHEAD if self.worker else 0
        while self.in_flight < ahead and self.in_flight < len(q):
            kd, k, ys, later = q[self.in_flight]
            q[self.in_flight] = (kd, k, ys, self._job(ys, later.work, later.render))
            self.in_flight += 1

    def _job(self, ys: list, work: bool, render: bool, drawn=None):
        """`_render` on the worker (a ticket or a future) or here (its value)."""
        if self.proc is not None:
            return self.proc.submit(ys, work, render, drawn)
        if self.pool is not None:
            return self.pool.submit(self._render, ys, work, render, drawn)
        return self._render(ys, work, render, drawn)

    def _value(self, job) -> tuple:
        if self.proc is not None:
            return self.proc.result(job)
        if self.pool is not None:
            return job.result()
        return job

    def due(self, k: int) -> bool:
        q = self.queue
        return bool(q) and q[0][0] <= k

    def pop(self) -> tuple[int, list, np.ndarray | None]:
        """(capture tick, plant outputs at capture, image); the image is None for a frame
        nobody wanted (see `prepare_with`)."""
        kd, k, ys, job = self.queue.popleft()
        if isinstance(job, Later):        # rendered now, at its delivery
            job = self._job(ys, job.work, job.render)
        else:
            self.in_flight -= 1
        self._hand_out()
        img, blur_px, pre = self._value(job)
        if isinstance(pre, Skipped):      # not rendered at capture: its draws
            if self.wanted():             # ... but wanted now: made from them, the same
                img, _, pre = self._value(self._job(ys, self.stage is not None, True,
                                                    pre.drawn))
            else:
                self.skipped += 1
                pre = None
        if self.stage is not None and pre is not None:
            self.stage.offer(img, pre)
        self.times.append((k, kd, blur_px))
        return k, ys, img

    def _render(self, y: list, work: bool = False, render: bool = True, drawn=None
                ) -> tuple[np.ndarray | None, float, Any]:
        """(frame, its blur px, the app's FrameStage of it if `work`, else None); not
        `render`: (None, its blur px, the camera's draws for it); `drawn`: a skipped
        frame's draws, to make it now."""
        cam = self.camera
        p, q = y[Y_X:Y_Z + 1], tuple(y[Y_QW:Y_QZ + 1])
        kw: dict[str, Any] = {}
        if self.moving:
            kw["motion"] = (y[Y_VX:Y_VZ + 1], y[Y_P:Y_R + 1])
        if not render:
            drawn = cam.skip(p, q, **kw)
            return None, (cam.last_blur_px if self.moving else 0.0), Skipped(drawn)
        if drawn is not None:
            kw["drawn"] = drawn
        img = cam.render(p, q, **kw)
        blur_px = cam.last_blur_px if self.moving else 0.0
        return img, blur_px, (self.stage.fn(img) if work else None)

    def close(self) -> None:
        """Stop the worker (frames not yet delivered are not rendered further)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
        if self.proc is not None:
            self.proc.close()
            self.worker_cpu_s = self.proc.cpu_s
            self.proc = None

    def summary(self, h_s: float) -> dict[str, Any]:
        """The stream's figures for summary.json."""
        s = self.spec
        out: dict[str, Any] = {"preset": s.preset, "latency_s": s.latency_s,
                               "jitter_s": s.jitter_s, "frames": len(self.times),
                               "pipelined": self.pipelined, "worker": self.worker,
                               "skipped": self.skipped}
        if self.worker_cpu_s is not None:
            out["worker_cpu_s"] = self.worker_cpu_s      # the render process's CPU time
        if self.times:
            delay = np.array([(kd - k) * h_s for k, kd, _ in self.times])
            blur = np.array([b for _, _, b in self.times])
            out.update(delay_mean_s=float(delay.mean()), delay_max_s=float(delay.max()),
                       blur_mean_px=float(blur.mean()), blur_max_px=float(blur.max()))
        return out


def frame_rows(times, h_s: float) -> list[tuple[int, float, float, float, float]]:
    """Rows of camera_frames.csv: frame, t_capture_s, t_delivery_s, delay_s, blur_px."""
    return [(i, k * h_s, kd * h_s, (kd - k) * h_s, b) for i, (k, kd, b) in enumerate(times)]
