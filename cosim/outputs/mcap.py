"""A run as an MCAP file for Foxglove, Lichtblick and PlotJuggler, written through the Foxglove
SDK (`foxglove-sdk`). Every log time is simulation time (ns since t = 0), so the file of a run
is as deterministic as the run.

The topics and their schemas are `fox_topics.TOPICS` (the frames and 3D scene:
`fox_scene.py`), plus one `/mavlink/<NAME>` topic per MAVLink message type of the API and GCS
links (from the tlog). Camera frames are added while the run goes (`frame`); the per-tick
topics are written from the recorded series, block by block, after the run (`finish`), so the
tick loop pays nothing for them. A real-time run (one a person may kill) also calls `progress`
every simulated second: the rows recorded since are written and the chunk flushed, so the file
reads up to the last second after a SIGKILL (a reader of unindexed MCAP, e.g. `mcap`'s
StreamReader, takes it; `mcap recover` indexes it). docs/viewers.md says how to open the file
with the layout docs/cosim-layout.json.
"""

from __future__ import annotations

from pathlib import Path

import foxglove
import numpy as np
from foxglove import Context

from cosim.outputs.fox_topics import TOPICS, Topics

__all__ = ["TOPICS", "McapRun"]


class McapRun:
    """An open MCAP file for one run; `frame(t, img, p, q)` during the run, `finish(res)`
    after."""

    def __init__(self, path: Path, scenario) -> None:
        self.path = Path(path)
        self.ctx = Context()
        self._writer = foxglove.open_mcap(str(self.path), allow_overwrite=True, context=self.ctx)
        self.topics = Topics(self.ctx, scenario)
        self.topics.static()
        self.frames = 0
        self.written = 0            # rows of the series written (by `progress`)

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
            self.topics.row(row, phases or ["none"],
                            est=est[i] if est is not None and i < len(est) else None)
        self.written += len(rows)
        self._writer.flush()

    def finish(self, res) -> Path:
        """Write the recorded series (the rows `progress` did not), the app's outputs and
        the MAVLink traffic; close. A sensor-fed run's `/vehicle/estimate` carries the
        vehicle's whole estimate (`res.estimate`, one row per tick), not only its position."""
        topics, phases = self.topics, res.phases or ["none"]
        est = res.estimate
        n = 0 if est is None else len(est)
        k = 0                       # the row index of the block's first row
        for block in res.recorded.blocks():
            for i in range(min(len(block), max(0, self.written - k)), len(block)):
                topics.row(block[i], phases, est=est[k + i] if k + i < n else None)
            k += len(block)
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
