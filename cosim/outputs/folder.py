"""A run folder: the files a run writes, and clearing them before a new run writes there."""

from __future__ import annotations

from pathlib import Path

# files a run folder may hold; removed before a run writes there, so folders never mix runs
OUTPUT_FILES = ("summary.json", "timeseries.csv", "frames.csv", "flight.tlog", "trajectory.png",
                "timeseries.png", "camera.mp4", "camera.avi", "run.mcap")


def clean_run_folder(out: Path) -> None:
    """Remove what an earlier run wrote into `out` (only the files a run writes)."""
    for name in OUTPUT_FILES:
        (out / name).unlink(missing_ok=True)
    frames = out / "frames"
    if frames.is_dir():
        for f in frames.glob("frame_*.png"):
            f.unlink()
