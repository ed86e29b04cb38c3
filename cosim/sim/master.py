"""The master algorithm: owns simulated time and steps every part in lockstep.

Tick k (t_k = k * h from the integer counter, h = 5 ms), the order of ARCHITECTURE.md:
1. read plant outputs y(t_k); 2. sensor models -> ODOMETRY stamped t_k; 3. on a camera tick,
render and hand the frame to the app; 4. the app's tick (reads telemetry, may send setpoints);
5. HIL: send ODOMETRY, the onboard stack drains its links, runs its controller, answers
HIL_ACTUATOR_CONTROLS stamped t_k; 6. apply the motor commands, step the plant to t_k+1;
7. record, check the exit conditions.

MIL runs the onboard stack in this process over in-memory links carrying the same MAVLink bytes;
SIL runs it as a separate process over loopback UDP. Both give bit-identical trajectories.
The parts are built by the small functions below; the tick itself is `cosim/sim/tick.py`
(the one tick of every loop: this one, with or without fault hooks, and `cosim sitl`'s);
`run_scenario` is the loop around it. A part that fails is named (`part` while building,
`Tick.stage` while flying), and the run still returns what it recorded.
"""

from __future__ import annotations

import contextlib
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from cosim import numerics, tempdirs
from cosim.errors import ComponentError, ScenarioError, output_error
from cosim.outputs.folder import check_inputs_kept, clean_run_folder
from cosim.outputs.result import RunResult
from cosim.outputs.series import SERIES_COLUMNS, SeriesSpool
from cosim.outputs.tlog import Tlog
from cosim.plant.fmu import Y_QW, Y_QZ, Y_X, Y_Z, Plant
from cosim.scenario.records import Scenario
from cosim.sensors.camera import PngSink, VideoSink, make_camera
from cosim.sensors.odometry import OdometrySensor
from cosim.sensors.stream import FrameStream
from cosim.sim.exits import ExitMonitor, ExitReason, failsafe_note
from cosim.sim.onboard import OnboardHandle
from cosim.sim.options import RunOptions
from cosim.sim.tick import Tick
from mav.hil import HilSimulatorCodec

__all__ = ["ExitReason", "RunOptions", "RunResult", "SERIES_COLUMNS", "run_scenario"]

STALL_S = 0.2                # s, real-time mode: further behind the wall clock than this is a
                             # host stall; the pacing skips it instead of running the missed
                             # ticks back to back (a client could not have seen them)


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
    if sc.plant is not None:    # a user's FMU or the FMI 3.0 build, through fmpy and the map
        from cosim.plant.mapped import MappedPlant

        pose = dict(step_size=sc.timing.tick_s, x0=sc.start.n, y0=sc.start.e,
                    yaw0=math.radians(sc.start.yaw_deg))
        with part("plant"):
            if sc.plant.fmu is not None:     # a user's: in a process of its own, with a timeout
                from cosim.plant.isolated import IsolatedPlant

                return IsolatedPlant(sc.vehicle, sc.plant, timeout_s=sc.plant.timeout_s, **pose)
            return MappedPlant(sc.vehicle, sc.plant, **pose)
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


def build_stream(sc: Scenario, camera, h_us: int, opts: RunOptions) -> FrameStream | None:
    """The camera's frames as its stream delivers them (cosim/sensors/stream.py)."""
    if camera is None:
        return None
    pipelined = opts.pipeline
    if pipelined is None:
        from cosim import cvthreads

        pipelined = cvthreads.run_threads() > 1
    return FrameStream(camera, sc.camera.stream, h_us, sc.seed, pipelined=pipelined)


def frames_wanted(app):
    """The app's own `frames_wanted` (cosim/apps/base.py), bound; None if its class has none.
    Looked up on the class: a wrapper that hands other attributes on to an app it wraps
    sees every frame unless it says otherwise itself."""
    fn = getattr(type(app), "frames_wanted", None)
    return fn.__get__(app) if callable(fn) else None


def build_app(sc: Scenario, opts: RunOptions):
    from cosim.apps.registry import make_app

    with part("app"):
        return opts.app_override if opts.app_override is not None else make_app(sc.app)


def start_app(app, sc: Scenario, vehicle: OnboardHandle, camera, run_dir: Path):
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
    return ctx


def run_dir_for(opts: RunOptions) -> tuple[Path, Any]:
    """The folder the run streams its outputs to: `out_dir`, or a temporary one that lives as
    long as the result."""
    if opts.out_dir is not None:
        opts.out_dir.mkdir(parents=True, exist_ok=True)
        clean_run_folder(opts.out_dir)
        return opts.out_dir, None
    tmp = tempdirs.folder("run")
    return Path(tmp.name), tmp


# ------------------------------------------------------------------ the loop
def run_scenario(sc: Scenario, opts: RunOptions | None = None) -> RunResult:
    """Fly one scenario. Never raises for a failing part: the result says why the run ended."""
    opts = opts or RunOptions()
    if opts.mode not in ("mil", "sil"):
        raise ValueError(f"mode: got {opts.mode!r}; allowed: mil, sil")
    if opts.hil_transport not in ("udp", "unix"):
        raise ValueError(f"hil_transport: got {opts.hil_transport!r}; allowed: udp, unix")
    try:                   # portable numerics are the process's, from its start
        numerics.check(sc.numerics)
    except numerics.NumericsError as exc:
        raise ScenarioError("run.numerics", sc.numerics, str(exc)) from None
    if opts.out_dir is not None:      # a run never clears what it reads (issue 31)
        from cosim.apps.registry import app_inputs

        check_inputs_kept(opts.out_dir, app_inputs(sc.app, sc.source))
    run_dir, tmp = run_dir_for(opts)
    try:
        spool_tmp = tmp or tempdirs.folder("spool")
        spool = SeriesSpool(Path(spool_tmp.name) / "series.f64")
    except OSError as exc:          # a full TMPDIR: said in one line, nothing flown
        raise output_error(exc, f"the series spool in TMPDIR ({tempfile.gettempdir()})"
                           ) from None
    tlog = Tlog(run_dir / "flight.tlog")

    h = sc.timing.tick_s
    h_us = int(round(h * 1e6))
    n_ticks = int(round(sc.timing.t_final_s / h))
    cam_every = sc.timing.camera_every
    sensor = OdometrySensor(sc.noise, np.random.default_rng([sc.seed, 0]))
    home_n, home_e = sc.start.n, sc.start.e   # the vehicle's local origin, in world NED
    gusty = None                 # gusts or turbulence: the wind changes every tick
    if sc.wind is not None and not sc.wind.steady:
        from cosim.world.wind import WindField

        gusty = WindField(sc.wind, h, sc.seed).at
    hooks = opts.hooks
    if hooks is None and sc.faults:
        from cosim.faults.core import FaultHooks

        hooks = FaultHooks(sc.faults, sc.seed)
    fps = 1.0 / (cam_every * h)
    video = VideoSink(run_dir / "camera.mp4", fps) if opts.video else None
    pngs = PngSink(run_dir / "frames") if opts.png_every else None
    mcap = None
    if opts.mcap:
        from cosim.outputs.mcap import McapRun

        mcap = McapRun(run_dir / "run.mcap", sc, opts.images)

    phases: list[str] = []
    exit_reason, message = ExitReason.TIME_LIMIT, "time limit reached"
    plant = vehicle = app = monitor = feed = stream = ctx = None
    pacer = None                 # real-time mode: the wall-clock pacing and its host stalls
    wall0 = time.perf_counter()
    loop0 = None
    try:
        plant = build_plant(sc)
        camera = build_camera(sc)
        stream = build_stream(sc, camera, h_us, opts)
        vehicle = OnboardHandle(sc, opts, tlog, run_dir, hooks)
        app = build_app(sc, opts)
        if app is not None:
            ctx = start_app(app, sc, vehicle, camera, run_dir)
        monitor = ExitMonitor(sc.world.arena, h, app, sitl=opts.sitl, scene=sc.world.scene,
                              body_radius=sc.vehicle.body_radius)
        sinks = []
        if video is not None:
            sinks.append(lambda k, t, img: video.add(img))
        if pngs is not None:
            png_every = opts.png_every
            sinks.append(lambda k, t, img: (k // cam_every) % png_every == 0
                         and pngs.add(t, img))
        if mcap is not None:
            sinks.append(lambda k, t, img: mcap.frame(t, img, tick.frame_y[Y_X:Y_Z + 1],
                                                      tick.frame_y[Y_QW:Y_QZ + 1]))
        live = None
        if opts.live is not None:   # the live view: its topics, the frames as they come
            with part("live view"):
                live = opts.live.vehicle(sc, app=app)
            sinks.append(lambda k, t, img: live.frame(t, img, tick.frame_y[Y_X:Y_Z + 1],
                                                      tick.frame_y[Y_QW:Y_QZ + 1]))
        if stream is not None:    # frames the app does not want are rendered only if seen
            stream.prepare_with(getattr(app, "frame_stage", None), frames_wanted(app),
                                render_all=bool(sinks) or hooks is not None)
            if stream.pipelined:
                from cosim import cvthreads

                cvthreads.apply(pipelined=True)
        codec = HilSimulatorCodec()
        if sc.sensors is not None and sc.sensors.hil:   # sensor messages, the vehicle estimates
            from cosim.sim.estimate import SensorFeed

            sensor = codec = feed = SensorFeed(sc, h, Path(spool_tmp.name) / "estimate.f64")
        tick = Tick(plant=plant, sensor=sensor, codec=codec,
                    exchange=vehicle.exchange_record if vehicle.typed else vehicle.exchange,
                    gcs_recv=vehicle.gcs.recv, tlog=tlog, spool=spool, monitor=monitor,
                    h_us=h_us, app=app, stream=stream, ctx=ctx, cam_every=cam_every,
                    sinks=sinks, hooks=hooks, home=(home_n, home_e), typed=vehicle.typed)
        phases = tick.phases
        run_tick = tick.run
        wind = sc.wind_ned_mps
        realtime, progress = opts.realtime, opts.progress
        loop0 = time.perf_counter()
        pacer = Pacer(opts.speed, loop0)
        pace = pacer.wait
        if live is not None:   # the live view logs the last recorded tick, then paces
            pace = live.pacing(spool.rows, phases, pace if realtime else None)
            realtime = True
        # real time, each simulated second: the tlog and the MCAP on disk up to now (what a
        # SIGKILL leaves is readable up to the last second)
        per_s = max(1, int(round(1.0 / h)))
        keep = keep_so_far(tlog, mcap, spool, phases, feed)
        for k in range(n_ticks):
            if gusty is not None:
                wind = gusty(k)
            ended = run_tick(k, wind)
            if ended is not None:
                exit_reason, message = ended
                break
            if realtime or progress:
                t = k * h_us * 1e-6
                if realtime:
                    if (k + 1) % per_s == 0:
                        keep()
                    pace(t + h)
                if progress and k % 2000 == 0:
                    show_progress(t, wall0, phases[tick.phase])
    except ComponentError as exc:
        exit_reason, message = ExitReason.COMPONENT_ERROR, str(exc)
    except KeyboardInterrupt:
        exit_reason, message = ExitReason.INTERRUPTED, "interrupted"
    finally:
        wall_end = time.perf_counter()
        if opts.progress:
            print(file=sys.stderr)
        stats = {}
        if stream is not None:   # first: a render process holds copies of the run's files
            stream.close()
        if vehicle is not None:
            vehicle.close()  # then: a SIL process reports its counters as it exits
            stats = vehicle.stats()
        if plant is not None:
            plant.close()
        tlog.close()
        recorded = spool.finish()
        message += failsafe_note(stats)      # why the vehicle did what it did, if it had to
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
    if stream is not None:
        res.frame_times = stream.times
        res.camera_stream = stream.summary(h)
    if feed is not None:
        res.estimate = feed.array()
        res.faults = sorted(res.faults + feed.fired())
    res.warnings = full_tmpdir(h, recorded, feed.spool.finish() if feed is not None else None)
    if mcap is not None:
        res.mcap = mcap.finish(res)
    return res


def keep_so_far(tlog: Tlog, mcap, spool: SeriesSpool, phases: list[str], feed):
    """What a real-time run writes out each simulated second: its tlog's buffer, and with
    `--mcap` the rows recorded since the last time (cosim/outputs/mcap.py `progress`)."""
    def keep() -> None:
        with part("recorder"):         # a write that fails ends the run as a part's failure
            tlog.flush()
            if mcap is not None:
                mcap.progress(spool, phases, feed.spool if feed is not None else None)
    return keep


def full_tmpdir(h: float, *spooled) -> list[str]:
    """One line naming TMPDIR when a spool there found its disk full: its rows from then on
    were held in memory (cosim/outputs/series.py), so nothing is lost, but the user should
    know."""
    for rec in spooled:
        if rec is not None and rec.error is not None:
            e = rec.error
            return [f"TMPDIR ({tempfile.gettempdir()}) is full ({e.strerror or e}): the run's "
                    f"series from t = {rec.on_disk * h:.2f} s on was held in memory, nothing "
                    "is lost; give TMPDIR a folder with room"]
    return []


def show_progress(t: float, wall0: float, phase: str) -> None:
    el = time.perf_counter() - wall0
    print(f"\r  t = {t:7.1f} s  phase = {phase:<12s} "
          f"{t / el if el > 0 else 0:6.0f}x real time", end="", file=sys.stderr)


def _app_metrics(app) -> dict[str, float]:
    if app is None or not hasattr(app, "metrics"):
        return {}
    try:
        return dict(app.metrics())
    except Exception:
        return {}
