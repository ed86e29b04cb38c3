"""Checks and set-up the `cosim` sub-commands share (cosim/cli.py, cosim/cli_sitl.py)."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from cosim.errors import ScenarioError


@contextlib.contextmanager
def live_view(args):
    """The live view asked for by --foxglove (None without), stopped at the end."""
    if args.foxglove is None:
        yield None
        return
    if not 0 <= args.foxglove <= 65535:
        raise ScenarioError("--foxglove", args.foxglove, "a port in 0..65535")
    from cosim.outputs.live import LiveView

    try:
        live = LiveView(args.foxglove, args.foxglove_host)
    except Exception as exc:
        raise ScenarioError("--foxglove", f"{args.foxglove_host}:{args.foxglove}",
                            f"an address the live view can listen on ({exc})") from None
    print(f"cosim: live view on {live.url} (Foxglove / Lichtblick: Open connection -> "
          f"Foxglove WebSocket)", file=sys.stderr, flush=True)
    try:
        yield live
    finally:
        live.close()


def check_speed(speed: float) -> None:
    if not (speed > 0 and speed < float("inf")):
        raise ScenarioError("--speed", speed, "a finite number > 0")


def check_out_dir(out: Path, flag: str) -> None:
    try:
        is_file = out.exists() and not out.is_dir()
    except OSError as exc:             # a name too long, ...
        raise ScenarioError(flag, str(out), f"a usable folder name ({exc.strerror})") from None
    if is_file:
        raise ScenarioError(flag, str(out), "a folder (this path is a file)")
