"""run.mcap: written with the Foxglove SDK, read back with the MCAP reader library: the
expected topics and schemas, one message per tick / frame / MAVLink datagram, simulation-time
stamps, decodable images and poses, and the same bytes run to run."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader

from cosim.load import load_scenario, with_set
from cosim.outputs.mcap import TOPICS
from cosim.outputs.series import COL
from cosim.outputs.tlog import read_tlog
from cosim.sensors.camera import make_camera
from cosim.sim.master import RunOptions, run_scenario

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap")
    sc = with_set(load_scenario(SEED), {"timing.t_final_s": 6.0})
    res = run_scenario(sc, RunOptions(out_dir=out, mcap=True))
    return res, out


def _read(path: Path):
    with open(path, "rb") as f:
        r = make_reader(f)
        s = r.get_summary()
        kinds = {c.topic: (s.schemas[c.schema_id].name if c.schema_id else "", c.message_encoding)
                 for c in s.channels.values()}
        msgs: dict[str, list] = {}
        for _, ch, m in r.iter_messages(log_time_order=True):
            msgs.setdefault(ch.topic, []).append(m)
    return kinds, msgs


def test_topics_schemas_counts_and_sim_time(run):
    res, out = run
    kinds, msgs = _read(out / "run.mcap")
    mav = {t for t in kinds if t.startswith("/mavlink/")}
    assert set(kinds) == set(TOPICS) | mav
    for topic, name in TOPICS.items():
        encoding = "protobuf" if name.startswith("foxglove.") else "json"
        assert kinds[topic] == (name, encoding), topic
    n = Counter({t: len(m) for t, m in msgs.items()})
    assert n["/vehicle/pose"] == n["/vehicle/motors"] == res.ticks == 1200
    assert n["/camera/image"] == n["/app/vision"] == len(res.frame_log) == 30   # 5 Hz
    assert n["/camera/calibration"] == 30 and n["/tf"] == 1200 + 30
    assert n["/world/scene"] == n["/tf_static"] == n["/vehicle/model"] == 6    # 1 Hz
    tlog = read_tlog(res.tlog.path)
    assert sum(n[t] for t in mav) == len(tlog)         # every datagram, on its type's topic
    pose_t = [m.log_time for m in msgs["/vehicle/pose"]]
    assert pose_t == [k * 5_000_000 for k in range(res.ticks)]    # simulation time, ns
    assert sorted(m.log_time for t in mav for m in msgs[t]) == sorted(t * 1000 for t, _ in tlog)


def test_the_statics_are_in_every_second_of_playback(run):
    """A viewer that plays the file keeps only what it read since its last seek: the scene,
    the vehicle model, the static transforms and the camera's calibration are in every
    1 s window of simulation time, the same message each time."""
    res, out = run
    _, msgs = _read(out / "run.mcap")
    for topic in ("/world/scene", "/vehicle/model", "/tf_static", "/camera/calibration"):
        seconds = {m.log_time // 1_000_000_000 for m in msgs[topic]}
        assert seconds >= set(range(int(res.t_end_s))), (topic, sorted(seconds))
        if topic != "/camera/calibration":
            assert len({m.data for m in msgs[topic]}) == 1, topic


def test_every_json_field_says_what_it_is_and_its_unit(run):
    res, out = run
    with open(out / "run.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    for c in summary.channels.values():
        if c.message_encoding != "json":
            continue
        props = json.loads(summary.schemas[c.schema_id].data)["properties"]
        for k, p in props.items():
            assert p.get("description"), (c.topic, k)
        if c.topic == "/vehicle/truth":
            assert props["roll_deg"]["description"].endswith("deg")
            assert props["x"]["description"].endswith(" m")
        if c.topic == "/mavlink/ATTITUDE":         # MAVLink's angles are radians
            assert props["roll"]["description"].endswith("rad")


def test_the_log_the_summary_and_the_scenario_file(run):
    """/log: each STATUSTEXT once, long ones joined from their chunks, and the run's events
    and end; the summary as metadata; the scenario file attached."""
    from mcap_protobuf.decoder import DecoderFactory

    res, out = run
    with open(out / "run.mcap", "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        log = [(m.log_time, d) for _, _, m, d in r.iter_decoded_messages(topics=["/log"])]
        meta = {m.name: m.metadata for m in r.iter_metadata()}
        att = {a.name: a.data for a in r.iter_attachments()}
    texts = [d.message for _, d in log]
    assert texts.count("Arming denied: attitude not aligned yet (estimator)") == 1, texts
    assert texts.count("Armed") == 1 and texts.count("Takeoff complete") == 1, texts
    assert all(t == d.timestamp.seconds * 10**9 + d.timestamp.nanos for t, d in log)
    times = {d.message: t for t, d in log}
    for t, what in res.events:
        assert times[what] == int(round(t * 1e9))
    assert texts[-1] == f"run ended: {res.exit_reason.value}: {res.message}"
    s = meta["cosim.summary"]
    assert s["scenario"] == res.scenario.name and s["seed"] == str(res.scenario.seed)
    assert s["exit_reason"] == res.exit_reason.value and int(s["ticks"]) == res.ticks
    assert set(json.loads(s["criteria"])) >= {"must_complete"} and s["passed"] in (
        "true", "false")
    assert att == {SEED.name: SEED.read_bytes()}


def test_the_3d_view_gets_the_estimate_and_the_setpoint(run):
    """The estimate's pose at 50 Hz where the series has it, the setpoint as a sphere where
    the series has it (deleted while none is commanded), both with a 10 s trail at 5 Hz."""
    import numpy as np
    from mcap_protobuf.decoder import DecoderFactory

    res, out = run
    s = res.series
    got: dict[str, list] = {}
    with open(out / "run.mcap", "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, m, d in r.iter_decoded_messages(topics=[
                "/vehicle/estimate_pose", "/app/setpoint_marker", "/vehicle/estimate_path",
                "/app/setpoint_path"]):
            got.setdefault(ch.topic, []).append((m.log_time, d))
    est = got["/vehicle/estimate_pose"]
    assert [t for t, _ in est] == [k * 20_000_000 for k in range(len(est))]    # 50 Hz
    for t, p in est[::50]:
        k = t // 5_000_000
        assert p.frame_id == "world" and (p.pose.position.x, p.pose.position.z) == (
            s[k, COL["est_x"]], s[k, COL["est_z"]])
    shown = [(t, u) for t, u in got["/app/setpoint_marker"] if u.entities]
    assert shown and all(not u.deletions for _, u in shown)
    for t, u in shown[::25]:
        k = t // 5_000_000
        (sphere,) = u.entities[0].spheres
        assert sphere.pose.position.y == s[k, COL["sp_y"]] and u.entities[0].id == "setpoint"
    if not np.isfinite(s[0, COL["sp_x"]]):        # none commanded at first: nothing drawn
        (t, first), = got["/app/setpoint_marker"][:1]
        assert t == 0 and first.deletions[0].id == "setpoint" and shown[0][0] > 0
    path = got["/vehicle/estimate_path"]
    assert np.diff([t for t, _ in path]).min() == 200_000_000
    assert [len(p.poses) for _, p in path] == [min(k + 1, 50) for k in range(len(path))]
    sp_path = got["/app/setpoint_path"]
    assert len(sp_path) == len(path) and not sp_path[0][1].poses and sp_path[-1][1].poses


def test_json_topics_carry_the_recorded_values(run):
    res, out = run
    _, msgs = _read(out / "run.mcap")
    s = res.series
    k = 700
    truth = json.loads(msgs["/vehicle/truth"][k].data)
    assert truth["z"] == s[k, COL["z"]] and truth["t"] == s[k, COL["t"]]
    import numpy as np

    k = int(np.nonzero(np.isfinite(s[:, COL["sp_z"]]))[0][-1])       # a setpoint commanded
    sp = json.loads(msgs["/app/setpoint"][k].data)
    assert sp["x"] == s[k, COL["sp_x"]] and sp["alt"] == -s[k, COL["sp_z"]]
    # the app's SET_POSITION_TARGET_LOCAL_NED in force: the line follower sets a yaw
    from cosim.outputs.mcap import commands

    cmds = commands(res.tlog.path)
    t0, first = cmds[0]
    assert first == {"yaw": 0.0, "frame": 1}
    k0 = t0 // 5_000_000
    assert "frame" not in json.loads(msgs["/app/setpoint"][k0 - 1].data)
    assert {k: v for k, v in json.loads(msgs["/app/setpoint"][k0].data).items()
            if k in first} == first
    motors = json.loads(msgs["/vehicle/motors"][k].data)
    assert [motors[f"u{i}"] for i in range(1, 5)] == [s[k, COL[f"u{i}"]] for i in range(1, 5)]
    phase = json.loads(msgs["/app/phase"][k].data)
    assert phase["phase"] == res.phases[int(s[k, -1])]
    hb = [json.loads(m.data) for m in msgs["/mavlink/HEARTBEAT"]]
    assert {d["mavpackettype"] for d in hb} == {"HEARTBEAT"} and {d["sysid"] for d in hb} >= {1}
    sp = [json.loads(m.data) for m in msgs["/mavlink/SET_POSITION_TARGET_LOCAL_NED"]]
    assert sp and all(isinstance(d["type_mask"], int) for d in sp)


@pytest.mark.flight          # png and raw fly the mission again with their images
@pytest.mark.parametrize("images", ["jpeg", "png", "raw"])
def test_image_payload_is_the_rendered_frame(run, images, tmp_path):
    """The first frame (the camera rendered again at the recorded pose) is the image's
    payload: JPEG by default (foxglove.CompressedImage, close to it), PNG (the same pixels),
    or raw on request (foxglove.RawImage, the same bytes, the encoding named)."""
    import cv2
    import numpy as np

    res, out = run
    if images != "jpeg":        # the default: the module's run
        res = run_scenario(with_set(res.scenario, {"timing.t_final_s": 0.5}), RunOptions(
            out_dir=tmp_path, mcap=True, images=images))
        out = tmp_path
    kinds, msgs = _read(out / "run.mcap")
    sc = res.scenario
    seed = int(np.random.SeedSequence([sc.seed, 2]).generate_state(1)[0])
    y = res.series[0]
    img = make_camera(sc.camera, sc.world, seed=seed).render(
        y[COL["x"]:COL["z"] + 1], tuple(y[COL["qw"]:COL["qz"] + 1]))
    data = msgs["/camera/image"][0].data
    if images == "raw":
        assert kinds["/camera/image"][0] == "foxglove.RawImage"
        assert img.tobytes() in data and b"rgb8" in data and b"camera" in data
        return
    assert kinds["/camera/image"][0] == "foxglove.CompressedImage"
    magic = b"\xff\xd8\xff" if images == "jpeg" else b"\x89PNG"
    k = data.index(magic)
    got = cv2.cvtColor(cv2.imdecode(np.frombuffer(data[k:], np.uint8), cv2.IMREAD_COLOR),
                       cv2.COLOR_BGR2RGB)
    assert images.encode() in data and b"camera" in data and got.shape == img.shape
    err = np.abs(got.astype(int) - img.astype(int))
    if images == "png":
        assert not err.any()
    else:
        assert err.mean() < 3.0, err.mean()
    assert len(data) < img.nbytes / 3


@pytest.mark.flight
def test_same_bytes_run_to_run(run, tmp_path):
    res, out = run
    again = run_scenario(res.scenario, RunOptions(out_dir=tmp_path, mcap=True))
    assert again.mcap.read_bytes() == (out / "run.mcap").read_bytes()


@pytest.mark.flight
def test_a_study_keeps_an_mcap_per_kept_run(tmp_path):
    import subprocess
    import sys

    def cosim(*args):
        return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                              text=True, timeout=600, cwd=ROOT)

    out = tmp_path / "mc"
    args = ["montecarlo", str(SEED), "-n", "2", "--seed", "3", "--executor", "serial",
            "--vary", "wind.n_mps=uniform(0,0.05)", "--set", "timing.t_final_s=2.0",
            "--out", str(out), "--quiet"]
    bad = cosim(*args, "--mcap")
    assert bad.returncode == 2 and "--mcap" in bad.stderr and "--keep-runs" in bad.stderr
    r = cosim(*args, "--keep-runs", "--mcap")
    assert r.returncode in (0, 1), r.stderr
    for run in ("000000", "000001"):
        _, msgs = _read(out / "runs" / run / "run.mcap")
        assert len(msgs["/vehicle/pose"]) == 400


def test_a_failed_write_of_a_realtime_runs_mcap_ends_it_as_a_recorder_failure(tmp_path,
                                                                            monkeypatch):
    """Each simulated second a real-time run writes its MCAP so far (`progress`); a write
    that fails there (a full disk) ends the run as the recorder's failure, with what was
    recorded written, not as a traceback."""
    from cosim.outputs import mcap as mcap_mod
    from cosim.scenario.records import ExitReason

    def full(*_a, **_k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mcap_mod.McapRun, "progress", full)
    sc = with_set(load_scenario(ROOT / "scenarios" / "mambo_hover.toml"),
                  {"timing.t_final_s": 3.0, "sensors.feed": "truth"})
    res = run_scenario(sc, RunOptions(out_dir=tmp_path, mcap=True, realtime=True,
                                      speed=50.0))
    assert res.exit_reason is ExitReason.COMPONENT_ERROR
    assert res.message.startswith("recorder: OSError") and "No space left" in res.message
    assert 0.9 < res.t_end_s < 1.2                   # at the first second's write
