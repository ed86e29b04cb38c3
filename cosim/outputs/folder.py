"""A run folder: the files a run writes, and clearing them before a new run writes there."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

from cosim.errors import ScenarioError, output_error

# files a run folder may hold; removed before a run writes there, so folders never mix runs
OUTPUT_FILES = ("summary.json", "timeseries.csv", "frames.csv", "camera_frames.csv",
                "flight.tlog", "trajectory.png",
                "timeseries.png", "visual_servo.png", "camera.mp4", "camera.avi", "run.mcap",
                ".series.f64")   # the last: cosim sitl's series spool, if a run was killed


def clean_run_folder(out: Path) -> None:
    """Remove what an earlier run wrote into `out` (only the files a run writes). A folder
    where a run writes a file is not removed: ScenarioError naming it."""
    for name in OUTPUT_FILES:
        if (out / name).is_dir():
            raise ScenarioError("--out", str(out / name), f"a run folder where {name} can be "
                                "written (this is a folder: move it)")
    for name in OUTPUT_FILES:
        (out / name).unlink(missing_ok=True)
    frames = out / "frames"
    if frames.is_dir():
        for f in frames.glob("frame_*.png"):
            f.unlink()
    taught = out / "visual_path"       # a visual path the run taught itself (visual_servo)
    if (taught / "path.json").is_file():
        for f in [*taught.glob("[0-9][0-9][0-9].png"), taught / "path.json",
                  taught / "features.npz"]:
            f.unlink(missing_ok=True)


def cleared_by_run(out: Path) -> list[Path]:
    """The paths a run into `out` clears before it writes (resolved): its output files, the
    PNG frames folder and the visual path a run teaches itself."""
    out = out.resolve()
    return [*(out / n for n in OUTPUT_FILES), out / "frames", out / "visual_path"]


def check_inputs_kept(out: Path, inputs: dict[str, Path], flag: str = "--out") -> None:
    """A run never deletes what it reads: ScenarioError (naming the input's field and
    `flag`) when an input is, or lies in, something a run into `out` clears."""
    cleared = cleared_by_run(out)
    for name, path in inputs.items():
        p = path.resolve()
        for c in cleared:
            if p == c or c in p.parents:
                raise ScenarioError(name, str(path), f"an input outside what `{flag} {out}` "
                                    f"clears before the run writes there ({c}); give another "
                                    f"{flag} or move the input")


@contextlib.contextmanager
def claim_run_folder(out: Path, flag: str = "--out", what: str = "run") -> Iterator[Path]:
    """Hold `out` for one run (or one study, `what`): create it, check it is writable, and
    lock it so a second one into the same folder at the same time fails at once
    (ScenarioError naming `flag`) instead of both overwriting each other. The lock goes with
    the process (flock)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out / f".{what}.lock", os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise output_error(exc, out) from None
        raise ScenarioError(flag, str(out), f"a writable folder ({exc.strerror})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise ScenarioError(flag, str(out), f"a folder no other {what} is writing to (one "
                                "is running there now)") from None
        yield out
    finally:
        os.close(fd)
