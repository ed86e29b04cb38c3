"""The render worker of a delayed camera stream (issue 29's second core): paper 2's E2 with a
stream latency, flown with each frame rendered at capture in the loop ("sequential") and in
the stream's worker from capture to delivery ("pipelined": the render process, or the thread
with COSIM_RENDER_PROCESS=0), alternately in this one process (OpenCV as `cosim run` sets
it). Prints the wall time of each flight, the ratio of the medians, and whether the flights
are the same bit for bit (they must be).

    python -m cosim.bench.stream [--repeats N] [--set camera.latency_s=0.12 ...]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from cosim.bench.common import ROOT


def fly(sc, pipeline: bool) -> tuple[float, float, bytes, list]:
    """(wall s, simulated s, the series' bytes, the frames' capture/delivery ticks)."""
    from cosim.sim.master import RunOptions, run_scenario

    with tempfile.TemporaryDirectory(prefix="cosim-bench-stream-") as tmp:
        t0 = time.perf_counter()
        res = run_scenario(sc, RunOptions(mode="mil", out_dir=Path(tmp), pipeline=pipeline))
        wall = time.perf_counter() - t0
        return wall, res.t_end_s, np.asarray(res.series).tobytes(), res.frame_times


def main(argv: list[str] | None = None) -> int:
    from cosim.load import load_scenario, with_set
    from cosim.scenario.sets import one_each

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default=str(ROOT / "scenarios/bebop2_vs_e2.toml"))
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    a = ap.parse_args(argv)
    sets = one_each(a.set or ["camera.latency_s=0.12"])
    sc = with_set(load_scenario(a.scenario), sets)
    fly(sc, True)                                    # warm: textures, tiles, taught keys
    walls: dict[bool, list[float]] = {False: [], True: []}
    flights = {}
    for _ in range(a.repeats):
        for pipeline in (False, True):
            wall, sim, series, frames = fly(sc, pipeline)
            walls[pipeline].append(wall)
            flights[pipeline] = (series, frames)
            print(f"{'pipelined ' if pipeline else 'sequential'} {wall:7.2f} s wall for "
                  f"{sim:.1f} s simulated ({sim / wall:.1f}x real time)", flush=True)
    seq, pipe = statistics.median(walls[False]), statistics.median(walls[True])
    same = flights[False] == flights[True]
    print(f"{Path(a.scenario).name} with {sets}: sequential {seq:.2f} s, pipelined "
          f"{pipe:.2f} s (median of {a.repeats}): pipelined / sequential = {pipe / seq:.3f}; "
          f"same flight bit for bit: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
