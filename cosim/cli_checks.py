"""Checks and set-up the `cosim` sub-commands share (cosim/cli.py, cosim/cli_sitl.py)."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from cosim.errors import ScenarioError

# the arguments `cosim` was started with when it runs as the command (cli.main with no argv):
# such a process may start again with the numerics a run needs; one called from Python may not
ENTRY_ARGV: list[str] | None = None


def add_numerics(p) -> None:
    p.add_argument("--numerics", choices=("native", "portable"), default=None,
                   help="portable: the same bits on every x86-64 CPU (OpenCV, numpy, OpenBLAS "
                        "and libm held to SSE4.2; E2 ~19%% slower); default: the scenario's "
                        "[run] numerics, else native (cosim/numerics.py)")


def enter_numerics(args, sc):
    """The scenario with the run's numerics (--numerics, else its [run] numerics); the `cosim`
    command starts itself again with them when its process does not run them. Called before
    anything is written. From Python (tests, scripts) the process stays as it is and
    run_scenario refuses portable numerics it does not have."""
    from cosim import numerics

    if args.numerics is not None and args.numerics != sc.numerics:
        from cosim.load import with_set

        sc = with_set(sc, {"run.numerics": args.numerics})
    if ENTRY_ARGV is not None and (args.numerics is not None or sc.numerics == "portable"):
        try:
            numerics.enter(sc.numerics, ENTRY_ARGV)
        except numerics.NumericsError as exc:
            raise ScenarioError("--numerics", sc.numerics, str(exc)) from None
    return sc


@contextlib.contextmanager
def live_view(args):
    """The live view asked for by --foxglove (None without), stopped at the end."""
    if args.foxglove is None:
        yield None
        return
    if not 0 <= args.foxglove <= 65535:
        raise ScenarioError("--foxglove", args.foxglove, "a port in 0..65535")
    from cosim.outputs.live import FPS, LiveView

    fps = getattr(args, "foxglove_fps", FPS)     # cosim run's options (sitl has no camera)
    if not (fps > 0 and fps < float("inf")):
        raise ScenarioError("--foxglove-fps", fps, "a number of frames a second > 0")
    try:
        live = LiveView(args.foxglove, args.foxglove_host, images=getattr(args, "images", "jpeg"),
                        fps=fps)
    except Exception as exc:
        raise ScenarioError("--foxglove", f"{args.foxglove_host}:{args.foxglove}",
                            f"an address the live view can listen on ({exc})") from None
    print(f"cosim: live view on {live.url} (Foxglove / Lichtblick: Open connection -> "
          f"Foxglove WebSocket)", file=sys.stderr, flush=True)
    try:
        yield live
    finally:
        if not live.close():
            print("cosim: live view: a client did not let go in time; not waited for",
                  file=sys.stderr, flush=True)


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
