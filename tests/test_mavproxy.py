"""ACCEPTANCE: MAVProxy (a real ground station, headless, scripted on stdin) flies `cosim sitl`.

`mavproxy.py --master udpin:127.0.0.1:PORT` on the vehicle's GCS link, commands written to its
stdin; the vehicle watched on its API link with pymavlink and, afterwards, in the tlog MAVProxy
writes (both directions, wall-clock stamps; the vehicle's own time from its telemetry):
parameters fetched (the FTP request NAK'd at once, no FTP retry; the list itself in < 1 s of
vehicle time), mode change, `arm throttle`, `takeoff 1.2`, in the air at the take-off height,
land, disarmed. Nothing says "fence breach".

MAVProxy 1.8.74/1.8.75 with pymavlink 2.4.50 cannot change a PX4 vehicle's mode by name: its
`mode LOITER` passes pymavlink's px4_map tuple where set_mode_px4 expects the name, and fails
inside MAVProxy before anything is sent ("required argument is not a float"). The test checks
that this is still the reason (if a MAVProxy fixes it, the name works and is used), then
changes modes with MAVProxy's own `long DO_SET_MODE 1 4 3` / `long NAV_LAND`.

No step depends on how fast the machine is: each waits (bounded) for what the vehicle says.
"""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from sitl_proc import free_udp_port, sitl

pytestmark = pytest.mark.flight     # whole flights (make test-fast leaves them out)

M = mavlink2
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
STEP_S = 20.0             # wall-clock bound of every step
BUG = "required argument is not a float"


class Proxy:
    """mavproxy.py in a subprocess: stdin commands, stdout lines collected by a thread."""

    def __init__(self, port: int, cwd: Path) -> None:
        self.p = subprocess.Popen(
            [sys.executable, str(MAVPROXY), "--master", f"udpin:127.0.0.1:{port}", "--nodtr"],
            cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, bufsize=1)
        self.lines: list[str] = []
        self.q: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.p.stdout:
            self.lines.append(line.rstrip())
            self.q.put(line)

    def cmd(self, text: str) -> None:
        self.lines.append(f">>> {text}")
        self.p.stdin.write(text + "\n")
        self.p.stdin.flush()

    def mark(self) -> int:
        return len(self.lines)

    def expect(self, *words: str, since: int = 0, timeout_s: float = STEP_S) -> str:
        """The first output line from line `since` on holding any of `words`."""
        end = time.monotonic() + timeout_s
        seen = since
        while True:
            for line in self.lines[seen:]:
                if not line.startswith(">>>") and any(w in line for w in words):
                    return line
            seen = len(self.lines)
            left = end - time.monotonic()
            assert left > 0, f"MAVProxy did not print any of {words} within {timeout_s} s"
            try:
                self.q.get(timeout=min(left, 0.2))
            except queue.Empty:
                pass

    def close(self) -> None:
        self.p.kill()            # MAVProxy does not always exit on SIGTERM
        self.p.wait(10)


class Watch:
    """The vehicle's API link, decoded by pymavlink (what the vehicle says of itself). A thread
    reads it all the time: read only while waiting, the socket's buffer filled with telemetry
    during MAVProxy's steps on a loaded host, and a STATUSTEXT sent meanwhile was dropped."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=200)
        self.hb = self.ext = self.lpos = self.sys = None
        self.texts: list[str] = []
        self.reached: list[int] = []
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                m = self.conn.recv_match(blocking=True, timeout=0.2)
            except OSError:                  # the link closed
                return
            if m is None:
                continue
            t = m.get_type()
            if t == "HEARTBEAT":
                self.hb = m
            elif t == "EXTENDED_SYS_STATE":
                self.ext = m
            elif t == "SYS_STATUS":
                self.sys = m
            elif t == "LOCAL_POSITION_NED":
                self.lpos = m
            elif t == "STATUSTEXT":
                self.texts.append(m.text)
            elif t == "MISSION_ITEM_REACHED":
                self.reached.append(m.seq)

    def until(self, cond, what: str, timeout_s: float = STEP_S) -> None:
        end = time.monotonic() + timeout_s
        while not cond(self):
            assert time.monotonic() < end, f"vehicle: {what} not within {timeout_s} s"
            time.sleep(0.02)

    def close(self) -> None:
        self._stop.set()
        self._reader.join(5.0)
        self.conn.close()

    @property
    def mode(self) -> str:
        return mavutil.mode_string_v10(self.hb) if self.hb else ""

    @property
    def armed(self) -> bool:
        return bool(self.hb and self.hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def ready(self) -> bool:
        """The pre-arm check healthy (on the sensors: once the estimator is aligned), what a
        MAVProxy user waits for before `arm throttle`."""
        return bool(self.sys and self.sys.onboard_control_sensors_health
                    & M.MAV_SYS_STATUS_PREARM_CHECK)

    @property
    def landed(self) -> int:
        return self.ext.landed_state if self.ext else -1


def _change_mode(mp: Proxy, w: Watch, name: str, main: int, sub: int) -> None:
    since = mp.mark()
    mp.cmd(f"mode {name}")
    line = mp.expect(BUG, f"Mode {name}", since=since)
    if BUG in line:          # the client bug (module docstring): nothing was sent
        assert w.mode != name
        mp.cmd(f"long DO_SET_MODE 1 {main} {sub}")
    w.until(lambda v: v.mode == name, f"mode {name}")


def _tlog_checks(tlog: Path) -> dict:
    """From MAVProxy's tlog: its FTP open requests and their answers, and the vehicle time the
    parameter list took (between the telemetry just before the request and just after the
    last value)."""
    log = mavutil.mavlink_connection(str(tlog))
    ftp_out, ftp_in = [], []
    t_req = t_before = t_last_param = t_after = None
    count = None
    got = set()
    while (m := log.recv_match()) is not None:
        t = m.get_type()
        if t == "FILE_TRANSFER_PROTOCOL":
            (ftp_out if m.get_srcSystem() == 255 else ftp_in).append(bytes(m.payload[:6]))
        elif t == "PARAM_REQUEST_LIST" and t_req is None:
            t_req = t_before
        elif t == "PARAM_VALUE" and t_req is not None:
            got.add(m.param_index)
            count = m.param_count
            if len(got) == count:
                t_last_param = True
        elif hasattr(m, "time_boot_ms") and m.get_srcSystem() == 1:
            if t_req is None:
                t_before = m.time_boot_ms
            elif t_last_param is True and t_after is None:
                t_after = m.time_boot_ms
    return {"ftp_out": ftp_out, "ftp_in": ftp_in, "count": count,
            "list_ms": None if t_after is None or t_req is None else t_after - t_req}


def test_mavproxy_flies_cosim_sitl(tmp_path):
    gcs_port, api_port = free_udp_port(), free_udp_port()
    w = Watch(api_port)
    mp = None
    try:
        with sitl(tmp_path, api_port=api_port, gcs_port=gcs_port, speed=4.0):
            w.until(lambda v: v.hb is not None, "heartbeat")
            mp = Proxy(gcs_port, tmp_path)
            mp.expect("Detected vehicle")
            n = int(mp.expect("Received").split()[1])              # "Received 34 parameters"
            assert n > 30
            _change_mode(mp, w, "LOITER", 4, 3)
            since = mp.mark()
            w.until(lambda v: v.ready, "ready to arm")
            mp.cmd("arm throttle")
            w.until(lambda v: v.armed, "armed")
            mp.expect("ARMED", since=since)
            mp.cmd("takeoff 1.2")                  # param7 = 1.2 m AMSL: raised to MIS_TAKEOFF_ALT
            w.until(lambda v: v.landed == M.MAV_LANDED_STATE_IN_AIR and v.lpos is not None
                    and v.lpos.z < -0.9, "in the air at 1 m")
            w.until(lambda v: v.mode == "LOITER", "take-off complete, holding")
            assert abs(w.lpos.z + 1.0) < 0.1
            assert any("Using minimum takeoff altitude" in t for t in w.texts)
            since = mp.mark()
            _change_mode(mp, w, "LAND", 4, 6)
            w.until(lambda v: v.landed == M.MAV_LANDED_STATE_ON_GROUND and not v.armed,
                    "landed and disarmed")
            mp.expect("DISARMED", since=since)
            time.sleep(0.5)                        # the tlog writer's last flush
        out = "\n".join(mp.lines)
        assert "fence breach" not in out and "Fence" not in out
        tl = _tlog_checks(tmp_path / "mav.tlog")
        assert tl["count"] == n
        # one FTP request for @PARAM/param.pck (opcode 4 OpenFileRO), answered with a NAK
        # (129) at once: MAVProxy did not retry it (a retry resends OpenFileRO after 1 s)
        opens = [p for p in tl["ftp_out"] if p[3] == 4]
        assert len(opens) == 1 and any(p[3] == 129 and p[5] == 4 for p in tl["ftp_in"])
        assert tl["list_ms"] is not None and tl["list_ms"] < 1000, tl
    except BaseException:
        if mp is not None:
            print("\n".join(mp.lines[-80:]))
        print("vehicle said:", w.texts)
        raise
    finally:
        if mp is not None:
            mp.close()
        w.close()


def test_mavproxy_uploads_and_flies_a_mission_then_rtl(tmp_path):
    """MAVProxy's `wp load` (a QGC WPL 110 file) uploads a mission over the mission protocol,
    `wp list` reads it back, AUTO.MISSION flies it from the ground (the vehicle climbs first,
    as PX4 does), MISSION_ITEM_REACHED for each item, then RTL lands at home."""
    from mav import wire

    geo = wire.FlatEarth(42.299886, -71.350447, 71.3232)    # the vehicle's default origin
    corners = [(-1.0, 0.0), (-1.0, 1.0), (0.0, 1.0)]        # inside the seed world's arena
    lines = ["QGC WPL 110"]
    for i, (n, e) in enumerate(corners):
        lat, lon, _ = geo.to_geodetic(n, e, 0.0)
        lines.append(f"{i}\t0\t3\t16\t0\t0\t0\t0\t{lat:.8f}\t{lon:.8f}\t1.0\t1")
    (tmp_path / "square.txt").write_text("\n".join(lines) + "\n")
    gcs_port, api_port = free_udp_port(), free_udp_port()
    w = Watch(api_port)
    mp = None
    try:
        with sitl(tmp_path, api_port=api_port, gcs_port=gcs_port, speed=4.0):
            w.until(lambda v: v.hb is not None, "heartbeat")
            mp = Proxy(gcs_port, tmp_path)
            mp.expect("Detected vehicle")
            mp.expect("Received")                                  # parameters
            since = mp.mark()
            mp.cmd("wp load square.txt")
            mp.expect("Sent all 3 waypoints", "Loaded 3 waypoints", since=since)
            w.until(lambda v: any("Mission uploaded: 3 items" in t for t in v.texts),
                    "mission stored")
            since = mp.mark()
            mp.cmd("wp list")
            mp.expect("Saved 3 waypoints", "Requesting 3 waypoints", since=since)
            w.until(lambda v: v.ready, "ready to arm")
            mp.cmd("arm throttle")
            w.until(lambda v: v.armed, "armed")
            mp.cmd("long DO_SET_MODE 1 4 4")                     # AUTO.MISSION
            w.until(lambda v: v.mode == "MISSION", "mission mode")
            w.until(lambda v: v.reached[-1:] == [2], "the last item reached", timeout_s=40.0)
            mp.cmd("long DO_SET_MODE 1 4 5")                     # AUTO.RTL
            w.until(lambda v: v.mode == "RTL", "RTL mode")
            w.until(lambda v: v.landed == M.MAV_LANDED_STATE_ON_GROUND and not v.armed,
                    "landed and disarmed", timeout_s=40.0)
            assert abs(w.lpos.x) < 0.15 and abs(w.lpos.y) < 0.15
        assert w.reached == [0, 1, 2], w.reached
    except BaseException:
        if mp is not None:
            print("\n".join(mp.lines[-80:]))
        print("vehicle said:", w.texts)
        raise
    finally:
        if mp is not None:
            mp.close()
        w.close()
