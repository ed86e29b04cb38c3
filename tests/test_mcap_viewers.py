"""run.mcap as viewers read it: every topic has a schema; every JSON message of a seed run and
of an E1 run (the front camera in the room, visual servoing) validates against its channel's
JSON Schema; the protobuf messages decode with the schemas the file carries; the frame
transforms put the vehicle above the floor, right way up, near the map origin; the 3D world
of E1 (walls, bar, posters) is in the scene; each camera has its calibration."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from jsonschema import Draft202012Validator
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from cosim.load import load_scenario, with_set
from cosim.outputs.mcap import TOPICS
from cosim.sim.master import RunOptions, run_scenario
from mav.rotations import R_from_quat

pytestmark = pytest.mark.flight     # whole flights (make test-fast leaves them out)

ROOT = Path(__file__).resolve().parents[1]


def _run(tmp_path_factory, name: str, t_final: float):
    out = tmp_path_factory.mktemp(name)
    sc = with_set(load_scenario(ROOT / "scenarios" / f"{name}.toml"),
                  {"timing.t_final_s": t_final})
    return run_scenario(sc, RunOptions(out_dir=out, mcap=True))


@pytest.fixture(scope="module")
def seed(tmp_path_factory):
    return _run(tmp_path_factory, "mambo_seed_track", 8.0)


@pytest.fixture(scope="module")
def e1(tmp_path_factory):
    return _run(tmp_path_factory, "bebop2_vs_e1", 8.0)


class _Json(McapDecoderFactory):
    def decoder_for(self, message_encoding, schema):
        return json.loads if message_encoding == "json" else None


@functools.cache
def read(path: Path) -> dict[str, tuple[str, str, list]]:
    """{topic: (schema name, schema encoding, [(log_time, message)])}: JSON messages as dicts,
    the others decoded by the protobuf schemas the file carries."""
    out: dict[str, tuple[str, str, list]] = {}
    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory(), _Json()])
        s = r.get_summary()
        for c in s.channels.values():
            sch = s.schemas.get(c.schema_id)
            out[c.topic] = (sch.name if sch else "", sch.encoding if sch else "", [])
        for _, ch, m, dec in r.iter_decoded_messages(log_time_order=True):
            out[ch.topic][2].append((m.log_time, dec))
    return out


def json_schemas(path: Path) -> dict[str, dict]:
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
        return {c.topic: json.loads(s.schemas[c.schema_id].data) for c in s.channels.values()
                if c.message_encoding == "json"}


@pytest.mark.parametrize("which", ["seed", "e1"])
def test_every_topic_has_a_schema_and_every_json_message_validates(which, request):
    res = request.getfixturevalue(which)
    topics = read(res.mcap)
    for topic, name in TOPICS.items():
        assert topics[topic][0] == name, topic
    mav = [t for t in topics if t.startswith("/mavlink/")]
    assert {"/mavlink/HEARTBEAT", "/mavlink/ATTITUDE"} <= set(mav)
    assert set(topics) == set(TOPICS) | set(mav)
    schemas = json_schemas(res.mcap)
    checked = 0
    for topic, (name, encoding, msgs) in topics.items():
        assert name and encoding in ("protobuf", "jsonschema"), topic   # no empty schema
        assert msgs, topic
        if encoding != "jsonschema":
            continue
        schema = schemas[topic]
        Draft202012Validator.check_schema(schema)
        assert schema["properties"], topic          # fields a viewer can plot
        v = Draft202012Validator(schema)
        for _, m in msgs:
            v.validate(m)
            checked += 1
    assert checked > 5000
    # the schemas are strict: an unknown field or a wrong type is refused
    v = Draft202012Validator(schemas["/vehicle/truth"])
    ok = topics["/vehicle/truth"][2][0][1]
    assert v.is_valid(ok)
    assert not v.is_valid({**ok, "z": "1.0"}) and not v.is_valid({**ok, "extra": 1.0})
    assert not v.is_valid({k: x for k, x in ok.items() if k != "t"})   # t is always there


def test_vision_fields_are_the_apps_frame_columns(seed, e1):
    for res in (seed, e1):
        schema = json_schemas(res.mcap)["/app/vision"]
        cols = res.frame_columns or ("t", "flag_track", "flag_marker", "e_x_px", "e_y_px")
        assert list(schema["properties"]) == list(cols[1:])
    msgs = read(e1.mcap)["/app/vision"][2]
    assert len(msgs) == len(e1.frame_log) and "eps_px" in msgs[-1][1]


def test_the_apps_commands_are_in_the_setpoint(e1):
    """Visual servoing commands relative moves (MAV_FRAME_BODY_OFFSET_NED): /app/setpoint
    carries each move in force (it had no position setpoint, and was empty)."""
    moves = [m for _, m in read(e1.mcap)["/app/setpoint"][2] if "dx" in m]
    assert moves and all(m["frame"] == 9 and {"dy", "dz", "dyaw"} <= set(m) for m in moves)
    assert any(m["dx"] != 0.0 for m in moves)


def _transform(tf) -> tuple[np.ndarray, np.ndarray]:
    q = tf.rotation
    return R_from_quat((q.w, q.x, q.y, q.z)), np.array(
        [tf.translation.x, tf.translation.y, tf.translation.z])


def _frames(topics) -> tuple[tuple, list, list]:
    static, flu = topics["/tf_static"][2][0][1].transforms     # the same every second
    assert (flu.parent_frame_id, flu.child_frame_id) == ("body", "body_flu")
    R_bf, _ = _transform(flu)
    assert np.allclose(R_bf @ np.array([0.0, 0.0, 1.0]), [0.0, 0.0, -1.0])   # z up = -z FRD
    body = [(t, tf) for t, m in topics["/tf"][2] for tf in m.transforms
            if tf.child_frame_id == "body"]
    cam = [(t, tf) for t, m in topics["/tf"][2] for tf in m.transforms
           if tf.child_frame_id == "camera"]
    return static, body, cam


@pytest.mark.parametrize("which", ["seed", "e1"])
def test_transforms_put_the_vehicle_above_the_floor_right_way_up(which, request):
    res = request.getfixturevalue(which)
    topics = read(res.mcap)
    static, body, cam = _frames(topics)
    assert (static.parent_frame_id, static.child_frame_id) == ("map", "world")
    R_mw, t_mw = _transform(static)
    assert len(body) == res.ticks
    a = res.scenario.world.arena
    half = 0.5 * max(a[1] - a[0], a[3] - a[2])
    z, up = [], []
    for _, tf in body:
        assert tf.parent_frame_id == "world"
        R_wb, t_wb = _transform(tf)
        p = R_mw @ t_wb + t_mw                     # the body's origin in the map frame
        assert abs(p[0]) <= half and abs(p[1]) <= half     # centred: inside the arena
        z.append(p[2])
        up.append((R_mw @ R_wb @ np.array([0.0, 0.0, -1.0]))[2])   # body "up" (-z FRD)
    z = np.array(z)
    # never under the floor (z = 0 in the map) but for the plant's ground contact, which
    # lets the resting body sink 0.25 mm
    assert z.min() > -0.001
    assert z.max() > 0.4                          # and it flew
    assert min(up) > 0.9                          # right way up (not mirrored, not flipped)
    # the floor's top is z = 0 in the map: the slab of the scene lies under it
    scene = topics["/world/scene"][2][0]
    floor = scene[1].entities[0].cubes[0]
    top = floor.pose.position.z - 0.5 * floor.size.z          # NED: up is -z
    assert abs((R_mw @ np.array([floor.pose.position.x, floor.pose.position.y, top])
                + t_mw)[2]) < 1e-9
    # the map origin is the arena's centre
    centre = R_mw @ np.array([0.5 * (a[0] + a[1]), 0.5 * (a[2] + a[3]), 0.0]) + t_mw
    assert np.allclose(centre, 0.0, atol=1e-9)
    # the camera frame: one transform per image, its optical axis where the camera looks
    assert len(cam) == len(topics["/camera/image"][2])
    (t0, tf_b), (t1, tf_c) = body[0], cam[0]
    assert t0 == t1 == 0 and tf_c.parent_frame_id == "body"
    R_wb, _ = _transform(tf_b)
    R_bc, t_bc = _transform(tf_c)
    assert np.allclose(t_bc, res.scenario.camera.mount_B)
    axis = R_mw @ R_wb @ R_bc @ np.array([0.0, 0.0, 1.0])
    if which == "seed":
        assert axis[2] < -0.99                    # the Mambo's camera looks down
    else:
        assert abs(axis[2]) < 0.05 and axis[1] > 0.99   # the Bebop's looks ahead: north = +y


def test_camera_calibration_matches_each_image(seed, e1):
    for res in (seed, e1):
        topics = read(res.mcap)
        cal, img = topics["/camera/calibration"][2], topics["/camera/image"][2]
        assert len(cal) == len(img) > 0
        K = res.scenario.camera.K()
        for (tc, c), (ti, i) in zip(cal, img, strict=True):
            assert tc == ti and c.frame_id == i.frame_id == "camera"
            assert i.format == "jpeg"                          # the default
            h, w = cv2.imdecode(np.frombuffer(i.data, np.uint8), cv2.IMREAD_COLOR).shape[:2]
            assert (c.width, c.height) == (w, h)
            assert np.allclose(np.array(c.K).reshape(3, 3), K)
            assert np.allclose(np.array(c.P).reshape(3, 4)[:, :3], K)


def test_the_3d_world_is_in_the_scene(seed, e1):
    flat = read(seed.mcap)["/world/scene"][2][0][1].entities[0]
    assert flat.frame_id == "world" and len(flat.lines) == len(seed.scenario.world.track) + 1
    assert len(flat.cylinders) == 1                               # the end marker
    room = read(e1.mcap)["/world/scene"][2][0][1].entities[0]
    w = e1.scenario.world
    # 4 walls, the bar's 4 sides (it reaches the ceiling: no top), 2 boxes x (4 sides + top),
    # 2 posters x (frame + picture); no ceiling (it would hide the room from above)
    assert len(w.scene.columns) == 1 and len(w.scene.boxes) == len(w.scene.posters) == 2
    assert len(room.triangles) == 4 + 4 + 2 * 5 + 2 * 2
    assert all(len(t.points) >= 3 and len(t.points) % 3 == 0 for t in room.triangles)
    pts = np.array([[p.x, p.y, p.z] for t in room.triangles for p in t.points])
    a = w.arena
    assert pts[:, 0].min() >= a[0] - 1e-6 and pts[:, 0].max() <= a[1] + 1e-6
    assert pts[:, 2].max() <= 1e-6 and pts[:, 2].min() >= -w.scene.room.height - 1e-6
    bar = w.scene.columns[0]
    near_bar = [t for t in room.triangles
                if math.hypot(t.points[0].x - bar.center[0], t.points[0].y - bar.center[1]) < 0.1]
    assert near_bar and all(t.color.g > 0.5 and t.color.r < 0.1 for t in near_bar)   # green


def test_vehicle_model_follows_the_body_frame(seed):
    model = read(seed.mcap)["/vehicle/model"][2][0]
    e = model[1].entities[0]
    assert e.frame_id == "body" and e.frame_locked and len(e.cubes) == 2
    assert len(e.cylinders) == 4 and len(e.arrows) == 1


def test_an_e1_file_is_small(e1):
    """E1's 856 x 480 frames as JPEG in zstd chunks: the whole run's file (22.5 s) must stay
    under 30 MB (it measured 29.0 MB, docs/viewers.md; 264 MB with raw frames). This shorter
    run keeps to that rate."""
    assert e1.mcap.stat().st_size <= 30e6 * e1.t_end_s / 22.46, e1.mcap.stat().st_size
