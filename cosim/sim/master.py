"""The master algorithm: owns simulated time and steps every part in lockstep.

Tick k (t_k = k * h from the integer counter, h = 5 ms), the order of ARCHITECTURE.md:
1. read plant outputs y(t_k); 2. sensor models -> ODOMETRY stamped t_k; 3. on a camera tick,
render and hand the frame to the app; 4. the app's tick (reads telemetry, may send setpoints);
5. HIL: send ODOMETRY, the onboard stack drains its links, runs its controller, answers
HIL_ACTUATOR_CONTROLS stamped t_k; 6. apply the motor commands, step the plant to t_k+1;
7. record, check the exit conditions.

MIL runs the onboard stack in this process over in-memory links carrying the same MAVLink bytes;
SIL runs it as a separate process over loopback UDP. Both give bit-identical trajectories.
"""

from __future__ import annotations

import enum
import importlib
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import ComponentError
from cosim.outputs.tlog import TapLink, Tlog
from cosim.plant.fmu import OUTPUT_NAMES, Y_ON_GROUND, Y_QX, Y_QY, Y_X, Y_Y, Y_Z, Plant
from cosim.scenario.parse import Scenario, build_camera_config, build_world
from cosim.sensors.odometry import OdometrySensor
from mav.hil import HilSimulatorCodec
from mav.links import MemoryLink, UdpLink


class ExitReason(enum.Enum):
    MISSION_COMPLETE = "mission_complete"   # the app finished and the vehicle is down, disarmed
    LANDED = "landed"                       # down and disarmed, but the app did not finish
    CRASHED = "crashed"                     # hard touchdown or flipped
    LEFT_ARENA = "left_arena"               # outside the world's arena or above the ceiling
    TIME_LIMIT = "time_limit"               # timing.t_final_s reached
    COMPONENT_ERROR = "component_error"     # a part failed (plant, onboard, app, camera)
    INTERRUPTED = "interrupted"             # Ctrl-C


CEILING_M = 5.0            # m above the floor: higher is "left the arena"
ARENA_MARGIN_M = 0.5       # m outside the arena bounds before LEFT_ARENA
CRASH_VZ_MPS = 2.0         # m/s, touchdown faster than this is a crash
CRASH_TILT_COS = 0.0       # cos(90 deg): flipped over
AIRBORNE_Z_M = -0.10       # m, higher than this counts as having flown
REST_TIMEOUT_S = 3.0       # s on the ground, armed, after flying: LANDED anyway

SERIES_COLUMNS = (
    ("t",) + OUTPUT_NAMES + ("u1", "u2", "u3", "u4", "est_x", "est_y", "est_z",
                             "sp_x", "sp_y", "sp_z", "phase")
)


@dataclass
class RunOptions:
    mode: str = "mil"                 # 'mil' | 'sil'
    realtime: bool = False
    speed: float = 1.0                # real-time factor target when realtime
    video: bool = False               # keep camera frames for a video
    png_every: int = 0                # save every Nth frame as PNG (0: none)
    progress: bool = False
    out_dir: Path | None = None       # where the SIL onboard log goes (None: a temp dir)
    hil_timeout_s: float = 2.0        # s wall clock without a HIL answer -> onboard failed
    app_override: Any = None          # an app object to use instead of the scenario's
    # sitl: the onboard stack's API and GCS links are real UDP sockets for outside clients,
    # {'gcs': ((bind_host, port), (remote_host, port)), 'api': (...)}; MIL only
    external_links: dict[str, tuple[tuple[str, int], tuple[str, int]]] | None = None
    sitl: bool = False                # no mission or arena exits: only crash, time, Ctrl-C


@dataclass
class RunResult:
    scenario: Scenario
    mode: str
    exit_reason: ExitReason
    message: str
    ticks: int
    t_end_s: float
    wall_s: float
    series: np.ndarray                         # (ticks, len(SERIES_COLUMNS)) float64
    phases: list[str]                          # phase index -> name
    events: list[tuple[float, str]]
    frame_log: list[tuple]                     # per camera frame records from the app
    app_metrics: dict[str, float]
    touchdown: tuple[float, float, float] | None   # (t, x, y) of the final touchdown
    tlog: Tlog
    frames: list[np.ndarray] = field(default_factory=list)
    png_frames: list[tuple[float, np.ndarray]] = field(default_factory=list)
    onboard_stats: dict[str, Any] = field(default_factory=dict)
    loop_wall_s: float = 0.0                   # s wall clock of the tick loop alone (no setup)

    @property
    def real_time_factor(self) -> float:
        """End to end: simulated time / wall time including setup (FMU load, SIL start)."""
        return self.t_end_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def loop_real_time_factor(self) -> float:
        """The tick loop alone: simulated time / wall time from the first to the last tick."""
        return self.t_end_s / self.loop_wall_s if self.loop_wall_s > 0 else math.inf


def make_app(sc: Scenario):
    name = sc.app.name
    if name == "none":
        return None
    if name == "scripted":
        from cosim.apps.scripted import ScriptedApp

        return ScriptedApp(sc.app.params)
    if name == "line_follower":
        from cosim.apps.line_follower import LineFollowerApp

        return LineFollowerApp(sc.app.params)
    mod, _, cls = name.partition(":")
    try:
        return getattr(importlib.import_module(mod), cls)(sc.app.params)
    except (ImportError, AttributeError) as exc:
        raise ComponentError("app", f"cannot load {name!r}: {exc}") from exc


class _Vehicle:
    """The onboard stack seen from the master: MIL in-process or SIL subprocess."""

    def __init__(self, sc: Scenario, opts: RunOptions, tlog: Tlog, log_dir: Path) -> None:
        self.mode = opts.mode
        self.proc = None
        self._own: tuple = ()
        vname = sc.vehicle.name
        if opts.mode == "mil":
            from mav.onboard import Onboard, OnboardConfig

            hil_m, hil_v = MemoryLink.pair()
            if opts.external_links:
                api_app = gcs_m = MemoryLink()  # nothing of the master's on these links
                try:
                    api_v = UdpLink(*opts.external_links["api"])
                    gcs_v = UdpLink(*opts.external_links["gcs"])
                except OSError as exc:
                    raise ComponentError("onboard", f"cannot bind the API/GCS links: {exc}"
                                         ) from None
            else:
                api_app, api_v = MemoryLink.pair()
                gcs_m, gcs_v = MemoryLink.pair()
            self.onboard = Onboard(OnboardConfig(vehicle=vname), hil_v, api_v, gcs_v)
            self._own = (api_v, gcs_v) if opts.external_links else ()
            if sc.vehicle != _preset(vname):
                self.onboard.set_vehicle_params(sc.vehicle)
            self.hil = hil_m
            self.api = TapLink(api_app, tlog)
            self.gcs = TapLink(gcs_m, tlog)
        else:
            try:
                self._start_sil(sc, opts, tlog, log_dir)
            except BaseException:
                self.close_partial()
                raise

    def close_partial(self) -> None:
        """After a failed SIL start: close what was opened (process, sockets)."""
        for link in self._own:
            link.close()
        if self.proc is not None:
            self.proc.close()

    def _start_sil(self, sc: Scenario, opts: RunOptions, tlog: Tlog, log_dir: Path) -> None:
        from cosim.sim.sil import OnboardProcess

        vname = sc.vehicle.name
        hil = UdpLink(("127.0.0.1", 0))
        api = UdpLink(("127.0.0.1", 0))
        gcs = UdpLink(("127.0.0.1", 0))
        self._own = (hil, api, gcs)
        preset = _preset(vname)
        overrides = tuple(  # scenario vehicle.overrides, passed to the process
            f"--vehicle-param={k}={v!r}" for k, v in sc.vehicle.fmu_parameters().items()
            if getattr(preset, k) != v
        )
        self.proc = OnboardProcess(
            vname, api.local_address, gcs.local_address, log_dir / "onboard.log",
            hil_timeout_s=max(10.0, 5 * opts.hil_timeout_s), extra_args=overrides,
        )
        ports = self.proc.ports
        for link, name in ((hil, "hil"), (api, "api"), (gcs, "gcs")):
            link.remote = ("127.0.0.1", ports[name])
            link._fixed_remote = True
        hil.sock.setblocking(True)
        hil.sock.settimeout(opts.hil_timeout_s)
        self.hil = hil
        self.api = TapLink(api, tlog)
        self.gcs = TapLink(gcs, tlog)
        self._own = ()

    def exchange(self, data: bytes) -> bytes:
        """Send one HIL datagram and return the answer."""
        self.hil.send(data)
        if self.proc is None:
            try:
                self.onboard.poll()
            except Exception as exc:  # the onboard stack is a separate part: name it
                raise ComponentError("onboard", f"{type(exc).__name__}: {exc}") from exc
            ans = self.hil.recv()
            if ans is None:
                raise ComponentError("onboard", "no HIL_ACTUATOR_CONTROLS answer")
            return ans
        try:
            return self.hil.sock.recv(65535)
        except (TimeoutError, ConnectionRefusedError, OSError):
            what = self.proc.failure_text()
            raise ComponentError("onboard", f"stopped answering HIL ({what})") from None

    def drain_gcs(self) -> None:
        while self.gcs.recv() is not None:
            pass

    def stats(self) -> dict[str, Any]:
        """The onboard stack's counters (SIL: as the process reported them at exit)."""
        if self.proc is None:
            return dict(getattr(self.onboard, "stats", {}))
        return dict(self.proc.stats)

    def close(self) -> None:
        for link in (self.hil, self.api, self.gcs, *self._own):
            try:
                link.close()
            except Exception:
                pass
        if self.proc is not None:
            self.proc.close()


def _preset(name: str):
    from cosim.plant.vehicles import get_vehicle

    return get_vehicle(name)


def run_scenario(sc: Scenario, opts: RunOptions | None = None) -> RunResult:
    """Fly one scenario. Never raises for a failing part: the result says why the run ended."""
    opts = opts or RunOptions()
    if opts.mode not in ("mil", "sil"):
        raise ValueError(f"mode: got {opts.mode!r}; allowed: mil, sil")
    import tempfile

    log_dir = opts.out_dir or Path(tempfile.mkdtemp(prefix="cosim-"))
    log_dir.mkdir(parents=True, exist_ok=True)

    h = sc.timing.tick_s
    h_us = int(round(h * 1e6))
    n_ticks = int(round(sc.timing.t_final_s / h))
    cam_every = sc.timing.camera_every
    # one independent random stream per consumer, all from the scenario seed
    rng = np.random.default_rng([sc.seed, 0])                       # sensor model
    tlog = Tlog()
    world = build_world(sc)
    camera = None
    if sc.camera is not None:
        from cosim.sensors.camera import DownwardCamera

        cam_seed = int(np.random.SeedSequence([sc.seed, 2]).generate_state(1)[0])
        camera = DownwardCamera(world, build_camera_config(sc), seed=cam_seed)
    sensor = OdometrySensor(sc.noise, rng)
    wind_n, wind_e, wind_d = sc.wind_ned_mps
    arena = world.arena

    rows: list[tuple] = []
    phases: list[str] = []
    phase_idx: dict[str, int] = {}
    frames: list[np.ndarray] = []
    png_frames: list[tuple[float, np.ndarray]] = []
    exit_reason, message = ExitReason.TIME_LIMIT, "time limit reached"
    touchdown = None
    k = 0
    plant = vehicle = app = None
    wall0 = time.perf_counter()
    loop0 = None
    try:
        try:
            plant = Plant(sc.vehicle, step_size=h, x0=sc.start.n, y0=sc.start.e, z0=0.0,
                          yaw0=math.radians(sc.start.yaw_deg))
        except ComponentError:
            raise
        except Exception as exc:
            raise ComponentError("plant", f"{type(exc).__name__}: {exc}") from exc
        vehicle = _Vehicle(sc, opts, tlog, log_dir)
        try:
            app = opts.app_override if opts.app_override is not None else make_app(sc)
        except ComponentError:
            raise
        except Exception as exc:
            raise ComponentError("app", f"{type(exc).__name__}: {exc}") from exc
        codec = HilSimulatorCodec()
        client = None
        if app is not None:
            from cosim.apps.base import AppContext
            from mav.client import OffboardClient

            client = OffboardClient(vehicle.api)
            ctx = AppContext(client=client, tick_s=h,
                             frame_period_s=cam_every * h if camera else None,
                             rng=np.random.default_rng([sc.seed, 1]),
                             home_ned=(sc.start.n, sc.start.e, 0.0))
            _call_app(app.on_start, ctx)
        airborne = False
        ground_ticks = 0
        t_touch = None
        rest_ticks = int(round(REST_TIMEOUT_S / h))
        nan3 = (math.nan, math.nan, math.nan)
        y = plant.y
        # the per-tick calls as locals (one lookup each per run, not per tick)
        measure, encode_odometry = sensor.measure, codec.encode_odometry
        exchange, decode_actuators = vehicle.exchange, codec.decode_actuators
        drain_gcs, plant_step, record = vehicle.drain_gcs, plant.step, rows.append
        on_tick = app.on_tick if app is not None else None
        realtime, progress, sitl = opts.realtime, opts.progress, opts.sitl
        loop0 = time.perf_counter()
        for k in range(n_ticks):
            t_us = k * h_us
            t = t_us * 1e-6
            tlog.t_us = t_us
            meas = measure(y)
            if app is not None:
                if camera is not None and k % cam_every == 0:
                    try:
                        img = camera.render(y[Y_X:Y_Z + 1], _quat(y))
                    except Exception as exc:
                        raise ComponentError("camera", f"{type(exc).__name__}: {exc}") from exc
                    if opts.video:
                        frames.append(img)
                    if opts.png_every and (k // cam_every) % opts.png_every == 0:
                        png_frames.append((t, img))
                    _call_app(app.on_frame, t, img)
                try:
                    on_tick(t)
                except ComponentError:
                    raise
                except Exception as exc:
                    raise ComponentError("app", f"{type(exc).__name__}: {exc}") from exc
            ans = exchange(encode_odometry(t_us, meas))
            try:
                t_ans, u1, u2, u3, u4 = decode_actuators(ans)
            except Exception as exc:
                raise ComponentError("onboard", f"bad HIL answer: {exc}") from exc
            if t_ans != t_us:
                raise ComponentError("onboard", f"HIL answer stamped {t_ans} us for {t_us} us")
            drain_gcs()
            if app is not None:
                sp = app.setpoint
                ph = app.phase
            else:
                sp, ph = nan3, "none"
            pi = phase_idx.get(ph)
            if pi is None:
                pi = phase_idx[ph] = len(phases)
                phases.append(ph)
            record((t, *y, u1, u2, u3, u4, meas[0], meas[1], meas[2],
                         sp[0], sp[1], sp[2], pi))
            try:
                y = plant_step(u1, u2, u3, u4, wind_n, wind_e, wind_d)
            except ComponentError:
                raise
            except Exception as exc:
                raise ComponentError("plant", f"{type(exc).__name__}: {exc}") from exc
            # ---- exit conditions, on the state at t_k+1
            x_, y_, z_ = y[Y_X], y[Y_Y], y[Y_Z]
            if not math.isfinite(z_):
                raise ComponentError("plant", "non-finite state")
            if z_ < AIRBORNE_Z_M:
                airborne = True
            on_ground = y[Y_ON_GROUND] > 0.5
            if airborne:
                if on_ground:
                    if ground_ticks == 0:
                        t_touch = (t + h, x_, y_)
                        if abs(rows[-1][1 + OUTPUT_NAMES.index("vz")]) > CRASH_VZ_MPS:
                            exit_reason, message = ExitReason.CRASHED, (
                                f"hard touchdown at {rows[-1][1 + OUTPUT_NAMES.index('vz')]:.2f}"
                                " m/s")
                            k += 1
                            touchdown = t_touch
                            break
                    ground_ticks += 1
                else:
                    ground_ticks = 0
            tilt_cos = 1.0 - 2.0 * (y[Y_QX] ** 2 + y[Y_QY] ** 2)
            if tilt_cos < CRASH_TILT_COS:
                exit_reason, message = ExitReason.CRASHED, "flipped over"
                k += 1
                break
            if not sitl and (x_ < arena[0] - ARENA_MARGIN_M or x_ > arena[1] + ARENA_MARGIN_M
                    or y_ < arena[2] - ARENA_MARGIN_M or y_ > arena[3] + ARENA_MARGIN_M
                    or z_ < -CEILING_M):
                exit_reason, message = ExitReason.LEFT_ARENA, (
                    f"left the arena at N {x_:.2f} E {y_:.2f} D {z_:.2f} m")
                k += 1
                break
            if airborne and ground_ticks > 0 and not sitl:
                disarmed = u1 == 0.0 and u2 == 0.0 and u3 == 0.0 and u4 == 0.0
                app_done = app is not None and app.done
                if disarmed and (app is None or app_done):
                    touchdown = t_touch
                    exit_reason, message = ExitReason.MISSION_COMPLETE, "mission complete"
                    k += 1
                    break
                if (disarmed and ground_ticks > rest_ticks // 3) or ground_ticks > rest_ticks:
                    touchdown = t_touch
                    exit_reason, message = ExitReason.LANDED, "landed before the app finished"
                    k += 1
                    break
            if realtime:
                ahead = (t + h) / opts.speed - (time.perf_counter() - wall0)
                if ahead > 0:
                    time.sleep(ahead)
            if progress and k % 2000 == 0:
                el = time.perf_counter() - wall0
                print(f"\r  t = {t:7.1f} s  phase = {phases[pi]:<12s} "
                      f"{t / el if el > 0 else 0:6.0f}x real time", end="", file=sys.stderr)
        else:
            k = n_ticks
    except ComponentError as exc:
        exit_reason, message = ExitReason.COMPONENT_ERROR, str(exc)
    except KeyboardInterrupt:
        exit_reason, message = ExitReason.INTERRUPTED, "interrupted"
    finally:
        wall_end = time.perf_counter()
        wall = wall_end - wall0
        loop_wall = wall_end - loop0 if loop0 is not None else 0.0
        if opts.progress:
            print(file=sys.stderr)
        stats = {}
        if vehicle is not None:
            vehicle.close()  # first: a SIL process reports its counters as it exits
            stats = vehicle.stats()
        if plant is not None:
            plant.close()
    ticks = len(rows)
    series = np.array(rows, dtype=np.float64).reshape(ticks, len(SERIES_COLUMNS))
    return RunResult(
        scenario=sc, mode=opts.mode, exit_reason=exit_reason, message=message, ticks=ticks,
        t_end_s=ticks * h, wall_s=wall, series=series, phases=phases,
        events=list(getattr(app, "events", [])) if app is not None else [],
        frame_log=list(getattr(app, "frame_log", [])) if app is not None else [],
        app_metrics=_app_metrics(app), touchdown=touchdown, tlog=tlog, frames=frames,
        png_frames=png_frames, onboard_stats=stats, loop_wall_s=loop_wall,
    )


def _app_metrics(app) -> dict[str, float]:
    if app is None or not hasattr(app, "metrics"):
        return {}
    try:
        return dict(app.metrics())
    except Exception:
        return {}


def _call_app(fn, *args) -> None:
    try:
        fn(*args)
    except ComponentError:
        raise
    except Exception as exc:
        raise ComponentError("app", f"{type(exc).__name__}: {exc}") from exc


def _quat(y: list[float]) -> tuple[float, float, float, float]:
    from cosim.plant.fmu import Y_QW, Y_QZ

    return tuple(y[Y_QW:Y_QZ + 1])
