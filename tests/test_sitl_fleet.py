"""`cosim sitl` with several vehicles and a life of its own (issue 13, items 8 and 9).

Each test starts `cosim sitl` as a subprocess on free loopback ports (never 14540 / 14550),
flies it with a plain pymavlink client listening on one UDP port (as QGroundControl listens on
14550 for every vehicle), and stops it with a signal. Waits are bounded in wall-clock time with
generous margins; nothing depends on how fast the machine is (`--speed` only shortens them).
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from cosim.sim.fleet import instance_links

SPEED = 5.0               # simulated time / wall time
WAIT_S = 30.0             # wall-clock bound of any one wait
FORCE_DISARM = 21196
IN_AIR, ON_GROUND = M.MAV_LANDED_STATE_IN_AIR, M.MAV_LANDED_STATE_ON_GROUND


def free_ports(n: int = 1) -> tuple[list[int], list[socket.socket]]:
    """n consecutive free UDP ports on loopback, bound (the caller closes or keeps them)."""
    for _ in range(50):
        first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        first.bind(("127.0.0.1", 0))
        base = first.getsockname()[1]
        socks = [first]
        try:
            for p in range(base + 1, base + n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", p))
        except OSError:
            for s in socks:
                s.close()
            continue
        return list(range(base, base + n)), socks
    raise RuntimeError(f"no {n} consecutive free UDP ports")


class Sitl:
    """`cosim sitl` in a subprocess, its output in a file, its folder under tmp_path."""

    def __init__(self, tmp_path: Path, *args: str, speed: float = SPEED) -> None:
        self.out = tmp_path / "sitl"
        self.log_path = tmp_path / "sitl.log"
        self._log = open(self.log_path, "w")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cosim.cli", "sitl", "--speed", str(speed), "--out",
             str(self.out), *args], cwd=tmp_path, stdout=self._log, stderr=subprocess.STDOUT)

    def text(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def stop(self, sig: int = signal.SIGINT) -> tuple[int, str]:
        """Send `sig`, wait for the exit; (status, output). Kills it if it hangs."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(WAIT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
            rc = None
        self._log.close()
        return rc, self.log_path.read_text()

    def summary(self, instance: int) -> dict:
        return json.loads((self.out / str(instance) / "summary.json").read_text())


class Gcs:
    """A pymavlink ground station on one UDP port; keeps the last message of each type from
    each system, and every STATUSTEXT."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255,
                                               source_component=190)
        self.last: dict[tuple[int, str], object] = {}
        self.texts: list[tuple[int, str]] = []

    def pump(self, cond, what: str, timeout_s: float = WAIT_S) -> None:
        end = time.monotonic() + timeout_s
        while not cond():
            assert time.monotonic() < end, f"GCS: {what} not within {timeout_s} s"
            m = self.conn.recv_match(blocking=True, timeout=0.1)
            if m is None or m.get_type() == "BAD_DATA":
                continue
            key = (m.get_srcSystem(), m.get_type())
            self.last[key] = m
            if m.get_type() == "STATUSTEXT":
                self.texts.append((m.get_srcSystem(), m.text))

    def get(self, sysid: int, mtype: str):
        return self.last.get((sysid, mtype))

    def command(self, sysid: int, command: int, *params: float) -> int:
        """COMMAND_LONG to `sysid`; its COMMAND_ACK's result."""
        self.last.pop((sysid, "COMMAND_ACK"), None)
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(sysid, 1, command, 0, *p)

        def acked() -> bool:
            a = self.get(sysid, "COMMAND_ACK")
            return a is not None and a.command == command

        self.pump(acked, f"ack of command {command} from sysid {sysid}")
        return self.get(sysid, "COMMAND_ACK").result

    def landed(self, sysid: int) -> int | None:
        m = self.get(sysid, "EXTENDED_SYS_STATE")
        return m.landed_state if m is not None else None

    def armed(self, sysid: int) -> bool:
        hb = self.get(sysid, "HEARTBEAT")
        return bool(hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    def ready(self, sysid: int) -> bool:
        """SYS_STATUS's pre-arm check healthy (QGC's "Ready To Fly", MAVSDK's is_armable): on
        the sensors, once the estimator's attitude is aligned."""
        m = self.get(sysid, "SYS_STATUS")
        return m is not None and bool(m.onboard_control_sensors_health
                                      & M.MAV_SYS_STATUS_PREARM_CHECK)

    def take_off(self, sysid: int) -> None:
        self.pump(lambda: self.ready(sysid), f"sysid {sysid} ready to arm")
        assert self.command(sysid, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        nan = math.nan
        assert self.command(sysid, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan,
                            nan) == M.MAV_RESULT_ACCEPTED

    def close(self) -> None:
        self.conn.close()


def no_children_left(children: list[psutil.Process]) -> bool:
    return not [c for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]


@contextlib.contextmanager
def sitl_and_gcs(tmp_path: Path, *args: str, count: int = 1, sig: int = signal.SIGINT):
    """`cosim sitl` on free ports: its GCS links send to a pymavlink client (`gcs`), its API
    links to `count` consecutive free ports (`sitl.api_sinks`: bound, unread unless a test
    reads them). Stopped by `sig` at the end: `sitl.rc`, `sitl.output`, `sitl.children`."""
    api_ports, sinks = free_ports(count)
    (gcs_port,), (g,) = free_ports(1)
    g.close()
    gcs = Gcs(gcs_port)
    sitl = Sitl(tmp_path, "--duration", "600", "-n", str(count),
                "--api-remote", f"127.0.0.1:{api_ports[0]}", "--api-bind", "127.0.0.1:0",
                "--gcs-remote", f"127.0.0.1:{gcs_port}", "--gcs-bind", "127.0.0.1:0", *args)
    sitl.api_sinks = sinks
    try:
        yield sitl, gcs
        sitl.children = psutil.Process(sitl.proc.pid).children(recursive=True)
    finally:
        sitl.rc, sitl.output = sitl.stop(sig)
        gcs.close()
        for s in sinks:
            s.close()


# ------------------------------------------------------------------ item 8: instances, fleets
def test_px4_instance_ports():
    assert instance_links(0) == {"api": (("127.0.0.1", 14580), ("127.0.0.1", 14540)),
                                 "gcs": (("127.0.0.1", 18570), ("127.0.0.1", 14550))}
    assert instance_links(1) == {"api": (("127.0.0.1", 14581), ("127.0.0.1", 14541)),
                                 "gcs": (("127.0.0.1", 18571), ("127.0.0.1", 14550))}
    # vehicle k = 2 of a fleet starting at instance 3: PX4's ports of instance 5, except
    # what is given: the first vehicle's, plus k; port 0 stays 0; the GCS remote is shared
    got = instance_links(5, 2, api_remote=("10.0.0.2", 15000), api_bind=("0.0.0.0", 0),
                         gcs_remote=("10.0.0.3", 14555))
    assert got == {"api": (("0.0.0.0", 0), ("10.0.0.2", 15002)),
                   "gcs": (("127.0.0.1", 18575), ("10.0.0.3", 14555))}


def test_instance_offsets_and_sysids_in_a_real_run(tmp_path):
    """`-i 1 -n 2`: sysids 2 and 3; the API links send to a free base B and B + 1, both GCS
    links to one port; SIGTERM is a normal stop."""
    with sitl_and_gcs(tmp_path, "-i", "1", count=2, sig=signal.SIGTERM) as (sitl, gcs):
        gcs.pump(lambda: gcs.get(2, "HEARTBEAT") and gcs.get(3, "HEARTBEAT"),
                 "heartbeats of sysids 2 and 3 on the GCS port")
        parser = M.MAVLink(None)
        for sock, sysid in zip(sitl.api_sinks, (2, 3), strict=True):
            sock.settimeout(0.2)
            seen: set[int] = set()
            end = time.monotonic() + WAIT_S
            while not seen and time.monotonic() < end:
                try:
                    data = sock.recv(65535)
                except TimeoutError:
                    continue
                seen |= {m.get_srcSystem() for m in parser.parse_buffer(data) or []}
            assert seen == {sysid}, (sock.getsockname(), seen)
        api_b = sitl.api_sinks[0].getsockname()[1]
    assert sitl.rc == 0, sitl.output
    assert "stopped by user (SIGTERM)" in sitl.output and "FAILED" not in sitl.output
    assert no_children_left(sitl.children)
    for instance in (1, 2):
        s = sitl.summary(instance)
        assert s["sitl"]["sysid"] == instance + 1 and s["exit_reason"] == "stopped"
        assert s["sitl"]["links"]["api"]["remote"] == f"127.0.0.1:{api_b + instance - 1}"


@pytest.mark.flight
def test_two_vehicles_in_one_world_flown_by_one_client(tmp_path):
    with sitl_and_gcs(tmp_path, count=2) as (sitl, gcs):
        gcs.pump(lambda: gcs.get(1, "GLOBAL_POSITION_INT") and gcs.get(2, "GLOBAL_POSITION_INT")
                 and gcs.get(1, "HEARTBEAT") and gcs.get(2, "HEARTBEAT"), "both vehicles")
        # vehicle 2 starts 1 m east of vehicle 1, and is shown there
        p1, p2 = gcs.get(1, "GLOBAL_POSITION_INT"), gcs.get(2, "GLOBAL_POSITION_INT")
        east_m = (p2.lon - p1.lon) * 1e-7 * math.radians(1) * 6378137 * math.cos(
            math.radians(p1.lat * 1e-7))
        assert abs(east_m - 1.0) < 0.05 and abs(p2.lat - p1.lat) < 5, (p1, p2)
        for sysid in (1, 2):
            gcs.take_off(sysid)
        gcs.pump(lambda: gcs.landed(1) == IN_AIR and gcs.landed(2) == IN_AIR, "both in air")
        for sysid in (1, 2):
            assert gcs.command(sysid, M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
        gcs.pump(lambda: all(gcs.landed(i) == ON_GROUND and not gcs.armed(i) for i in (1, 2)),
                 "both landed and disarmed")
        assert sitl.proc.poll() is None
    assert sitl.rc == 0, sitl.output
    assert "stopped by user (SIGINT)" in sitl.output and "FAILED" not in sitl.output
    for instance in (0, 1):
        s = sitl.summary(instance)
        assert s["sitl"]["respawns"] == []
        assert s["onboard_stats"]["commands"] >= 3            # arm, take off, land
        assert (sitl.out / str(instance) / "flight.tlog").stat().st_size > 10_000


# ------------------------------------------------------------------ item 9: lifetime
@pytest.mark.flight
def test_a_crash_respawns_the_vehicle_on_the_same_connection(tmp_path):
    with sitl_and_gcs(tmp_path) as (sitl, gcs):
        gcs.pump(lambda: gcs.get(1, "HEARTBEAT") is not None, "heartbeat")
        gcs.take_off(1)

        def up() -> bool:
            p = gcs.get(1, "GLOBAL_POSITION_INT")
            return gcs.landed(1) == IN_AIR and p is not None and p.relative_alt > 800

        gcs.pump(up, "in air above 0.8 m")
        # kill in the air: the vehicle falls and hits the floor at ~4 m/s
        assert gcs.command(1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                           FORCE_DISARM) == M.MAV_RESULT_ACCEPTED
        gcs.pump(lambda: (1, "Respawned at start, disarmed (crashed)") in gcs.texts,
                 "respawn notice")
        for key in [k for k in gcs.last if k[1] in ("HEARTBEAT", "EXTENDED_SYS_STATE",
                                                     "GLOBAL_POSITION_INT")]:
            del gcs.last[key]                 # from here on: what the respawned vehicle says
        gcs.pump(lambda: gcs.landed(1) == ON_GROUND and gcs.get(1, "HEARTBEAT")
                 and not gcs.armed(1) and gcs.get(1, "GLOBAL_POSITION_INT"),
                 "on the ground, disarmed")
        assert abs(gcs.get(1, "GLOBAL_POSITION_INT").relative_alt) < 50      # mm: at home
        gcs.take_off(1)                      # and it flies again
        gcs.pump(up, "in air again")
        assert sitl.proc.poll() is None, "cosim sitl ended after the crash"
        assert "crashed" in sitl.text() and "respawned" in sitl.text()
    assert sitl.rc == 0, sitl.output
    respawns = sitl.summary(0)["sitl"]["respawns"]
    assert [r["reason"] for r in respawns] == ["crashed"], respawns
    assert "hard touchdown" in respawns[0]["message"]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_is_a_normal_stop_with_outputs_and_no_child_left(tmp_path, sig):
    with sitl_and_gcs(tmp_path, "--mcap", sig=sig) as (sitl, gcs):
        gcs.pump(lambda: gcs.get(1, "HEARTBEAT") is not None, "heartbeat")
    name = signal.Signals(sig).name
    out = sitl.output
    assert sitl.rc == 0, out
    assert f"cosim sitl: stopped by user ({name})" in out
    assert "FAILED" not in out and "Traceback" not in out
    assert no_children_left(sitl.children)
    folder = sitl.out / "0"
    s = sitl.summary(0)
    assert s["exit_reason"] == "stopped" and s["message"] == "stopped by user"
    assert s["sim_time_s"] > 0 and s["sitl"]["sysid"] == 1
    for f in ("flight.tlog", "timeseries.csv", "run.mcap"):
        assert (folder / f).stat().st_size > 0, f
    assert not (folder / ".series.f64").exists()


@pytest.mark.flight
def test_duration_is_a_normal_stop_and_a_failed_part_is_status_1(tmp_path):
    (gcs_port, api_port), socks = free_ports(2)
    links = ("--api-remote", f"127.0.0.1:{api_port}", "--api-bind", "127.0.0.1:0")
    sitl = Sitl(tmp_path, "--duration", "1", *links, "--gcs-remote", f"127.0.0.1:{gcs_port}",
                "--gcs-bind", "127.0.0.1:0", speed=20.0)
    try:
        rc = sitl.proc.wait(WAIT_S)
    finally:
        _, out = sitl.stop()
    assert rc == 0 and "cosim sitl: duration reached" in out, out
    rows = (sitl.out / "0" / "timeseries.csv").read_text().splitlines()
    assert len(rows) == 1 + 200 // 20          # 1 s of 5 ms ticks, one row in 20
    summary = json.loads((sitl.out / "0" / "summary.json").read_text())
    # on its sensors by default: paper 1's release, the Mambo's estimator
    assert summary["estimator"] == "paper 1's release (TPL_EST_TYPE 2)"
    # the GCS link cannot bind (the port is taken): the flight stack's links failed
    taken = socks[0].getsockname()[1]
    sitl = Sitl(tmp_path, "--duration", "600", *links, "--gcs-bind", f"127.0.0.1:{taken}",
                "--gcs-remote", f"127.0.0.1:{gcs_port}")
    try:
        rc = sitl.proc.wait(WAIT_S)
    finally:
        _, out = sitl.stop()
        for s in socks:
            s.close()
    assert rc == 1, out
    assert "cosim sitl: failed: vehicle 0: onboard: cannot bind" in out, out


def test_feed_truth_flies_the_vehicles_on_the_plants_state(tmp_path):
    with sitl_and_gcs(tmp_path, "--feed", "truth") as (sitl, gcs):
        gcs.pump(lambda: gcs.ready(1), "ready to arm")
        assert gcs.command(1, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    summary = json.loads((sitl.out / "0" / "summary.json").read_text())
    assert summary["estimator"] == "none (truth ODOMETRY)"
