"""`cosim sitl`: vehicles in one world, in real time, for ground stations and scripts.

One process, one lockstep loop, one clock. Tick k (t_k = k h from the integer counter) steps
every vehicle in turn as the master steps its one (`master.py`, steps 1-2 and 5-7: ODOMETRY
stamped t_k out, HIL_ACTUATOR_CONTROLS stamped t_k back, record, the plant to t_k+1, the exit
conditions), then paces the loop against the wall clock (`master.Pacer`: a host stall is
skipped, not replayed). No app and no camera: the vehicles are flown from outside, each over
its own MAVLink links with PX4 SITL's ports for its instance (`instance_links`), with its own
plant (an FMU instance), flight stack (sysid instance + 1), tlog and folder.

A crash (`ExitMonitor` with `sitl`: hard touchdown, flipped, a collision in a 3D world) does
not end the run: the vehicle respawns at its start, on the ground, disarmed, its plant reset
and its flight stack rebooted on the same sockets and sysid (`Onboard.rebooted`), so the
client keeps its connection and can fly again. The run ends when `timing.t_final_s` is reached
or on `stop()` (Ctrl-C, SIGTERM: a normal stop), or when a part fails (the FMU, the flight
stack): `FleetResult.exit_reason` says which.

Memory stays flat however long it runs: the tlogs stream to disk and the truth series is
spooled to each vehicle's folder (not /tmp, which may live in RAM), one row every
SERIES_EVERY ticks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from cosim.errors import ComponentError
from cosim.outputs.folder import clean_run_folder
from cosim.outputs.result import RunResult
from cosim.outputs.series import SeriesSpool
from cosim.outputs.tlog import Tlog
from cosim.scenario.records import Scenario
from cosim.sensors.odometry import OdometrySensor
from cosim.sim.exits import Exit, ExitMonitor, ExitReason
from cosim.sim.master import Pacer, build_plant
from cosim.sim.onboard import OnboardHandle
from cosim.sim.options import RunOptions
from cosim.sim.tick import Tick
from mav import wire
from mav.hil import HilSimulatorCodec
from mav.onboard import OnboardConfig

Addr = tuple[str, int]
Links = dict[str, tuple[Addr, Addr]]      # {'api': (bind, remote), 'gcs': (bind, remote)}

# PX4 SITL's ports for instance 0; instance N adds N to each but the GCS remote
API_REMOTE_PORT = 14540    # the offboard / API peer (MAVSDK, scripts) listens here
API_BIND_PORT = 14580
GCS_REMOTE_PORT = 14550    # QGroundControl listens here, for every vehicle
GCS_BIND_PORT = 18570
MAX_INSTANCE = 254         # sysid = instance + 1 <= 255
SERIES_EVERY = 20          # ticks between two recorded rows (10 Hz at h = 5 ms)
SPOOL_NAME = ".series.f64" # the series spool, in the vehicle's folder until written out


def instance_links(instance: int, k: int = 0, *, host: str = "127.0.0.1",
                   api_bind: Addr | None = None, api_remote: Addr | None = None,
                   gcs_bind: Addr | None = None, gcs_remote: Addr | None = None) -> Links:
    """The (bind, remote) addresses of the API and GCS links of PX4 SITL instance `instance`:
    the API link sends to 14540 + N from 14580 + N, the GCS link to 14550 (QGroundControl
    listens there for all vehicles) from 18570 + N. An address given overrides that of the
    fleet's first vehicle; vehicle k of the fleet adds k to its port (port 0, any free port,
    stays 0), except the GCS remote, which every vehicle shares."""

    def addr(given: Addr | None, port: int, shared: bool = False) -> Addr:
        if given is None:
            return host, port
        h, p = given
        return h, p if shared or p == 0 else p + k

    return {"api": (addr(api_bind, API_BIND_PORT + instance),
                    addr(api_remote, API_REMOTE_PORT + instance)),
            "gcs": (addr(gcs_bind, GCS_BIND_PORT + instance),
                    addr(gcs_remote, GCS_REMOTE_PORT, shared=True))}


@dataclass(frozen=True)
class SitlOptions:
    """How `cosim sitl` runs its vehicles (world, vehicle and duration: the scenario)."""

    out_dir: Path                          # the vehicle of instance N writes out_dir / "N"
    instance: int = 0                      # the first vehicle's PX4 instance N: sysid N + 1
    count: int = 1                         # vehicles: instances instance .. instance+count-1
    spacing_m: float = 1.0                 # m east between neighbouring starts
    speed: float = 1.0                     # simulated time / wall time
    links: tuple[Links, ...] = ()          # per vehicle; () = PX4's (`instance_links`)
    signing_key: bytes | None = None       # 32 bytes: every vehicle signs, rejects unsigned
    live: Any = None                       # a cosim.outputs.live.LiveView serving the flight


@dataclass
class FleetResult:
    exit_reason: ExitReason                # TIME_LIMIT, STOPPED or COMPONENT_ERROR
    message: str
    runs: list[RunResult]                  # one per vehicle, in instance order
    sitl: list[dict[str, Any]]             # their summaries' `sitl` sections


def start_offset(k: int, spacing_m: float) -> float:
    """m east of the world's start where vehicle k of the fleet starts (same north, heading)."""
    return k * spacing_m


class SitlVehicle:
    """One vehicle of the fleet: plant, sensor, flight stack on its own links, exit monitor,
    tlog and series spool in its own folder. Its failures are named 'vehicle N: part: ...'."""

    def __init__(self, sc: Scenario, so: SitlOptions, k: int) -> None:
        self.instance = so.instance + k
        self.sysid = self.instance + 1
        self.links = so.links[k] if so.links else instance_links(self.instance, k)
        east = start_offset(k, so.spacing_m)
        self.sc = sc = dataclasses.replace(
            sc, start=dataclasses.replace(sc.start, e=sc.start.e + east))
        self.run_dir = d = so.out_dir / str(self.instance)
        d.mkdir(parents=True, exist_ok=True)
        clean_run_folder(d)
        self.h = sc.timing.tick_s
        self.tlog = Tlog(d / "flight.tlog")
        self.spool = SeriesSpool(d / SPOOL_NAME)
        self.plant = self.handle = self.feed = None
        self.respawns: list[dict[str, Any]] = []
        self.min_clearance: tuple[float, float, str] | None = None
        self.note: str | None = None       # told to the clients after the next exchange
        try:
            with self.named():
                self.plant = build_plant(sc)
                self.y = self.plant.y
                c = OnboardConfig()        # each local frame's origin where the vehicle starts
                origin = None if east == 0.0 else wire.FlatEarth(
                    c.origin_lat_deg, c.origin_lon_deg, c.origin_alt_m).to_geodetic(0, east, 0)
                opts = RunOptions(mode="mil", realtime=True, speed=so.speed, out_dir=d,
                                  external_links=self.links, sitl=True,
                                  signing_key=so.signing_key)
                self.handle = OnboardHandle(sc, opts, self.tlog, d, sysid=self.sysid,
                                            origin=origin)
        except BaseException:
            self.close()
            raise
        self.monitor = self._monitor()
        sensor = OdometrySensor(sc.noise, np.random.default_rng([sc.seed, 0, k]))
        codec = HilSimulatorCodec()
        if sc.sensors is not None and sc.sensors.hil:   # the sensors, the onboard estimator
            from cosim.sim.estimate import SensorFeed

            # (its rows are not kept: sitl runs for hours; the series' columns have it)
            self.feed = sensor = codec = SensorFeed(dataclasses.replace(sc, seed=sc.seed + k),
                                                    self.h, keep=False)
        hd = self.handle
        self.tick = Tick(plant=self.plant, sensor=sensor, codec=codec,
                         exchange=hd.exchange_record if hd.typed else hd.exchange,
                         gcs_recv=None, tlog=self.tlog, spool=self.spool, monitor=self.monitor,
                         h_us=int(round(self.h * 1e6)), record_every=SERIES_EVERY,
                         typed=hd.typed)

    @contextlib.contextmanager
    def named(self) -> Iterator[None]:
        """Any failure inside becomes ComponentError('vehicle N', 'part: what')."""
        try:
            yield
        except ComponentError as exc:
            raise ComponentError(f"vehicle {self.instance}", str(exc)) from exc
        except Exception as exc:
            raise ComponentError(f"vehicle {self.instance}",
                                 f"{type(exc).__name__}: {exc}") from exc

    def _monitor(self) -> ExitMonitor:
        w = self.sc.world
        return ExitMonitor(w.arena, self.h, None, sitl=True, scene=w.scene,
                           body_radius=self.sc.vehicle.body_radius)

    def describe(self) -> str:
        st, b = self.sc.start, self.handle.bound
        (_, api_r), (_, gcs_r) = self.links["api"], self.links["gcs"]
        return (f"vehicle {self.instance} (sysid {self.sysid}) at N {st.n:.2f} E {st.e:.2f} m: "
                f"API {_hp(b['api'])} -> {_hp(api_r)}, GCS {_hp(b['gcs'])} -> {_hp(gcs_r)}")

    def step(self, k: int, wind: tuple[float, float, float],
             log: Callable[[str], None]) -> None:
        """Tick k of this vehicle (cosim/sim/tick.py: ODOMETRY stamped t_k out, the HIL answer
        back, a row every SERIES_EVERY ticks, the plant to t_k+1, then the crash conditions; a
        crash: respawn), then the note of a respawn to the clients."""
        crash = self.tick.run(k, wind)
        if self.note is not None:
            self.handle.onboard.statustext(self.note, mavlink2.MAV_SEVERITY_WARNING)
            self.note = None
        if crash is not None:
            self.respawn(k * self.tick.h_us * 1e-6 + self.h, crash, log)

    def respawn(self, t: float, crash: Exit, log: Callable[[str], None]) -> None:
        """Back to the start, on the ground, disarmed: the plant reset, the flight stack
        rebooted on the same links; the clients are told by a STATUSTEXT."""
        reason, message = crash
        self.respawns.append({"t_s": round(t, 6), "reason": reason.value, "message": message})
        self._keep_clearance()
        self.plant.reset()
        if self.feed is not None:          # the sensors restart with the plant
            self.feed.reset()
        self.monitor = self.tick.monitor = self._monitor()
        self.tick.y = self.plant.y
        self.handle.respawn()
        self.note = f"Respawned at start, disarmed ({reason.value})"   # one STATUSTEXT
        log(f"cosim sitl: t = {t:.2f} s: vehicle {self.instance} (sysid {self.sysid}) "
            f"{reason.value}: {message}; respawned at its start, on the ground, disarmed")

    def _keep_clearance(self) -> None:
        mc = self.monitor.min_clearance
        if mc is not None and (self.min_clearance is None or mc[0] < self.min_clearance[0]):
            self.min_clearance = mc

    def close(self) -> None:
        """Close the links, the plant, the tlog and the spool (idempotent)."""
        if self.handle is not None:
            self.handle.close()
        if self.plant is not None:
            self.plant.close()
        self.tlog.close()
        self.spool.finish()
        if self.feed is not None:
            self.feed.close()

    def result(self, ended: tuple[ExitReason, str], ticks: int, wall_s: float,
               loop_wall_s: float, pacer: Pacer | None) -> RunResult:
        self.close()
        self._keep_clearance()
        return RunResult(
            scenario=self.sc, mode="sitl", exit_reason=ended[0], message=ended[1],
            ticks=ticks, t_end_s=ticks * self.h, wall_s=wall_s, recorded=self.spool.finish(),
            phases=["none"], events=[], frame_log=[], app_metrics={}, touchdown=None,
            tlog=self.tlog, run_dir=self.run_dir,
            onboard_stats=self.handle.stats() if self.handle is not None else {},
            loop_wall_s=loop_wall_s, min_clearance=self.min_clearance,
            realtime_stalls=pacer.stalls if pacer else 0,
            realtime_lost_s=pacer.lost_s if pacer else 0.0)

    def summary(self) -> dict[str, Any]:
        st = self.sc.start
        return {"instance": self.instance, "sysid": self.sysid,
                "start": {"n": st.n, "e": st.e, "yaw_deg": st.yaw_deg},
                "links": {name: {"bind": _hp(self.handle.bound.get(name, b)), "remote": _hp(r)}
                          for name, (b, r) in self.links.items()},
                "series_every_ticks": SERIES_EVERY, "respawns": self.respawns}


def _hp(a: Addr) -> str:
    return f"{a[0]}:{a[1]}"


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def run_fleet(sc: Scenario, so: SitlOptions, stop: Callable[[], bool] = lambda: False,
              log: Callable[[str], None] = _log) -> FleetResult:
    """Fly `so.count` vehicles in the scenario's world in real time until its t_final_s,
    `stop()` or a failure. Never raises for a failing part; the result says why it ended."""
    h = sc.timing.tick_s
    h_us = int(round(h * 1e6))
    n_ticks = int(round(sc.timing.t_final_s / h))
    wind = sc.wind_ned_mps
    gusty = None
    if sc.wind is not None and not sc.wind.steady:
        from cosim.world.wind import WindField

        gusty = WindField(sc.wind, h, sc.seed).at
    vehicles: list[SitlVehicle] = []
    ended = ExitReason.TIME_LIMIT, "duration reached"
    ticks, pacer, loop0 = 0, None, None
    wall0 = time.perf_counter()
    try:
        for k in range(so.count):
            vehicles.append(SitlVehicle(sc, so, k))
            log(f"cosim sitl: {vehicles[-1].describe()}")
        lives = [] if so.live is None else [   # one vehicle: the topics of `cosim run`
            so.live.vehicle(v.sc, *(() if so.count == 1 else (f"/v{v.instance}",
                                                              f"body{v.instance}")))
            for v in vehicles]
        loop0 = time.perf_counter()
        pacer = Pacer(so.speed, loop0)
        for k in range(n_ticks):
            if stop():
                break
            if gusty is not None:
                wind = gusty(k)
            for v in vehicles:
                with v.named():
                    v.step(k, wind, log)
            for lv, v in zip(lives, vehicles, strict=False):   # lives: [] or one each
                lv.sitl_tick((k + 1) * h_us * 1e-6, v.tick.y,
                             v.spool.rows if k % SERIES_EVERY == 0 else None)
            ticks = k + 1
            pacer.wait(k * h_us * 1e-6 + h)
        if stop():
            ended = ExitReason.STOPPED, "stopped by user"
    except ComponentError as exc:
        ended = ExitReason.COMPONENT_ERROR, str(exc)
    except KeyboardInterrupt:        # without `stop_on_signals` around the run
        ended = ExitReason.STOPPED, "stopped by user"
    finally:
        wall_end = time.perf_counter()
        loop_wall = wall_end - loop0 if loop0 is not None else 0.0
        runs = [v.result(ended, ticks, wall_end - wall0, loop_wall, pacer) for v in vehicles]
    return FleetResult(ended[0], ended[1], runs, [v.summary() for v in vehicles])


class StopFlag:
    """Set by Ctrl-C or SIGTERM under `stop_on_signals`; the loop calls it once a tick."""

    def __init__(self) -> None:
        self.signals: list[int] = []       # the signals received, in order

    def __call__(self) -> bool:
        return bool(self.signals)

    def set(self, signum: int, _frame=None) -> None:
        self.signals.append(signum)


@contextlib.contextmanager
def stop_on_signals() -> Iterator[StopFlag]:
    """Ctrl-C and SIGTERM set the flag instead of raising wherever they land, so a stop ends
    the loop between two ticks and the outputs are always written (outside the main thread,
    where signals cannot be handled, the flag is never set)."""
    flag = StopFlag()
    old: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        old = {s: signal.signal(s, flag.set) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def write_fleet(fr: FleetResult, *, mcap: bool = False) -> list[str]:
    """Write each vehicle's folder: summary.json (with its `sitl` section: instance, links,
    respawns), timeseries.csv (one row every SERIES_EVERY ticks), flight.tlog (streamed there
    already), run.mcap when asked. Returns one line per vehicle for the screen."""
    from cosim.outputs.report import write_run

    lines = []
    for res, sitl in zip(fr.runs, fr.sitl, strict=True):
        if mcap:
            from cosim.outputs.mcap import McapRun

            res.mcap = McapRun(res.run_dir / "run.mcap", res.scenario).finish(res)
        write_run(res, res.run_dir, plots=False, extra={"sitl": sitl})
        res.recorded.path.unlink(missing_ok=True)
        n = len(sitl["respawns"])
        lines.append(f"vehicle {sitl['instance']} (sysid {sitl['sysid']}): "
                     f"{res.t_end_s:.1f} s simulated, {n} respawn{'' if n == 1 else 's'}, "
                     f"outputs in {res.run_dir}")
    return lines
