"""The live view never keeps a run from ending (issue 43, item 1): with clients that misbehave
(one sends half an HTTP upgrade request and then nothing; one subscribes to the camera and
then stops reading), `cosim run --realtime --foxglove` ends when its run does, and both it and
`cosim sitl --foxglove` end within a few seconds of SIGINT or SIGTERM, with their exit
status. Real processes, real TCP clients, port 0 everywhere."""

from __future__ import annotations

import contextlib
import json
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"
STOP_S = 5.0                 # a signal ends the process within this
START_S = 120.0              # time to start (imports, FMU, compile checks)


class Proc:
    """A cosim process whose output is read by a thread; `url` once it says where its live
    view is."""

    def __init__(self, argv: list[str], cwd: Path) -> None:
        self.p = subprocess.Popen([sys.executable, "-m", "cosim.cli", *argv], cwd=cwd,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self.url_seen = threading.Event()
        self.url = ""
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.p.stdout:
            self.lines.append(line)
            m = re.search(r"live view on (ws://\S+)", line)
            if m:
                self.url = m.group(1)
                self.url_seen.set()

    def output(self) -> str:
        return "".join(self.lines)

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(10)


def half_handshake(url: str) -> socket.socket:
    """A TCP client that sends the first lines of a WebSocket upgrade request, then nothing."""
    host, port = url.removeprefix("ws://").rsplit(":", 1)
    s = socket.create_connection((host, int(port)), timeout=10)
    s.sendall(b"GET / HTTP/1.1\r\nHost: " + host.encode() + b"\r\nUpgrade: websocket\r\n")
    return s


def stalled_subscriber(url: str, topics=("/camera/image", "/vehicle/pose")):
    """A Foxglove WebSocket client that subscribes to `topics` and then reads no more: its
    receive buffer is small and its library stops reading once one message is queued."""
    conn = connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=20, max_size=None,
                   max_queue=1).__enter__()
    sock = conn.socket
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    subs = []
    end = time.monotonic() + 30
    while len(subs) < len(topics) and time.monotonic() < end:
        m = conn.recv(timeout=10)
        if isinstance(m, str) and json.loads(m)["op"] == "advertise":
            subs += [{"id": c["id"], "channelId": c["id"]} for c in json.loads(m)["channels"]
                     if c["topic"] in topics]
    assert len(subs) == len(topics), subs
    conn.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    return conn


@contextlib.contextmanager
def bad_clients(url: str, topics=("/camera/image", "/vehicle/pose")):
    half = half_handshake(url)
    sub = stalled_subscriber(url, topics)
    try:
        yield
    finally:
        half.close()
        with contextlib.suppress(Exception):
            sub.socket.close()


def wait_exit(proc: Proc, within: float) -> float:
    t0 = time.monotonic()
    try:
        proc.p.wait(within)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"still running {within} s later (killed):\n{proc.output()}")\
            from None
    return time.monotonic() - t0


def run_argv(tmp_path: Path, t_final: float) -> list[str]:
    return ["run", str(SEED), "--realtime", "--foxglove", "0", "--no-plots",
            "--set", f"timing.t_final_s={t_final}", "--out", str(tmp_path / "run")]


def test_a_realtime_run_ends_when_its_run_does_whatever_the_clients_do(tmp_path):
    proc = Proc(run_argv(tmp_path, 3.0), tmp_path)
    try:
        assert proc.url_seen.wait(START_S), proc.output()
        with bad_clients(proc.url):
            summary = tmp_path / "run" / "summary.json"
            end = time.monotonic() + START_S
            while not summary.exists():
                assert time.monotonic() < end and proc.p.poll() is None, proc.output()
                time.sleep(0.05)
            wait_exit(proc, STOP_S)
    finally:
        proc.kill()
    assert proc.p.returncode in (0, 1), proc.output()
    assert "Traceback" not in proc.output()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_realtime_run_with_bad_clients_ends_on_a_signal(tmp_path, sig):
    proc = Proc(run_argv(tmp_path, 60.0), tmp_path)
    try:
        assert proc.url_seen.wait(START_S), proc.output()
        with bad_clients(proc.url):
            time.sleep(1.0)
            proc.p.send_signal(sig)
            wait_exit(proc, STOP_S)
    finally:
        proc.kill()
    assert proc.p.returncode == 128 + sig, proc.output()
    assert (tmp_path / "run" / "summary.json").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_sitl_with_bad_clients_ends_on_a_signal(tmp_path, sig):
    sinks = []
    for _ in range(2):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        sinks.append(s)
    api, gcs = (s.getsockname()[1] for s in sinks)
    proc = Proc(["sitl", "--foxglove", "0", "--out", str(tmp_path / "sitl"),
                 "--api-remote", f"127.0.0.1:{api}", "--api-bind", "127.0.0.1:0",
                 "--gcs-remote", f"127.0.0.1:{gcs}", "--gcs-bind", "127.0.0.1:0"], tmp_path)
    try:
        assert proc.url_seen.wait(START_S), proc.output()
        with bad_clients(proc.url, ("/vehicle/pose", "/tf")):     # sitl has no camera
            time.sleep(1.0)
            proc.p.send_signal(sig)
            wait_exit(proc, STOP_S)
    finally:
        proc.kill()
        for s in sinks:
            s.close()
    # Ctrl-C and SIGTERM are sitl's documented normal stop (docs/ground-stations.md)
    assert proc.p.returncode == 0, proc.output()
    assert f"stopped by user ({signal.Signals(sig).name})" in proc.output()
    assert (tmp_path / "sitl" / "0" / "summary.json").exists()


def test_a_client_that_stops_reading_is_dropped_and_the_others_served(monkeypatch):
    """The relay drops a client that takes no data for SLOW_S (2 s here), while another
    client, reading, keeps receiving."""
    import foxglove

    from cosim.outputs import live_relay
    from cosim.outputs.live import LiveView

    monkeypatch.setattr(live_relay, "SLOW_S", 2.0)
    live = LiveView(port=0)
    stop = threading.Event()
    got: list[int] = []
    try:
        ch = foxglove.Channel("/flood", message_encoding="json", context=live.ctx)

        def flood() -> None:
            blob = {"x": "y" * 20_000}
            while not stop.is_set():
                ch.log(blob)
                time.sleep(0.01)
        threading.Thread(target=flood, daemon=True).start()
        good = connect(live.url, subprotocols=["foxglove.sdk.v1"], max_size=None).__enter__()
        subs = []
        while not subs:
            m = good.recv(timeout=10)
            if isinstance(m, str) and json.loads(m)["op"] == "advertise":
                subs = [{"id": c["id"], "channelId": c["id"]} for c in json.loads(m)["channels"]
                        if c["topic"] == "/flood"]
        good.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

        def read() -> None:
            with contextlib.suppress(Exception):
                while not stop.is_set():
                    if isinstance(good.recv(timeout=5), bytes):
                        got.append(1)
        threading.Thread(target=read, daemon=True).start()
        stalled_subscriber(live.url, ("/flood",))
        assert live.relay.clients == 2
        end = time.monotonic() + 20
        while live.relay.clients > 1:
            assert time.monotonic() < end, live.relay.clients
            time.sleep(0.1)
        n = len(got)
        time.sleep(1.0)
        assert len(got) > n + 10, (n, len(got))       # the reading client is still served
    finally:
        stop.set()
        assert live.close()
