"""What a run produced (`RunResult`): the record the master returns and every output reads
(summary, metrics, plots, MCAP, the report)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.outputs.series import SeriesFile
from cosim.outputs.tlog import Tlog
from cosim.scenario.records import ExitReason, Scenario


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
    frame_times: list[tuple[int, int, float]] = field(default_factory=list)  # per delivered
                                               # frame: capture tick, delivery tick, blur px
    camera_stream: dict[str, Any] | None = None   # the stream's figures (FrameStream.summary)
    warnings: list[str] = field(default_factory=list)   # one line each (a full TMPDIR: ...)
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
