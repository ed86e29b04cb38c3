"""One tick of the master algorithm, for every loop that steps a vehicle: `cosim run`
(master.py, with or without fault hooks, MIL or SIL) and `cosim sitl` (fleet.py, one `Tick`
per vehicle). Written once, in Python; compiled by Cython when built (onesource/switch.py).

Tick k (t_k = k * h from the integer counter), the order of ARCHITECTURE.md:
1-2. plant outputs y(t_k) -> the sensor -> ODOMETRY stamped t_k (`hooks.on_odometry`);
3. on a camera tick the frame is captured (the pose at t_k; rendered now, or on the stream's
   worker); every frame due at this tick (cosim/sensors/stream.py: capture + latency +
   jitter, in capture order; at once without a delay) goes to the sinks (video, PNG, MCAP,
   with its capture tick and pose), then (`hooks.on_frame`) to the app with its capture
   time in `ctx.frame_time`;
4. the app's tick (it reads telemetry, may send setpoints);
5. HIL: ODOMETRY out, the onboard stack's HIL_ACTUATOR_CONTROLS stamped t_k back; the GCS end
   of the master's links drained (into the tlog);
6. the row recorded (state at t_k, commands held over [t_k, t_k+1), setpoint, phase);
7. (`hooks.on_actuators`) the motor commands -> the plant, stepped to t_k+1;
8. the exit conditions on y(t_k+1) (`ExitMonitor.check`).

`run(k, wind)` returns the exit condition met, or None to go on. A failure inside is raised
as ComponentError naming the part that was running (`stage`).
"""

from __future__ import annotations

import math

import cython

from cosim.errors import ComponentError
from cosim.outputs.series import CHUNK
from cosim.plant.fmu import Y_VZ

NAN3 = (math.nan, math.nan, math.nan)


class Tick:
    """The parts of one vehicle, stepped together. `app`, `stream` (a camera's
    cosim.sensors.stream.FrameStream), `ctx` (the app's AppContext) and `hooks` may be None;
    `sinks` are called `(k, t, img)` with each delivered frame, k and t its capture tick and
    time (`frame_y`: the plant outputs at capture), before the app sees it; `record_every`
    ticks make one recorded row; `home` is the vehicle's local origin in world NED (setpoints
    are recorded in world coordinates); `typed`: `exchange` is the vehicle's typed HIL
    exchange (`OnboardHandle.exchange_record`) and `codec` gives and reads its records."""

    def __init__(self, *, plant, sensor, codec, exchange, gcs_recv, tlog, spool, monitor,
                 h_us: int, app=None, stream=None, ctx=None, cam_every: int = 1, sinks=(),
                 hooks=None, home: tuple[float, float] = (0.0, 0.0),
                 record_every: int = 1, typed: bool = False) -> None:
        self.y = plant.y
        self.plant_step = plant.step
        self.measure = sensor.measure
        if typed:     # MIL's typed HIL exchange: records, not frames (cosim/sim/onboard.py)
            self.encode = codec.record_odometry
            self.encode_lost = codec.record_odometry_lost
            self.decode = codec.decode_record
        else:
            self.encode = codec.encode_odometry
            self.encode_lost = codec.encode_odometry_lost
            self.decode = codec.decode_actuators
        self.exchange = exchange
        self.gcs_recv = gcs_recv
        self.tlog = tlog
        self.spool = spool
        self.monitor = monitor
        self.h_us = h_us
        self.app = app
        self.stream = stream
        self.ctx = ctx
        self.frame_y = self.y                # plant outputs at the capture of the last frame
        self.cam_every = cam_every
        self.sinks = tuple(sinks)
        self.hooks = hooks
        self.home_n, self.home_e = home
        self.record_every = record_every
        self.phases: list[str] = []          # phase index -> the app's phase name
        self.phase_idx: dict[str, int] = {}
        self.phase = 0                       # index of the phase last recorded
        self.stage = "sensor"                # the part running now

    def run(self, k: int, wind: tuple[float, float, float]):
        """Tick k; the exit condition met at t_k+1, or None."""
        try:
            return self._run(k, wind)
        except ComponentError:
            raise
        except Exception as exc:   # the one place a part's failure is named
            raise ComponentError(self.stage, f"{type(exc).__name__}: {exc}") from exc

    @cython.locals(t_us=cython.longlong, t=cython.double, vz=cython.double, y=list)
    def _run(self, k: int, wind: tuple[float, float, float]):
        t_us = k * self.h_us
        t = t_us * 1e-6
        self.tlog.t_us = t_us
        y = self.y
        hooks = self.hooks
        # 1-2. plant outputs at t_k -> ODOMETRY stamped t_k
        self.stage = "sensor"
        meas = self.measure(y)
        encode = self.encode
        if hooks is not None:
            meas = hooks.on_odometry(t_us, meas)
            if hooks.odometry_lost:
                encode = self.encode_lost
        # 3-4. the camera on its ticks, then the app's tick
        app = self.app
        if app is not None:
            self._camera_and_app(k, t_us, t, y)
        # 5. HIL exchange: ODOMETRY out, HIL_ACTUATOR_CONTROLS stamped t_k back
        self.stage = "onboard"
        ans = self.exchange(encode(t_us, meas))
        if ans is None:
            raise ComponentError("onboard", "no HIL_ACTUATOR_CONTROLS answer")
        t_ans, u1, u2, u3, u4 = self.decode(ans)
        if t_ans != t_us:
            raise ComponentError("onboard", f"HIL answer stamped {t_ans} us for {t_us} us")
        gcs_recv = self.gcs_recv
        if gcs_recv is not None:
            while gcs_recv() is not None:   # the master's GCS end: into the tlog
                pass
        # 6. record the tick (state at t_k, commands held over [t_k, t_k+1))
        if k % self.record_every == 0:
            if app is not None:
                sp = app.setpoint
                ph = app.phase
            else:
                sp = NAN3
                ph = "none"
            pi = self.phase_idx.get(ph)
            if pi is None:
                pi = self.phase_idx[ph] = len(self.phases)
                self.phases.append(ph)
            self.phase = pi
            spool = self.spool
            spool.append(spool.row(t, y, u1, u2, u3, u4, meas[0], meas[1], meas[2],
                                   sp[0] + self.home_n, sp[1] + self.home_e, sp[2], pi))
            if len(spool.rows) >= CHUNK:
                self.stage = "recorder"
                spool.flush()
                self.tlog.flush()       # a slow run killed later keeps its log up to here
        # 7. the motor commands -> the plant, stepped to t_k+1
        if hooks is not None:
            u1, u2, u3, u4 = hooks.on_actuators(t_us, (u1, u2, u3, u4))
        vz = y[Y_VZ]
        self.stage = "plant"
        self.y = y = self.plant_step(u1, u2, u3, u4, wind[0], wind[1], wind[2])
        # 8. exit conditions on the state at t_k+1
        return self.monitor.check(t, y, vz, (u1, u2, u3, u4))

    def _camera_and_app(self, k: int, t_us: int, t: float, y) -> None:
        """Steps 3-4: the capture on camera ticks; each frame due now to the sinks,
        `hooks.on_frame` and the app's `on_frame`; then the app's `on_tick`."""
        app, stream, hooks = self.app, self.stream, self.hooks
        if stream is not None:
            if k % self.cam_every == 0:
                self.stage = "camera"
                stream.capture(k, y)
            while stream.due(k):
                self.stage = "camera"
                kc, self.frame_y, img = stream.pop()
                tc = kc * self.h_us * 1e-6
                for sink in self.sinks:
                    sink(kc, tc, img)
                if hooks is not None:
                    img = hooks.on_frame(t_us, img)
                self.stage = "app"
                if img is not None:
                    if self.ctx is not None:
                        self.ctx.frame_time = tc
                    app.on_frame(t, img)
        self.stage = "app"
        app.on_tick(t)
