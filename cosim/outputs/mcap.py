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
docs/viewers.md says how to open the file with the layout docs/cosim-layout.json.
"""

from __future__ import annotations

from pathlib import Path

import foxglove
from foxglove import Context
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from cosim.outputs.fox_topics import IMAGES, TOPICS, Topics
from cosim.outputs.series import COL

__all__ = ["TOPICS", "McapRun"]

STATIC_EVERY_S = 1.0        # the static messages again every this many seconds of sim time


class McapRun:
    """An open MCAP file for one run; `frame(t, img, p, q)` during the run, `finish(res)`
    after."""

    def __init__(self, path: Path, scenario, images: str = IMAGES[0]) -> None:
        self.path = Path(path)
        self.ctx = Context()
        # zstd chunks, compressed on this thread: the same bytes whatever the machine's cores
        self._writer = foxglove.open_mcap(str(self.path), allow_overwrite=True, context=self.ctx,
                                          writer_options=MCAPWriteOptions(
                                              compression=MCAPCompression.Zstd,
                                              compression_threads=0))
        self.topics = Topics(self.ctx, scenario, images=images)
        self.topics.static()
        self.frames = 0

    def frame(self, t: float, img, p_W, q_WB) -> None:
        """A camera frame (H x W x 3 uint8 RGB) at simulation time t (s), body pose p_W, q_WB."""
        self.topics.frame(t, img, p_W, q_WB)
        self.frames += 1

    def finish(self, res) -> Path:
        """Write the recorded series, the app's outputs and the MAVLink traffic; close.
        A sensor-fed run's `/vehicle/estimate` carries the vehicle's whole estimate
        (`res.estimate`, one row per tick), not only its position."""
        topics, phases = self.topics, res.phases or ["none"]
        est = res.estimate
        n = 0 if est is None else len(est)
        k = 0
        every = int(round(STATIC_EVERY_S * 1e9))
        next_static = every                   # the first: at t = 0, when the file opened
        t_col = COL["t"]
        for block in res.recorded.blocks():
            for row in block:
                t_ns = int(round(float(row[t_col]) * 1e9))
                if t_ns >= next_static:
                    topics.static(t_ns)
                    next_static = (t_ns // every + 1) * every
                topics.row(row, phases, est=est[k] if k < n else None)
                k += 1
        for r in res.frame_log:
            topics.vision(r, res.frame_columns)
        self._mavlink(res.tlog.path)
        self._writer.close()
        return self.path

    def close(self) -> None:
        """Close without the series (a run that could not finish writing)."""
        self._writer.close()

    def _mavlink(self, tlog_path: Path) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        from cosim.outputs.tlog import read_tlog

        mav = mavlink2.MAVLink(None)
        mav.robust_parsing = True
        for t_us, data in read_tlog(tlog_path):
            try:
                msg = mav.decode(bytearray(data))
            except Exception:
                continue
            if msg is not None:
                self.topics.mavlink(msg, t_us * 1000)
