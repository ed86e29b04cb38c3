"""`python -m mav.onboard` as a real process (SIL): ports, parameters over UDP with a pymavlink
ground station, signing, SIGTERM/SIGINT, HIL silence, bad arguments."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import UdpSim

from cosim.sim.sil import OnboardProcess
from mav.links import UdpLink

M = mavlink2
KEY_HEX = "a5" * 32


class Sil:
    """Onboard process + fixed-state simulator + a mavutil GCS on udpin (port 0)."""

    def __init__(self, tmp_path, *extra: str, gcs_kwargs=None, plant: bool = False) -> None:
        self.gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255,
                                              source_component=190, **(gcs_kwargs or {}))
        self.api_sink = UdpLink(("127.0.0.1", 0))
        gcs_port = self.gcs.port.getsockname()[1]
        self.proc = OnboardProcess("mambo", self.api_sink.local_address, ("127.0.0.1", gcs_port),
                                   tmp_path / "onboard.log", hil_timeout_s=5.0,
                                   extra_args=tuple(extra))
        self.sim = UdpSim(self.proc.ports["hil"], plant=plant)
        self.seen: list = []

    def pump(self, ticks: int = 1) -> None:
        for _ in range(ticks):
            self.sim.tick()
            while (m := self.gcs.recv_match(blocking=False)) is not None:
                self.seen.append(m)
            while self.api_sink.recv() is not None:
                pass

    def until(self, cond, timeout_s: float) -> None:
        end = self.sim.k + round(timeout_s * 200)
        while not cond():
            assert self.sim.k < end, f"timeout after {timeout_s} s of vehicle time"
            self.pump()

    def of(self, mtype: str) -> list:
        return [m for m in self.seen if m.get_type() == mtype]

    def close(self) -> str:
        self.proc.close()
        self.sim.close()
        self.gcs.close()
        self.api_sink.close()
        return self.proc.log_path.read_text()


def test_ports_line_and_param_round_trip(tmp_path):
    pfile = tmp_path / "mambo.params"
    pfile.write_text("MIS_TAKEOFF_ALT 1.25\n1\t1\tTPL_LAND_SPEED\t0.35\t9\n")
    s = Sil(tmp_path, "--params", str(pfile))
    try:
        assert set(s.proc.ports) == {"hil", "api", "gcs"} and all(s.proc.ports.values())
        gcs = s.gcs
        s.until(lambda: s.of("HEARTBEAT"), 1.0)
        gcs.target_system, gcs.target_component = 1, 1
        gcs.param_fetch_all()
        s.until(lambda: s.of("PARAM_VALUE") and len(gcs.params) == s.of("PARAM_VALUE")[0]
                .param_count, 2.0)
        pv = s.of("PARAM_VALUE")
        n = pv[0].param_count
        assert sorted(m.param_index for m in pv) == list(range(n)) and n > 10
        assert gcs.params["MIS_TAKEOFF_ALT"] == 1.25                  # from the file
        assert gcs.params["TPL_LAND_SPEED"] == pytest.approx(0.35)
        gcs.param_set_send("TPL_LAND_SPEED", 0.3)
        s.until(lambda: gcs.params["TPL_LAND_SPEED"] == pytest.approx(0.3), 0.5)
        gcs.param_set_send("TPL_LAND_SPEED", 50.0)                    # out of range
        s.until(lambda: any("Param rejected" in m.text for m in s.of("STATUSTEXT")), 0.5)
        s.pump(2)
        assert gcs.params["TPL_LAND_SPEED"] == pytest.approx(0.3)
        gcs.param_fetch_one("COM_OF_LOSS_T")
        n_before = len(s.of("PARAM_VALUE"))
        s.until(lambda: len(s.of("PARAM_VALUE")) > n_before, 0.5)
        last = s.of("PARAM_VALUE")[-1]
        assert (last.param_id, last.param_value) == ("COM_OF_LOSS_T", 1.0)
        # QGC's mission handshake: MISSION_COUNT 0
        gcs.waypoint_request_list_send()
        s.until(lambda: s.of("MISSION_COUNT"), 0.5)
        assert s.of("MISSION_COUNT")[0].count == 0
    finally:
        log = s.close()
    assert "exit 0" in log


def test_signing_over_udp(tmp_path):
    s = Sil(tmp_path, "--signing-key", KEY_HEX)
    intruder = mavutil.mavlink_connection(f"udpout:127.0.0.1:{s.proc.ports['gcs']}",
                                          source_system=255, source_component=190)
    try:
        gcs = s.gcs
        s.pump(5)        # mavutil starts in MAVLink 1 and switches on the first MAVLink 2 packet
        assert gcs.mavlink20()
        gcs.setup_signing(bytes.fromhex(KEY_HEX), sign_outgoing=True)   # wall-clock stamps
        gcs.target_system, gcs.target_component = 1, 1
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        # the vehicle's stamps start at 2024-01-01 + vehicle time, which the GCS finds stale;
        # once it has seen the GCS's signed heartbeat it signs with the GCS's newer time
        s.pump(2)
        s.seen.clear()
        s.pump(200)
        assert s.of("HEARTBEAT") and not s.of("BAD_DATA")
        assert all(m.get_signed() for m in s.seen)
        # an unsigned intruder cannot arm it; the signed GCS can
        intruder.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        s.pump(20)
        assert not gcs.motors_armed() and not s.of("COMMAND_ACK")
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        s.until(lambda: s.of("COMMAND_ACK"), 0.5)
        assert s.of("COMMAND_ACK")[0].result == M.MAV_RESULT_ACCEPTED
    finally:
        intruder.close()
        log = s.close()
    assert "'unsigned_rejected': 1" in log


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_exits_cleanly(tmp_path, sig):
    s = Sil(tmp_path)
    try:
        s.pump(50)
        s.proc.proc.send_signal(sig)
        assert s.proc.proc.wait(timeout=5.0) == 0
    finally:
        log = s.close()
    assert "exit 0" in log and "'ticks': 50" in log


@pytest.mark.skipif(not os.path.exists("/proc/net/udp"), reason="Linux's /proc/net/udp")
def test_exit_stats_count_kernel_drops(tmp_path):
    """A flood faster than the process drains (here: between two ticks) overflows its GCS
    socket; the exit stats say how much the kernel dropped, and with what it handled that is
    every datagram sent."""
    import socket

    s = Sil(tmp_path)
    n = 30_000
    hb = s.gcs.mav.heartbeat_encode(6, 8, 0, 0, 4).pack(s.gcs.mav)
    flood = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.pump(2)
        for _ in range(n):
            flood.sendto(hb, ("127.0.0.1", s.proc.ports["gcs"]))
        s.pump(200)                      # 256 datagrams a tick: what was queued is handled
        s.proc.proc.send_signal(signal.SIGTERM)
        assert s.proc.proc.wait(timeout=5.0) == 0
    finally:
        flood.close()
        s.close()
    st = s.proc.stats
    assert st["dropped_kernel_gcs"] > 0 and st["drain_deferred"] > 0
    assert st["rx_gcs"] + st["dropped_kernel_gcs"] == n
    assert "dropped_kernel_api" not in st and "dropped_kernel_hil" not in st   # 0: not printed


def test_hil_silence_exits(tmp_path):
    gcs_sink = UdpLink(("127.0.0.1", 0))
    api_sink = UdpLink(("127.0.0.1", 0))
    t0 = time.monotonic()
    with OnboardProcess("mambo", api_sink.local_address, gcs_sink.local_address,
                        tmp_path / "onboard.log", hil_timeout_s=0.5) as proc:
        sim = UdpSim(proc.ports["hil"], plant=False)
        for _ in range(20):
            sim.tick()
        assert proc.proc.wait(timeout=5.0) == 0
        sim.close()
    assert time.monotonic() - t0 < 4.0
    assert "no HIL input for 0.5 s" in (tmp_path / "onboard.log").read_text()
    gcs_sink.close()
    api_sink.close()


@pytest.mark.parametrize("args,msg", [
    (["--vehicle", "tello"], "invalid choice"),
    (["--hil-bind", "nohost"], "HOST:PORT"),
    (["--signing-key", "zz"], "64 hex digits"),
    (["--signing-key", "ab" * 8], "need 32"),
    (["--hil-timeout", "0"], "seconds > 0"),
    (["--hil-spin-us", "-5"], "0..1e6 microseconds"),
])
def test_bad_arguments_exit_2(args, msg):
    module = "mav" if args[0] == "--vehicle" else "mav.onboard"     # `python -m mav` too
    r = subprocess.run([sys.executable, "-m", module, *args], capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 2 and msg in r.stderr


def test_main_is_callable_in_process(tmp_path):
    from mav.onboard import main

    assert main(["--hil-bind", "127.0.0.1:0", "--hil-timeout", "0.2"]) == 0
