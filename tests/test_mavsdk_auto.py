"""ACCEPTANCE: MAVSDK flies the automatic modes of `cosim sitl` (the `field` world, 40 m x 40 m):
a 4-waypoint mission uploaded, flown and reported (Mission plugin), a speed change
(Action.set_current_speed), goto_location 10 m away, RTL from there, landing at home and the
disarm. The same free-port set-up as test_mavsdk.py; every step is bounded in wall time,
nothing depends on how fast the host is beyond those generous bounds.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import socket
import subprocess
import sys

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync
from test_mavsdk import _first, _free_udp_port, _step

SPEED = 6.0            # sim time / wall time
ALT_M = 2.0
STEP_S = 30.0
TOTAL_S = 150.0
# the mission's corners, (north, east) m from home, and the go-to 10 m east
CORNERS = ((4.0, 0.0), (4.0, 4.0), (0.0, 4.0), (0.0, 2.0))
GOTO_NE = (0.0, 10.0)
NAV_ACC_RAD = 0.3      # m, the vehicle's default acceptance radius


def _ll(home, n: float, e: float) -> tuple[float, float]:
    """Flat-earth lat/lon n, e metres from `home` (a MAVSDK Position)."""
    lat = home.latitude_deg + math.degrees(n / 6_378_137.0)
    lon = home.longitude_deg + math.degrees(e / (6_378_137.0 * math.cos(math.radians(
        home.latitude_deg))))
    return lat, lon


def _item(lat: float, lon: float) -> MissionItem:
    return MissionItem(lat, lon, ALT_M, math.nan, False, math.nan, math.nan,
                       MissionItem.CameraAction.NONE, math.nan, math.nan, math.nan, math.nan,
                       math.nan, MissionItem.VehicleAction.NONE)


async def _fly(api_port: int, log: list[str]) -> None:
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{api_port}")
        drone = await _step(mavsdk.first_autopilot(timeout_s=10.0), "autopilot discovered")
        tel, act, mis = TelemetryAsync(drone), ActionAsync(drone), MissionAsync(drone)
        await _first(tel.subscribe_health(), lambda h: h.is_home_position_ok and h.is_armable,
                     "health ok and armable")
        home = await _first(tel.subscribe_home(), lambda _: True, "home")

        # ---- the mission: upload, arm, start from the ground, progress to the end
        plan = MissionPlan([_item(*_ll(home, n, e)) for n, e in CORNERS])
        await _step(mis.set_return_to_launch_after_mission(False), "no RTL after mission")
        await _step(mis.upload_mission(plan), "mission upload")
        await _step(act.arm(), "arm")
        await _step(mis.start_mission(), "start mission")
        prog = await _first(mis.subscribe_mission_progress(),
                            lambda p: p.current == p.total == len(CORNERS), "mission progress")
        assert await _step(mis.is_mission_finished(), "finished?")
        log.append(f"mission {prog.current}/{prog.total}")
        pos = await _first(tel.subscribe_position_velocity_ned(), lambda _: True, "position")
        n, e = CORNERS[-1]
        assert math.hypot(pos.position.north_m - n, pos.position.east_m - e) < 2 * NAV_ACC_RAD
        assert abs(-pos.position.down_m - ALT_M) < 0.2

        # ---- a speed change, then go-to 10 m away: it flies there at that speed
        await _step(act.set_current_speed(2.0), "set_current_speed")
        lat, lon = _ll(home, *GOTO_NE)
        await _step(act.goto_location(lat, lon, home.absolute_altitude_m + ALT_M, math.nan),
                    "goto_location")
        top = [0.0]

        def arrived(pv) -> bool:
            top[0] = max(top[0], math.hypot(pv.velocity.north_m_s, pv.velocity.east_m_s))
            return math.hypot(pv.position.north_m - GOTO_NE[0],
                              pv.position.east_m - GOTO_NE[1]) < NAV_ACC_RAD
        await _first(tel.subscribe_position_velocity_ned(), arrived, "go-to reached")
        log.append(f"go-to reached, top speed {top[0]:.2f} m/s")
        assert 1.7 < top[0] < 2.3, top[0]          # the cruise speed was 1 m/s before

        # ---- RTL from 10 m away: home, down, disarmed
        await _step(act.return_to_launch(), "return_to_launch")
        await _first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.RETURN_TO_LAUNCH,
                     "RTL mode")
        await _first(tel.subscribe_landed_state(), lambda s: s == LandedState.ON_GROUND,
                     "landed")
        await _first(tel.subscribe_armed(), lambda a: not a, "disarmed")
        pos = await _first(tel.subscribe_position_velocity_ned(), lambda _: True, "position")
        d = math.hypot(pos.position.north_m, pos.position.east_m)
        log.append(f"landed {d:.3f} m from home")
        assert d < 0.2


@pytest.mark.flight
def test_mavsdk_mission_goto_speed_and_rtl(tmp_path):
    api_port = _free_udp_port()
    gcs_sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs_sink.bind(("127.0.0.1", 0))
    out = open(tmp_path / "sitl.log", "w")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sitl", "--vehicle", "mambo", "--world", "field",
         "--speed", str(SPEED), "--duration", "900",
         "--api-remote", f"127.0.0.1:{api_port}", "--api-bind", "127.0.0.1:0",
         "--gcs-remote", f"127.0.0.1:{gcs_sink.getsockname()[1]}",
         "--gcs-bind", "127.0.0.1:0"],
        cwd=tmp_path, stdout=out, stderr=subprocess.STDOUT)
    log: list[str] = []
    try:
        asyncio.run(asyncio.wait_for(_fly(api_port, log), TOTAL_S))
        assert proc.poll() is None, "cosim sitl ended during the flight"
        print("\n".join(log))
    except BaseException:
        out.flush()
        print("\n".join(log))
        print((tmp_path / "sitl.log").read_text())
        raise
    finally:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(5)
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        out.close()
        gcs_sink.close()
