"""The camera's stream (issue 28): frame latency and jitter (delivery ticks, order, seeds),
the exposure noise, the motion blur, the fields' validation, and the loop's delivery (the
capture time the app sees, the same frames as before with the defaults, MIL == SIL)."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosim.errors import ScenarioError
from cosim.load import load_scenario, parse_scenario
from cosim.sensors import blur
from cosim.sensors.camera import make_camera, parse_camera
from cosim.sensors.front import FrontCamera, FrontCameraConfig
from cosim.sensors.noise import FrameNoise
from cosim.sensors.stream import PRESETS, FrameStream, StreamSpec
from cosim.sim.master import run_scenario
from cosim.sim.options import RunOptions
from cosim.world.floor import World
from mav.rotations import R_from_quat

ROOT = Path(__file__).resolve().parents[1]
H_US = 5000


class FakeCamera:
    """Renders a frame that says which pose it was rendered at (y[0])."""

    def __init__(self) -> None:
        self.calls: list[float] = []

    def render(self, p_W, q_WB):
        self.calls.append(float(p_W[0]))
        return np.full((2, 2, 3), int(p_W[0]) % 256, np.uint8)


def y_at(k: int) -> list[float]:
    y = [0.0] * 21
    y[0] = float(k)          # x = the tick, so a frame names its capture
    y[6] = 1.0               # qw
    return y


def fly_stream(spec: StreamSpec, n: int = 400, every: int = 2, seed: int = 0,
               pipelined: bool = False):
    """(capture tick, delivery tick, frame value) of every frame delivered over n ticks."""
    cam = FakeCamera()
    st = FrameStream(cam, spec, H_US, seed, pipelined=pipelined)
    got = []
    try:
        for k in range(n):
            if k % every == 0:
                st.capture(k, y_at(k))
            while st.due(k):
                kc, yc, img = st.pop()
                assert yc[0] == kc                          # the pose at capture
                got.append((kc, k, int(img[0, 0, 0])))
    finally:
        st.close()
    return got


# ------------------------------------------------------------------ delivery
def test_no_delay_delivers_each_frame_on_its_capture_tick():
    got = fly_stream(StreamSpec())
    assert got == [(k, k, k % 256) for k in range(0, 400, 2)]


def test_latency_delivers_on_the_first_tick_at_or_after_capture_plus_latency():
    # 12 ms at 5 ms ticks: the first tick at or after t_k + 12 ms is k + 3; 10 ms: k + 2
    for lat, ticks in ((0.012, 3), (0.010, 2), (0.0001, 1)):
        got = fly_stream(StreamSpec(latency_s=lat))
        assert [(kc, kd) for kc, kd, _ in got] == [(k, k + ticks) for k in range(0, 400 - ticks,
                                                                                   2)]


def test_jitter_is_seeded_and_frames_never_overtake():
    spec = StreamSpec(latency_s=0.05, jitter_s=0.03)     # jitter >> frame period: clamping
    a, b = fly_stream(spec, seed=4), fly_stream(spec, seed=4)
    assert a == b                                        # same seed, same delivery ticks
    assert fly_stream(spec, seed=5) != a                 # its own seeded draws
    caps = [kc for kc, _, _ in a]
    dels = [kd for _, kd, _ in a]
    assert caps == sorted(caps) and len(set(caps)) == len(caps)   # in capture order, no loss
    assert dels == sorted(dels)                                    # none overtakes
    assert all(kd >= kc for kc, kd, _ in a)
    delays = np.array([kd - kc for kc, kd, _ in a]) * H_US * 1e-6
    assert len(set(dels)) < len(dels)                    # some frames held back by earlier ones
    assert 0.04 < delays.mean() < 0.08 and delays.std() > 0.01
    assert all(v == kc % 256 for kc, _, v in a)          # each frame is its capture's


def test_the_render_worker_gives_the_same_frames_at_the_same_ticks():
    spec = StreamSpec(latency_s=0.05, jitter_s=0.03)
    assert fly_stream(spec, pipelined=True) == fly_stream(spec, pipelined=False)


# ------------------------------------------------------------------ configuration
def test_defaults_and_the_bebop2_preset():
    assert parse_camera({"kind": "front"}).stream == StreamSpec()
    assert parse_camera({}).stream == StreamSpec()                       # the down camera
    c = parse_camera({"kind": "front", "stream": "bebop2"})
    p = PRESETS["bebop2"]
    assert c.stream == StreamSpec("bebop2", p["latency_s"], p["jitter_s"])
    assert (c.exposure_s, c.lighting_noise, c.offset_noise) == (
        p["exposure_s"], p["lighting_noise"], p["offset_noise"])
    c = parse_camera({"kind": "front", "stream": "bebop2", "latency_s": 0.2, "exposure_s": 0})
    assert c.stream.latency_s == 0.2 and c.exposure_s == 0.0    # a set key wins
    c = parse_camera({"latency_s": 0.1, "jitter_s": 0.02})      # any camera has a stream
    assert c.stream == StreamSpec("ideal", 0.1, 0.02)


@pytest.mark.parametrize("cam, field", [
    ({"latency_s": -0.1}, "camera.latency_s"),
    ({"latency_s": "fast"}, "camera.latency_s"),
    ({"latency_s": 10.0}, "camera.latency_s"),
    ({"jitter_s": -1.0}, "camera.jitter_s"),
    ({"jitter_s": float("nan")}, "camera.jitter_s"),
    ({"stream": "wifi"}, "camera.stream"),
    ({"stream": 1}, "camera.stream"),
    ({"exposure_s": -0.01}, "camera.exposure_s"),
    ({"exposure_s": 1.0}, "camera.exposure_s"),
    ({"offset_noise": -1.0}, "camera.offset_noise"),
    ({"offset_noise": True}, "camera.offset_noise"),
])
def test_bad_stream_fields_name_the_field(cam, field):
    with pytest.raises(ScenarioError) as e:
        parse_camera({"kind": "front", **cam})
    assert e.value.field == field


def test_a_front_preset_on_the_down_camera_and_blur_on_it_are_refused():
    with pytest.raises(ScenarioError) as e:
        parse_camera({"kind": "down", "stream": "bebop2"})
    assert e.value.field == "camera.stream"
    with pytest.raises(ScenarioError) as e:
        parse_camera({"kind": "down", "exposure_s": 0.01})
    assert e.value.field == "camera.exposure_s"


def test_cosim_validate_exits_2_naming_a_bad_stream_field(tmp_path):
    src = (ROOT / "scenarios/bebop2_room_e1.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(src.replace('file = "worlds/room_e1.toml"',
                               f'file = "{ROOT / "scenarios/worlds/room_e1.toml"}"')
                   .replace('kind = "front"', 'kind = "front"\njitter_s = -0.5'))
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "validate", str(bad)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "camera.jitter_s" in r.stderr, r.stderr


# ------------------------------------------------------------------ exposure noise
def test_exposure_offset_is_one_seeded_value_per_frame_and_clips():
    img = np.full((4, 5, 3), 100, np.uint8)
    a = FrameNoise(np.random.default_rng(3), 0.0, 0.0, img.size, offset_noise=5.0)
    b = FrameNoise(np.random.default_rng(3), 0.0, 0.0, img.size, offset_noise=5.0)
    fa = [a.apply(img) for _ in range(20)]
    assert all(np.array_equal(x, b.apply(img)) for x in fa)          # seeded
    assert all(len(np.unique(f)) == 1 for f in fa)                   # one offset per frame
    vals = np.array([int(f[0, 0, 0]) for f in fa])
    assert len(set(vals)) > 5 and abs(vals.mean() - 100) < 4 and 2 < vals.std() < 9
    dark = FrameNoise(np.random.default_rng(0), 0.0, 0.0, img.size, offset_noise=50.0)
    lows = [int(dark.apply(np.zeros_like(img)).max()) for _ in range(40)]
    assert min(lows) == 0 and max(lows) > 20    # negative offsets clip at 0, not fold back up
    with_pixels = FrameNoise(np.random.default_rng(3), 2.0, 0.01, img.size, offset_noise=5.0)
    f = with_pixels.apply(img)
    assert f.dtype == np.uint8 and len(np.unique(f)) > 1


# ------------------------------------------------------------------ motion blur
@pytest.fixture(scope="module")
def cam():
    w = World.from_dict({"arena": {"n_min": -1.5, "n_max": 4.5, "e_min": -2.0, "e_max": 2.0},
                         "room": {"height": 2.6}})
    return FrontCamera(w, FrontCameraConfig.from_dict({"width": 428, "height": 240,
                                                       "exposure_s": 0.02}))


P, Q = np.array([0.0, 0.0, -1.0]), (1.0, 0.0, 0.0, 0.0)


def test_no_motion_no_blur(cam):
    sharp = cam.render(P, Q)
    assert np.array_equal(cam.render(P, Q, motion=((0, 0, 0), (0, 0, 0))), sharp)
    assert cam.last_blur_px == 0.0


def test_blur_grows_with_speed(cam):
    sharp = cam.render(P, Q).astype(int)
    lengths, diffs = [], []
    for r in (0.25, 0.5, 1.0, 2.0):                    # yaw rate, rad/s
        img = cam.render(P, Q, motion=((0, 0, 0), (0, 0, r)))
        lengths.append(cam.last_blur_px)
        diffs.append(np.abs(img.astype(int) - sharp).mean())
    # the rotation, and the camera 0.09 m ahead of the CoG swung sideways: r (1 + 0.09 / Z)
    assert lengths == pytest.approx([cam.config.fx * 0.02 * r * (1 + 0.09 / 4.41)
                                     for r in (0.25, 0.5, 1.0, 2.0)])
    assert diffs == sorted(diffs) and diffs[0] > 0.0
    # sideways at 1 m/s past the north wall 4.41 m ahead of the camera: fx T v / Z
    cam.render(P, Q, motion=((0.0, 1.0, 0.0), (0, 0, 0)))
    assert cam.last_blur_px == pytest.approx(cam.config.fx * 0.02 / 4.41)


def test_a_yaw_blur_changes_only_pixels_near_a_vertical_edge(cam):
    sharp = cam.render(P, Q)
    img = cam.render(P, Q, motion=((0, 0, 0), (0, 0, 1.0)))     # du = -fx T r, dv = 0
    r = int(cam.last_blur_px / 2.0) + 1                         # the kernel's half width
    s = sharp.astype(int)
    pad = np.pad(s, ((0, 0), (r, r), (0, 0)), mode="edge")
    win = np.stack([pad[:, i:i + s.shape[1]] for i in range(2 * r + 1)])
    flat = (win == s[None]).all(axis=0).all(axis=-1)            # the row is constant around
    changed = (img != sharp).any(axis=-1)
    assert changed.sum() > 100
    assert not (changed & flat).any()


def test_the_kernel_is_a_centred_unit_segment():
    for du, dv in ((5.3, -2.2), (0.4, 0.0), (0.0, 7.0), (-3.0, -3.0)):
        k = blur.kernel(du, dv)
        ys, xs = np.indices(k.shape)
        assert k.sum() == pytest.approx(1.0, abs=1e-6)
        assert (k * xs).sum() == pytest.approx((k.shape[1] - 1) / 2, abs=1e-5)
        assert (k * ys).sum() == pytest.approx((k.shape[0] - 1) / 2, abs=1e-5)
    assert blur.kernel(0.0, 0.0) is None and blur.kernel(0.001, 0.0) is None


def test_the_body_rates_blur_a_stabilized_view_too(cam):
    """Pitching at 1 rad/s: the level (stabilized) view streaks vertically by fy T q (and the
    camera, 0.09 m ahead, moves up); a roll turns the image about its centre: no streak at
    the centre (the model's limit)."""
    assert np.allclose(R_from_quat(Q), np.eye(3))
    sharp = cam.render(P, Q)
    img = cam.render(P, Q, motion=((0, 0, 0), (0, 1.0, 0)))
    assert cam.last_blur_px == pytest.approx(cam.config.fy * 0.02 * (1 + 0.09 / 4.41))
    assert not np.array_equal(img, sharp)
    cam.render(P, Q, motion=((0, 0, 0), (1.0, 0, 0)))
    assert cam.last_blur_px == 0.0


# ------------------------------------------------------------------ in the loop
def room_run(tmp_path, camera: dict, t_final: float = 3.0, mode: str = "mil", **opts):
    sc = load_scenario(ROOT / "scenarios/bebop2_room_e1.toml")
    raw = copy.deepcopy(sc.raw)
    raw["world"] = {"file": str(ROOT / "scenarios/worlds/room_e1.toml")}
    raw["camera"].update({"width": 428, "height": 240, **camera})
    raw["timing"]["t_final_s"] = t_final
    raw["criteria"]["must_complete"] = False
    sc = parse_scenario(raw, source="t")
    from cosim.apps.registry import make_app
    rec = Recorder(make_app(sc.app))
    res = run_scenario(sc, RunOptions(mode=mode, out_dir=tmp_path, app_override=rec, **opts))
    return sc, res, rec


class Recorder:
    """The scenario's app, with what on_frame was given: (t, ctx.frame_time, frame)."""

    def __init__(self, app) -> None:
        self.app = app
        self.seen: list[tuple[float, float, np.ndarray]] = []

    def on_start(self, ctx) -> None:
        self.ctx = ctx
        self.app.on_start(ctx)

    def on_frame(self, t, image) -> None:
        self.seen.append((t, self.ctx.frame_time, image.copy()))
        self.app.on_frame(t, image)

    def on_tick(self, t) -> None:
        self.app.on_tick(t)

    def __getattr__(self, name):
        return getattr(self.app, name)


@pytest.mark.flight
def test_defaults_hand_the_app_the_frame_rendered_at_its_tick(tmp_path):
    """The zero-latency default is the loop as it was: every frame rendered at the pose of
    its camera tick and handed over on that tick (compared with a fresh camera rendering
    the recorded poses), capture time = delivery time."""
    sc, res, rec = room_run(tmp_path, {"noise_std": 2.0, "lighting_noise": 0.02})
    series = res.series
    fresh = make_camera(sc.camera, sc.world, seed=int(
        np.random.SeedSequence([sc.seed, 2]).generate_state(1)[0]))
    assert len(rec.seen) == 3.0 / (8 * 0.005)
    for i, (t, tc, img) in enumerate(rec.seen):
        k = i * 8
        assert t == tc == k * 5000 * 1e-6            # the tick's own t_k
        row = series[k]
        assert row[0] == t
        assert np.array_equal(img, fresh.render(np.array(row[1:4]), tuple(row[7:11])))


@pytest.mark.flight
def test_latency_hands_the_app_older_frames_with_their_capture_time(tmp_path):
    _, res, rec = room_run(tmp_path, {"latency_s": 0.1, "jitter_s": 0.01, "exposure_s": 0.01})
    assert len(rec.seen) >= 3.0 / (8 * 0.005) - 4
    caps = [tc for _, tc, _ in rec.seen]
    assert caps == sorted(caps)
    delays = np.array([t - tc for t, tc, _ in rec.seen])
    assert delays.min() >= 0.07 and 0.09 < delays.mean() < 0.12
    from cosim.outputs.report import write_run
    write_run(res, tmp_path, plots=False)
    rows = (tmp_path / "camera_frames.csv").read_text().splitlines()
    assert rows[0] == "frame,t_capture_s,t_delivery_s,delay_s,blur_px"
    tc, td = (np.array([float(r.split(",")[i]) for r in rows[1:]]) for i in (1, 2))
    assert np.allclose(tc, caps) and np.allclose(td - tc, delays)
    assert res.camera_stream["frames"] == len(rec.seen)


@pytest.mark.flight
def test_a_delayed_stream_flies_the_same_pipelined_or_not(tmp_path):
    a = room_run(tmp_path / "p", {"stream": "bebop2"}, pipeline=True)[1]
    b = room_run(tmp_path / "s", {"stream": "bebop2"}, pipeline=False)[1]
    assert a.camera_stream["pipelined"] and not b.camera_stream["pipelined"]
    assert np.array_equal(a.series, b.series, equal_nan=True)
    assert a.frame_times == b.frame_times and a.camera_stream["blur_max_px"] > 0.5


@pytest.mark.flight
def test_paper2_e1_with_the_bebop2_stream_is_the_same_in_mil_and_sil(tmp_path):
    sc = load_scenario(ROOT / "scenarios/bebop2_vs_e1.toml")
    from cosim.load import with_set
    sc = with_set(sc, {"camera.stream": "bebop2", "timing.t_final_s": 12.0})
    out = {}
    for mode in ("mil", "sil"):
        out[mode] = run_scenario(sc, RunOptions(mode=mode, out_dir=tmp_path / mode))
    a, b = out["mil"], out["sil"]
    assert a.camera_stream["delay_mean_s"] > 0.1 and a.camera_stream["blur_max_px"] > 0.0
    assert a.exit_reason == b.exit_reason
    assert np.array_equal(a.series, b.series, equal_nan=True)
    assert a.frame_log == b.frame_log and len(a.frame_log) > 20
    assert a.frame_times == b.frame_times


@pytest.mark.flight
def test_cli_render_worker_switch_flies_the_same(tmp_path):
    """`cosim run --render-worker on|off`: which worker ran is in summary.json and on the
    screen; the flight is the same bytes."""
    import json

    out = {}
    for how in ("on", "off"):
        d = tmp_path / how
        r = subprocess.run([sys.executable, "-m", "cosim.cli", "run",
                            str(ROOT / "scenarios/bebop2_vs_e1.toml"), "--set",
                            "camera.width=428", "--set", "camera.height=240", "--set",
                            "timing.t_final_s=7", "--no-plots", "--quiet",
                            "--render-worker", how, "--out", str(d)],
                           capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert r.returncode in (0, 1), r.stderr
        out[how] = (json.loads((d / "summary.json").read_text())["camera_stream"], r.stdout,
                    (d / "timeseries.csv").read_bytes())
    on, off = out["on"], out["off"]
    assert on[0]["pipelined"] and on[0]["worker"] in ("process", "thread")
    assert not off[0]["pipelined"] and off[0]["worker"] == ""
    assert "rendered in a worker" in on[1] and "rendered in the loop" in off[1]
    assert on[0]["skipped"] == off[0]["skipped"] > 20         # the take-off's frames
    assert on[2] == off[2]


@pytest.mark.flight
def test_a_term_to_the_process_group_ends_a_pipelined_run_cleanly(tmp_path):
    """Ctrl-C or `timeout` signal the whole process group, the render process too: it leaves
    the signal to the run, which ends 'interrupted' (exit 143), closes the stream (the
    child's CPU time in summary.json) and leaves no process behind."""
    import json
    import os
    import signal
    import time

    out = tmp_path / "r"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", str(ROOT / "scenarios/bebop2_room_e1.toml"),
         "--set", "camera.stream=bebop2", "--set", "camera.width=428", "--set",
         "camera.height=240", "--set", "timing.t_final_s=600", "--set",
         "app.params.waypoints=[[0.8, 0.45, -1.0, 600.0]]", "--render-worker", "on",
         "--no-plots", "--quiet", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120          # bounded wait for frames under way
        while time.monotonic() < deadline and not _kids(proc.pid):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        kids = _kids(proc.pid)
        assert kids, "the render process should be running"
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signal.SIGTERM, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["exit_reason"] == "interrupted"
    assert summary["camera_stream"]["worker"] == "process"
    assert summary["camera_stream"]["worker_cpu_s"] > 0.0
    for pid in kids:
        assert not os.path.exists(f"/proc/{pid}") or \
            Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"


def _kids(pid: int) -> list[int]:
    """The run's forked children (a render process is a copy of it: the same command)."""
    try:
        kids = [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
        mine = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return []
    out = []
    for k in kids:
        try:
            if Path(f"/proc/{k}/cmdline").read_bytes() == mine:
                out.append(k)
        except OSError:
            pass
    return out
