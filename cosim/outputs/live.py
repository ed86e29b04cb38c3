"""The live view: a run's topics served while it flies, through the Foxglove SDK's WebSocket
server (the Foxglove WebSocket protocol), for Foxglove or Lichtblick ("Open connection" ->
Foxglove WebSocket -> ws://127.0.0.1:PORT) next to the ground station that flies it. The
viewers connect to a relay (`live_relay.py`) in front of the SDK's server: it takes both
names of the protocol (`foxglove.websocket.v1`: Foxglove Studio 1.x, Lichtblick;
`foxglove.sdk.v1`: the current Foxglove), closes a client that does not finish its handshake,
drops one that stops reading, and lets `close` end within a deadline whatever the clients do.
The server announces the `time` capability and sends the simulation time (`clock`), so a
viewer's clock is the run's, not the wall clock.

The topics and schemas are the MCAP file's (`fox_topics.Topics`), but for the MAVLink topics
(the ground station shows those). `cosim run --realtime --foxglove [PORT]` and
`cosim sitl --foxglove [PORT]`; loopback by default, port 0 picks a free port (`port`).

The lockstep is never held up by a viewer: logging hands each message to the SDK, which
queues it per subscribed client (up to `BACKLOG` messages; a slow client loses the oldest)
and sends it from its own threads; nothing is encoded for a channel no client subscribed.
What the loop pays is the logging call: the last recorded tick every `EVERY` ticks (50 Hz at
h = 5 ms), the camera frames (compressed as in the file, at most `fps` a second of
simulation time), the app's new vision records, and the static messages (frames, world,
vehicle) again every `STATIC_EVERY` ticks (1 s) for clients that connect later.
`cosim bench --live` measures it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import foxglove
import numpy as np
from foxglove import Context
from foxglove.websocket import Capability

from cosim.outputs import fox_scene as fs
from cosim.outputs.fox_topics import Topics
from cosim.outputs.live_relay import Relay
from cosim.plant.fmu import Y_QW, Y_QX, Y_QY, Y_QZ, Y_X, Y_Y, Y_Z

DEFAULT_PORT = 8765          # Foxglove's default for a WebSocket connection
EVERY = 4                    # ticks between two live ticks (50 Hz at h = 5 ms)
STATIC_EVERY = 200           # ticks between two sends of the static messages (1 s)
BACKLOG = 256                # messages queued per client before the oldest are dropped
STOP_S = 2.0                 # `close` returns within this, whatever the clients do
FPS = 10.0                   # camera frames sent a second (of simulation time), at most


class LiveView:
    """A WebSocket server on `host:port` (0: any free port; `port` then says which)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", *,
                 images: str = "jpeg", fps: float = FPS) -> None:
        if not fps > 0:
            raise ValueError(f"fps: a number > 0, not {fps}")
        self.images, self.fps = images, fps
        self.ctx = Context()
        self.server = foxglove.start_server(name="cosim", host="127.0.0.1", port=0,
                                            context=self.ctx, message_backlog_size=BACKLOG,
                                            capabilities=[Capability.Time])
        try:
            self.relay = Relay(host, port, ("127.0.0.1", self.server.port))
        except BaseException:
            _bounded(self.server.stop, STOP_S)
            raise
        self.host = host
        self.port = self.relay.port
        self._t_ns = -1

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def vehicle(self, scenario, prefix: str = "", body: str = fs.BODY, app=None
                ) -> LiveVehicle:
        """The topics of one vehicle (a fleet's: one `prefix` and body frame each)."""
        return LiveVehicle(Topics(self.ctx, scenario, prefix=prefix, body=body,
                                  images=self.images), app, self.clock, self.fps)

    def clock(self, t_ns: int) -> None:
        """The simulation time (ns) to the clients (the `time` capability), if it moved on."""
        if t_ns > self._t_ns:
            self._t_ns = t_ns
            self.server.broadcast_time(t_ns)

    def close(self, timeout: float = STOP_S) -> bool:
        """Stop serving within `timeout` s: every client is disconnected (the relay first,
        so that the SDK's server has none left to wait for). False if a part did not stop
        in time; it is left to the end of the process (its threads never hold it)."""
        relay = self.relay.stop(0.5 * timeout)
        return _bounded(self.server.stop, 0.5 * timeout) and relay


def _bounded(fn: Callable[[], object], timeout: float) -> bool:
    """fn() in a daemon thread; whether it returned within `timeout` s. The wait can be
    interrupted by a signal (KeyboardInterrupt), unlike a call blocked in native code."""
    done = threading.Event()

    def call() -> None:
        try:
            fn()
        finally:
            done.set()
    threading.Thread(target=call, name="cosim-live-stop", daemon=True).start()
    return done.wait(timeout)


class LiveVehicle:
    """One vehicle's live topics; the loop calls `tick` (through `pacing`) and `frame`."""

    def __init__(self, topics: Topics, app=None,
                 clock: Callable[[int], None] | None = None, fps: float = FPS) -> None:
        self.topics = topics
        self.clock = clock
        self.frame_ns = int(round(1e9 / fps))       # a camera frame sent every this, at most
        self._next_frame = 0
        self.frame_log = getattr(app, "frame_log", None)
        self.columns = getattr(app, "frame_columns", None)
        self.k = 0
        self._vision = 0
        topics.static()

    def tick(self, rows: list[bytes], phases: list[str]) -> None:
        """After a tick: every EVERY ticks the last recorded row (if the recorder has one
        in memory: `SeriesSpool.rows`), the app's new vision records; now and then the
        static messages again."""
        k = self.k = self.k + 1
        if k % EVERY:
            return
        if rows and self.clock is not None:
            self.clock(int(round(float(np.frombuffer(rows[-1], dtype="<f8", count=1)[0])
                                 * 1e9)))
        if k % STATIC_EVERY and not self.topics.watched():
            return
        if rows:
            r = np.frombuffer(rows[-1], dtype="<f8")
            self.topics.row(r, phases)
            if k % STATIC_EVERY == 0:
                self.topics.static(int(round(float(r[0]) * 1e9)))
        log = self.frame_log
        if log is not None and len(log) > self._vision:
            for rec in log[self._vision:]:
                self.topics.vision(rec, self.columns)
            self._vision = len(log)

    def pacing(self, rows: list[bytes], phases: list[str],
               wait: Callable[[float], None] | None) -> Callable[[float], None]:
        """The loop's pacing call with the live tick first (`wait` None: not real time)."""
        tick = self.tick
        if wait is None:
            return lambda t: tick(rows, phases)

        def pace(t: float) -> None:
            tick(rows, phases)
            wait(t)
        return pace

    def frame(self, t: float, img, p_W, q_WB) -> None:
        """A camera frame, if `fps` lets it through (its transform and calibration with it)."""
        t_ns = int(round(t * 1e9))
        if t_ns < self._next_frame:
            return
        self._next_frame = t_ns + self.frame_ns - self.frame_ns // 100   # 1 % slack: jitter
        self.topics.frame(t, img, p_W, q_WB)

    def sitl_tick(self, t: float, y, rows: list[bytes] | None) -> None:
        """A fleet vehicle's tick: its pose at t (plant outputs y) every EVERY ticks, and
        the rest of a row when one was recorded this tick (`rows`: one every few ticks)."""
        k = self.k = self.k + 1
        if rows:
            self.topics.row(np.frombuffer(rows[-1], dtype="<f8"), ["none"], pose=False)
        if k % EVERY == 0:
            t_ns = int(round(t * 1e9))
            if self.clock is not None:
                self.clock(t_ns)
            self.topics.state(t_ns, float(y[Y_X]), float(y[Y_Y]), float(y[Y_Z]),
                              (float(y[Y_QW]), float(y[Y_QX]), float(y[Y_QY]), float(y[Y_QZ])))
            if k % STATIC_EVERY == 0:
                self.topics.static(t_ns)
