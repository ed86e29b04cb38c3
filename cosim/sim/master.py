"""The master algorithm: owns simulated time and steps every part in lockstep.

Tick k (t_k = k * h from the integer counter, h = 5 ms), the order of ARCHITECTURE.md:
1. read plant outputs y(t_k); 2. sensor models -> ODOMETRY stamped t_k; 3. on a camera tick,
render and hand the frame to the app; 4. the app's tick (reads telemetry, may send setpoints);
5. HIL: send ODOMETRY, the onboard stack drains its links, runs its controller, answers
HIL_ACTUATOR_CONTROLS stamped t_k; 6. apply the motor commands, step the plant to t_k+1;
7. record, check the exit conditions.

MIL runs the onboard stack in this process over in-memory links carrying the same MAVLink bytes;
SIL runs it as a separate process over loopback UDP. Both give bit-identical trajectories.
The parts are built by the small functions below; `run_scenario` is the loop. A part that fails
is named through one wrapper (`part`), and the run still returns what it recorded. Steps 5-7b
run as one C call (`cosim/plant/csrc/tail.c`, `make_tail`) when the simulator's extension is
built and no fault hook is set; the Python code of the loop is their reference
(tests/test_master_tail.py flies both).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import ComponentError
from cosim.outputs.folder import clean_run_folder
from cosim.outputs.tlog import Tlog
from cosim.plant.fmu import Y_ON_GROUND, Y_QW, Y_QX, Y_QY, Y_QZ, Y_VZ, Y_X, Y_Y, Y_Z, Plant
from cosim.scenario.records import Scenario
from cosim.sensors.camera import PngSink, VideoSink, make_camera
from cosim.sensors.odometry import OdometrySensor
from cosim.sim.exits import ExitMonitor, ExitReason
from cosim.sim.onboard import OnboardHandle
from cosim.sim.options import RunOptions
from cosim.sim.recorder import SERIES_COLUMNS, SeriesFile, SeriesSpool
from mav import wire
from mav.hil import HilSimulatorCodec

__all__ = ["ExitReason", "RunOptions", "RunResult", "SERIES_COLUMNS", "run_scenario"]

FLUSH_MASK = 4095            # the recorder writes a block every 4096 ticks (k & mask == mask)
COMPILED_TAIL = True         # steps 5-7b in one C call (cosim/plant/csrc/tail.c) when there is
                             # no fault hook; False (or COSIM_FMI2STEP=0, the simulator's
                             # compiled side off): the Python loop below (the reference)
STALL_S = 0.2                # s, real-time mode: further behind the wall clock than this is a
                             # host stall; the pacing skips it instead of running the missed
                             # ticks back to back (a client could not have seen them)


@dataclass
class RunResult:
    scenario: Scenario
    mode: str
    exit_reason: ExitReason
    message: str
    ticks: int
    t_end_s: float
    wall_s: float
    recorded: SeriesFile                       # (ticks, len(SERIES_COLUMNS)) float64, on disk
    phases: list[str]                          # phase index -> name
    events: list[tuple[float, str]]
    frame_log: list[tuple]                     # per camera frame records from the app
    app_metrics: dict[str, float]
    touchdown: tuple[float, float, float] | None   # (t, x, y) of the final touchdown
    tlog: Tlog                                 # streamed to run_dir / flight.tlog
    run_dir: Path                              # where the run streamed its files
    video: Path | None = None                  # the camera video written, if asked
    png_count: int = 0                         # PNG frames written to run_dir / frames
    onboard_stats: dict[str, Any] = field(default_factory=dict)
    loop_wall_s: float = 0.0                   # s wall clock of the tick loop alone (no setup)
    faults: list[tuple[float, str]] = field(default_factory=list)   # (t s, what) that fired
    mcap: Path | None = None                   # run_dir / run.mcap when asked (RunOptions.mcap)
    realtime_stalls: int = 0                   # real time: host stalls skipped (> STALL_S late)
    realtime_lost_s: float = 0.0               # s of wall time they lost (not replayed)
    min_clearance: tuple[float, float, str] | None = None   # 3D worlds: (m, t s, to what)
    frame_columns: tuple[str, ...] | None = None   # the app's names for frame_log fields
    reference_poses: list[tuple[float, ...]] | None = None   # the app's taught path (n,e,d,yaw)
    estimate: np.ndarray | None = None         # sensor-fed runs: the vehicle's estimate per
                                               # tick (cosim/sim/estimate.ESTIMATE_COLUMNS)
    _tmp: Any = field(default=None, repr=False)   # owns the temporary spool folder

    @property
    def series(self) -> np.ndarray:
        """The whole series as a read-only array (memory-mapped: for short runs and tests;
        outputs read `recorded` by blocks or columns)."""
        return self.recorded.array()

    @property
    def real_time_factor(self) -> float:
        """End to end: simulated time / wall time including setup (FMU load, SIL start)."""
        return self.t_end_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def loop_real_time_factor(self) -> float:
        """The tick loop alone: simulated time / wall time from the first to the last tick."""
        return self.t_end_s / self.loop_wall_s if self.loop_wall_s > 0 else math.inf


@contextlib.contextmanager
def part(name: str):
    """Run a part's code; any failure becomes ComponentError(name) (one place for all parts)."""
    try:
        yield
    except ComponentError:
        raise
    except Exception as exc:
        raise ComponentError(name, f"{type(exc).__name__}: {exc}") from exc


class Pacer:
    """Real time: `wait(t)` sleeps until simulated time t (s) is due on the wall clock, at
    `speed` x real time from `wall0` (a perf_counter reading). Further behind than STALL_S is
    a host stall: skipped (the clock is moved on), counted in `stalls` and `lost_s`, not
    replayed as fast ticks."""

    __slots__ = ("speed", "wall0", "stalls", "lost_s")

    def __init__(self, speed: float, wall0: float) -> None:
        self.speed = speed
        self.wall0 = wall0
        self.stalls = 0
        self.lost_s = 0.0          # s of wall time lost to host stalls

    def wait(self, t: float) -> None:
        late = (time.perf_counter() - self.wall0) - t / self.speed
        if late < 0.0:
            time.sleep(-late)
        elif late > STALL_S:   # the host stalled: not replayed as fast ticks
            self.wall0 += late
            self.lost_s += late
            self.stalls += 1


# ------------------------------------------------------------------ the parts, built once
def build_plant(sc: Scenario) -> Plant:
    with part("plant"):
        return Plant(sc.vehicle, step_size=sc.timing.tick_s, x0=sc.start.n, y0=sc.start.e,
                     z0=0.0, yaw0=math.radians(sc.start.yaw_deg))


def build_camera(sc: Scenario):
    """The scenario's camera, chosen by its kind; None without a [camera] table."""
    if sc.camera is None:
        return None
    cam_seed = int(np.random.SeedSequence([sc.seed, 2]).generate_state(1)[0])
    with part("camera"):
        return make_camera(sc.camera, sc.world, seed=cam_seed)


def build_app(sc: Scenario, opts: RunOptions):
    from cosim.apps.registry import make_app

    with part("app"):
        return opts.app_override if opts.app_override is not None else make_app(sc.app)


def start_app(app, sc: Scenario, vehicle: OnboardHandle, camera, run_dir: Path) -> None:
    from cosim.apps.base import AppContext
    from mav.client import OffboardClient

    h = sc.timing.tick_s
    ctx = AppContext(client=OffboardClient(vehicle.api), tick_s=h,
                     frame_period_s=sc.timing.camera_every * h if camera else None,
                     rng=np.random.default_rng([sc.seed, 1]),
                     home_ned=(sc.start.n, sc.start.e, 0.0))
    with part("app"):
        if hasattr(app, "prepare"):   # an app that needs the scenario before it flies
            app.prepare(sc, run_dir)
        app.on_start(ctx)


def run_dir_for(opts: RunOptions) -> tuple[Path, Any]:
    """The folder the run streams its outputs to: `out_dir`, or a temporary one that lives as
    long as the result."""
    if opts.out_dir is not None:
        opts.out_dir.mkdir(parents=True, exist_ok=True)
        clean_run_folder(opts.out_dir)
        return opts.out_dir, None
    tmp = tempfile.TemporaryDirectory(prefix="cosim-run-")
    return Path(tmp.name), tmp


# ------------------------------------------------------------------ the loop
def run_scenario(sc: Scenario, opts: RunOptions | None = None) -> RunResult:
    """Fly one scenario. Never raises for a failing part: the result says why the run ended."""
    opts = opts or RunOptions()
    if opts.mode not in ("mil", "sil"):
        raise ValueError(f"mode: got {opts.mode!r}; allowed: mil, sil")
    if opts.hil_transport not in ("udp", "unix"):
        raise ValueError(f"hil_transport: got {opts.hil_transport!r}; allowed: udp, unix")
    run_dir, tmp = run_dir_for(opts)
    spool_tmp = tmp or tempfile.TemporaryDirectory(prefix="cosim-spool-")
    spool = SeriesSpool(Path(spool_tmp.name) / "series.f64")
    tlog = Tlog(run_dir / "flight.tlog")

    h = sc.timing.tick_s
    h_us = int(round(h * 1e6))
    n_ticks = int(round(sc.timing.t_final_s / h))
    cam_every = sc.timing.camera_every
    sensor = OdometrySensor(sc.noise, np.random.default_rng([sc.seed, 0]))
    wind_n, wind_e, wind_d = sc.wind_ned_mps
    home_n, home_e = sc.start.n, sc.start.e   # the vehicle's local origin, in world NED
    gusty = None                 # gusts or turbulence: the wind changes every tick
    if sc.wind is not None and not sc.wind.steady:
        from cosim.world.wind import WindField

        gusty = WindField(sc.wind, h, sc.seed).at
    hooks = opts.hooks
    if hooks is None and sc.faults:
        from cosim.sim.faults import FaultHooks

        hooks = FaultHooks(sc.faults, sc.seed)
    fps = 1.0 / (cam_every * h)
    video = VideoSink(run_dir / "camera.mp4", fps) if opts.video else None
    pngs = PngSink(run_dir / "frames") if opts.png_every else None
    mcap = None
    if opts.mcap:
        from cosim.outputs.mcap import McapRun

        mcap = McapRun(run_dir / "run.mcap")

    phases: list[str] = []
    phase_idx: dict[str, int] = {}
    exit_reason, message = ExitReason.TIME_LIMIT, "time limit reached"
    plant = vehicle = app = monitor = feed = None
    pacer = None                 # real-time mode: the wall-clock pacing and its host stalls
    wall0 = time.perf_counter()
    loop0 = None
    try:
        plant = build_plant(sc)
        camera = build_camera(sc)
        vehicle = OnboardHandle(sc, opts, tlog, run_dir, hooks)
        app = build_app(sc, opts)
        if app is not None:
            start_app(app, sc, vehicle, camera, run_dir)
        monitor = ExitMonitor(sc.world.arena, h, app, sitl=opts.sitl, scene=sc.world.scene,
                              body_radius=sc.vehicle.body_radius)
        codec = HilSimulatorCodec()
        nan3 = (math.nan, math.nan, math.nan)
        y = plant.y
        # the per-tick calls as locals (one lookup each per run, not per tick)
        measure, encode_odometry = sensor.measure, codec.encode_odometry
        encode_valid, encode_lost = codec.encode_odometry, codec.encode_odometry_lost
        # (HilSimulatorCodec.decode_actuators without its Python frame: None is checked here)
        exchange, decode_actuators = vehicle.exchange_call(), wire.decode_hil_actuator_controls
        plant_step, record, row = plant.step, spool.append, spool.pack
        # OnboardHandle.drain_gcs inline (the GCS tap stays the same object; a fault hook
        # replaces what it wraps)
        gcs_recv = vehicle.gcs.recv
        check_exit = monitor.check
        on_tick = app.on_tick if app is not None else None
        realtime, progress, png_every = opts.realtime, opts.progress, opts.png_every
        feed = None
        if sc.sensors is not None and sc.sensors.hil:   # sensor messages, the vehicle estimates
            from cosim.sim.estimate import SensorFeed

            feed = SensorFeed(sc, h)
            measure, decode_actuators = feed.measure, feed.decode
            encode_odometry = encode_valid = encode_lost = feed.encode
        tail = make_tail(encode_odometry, exchange, gcs_recv, app, phase_idx, phases, spool,
                         plant_step, gusty, (wind_n, wind_e, wind_d), (home_n, home_e),
                         monitor, decode_actuators) if hooks is None else None
        tail_run = tail.run if tail is not None else None
        loop0 = time.perf_counter()
        pacer = Pacer(opts.speed, loop0)
        pace = pacer.wait
        stage = "sensor"   # the part running now: a failure is reported as this part's
        try:
            for k in range(n_ticks):
                # 1-2. plant outputs at t_k -> ODOMETRY stamped t_k
                t_us = k * h_us
                t = t_us * 1e-6
                tlog.t_us = t_us
                stage = "sensor"
                meas = measure(y)
                if hooks is not None:
                    meas = hooks.on_odometry(t_us, meas)
                    encode_odometry = encode_lost if hooks.odometry_lost else encode_valid
                # 3-4. the camera on its ticks, then the app's tick
                if app is not None:
                    if camera is not None and k % cam_every == 0:
                        stage = "camera"
                        img = camera.render(y[Y_X:Y_Z + 1], tuple(y[Y_QW:Y_QZ + 1]))
                        if video is not None:
                            video.add(img)
                        if pngs is not None and (k // cam_every) % png_every == 0:
                            pngs.add(t, img)
                        if mcap is not None:
                            mcap.frame(t, img)
                        if hooks is not None:
                            img = hooks.on_frame(t_us, img)
                        stage = "app"
                        if img is not None:
                            app.on_frame(t, img)
                    stage = "app"
                    on_tick(t)
                if tail_run is not None:   # 5-7b compiled
                    stage = "tail"
                    y = tail_run(k, t_us, t, meas, y)
                    if y is None:
                        exit_reason, message = tail.ended
                        break
                    if realtime:
                        pace(t + h)
                    if progress and k % 2000 == 0:
                        show_progress(t, wall0, phases[tail.phase_index])
                    continue
                # 5. HIL exchange: ODOMETRY out, HIL_ACTUATOR_CONTROLS stamped t_k back
                stage = "onboard"
                ans = exchange(encode_odometry(t_us, meas))
                if ans is None:
                    raise ComponentError("onboard", "no HIL_ACTUATOR_CONTROLS answer")
                act = decode_actuators(ans)
                if act is None:
                    raise ValueError(f"not a valid HIL_ACTUATOR_CONTROLS frame ({len(ans)} bytes)")
                t_ans, u1, u2, u3, u4 = act
                if t_ans != t_us:
                    raise ComponentError("onboard",
                                         f"HIL answer stamped {t_ans} us for {t_us} us")
                while gcs_recv() is not None:   # the master's GCS end: into the tlog
                    pass
                # 7a. record the tick (state at t_k, commands held over [t_k, t_k+1))
                if app is not None:
                    sp = app.setpoint
                    ph = app.phase
                else:
                    sp, ph = nan3, "none"
                pi = phase_idx.get(ph)
                if pi is None:
                    pi = phase_idx[ph] = len(phases)
                    phases.append(ph)
                record(row(t, *y, u1, u2, u3, u4, meas[0], meas[1], meas[2],
                           sp[0] + home_n, sp[1] + home_e, sp[2], pi))  # setpoints: local -> world
                if k & FLUSH_MASK == FLUSH_MASK:
                    spool.flush()
                # 6. the motor commands -> the plant, stepped to t_k+1
                if hooks is not None:
                    u1, u2, u3, u4 = hooks.on_actuators(t_us, (u1, u2, u3, u4))
                vz = y[Y_VZ]
                stage = "plant"
                if gusty is not None:
                    wind_n, wind_e, wind_d = gusty(k)
                y = plant_step(u1, u2, u3, u4, wind_n, wind_e, wind_d)
                # 7b. exit conditions on the state at t_k+1
                ended = check_exit(t, y, vz, (u1, u2, u3, u4))
                if ended is not None:
                    exit_reason, message = ended
                    break
                if realtime:
                    pace(t + h)
                if progress and k % 2000 == 0:
                    show_progress(t, wall0, phases[pi])
        except ComponentError:
            raise
        except Exception as exc:   # the one place a part's failure is named
            if stage == "tail":
                stage = tail.stage
            raise ComponentError(stage, f"{type(exc).__name__}: {exc}") from exc
    except ComponentError as exc:
        exit_reason, message = ExitReason.COMPONENT_ERROR, str(exc)
    except KeyboardInterrupt:
        exit_reason, message = ExitReason.INTERRUPTED, "interrupted"
    finally:
        wall_end = time.perf_counter()
        if opts.progress:
            print(file=sys.stderr)
        stats = {}
        if vehicle is not None:
            vehicle.close()  # first: a SIL process reports its counters as it exits
            stats = vehicle.stats()
        if plant is not None:
            plant.close()
        tlog.close()
        recorded = spool.finish()
        video_path = video.close() if video is not None else None
    res = RunResult(
        scenario=sc, mode=opts.mode, exit_reason=exit_reason, message=message,
        ticks=recorded.ticks, t_end_s=recorded.ticks * h, wall_s=wall_end - wall0,
        recorded=recorded, phases=phases,
        events=list(getattr(app, "events", [])) if app is not None else [],
        frame_log=list(getattr(app, "frame_log", [])) if app is not None else [],
        app_metrics=_app_metrics(app), touchdown=monitor.touchdown if monitor else None,
        tlog=tlog, run_dir=run_dir, video=video_path,
        png_count=pngs.count if pngs is not None else 0, onboard_stats=stats,
        loop_wall_s=wall_end - loop0 if loop0 is not None else 0.0,
        faults=hooks.fired() if hooks is not None else [],
        realtime_stalls=pacer.stalls if pacer else 0,
        realtime_lost_s=pacer.lost_s if pacer else 0.0,
        min_clearance=monitor.min_clearance if monitor else None,
        frame_columns=getattr(app, "frame_columns", None),
        reference_poses=list(getattr(app, "reference_poses", None) or []) or None,
        _tmp=(tmp, spool_tmp),
    )
    if feed is not None:
        res.estimate = feed.array()
        res.faults = sorted(res.faults + feed.fired())
    if mcap is not None:
        res.mcap = mcap.finish(res)
    return res


def show_progress(t: float, wall0: float, phase: str) -> None:
    el = time.perf_counter() - wall0
    print(f"\r  t = {t:7.1f} s  phase = {phase:<12s} "
          f"{t / el if el > 0 else 0:6.0f}x real time", end="", file=sys.stderr)


def make_tail(encode_odometry, exchange, gcs_recv, app, phase_idx, phases, spool, plant_step,
              gusty, wind, home, monitor, decode=None):
    """The compiled steps 5-7b of the loop (cosim/plant/csrc/tail.c), or None without the
    library or with COMPILED_TAIL off: the loop then runs them in Python, the reference."""
    if (not COMPILED_TAIL or os.environ.get("COSIM_FMI2STEP", "1") == "0"
            or type(monitor) is not ExitMonitor):   # its exit test is ExitMonitor.check's
        return None
    try:
        from cosim.plant._fmi2step import Tail
    except ImportError:
        return None
    from cosim.sim import exits

    consts = (Y_Z, Y_ON_GROUND, Y_QX, Y_QY, Y_X, Y_Y, Y_VZ, exits.AIRBORNE_Z_M,
              exits.FLIP_PRECHECK, exits.CEILING_M, FLUSH_MASK)
    return Tail(encode_odometry, exchange, decode or wire.decode_hil_actuator_controls,
                gcs_recv, app, phase_idx, phases, spool, plant_step, gusty, wind, home, monitor,
                consts, ComponentError)


def _app_metrics(app) -> dict[str, float]:
    if app is None or not hasattr(app, "metrics"):
        return {}
    try:
        return dict(app.metrics())
    except Exception:
        return {}
