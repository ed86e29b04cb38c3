"""The live view (`--foxglove`): a Foxglove WebSocket protocol client (what Foxglove and
Lichtblick speak, under either of its names: foxglove.websocket.v1, what Studio 1.x and
Lichtblick ask for, or foxglove.sdk.v1) subscribes to a run's topics while it
flies and receives poses, camera images with their calibration, the JSON topics with their
schemas and the static scene; the run's results are the same with and without viewers.
Port 0 everywhere (the OS picks a free port)."""

from __future__ import annotations

import base64
import json
import re
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from cosim.load import load_scenario, with_set
from cosim.outputs.live import LiveView
from cosim.sim.master import RunOptions, run_scenario

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"
WAIT_S = 60.0
WANT = ("/tf_static", "/tf", "/vehicle/pose", "/world/scene", "/camera/image",
        "/camera/calibration", "/vehicle/truth", "/app/phase", "/app/vision")


class Client:
    """A minimal Foxglove WebSocket protocol client: advertisements, subscriptions, messages
    decoded by the schemas the server advertised (protobuf or JSON)."""

    def __init__(self, url: str, protocol: str = "foxglove.sdk.v1") -> None:
        self._conn = connect(url, subprotocols=[protocol], open_timeout=10,
                             max_size=None)
        self.ws = self._conn.__enter__()
        assert self.ws.subprotocol == protocol
        self.channels: dict[int, dict] = {}          # id -> advertisement
        self.subs: dict[int, dict] = {}              # subscription id -> channel
        self.got: dict[str, list] = {}               # topic -> [(log_time, message)]
        self._types: dict[int, type] = {}
        self.status: list[dict] = []                 # the server's status messages
        self.info: dict = {}                         # its serverInfo
        self.times: list[int] = []                   # its time messages (ns)

    def pump(self, until, timeout: float = WAIT_S, subscribe=()) -> None:
        end = time.monotonic() + timeout
        while not until():
            assert time.monotonic() < end, f"timed out; got {sorted(self.got)}, {self.status}"
            try:
                m = self.ws.recv(timeout=1.0)
            except TimeoutError:
                continue
            except ConnectionClosed as exc:
                got = {t: len(v) for t, v in self.got.items()}
                subs = sorted(c["topic"] for c in self.subs.values())
                raise AssertionError(f"closed ({exc}); got {got}, subscribed {subs}, "
                                     f"{self.status}") from None
            if isinstance(m, str):
                op = json.loads(m)
                if op["op"] == "advertise":
                    # a channel made while the client connects may be advertised twice
                    new = [c for c in op["channels"]
                           if c["topic"] in subscribe and c["id"] not in self.subs]
                    for c in op["channels"]:
                        self.channels[c["id"]] = c
                    if new:
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in new]
                        for c in new:
                            self.subs[c["id"]] = c
                        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif op["op"] == "serverInfo":
                    self.info = op
                elif op["op"] == "status":
                    self.status.append(op)
                    # the SDK's server may advertise a channel being made before it takes
                    # subscriptions to it ("Unknown channel ID: N"): ask again
                    m = re.fullmatch(r"Unknown channel ID: (\d+)", op.get("message", ""))
                    if m and int(m.group(1)) in self.subs:
                        time.sleep(0.1)
                        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": int(m.group(1)), "channelId": int(m.group(1))}]}))
                continue
            if m[0] == 2:                             # time (the `time` capability)
                self.times.append(struct.unpack_from("<Q", m, 1)[0])
                continue
            assert m[0] == 1                          # message data
            sub, t_ns = struct.unpack_from("<IQ", m, 1)
            ch = self.subs[sub]
            self.got.setdefault(ch["topic"], []).append((t_ns, self._decode(ch, m[13:])))

    def _decode(self, ch: dict, data: bytes):
        if ch["encoding"] == "json":
            return json.loads(data)
        cls = self._types.get(ch["id"])
        if cls is None:
            fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(ch["schema"]))
            pool = descriptor_pool.DescriptorPool()
            for fd in fds.file:
                pool.Add(fd)
            cls = self._types[ch["id"]] = message_factory.GetMessageClass(
                pool.FindMessageTypeByName(ch["schemaName"]))
        return cls.FromString(data)

    def count(self, topic: str) -> int:
        return len(self.got.get(topic, []))

    def close(self) -> None:
        self._conn.__exit__(None, None, None)


@pytest.mark.flight
def test_a_client_receives_the_run_live_and_the_run_is_unchanged(tmp_path):
    sc = with_set(load_scenario(SEED), {"timing.t_final_s": 4.0})
    live = LiveView(port=0, fps=2.0)          # the camera runs at 5 Hz: 2 Hz sent
    try:
        assert live.port > 0 and live.url.startswith("ws://127.0.0.1:")
        # the protocol's first name, as Foxglove Studio 1.x and Lichtblick ask for it
        client = Client(live.url, "foxglove.websocket.v1")
        out: dict = {}
        run = threading.Thread(target=lambda: out.setdefault("res", run_scenario(
            sc, RunOptions(out_dir=tmp_path / "live", realtime=True, live=live))))
        run.start()
        try:
            client.pump(lambda: all(client.count(t) >= 2 for t in WANT if "static" not in t
                                    and "scene" not in t) and client.count("/world/scene"),
                        subscribe=WANT)
        finally:
            run.join(WAIT_S)
            client.close()
    finally:
        live.close()
    assert not run.is_alive()
    # the viewer's clock is the simulation's: the `time` capability, sim time on the tick grid
    assert "time" in client.info["capabilities"] and client.times
    assert all(t % 5_000_000 == 0 for t in client.times) and client.times == sorted(
        client.times) and client.times[-1] <= 4e9
    ads = {c["topic"]: c for c in client.channels.values()}
    for topic in ("/vehicle/truth", "/app/setpoint", "/vehicle/motors", "/app/phase"):
        schema = json.loads(ads[topic]["schema"])        # every JSON topic has its schema
        assert ads[topic]["schemaEncoding"] == "jsonschema" and schema["properties"]
    assert ads["/vehicle/pose"]["schemaName"] == "foxglove.PoseInFrame"
    # poses: sim time stamps on the tick grid, every EVERY-th tick, the vehicle where the
    # recorded series has it
    res = out["res"]
    s = res.series
    for t_ns, pose in client.got["/vehicle/pose"]:
        k = t_ns // 5_000_000
        assert t_ns == k * 5_000_000 and pose.frame_id == "world"
        assert pose.pose.position.z == s[k, 3] and pose.pose.position.x == s[k, 1]
    truth = client.got["/vehicle/truth"][-1][1]
    assert set(truth) >= {"t", "x", "y", "z"}
    vision = dict(client.got["/app/vision"])          # the app's frame log, as it grows
    log = {int(round(rec[0] * 1e9)): rec for rec in res.frame_log}
    assert vision and set(vision) <= set(log)
    for t_ns, v in vision.items():                    # (t, flag_track, flag_marker, e_x_px, ..)
        assert v.get("flag_track") == log[t_ns][1] and v.get("e_x_px", log[t_ns][3]) == \
            log[t_ns][3]
    # the frame rate cap: images at least 0.5 s of sim time apart, each with its calibration
    t_img = [t for t, _ in client.got["/camera/image"]]
    assert np.diff(t_img).min() >= 0.495e9, t_img
    assert t_img == [t for t, _ in client.got["/camera/calibration"]][:len(t_img)]
    # an image with its calibration, both in the camera frame
    (_, img), (_, cal) = client.got["/camera/image"][0], client.got["/camera/calibration"][0]
    assert img.format == "jpeg" and img.frame_id == cal.frame_id == "camera"    # compressed
    assert cv2.imdecode(np.frombuffer(img.data, np.uint8), cv2.IMREAD_COLOR).shape == (
        120, 160, 3)
    assert cal.K[0] > 0
    (_, scene), = client.got["/world/scene"][:1]
    assert scene.entities[0].frame_id == "world"
    # the viewer changed nothing: the same series as a run without it
    plain = run_scenario(sc, RunOptions(out_dir=tmp_path / "plain"))
    assert np.array_equal(plain.series, res.series, equal_nan=True)


@pytest.mark.flight
def test_cosim_sitl_foxglove_serves_the_vehicle(tmp_path):
    """`cosim sitl --foxglove 0`: the address on stderr; poses while it runs."""
    sinks = []
    import socket

    for _ in range(2):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        sinks.append(s)
    api, gcs = (s.getsockname()[1] for s in sinks)
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sitl", "--duration", "30", "--foxglove", "0",
         "--out", str(tmp_path / "sitl"),
         "--api-remote", f"127.0.0.1:{api}", "--api-bind", "127.0.0.1:0",
         "--gcs-remote", f"127.0.0.1:{gcs}", "--gcs-bind", "127.0.0.1:0"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url = None
        for line in proc.stdout:
            m = re.search(r"live view on (ws://\S+)", line)
            if m:
                url = m.group(1)
                break
        assert url is not None
        client = Client(url)
        try:
            client.pump(lambda: client.count("/vehicle/pose") >= 5
                        and client.count("/tf_static") >= 1,
                        subscribe=("/vehicle/pose", "/tf_static"), timeout=WAIT_S)
        finally:
            client.close()
        # no camera in sitl: none advertised
        assert not {c["topic"] for c in client.channels.values()} & {
            "/camera/image", "/camera/calibration"}
        z = [m.pose.position.z for _, m in client.got["/vehicle/pose"]]
        assert all(abs(v) < 0.01 for v in z)           # on the ground: nobody flies it
        (_, tfs), = client.got["/tf_static"][:1]
        assert [tf.child_frame_id for tf in tfs.transforms] == ["world", "body_flu"]
    finally:
        proc.terminate()
        proc.wait(10)
        for s in sinks:
            s.close()
    assert proc.returncode == 0


@pytest.mark.parametrize("args", [["run", str(SEED), "--foxglove", "0"],
                                  ["run", str(SEED), "--realtime", "--foxglove", "70000"],
                                  ["run", str(SEED), "--realtime", "--foxglove", "0",
                                   "--foxglove-fps", "0"]])
def test_bad_foxglove_options_are_exit_2(args, tmp_path):
    r = subprocess.run([sys.executable, "-m", "cosim.cli", *args, "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--foxglove" in r.stderr


@pytest.mark.flight
def test_bench_live_measures_the_three_ways_and_the_series_is_the_same():
    from cosim.bench.live import bench_live, format_live

    r = bench_live(t_final_s=1.0, repeats=1)
    for way in ("none", "unwatched", "watched"):
        assert r[way]["same_series"] and r[way]["loop_us_per_tick"] > 0
    assert r["watched"]["client_messages"] > 50          # 1 s: 50 live ticks x topics
    assert "a client on every topic" in "\n".join(format_live(r))
