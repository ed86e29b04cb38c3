"""A run as an MCAP file for Foxglove, Lichtblick and PlotJuggler, written through the Foxglove
SDK (`foxglove-sdk`). Every log time is simulation time (ns since t = 0), so the file of a run
is as deterministic as the run.

The topics and their schemas are `fox_topics.TOPICS` (the frames and 3D scene:
`fox_scene.py`), plus one `/mavlink/<NAME>` topic per MAVLink message type of the API and GCS
links (from the tlog). Camera frames are added while the run goes (`frame`); the per-tick
topics are written from the recorded series, block by block, after the run (`finish`), so the
tick loop pays nothing for them. The static messages (the frames' static transforms, the
world, the vehicle model) are written again every `STATIC_EVERY_S` of simulation time: a
viewer playing the file keeps only what it read since its last seek, and drops a scene sent
once when it plays on (Foxglove Studio 1.48: the room and the vehicle vanished on Play).
A real-time run (one a person may kill) also calls `progress` every simulated second: the
rows recorded since are written and the chunk flushed, so the file reads up to the last
second after a SIGKILL (a reader of unindexed MCAP, e.g. `mcap`'s StreamReader, takes it;
`mcap recover` indexes it); those rows carry no app command (`/app/setpoint` takes the
commands from the tlog at the end).

`/log` (foxglove.Log, the Log panel) holds the vehicle's STATUSTEXTs, one message per text
(its chunks joined, the copy the other link carried left out), and the run's events, faults
and end. The file's metadata record `cosim.summary` is the run's summary (scenario, seed,
exit, criteria, metrics: the deterministic part of summary.json), and the scenario file is
attached. docs/viewers.md says how to open the file with the layouts in docs/.
"""

from __future__ import annotations

from pathlib import Path

import foxglove
import numpy as np
from foxglove import Context
from foxglove.channels import LogChannel
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from foxglove.messages import Log, LogLevel

from cosim.outputs import fox_topics
from cosim.outputs.fox_scene import ts
from cosim.outputs.fox_topics import IMAGES, Topics
from cosim.outputs.series import COL

__all__ = ["TOPICS", "McapRun"]

TOPICS = {**fox_topics.TOPICS, "/log": "foxglove.Log"}     # the file's (and MAVLink's)
ZSTD_LEVEL = 9
# an app's setpoint command holds this long without a new one: PX4's offboard loss timeout
# (parameter COM_OF_LOSS_T, default 1 s)
COMMAND_HELD_NS = 1_000_000_000
SPT_ID = 84                  # SET_POSITION_TARGET_LOCAL_NED
# its type_mask bits (set: ignore; MAVLink POSITION_TARGET_TYPEMASK) of what /app/setpoint takes
SPT_FIELDS = (("x", 1), ("y", 2), ("z", 4), ("vx", 8), ("vy", 16), ("vz", 32), ("yaw", 1024),
              ("yaw_rate", 2048))
OFFSET_FRAMES = (7, 9)       # MAV_FRAME_LOCAL_OFFSET_NED, MAV_FRAME_BODY_OFFSET_NED: a move
STATIC_EVERY_S = 1.0        # the static messages again every this many seconds of sim time
SAME_TEXT_NS = 50_000_000   # a STATUSTEXT again within this: the other link's copy
CHUNK_CHARS = 50            # STATUSTEXT.text; a chunk shorter than this ends its text
# MAV_SEVERITY 0..7 (EMERGENCY .. DEBUG) -> the Log panel's levels
SEVERITY = (LogLevel.Fatal, LogLevel.Fatal, LogLevel.Error, LogLevel.Error, LogLevel.Warning,
            LogLevel.Info, LogLevel.Info, LogLevel.Debug)
# summary.json's fields that are the same run to run (not the wall time, versions, platform)
SUMMARY_KEYS = ("scenario", "description", "vehicle", "app", "sensors", "estimator", "seed",
                "mode", "exit_reason", "message", "sim_time_s", "ticks", "passed", "criteria",
                "metrics", "events", "faults")


class McapRun:
    """An open MCAP file for one run; `frame(t, img, p, q)` during the run, `finish(res)`
    after."""

    def __init__(self, path: Path, scenario, images: str = IMAGES[0]) -> None:
        self.path = Path(path)
        self.ctx = Context()
        # zstd chunks at level 9 (the seed mission's file 5 % smaller than the default 3, no
        # slower to write here; 19 was 12 % smaller and 4x slower), compressed on this thread:
        # the same bytes whatever the machine's cores
        self._writer = foxglove.open_mcap(str(self.path), allow_overwrite=True, context=self.ctx,
                                          writer_options=MCAPWriteOptions(
                                              compression=MCAPCompression.Zstd,
                                              compression_level=ZSTD_LEVEL,
                                              compression_threads=0))
        self.topics = Topics(self.ctx, scenario, images=images)
        self.topics.static()
        self.log = LogChannel("/log", context=self.ctx)
        self.frames = 0
        self.written = 0            # rows of the series written (by `progress`)
        self._every = int(round(STATIC_EVERY_S * 1e9))
        self._next_static = self._every     # the first: at t = 0, when the file opened

    def _row(self, row, phases: list[str], est, command=None) -> None:
        """One recorded row; the static messages again first when their time has come."""
        t_ns = int(round(float(row[COL["t"]]) * 1e9))
        if t_ns >= self._next_static:
            self.topics.static(t_ns)
            self._next_static = (t_ns // self._every + 1) * self._every
        self.topics.row(row, phases, est=est, command=command)

    def frame(self, t: float, img, p_W, q_WB) -> None:
        """A camera frame (H x W x 3 uint8 RGB) at simulation time t (s), body pose p_W, q_WB."""
        self.topics.frame(t, img, p_W, q_WB)
        self.frames += 1

    def progress(self, spool, phases: list[str], est_spool=None) -> None:
        """Write the series rows recorded since the last call (`spool`, the run's
        SeriesSpool; `est_spool`, a sensor-fed run's estimate spool) and flush the file."""
        ncols = spool.ncols
        rows = np.frombuffer(spool.since(self.written), dtype=np.float64).reshape(-1, ncols)
        est = None
        if est_spool is not None:
            est = np.frombuffer(est_spool.since(self.written), dtype=np.float64).reshape(
                -1, est_spool.ncols)
        for i, row in enumerate(rows):
            self._row(row, phases or ["none"],
                      est[i] if est is not None and i < len(est) else None)
        self.written += len(rows)
        self._writer.flush()

    def finish(self, res) -> Path:
        """Write the recorded series (the rows `progress` did not), the app's outputs and
        the MAVLink traffic; close. A sensor-fed run's `/vehicle/estimate` carries the
        vehicle's whole estimate (`res.estimate`, one row per tick), not only its position."""
        topics, phases = self.topics, res.phases or ["none"]
        est = res.estimate
        n = 0 if est is None else len(est)
        cmds = commands(res.tlog.path)
        j, cmd = 0, None
        k = 0                       # the row index of the block's first row
        t_col = COL["t"]
        for block in res.recorded.blocks():
            for i in range(min(len(block), max(0, self.written - k)), len(block)):
                row = block[i]
                t_ns = int(round(float(row[t_col]) * 1e9))
                while j < len(cmds) and cmds[j][0] <= t_ns:
                    cmd = cmds[j]
                    j += 1
                if cmd is not None and t_ns - cmd[0] > COMMAND_HELD_NS:
                    cmd = None
                self._row(row, phases, est[k + i] if k + i < n else None,
                          None if cmd is None else cmd[1])
            k += len(block)
        for r in res.frame_log:
            topics.vision(r, res.frame_columns)
        self._mavlink(res.tlog.path)
        self._run_log(res)
        self._summary(res)
        self._writer.close()
        return self.path

    def text(self, t_ns: int, level, name: str, message: str) -> None:
        self.log.log(Log(timestamp=ts(t_ns), level=level, message=message, name=name),
                     log_time=t_ns)

    def _run_log(self, res) -> None:
        """The run's events, faults and end on /log."""
        for t, what in res.events:
            self.text(int(round(t * 1e9)), LogLevel.Info, "cosim", str(what))
        for t, what in res.faults:
            self.text(int(round(t * 1e9)), LogLevel.Warning, "cosim fault", str(what))
        from cosim.outputs.report import FAILED_EXITS

        failed = res.exit_reason.value in FAILED_EXITS
        self.text(int(round(res.t_end_s * 1e9)), LogLevel.Error if failed else LogLevel.Info,
                  "cosim", f"run ended: {res.exit_reason.value}: {res.message}")

    def _summary(self, res) -> None:
        """The summary as metadata (strings: nested values as JSON), the scenario attached."""
        from cosim.outputs.report import summarize
        from cosim.outputs.strict import dumps

        s = summarize(res)
        self._writer.write_metadata("cosim.summary", {
            k: s[k] if isinstance(s[k], str) else dumps(s[k]) for k in SUMMARY_KEYS})
        src = Path(res.scenario.source) if res.scenario.source else None
        if src is not None and src.is_file():
            self._writer.attach(log_time=0, create_time=0, name=src.name,
                                media_type="application/toml", data=src.read_bytes())

    def close(self) -> None:
        """Close without the series (a run that could not finish writing)."""
        self._writer.close()

    def _mavlink(self, tlog_path: Path) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        from cosim.outputs.tlog import read_tlog

        mav = mavlink2.MAVLink(None)
        mav.robust_parsing = True
        texts = StatusTexts(self.text)
        for t_us, data in read_tlog(tlog_path):
            try:
                msg = mav.decode(bytearray(data))
            except Exception:
                continue
            if msg is not None:
                self.topics.mavlink(msg, t_us * 1000)
                if msg.get_type() == "STATUSTEXT":
                    texts.add(msg, t_us * 1000)


def commands(tlog_path: Path) -> list[tuple[int, dict[str, float]]]:
    """The apps' SET_POSITION_TARGET_LOCAL_NED in a tlog, in order: (t_ns, what it sets) with
    its MAV_FRAME: velocities (vx, vy, vz), yaw, yaw rate; a relative move's offsets (dx, dy,
    dz, dyaw: in an offset frame). An absolute position is left out (the series' setpoint has
    it, in world NED)."""
    from pymavlink.dialects.v20 import common as mavlink2

    from cosim.outputs.tlog import read_tlog

    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    out = []
    for t_us, data in read_tlog(tlog_path):
        v2 = data[0] == 0xFD and data[7] == SPT_ID and data[8] == data[9] == 0
        if not (v2 or (data[0] == 0xFE and data[5] == SPT_ID)):
            continue
        try:
            m = mav.decode(bytearray(data))
        except Exception:
            continue
        move = m.coordinate_frame in OFFSET_FRAMES
        d = {}
        for k, bit in SPT_FIELDS:
            if m.type_mask & bit or (k in "xyz" and not move):
                continue
            d[("d" + k) if move and k in ("x", "y", "z", "yaw") else k] = float(getattr(m, k))
        if d:
            d["frame"] = int(m.coordinate_frame)
            out.append((t_us * 1000, d))
    return out


class StatusTexts:
    """STATUSTEXTs to `out(t_ns, level, name, text)`, one call per text: the chunks of a long
    text (the same `id`, `chunk_seq` 0, 1, ...; the last shorter than 50 characters) joined,
    and the copy of a text the other link carried within SAME_TEXT_NS left out."""

    def __init__(self, out) -> None:
        self.out = out
        self._parts: dict[tuple, list[str]] = {}     # (sysid, compid, id) -> chunks so far
        self._last: dict[tuple, int] = {}            # (sysid, compid, severity, text) -> t_ns

    def add(self, msg, t_ns: int) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        text = msg.text if isinstance(msg.text, str) else msg.text.decode("utf-8", "replace")
        text = text.split("\0", 1)[0]
        if msg.id:
            key = (*src, msg.id)
            parts = self._parts.setdefault(key, [])
            if msg.chunk_seq != len(parts):       # a chunk lost or a copy: start again
                parts.clear()
                if msg.chunk_seq != 0:
                    return
            parts.append(text)
            if len(text) >= CHUNK_CHARS:
                return
            text = "".join(self._parts.pop(key))
        key = (*src, msg.severity, text)
        if t_ns - self._last.get(key, -SAME_TEXT_NS - 1) <= SAME_TEXT_NS:
            return
        self._last[key] = t_ns
        level = SEVERITY[msg.severity] if 0 <= msg.severity < len(SEVERITY) else LogLevel.Unknown
        self.out(t_ns, level, f"sysid {src[0]}", text)
