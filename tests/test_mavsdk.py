"""ACCEPTANCE: MAVSDK (a real third-party MAVLink client) flies `cosim sitl`.

`cosim sitl` runs as a subprocess at --speed 4 with its API link sending to a free loopback
port; MAVSDK (the `mavsdk` package >= 4, the native C++ library through ctypes, no
mavsdk_server) listens there with `udpin://127.0.0.1:PORT`, as it would for PX4 SITL on 14540.
Only MAVSDK's public plugins are used: Telemetry (health, flight mode, in-air, landed state,
position), Action (takeoff altitude, arm, takeoff, land) and Offboard (position NED).

Mission: connect, wait until healthy and armable, arm, take off to 1 m, OFFBOARD, fly 1 m
north, land, see the vehicle disarm. About 3 s of wall time; every step is bounded.

The import is unconditional on purpose: `mavsdk` is in the `test` extra, so a missing package
fails the run instead of skipping this test.
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
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

SPEED = 4.0            # sim time / wall time; MAVSDK's 20 Hz setpoints are then 5 Hz of sim time
ALT_M = 1.0
LEG_M = 1.0
TOL_M = 0.10
STEP_S = 15.0          # wall-clock bound of every step
TOTAL_S = 60.0


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _first(agen, pred, what: str, timeout_s: float = STEP_S):
    """The first item of a MAVSDK subscription that satisfies `pred`; closes the stream."""

    async def run():
        async with contextlib.aclosing(agen) as items:
            async for item in items:
                if pred(item):
                    return item

    try:
        return await asyncio.wait_for(run(), timeout_s)
    except TimeoutError:
        raise AssertionError(f"MAVSDK: {what} not within {timeout_s} s") from None


async def _step(coro, what: str, timeout_s: float = STEP_S):
    try:
        return await asyncio.wait_for(coro, timeout_s)
    except TimeoutError:
        raise AssertionError(f"MAVSDK: {what} not within {timeout_s} s") from None


async def _mission(api_port: int, log: list[str]) -> None:
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{api_port}")
        drone = await _step(mavsdk.first_autopilot(timeout_s=10.0), "autopilot discovered")
        assert drone is not None, "MAVSDK: no autopilot heard"
        assert (await drone.autopilot_type()).name == "PX4"
        tel, act, off = TelemetryAsync(drone), ActionAsync(drone), OffboardAsync(drone)

        modes: list[FlightMode] = []

        async def watch_modes():
            async with contextlib.aclosing(tel.subscribe_flight_mode()) as items:
                async for m in items:
                    if not modes or modes[-1] != m:
                        modes.append(m)
                        log.append(f"mode {m.name}")

        watcher = asyncio.create_task(watch_modes())
        try:
            await _first(tel.subscribe_health(),
                         lambda h: (h.is_global_position_ok and h.is_home_position_ok
                                    and h.is_local_position_ok and h.is_armable),
                         "health ok and armable")
            await _step(act.set_takeoff_altitude(ALT_M), "set_takeoff_altitude")
            await _step(act.arm(), "arm")
            await _step(act.takeoff(), "takeoff")
            await _first(tel.subscribe_in_air(), bool, "in air")
            pos = await _first(tel.subscribe_position(),
                               lambda p: abs(p.relative_altitude_m - ALT_M) < TOL_M,
                               f"altitude {ALT_M} m")
            log.append(f"at {pos.relative_altitude_m:.3f} m")

            here = await _first(tel.subscribe_position_velocity_ned(), lambda _: True,
                                "local position")
            n, e = here.position.north_m, here.position.east_m
            # the local frame's origin is the start, as on PX4 (the seed world's start is at
            # world N 57, E 95): MAVSDK's stock set_position_ned(0, 0, -h) is "above home"
            assert math.hypot(n, e) < TOL_M, (n, e)
            n = e = 0.0
            await _step(off.set_position_ned(PositionNedYaw(n, e, -ALT_M, 0.0)),
                        "first setpoint")
            await _step(off.start(), "offboard start")
            await _step(off.set_position_ned(PositionNedYaw(n + LEG_M, e, -ALT_M, 0.0)),
                        "setpoint 1 m north")
            there = await _first(
                tel.subscribe_position_velocity_ned(),
                lambda pv: math.hypot(pv.position.north_m - (n + LEG_M),
                                      pv.position.east_m - e) < TOL_M
                and abs(pv.position.down_m + ALT_M) < TOL_M,
                "1 m north reached")
            log.append(f"reached {there.position.north_m - n:.3f} m north")

            await _step(act.land(), "land")
            await _first(tel.subscribe_landed_state(), lambda s: s == LandedState.ON_GROUND,
                         "landed")
            await _first(tel.subscribe_armed(), lambda a: not a, "disarmed")
            await asyncio.sleep(0.1)             # the last flight-mode update
            assert [FlightMode.TAKEOFF, FlightMode.OFFBOARD, FlightMode.LAND] == [
                m for m in modes if m in (FlightMode.TAKEOFF, FlightMode.OFFBOARD,
                                          FlightMode.LAND)], modes
        finally:
            watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watcher


@pytest.mark.flight
def test_mavsdk_flies_cosim_sitl(tmp_path):
    api_port = _free_udp_port()
    gcs_sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # the GCS link's peer: unread
    gcs_sink.bind(("127.0.0.1", 0))
    out = open(tmp_path / "sitl.log", "w")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sitl", "--vehicle", "mambo",
         "--speed", str(SPEED), "--duration", "240",
         "--api-remote", f"127.0.0.1:{api_port}", "--api-bind", "127.0.0.1:0",
         "--gcs-remote", f"127.0.0.1:{gcs_sink.getsockname()[1]}",
         "--gcs-bind", "127.0.0.1:0"],
        cwd=tmp_path, stdout=out, stderr=subprocess.STDOUT)
    log: list[str] = []
    try:
        asyncio.run(asyncio.wait_for(_mission(api_port, log), TOTAL_S))
        assert proc.poll() is None, "cosim sitl ended during the flight"
    except BaseException:
        out.flush()
        print("\n".join(log))
        print((tmp_path / "sitl.log").read_text())
        raise
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        out.close()
        gcs_sink.close()
