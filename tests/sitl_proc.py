"""`cosim sitl` as a subprocess on free loopback ports, for the ground-station and API client
tests (MAVSDK, MAVProxy, a pymavlink QGroundControl sequence). Not a test module itself."""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path


def free_udp_port() -> int:
    """A UDP port nobody is bound to right now (never 14540/14550: the OS picks)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def sitl(run_dir: Path, *, api_port: int | None = None, gcs_port: int | None = None,
         speed: float = 4.0, vehicle: str = "mambo", duration_s: float = 240.0
         ) -> Iterator[subprocess.Popen]:
    """Run `cosim sitl` with its API / GCS links sending to these loopback ports (a sink that
    nobody reads when None); always terminated, its output in run_dir/sitl.log."""
    sinks = []
    ports = []
    for port in (api_port, gcs_port):
        if port is None:
            sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sink.bind(("127.0.0.1", 0))
            sinks.append(sink)
            port = sink.getsockname()[1]
        ports.append(port)
    log = open(run_dir / "sitl.log", "w")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sitl", "--vehicle", vehicle, "--speed", str(speed),
         "--duration", str(duration_s),
         "--api-remote", f"127.0.0.1:{ports[0]}", "--api-bind", "127.0.0.1:0",
         "--gcs-remote", f"127.0.0.1:{ports[1]}", "--gcs-bind", "127.0.0.1:0"],
        cwd=run_dir, stdout=log, stderr=subprocess.STDOUT)
    try:
        yield proc
    except BaseException:
        log.flush()
        print((run_dir / "sitl.log").read_text()[-4000:])
        raise
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        log.close()
        for s in sinks:
            s.close()
