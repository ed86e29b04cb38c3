"""`cosim`: run, validate, sweep, montecarlo, sitl, render, teach, onboard, tune, bench."""

from __future__ import annotations

import argparse
import contextlib
import errno
import signal
import sys
import threading
from pathlib import Path

from cosim import cli_checks
from cosim.cli_checks import add_numerics, check_out_dir, check_speed, enter_numerics, live_view
from cosim.errors import OutputError, ScenarioError
from onesource.switch import CompiledError

EXAMPLES = {
    "run": """examples:
  cosim run scenarios/mambo_seed_track.toml
  cosim run scenarios/mambo_seed_track.toml --mode sil --out runs/seed-sil
  cosim run scenarios/mambo_turns.toml --set app.alpha=0.008 --set seed=3
  cosim run scenarios/mambo_seed_track.toml --realtime --speed 2 --video --png-every 5
  cosim run scenarios/mambo_seed_track.toml --mcap      run.mcap for Foxglove / PlotJuggler
  cosim run scenarios/bebop2_vs_e1.toml --realtime --foxglove   watch it live (ws://...:8765)""",
    "validate": """examples:
  cosim validate scenarios/mambo_seed_track.toml
  cosim validate scenarios/*.toml""",
    "sweep": """examples:
  cosim sweep scenarios/mambo_seed_track.toml --set app.alpha=0.002,0.0038,0.006,0.008,0.010
  cosim sweep scenarios/mambo_textured.toml --set seed=0,1,2,3 --set app.k_t=100,150
  cosim sweep scenarios/scripted_square.toml --set seed=0,1 --executor serial
  cosim sweep scenarios/mambo_turns.toml --set app.alpha=0.004,0.006,0.008 --workers 2
a sweep is a study (cosim/studies), on a local Dask cluster by default: results.csv streamed
and resumable with the same command, report.md with statistics, sweep.png with one swept
key; study options (--executor, --scheduler, --keep-runs, --retry-failed, --limit): see
`cosim montecarlo --help`.""",
    "sitl": """examples:
  cosim sitl                                  then connect QGroundControl (UDP 14550)
  cosim sitl --vehicle bebop2 --world turns   MAVSDK / scripts on UDP 14540
  cosim sitl -i 1                             a second vehicle (own process, own world):
                                              sysid 2, API to 14541, GCS bound on 18571
  cosim sitl -n 3                             three vehicles in one world: sysid 1, 2, 3
  cosim sitl --gcs-remote 127.0.0.1:14551 --gcs-bind 127.0.0.1:18571
  cosim sitl --foxglove                       and watch it in Foxglove (ws://127.0.0.1:8765)
ports of instance N, as PX4 SITL (sysid N+1):
  API link  sends to 14540+N from 14580+N   (MAVSDK: udpin://0.0.0.0:14540+N)
  GCS link  sends to 14550   from 18570+N   (QGroundControl sees every vehicle on 14550)
  --api-remote/--api-bind/--gcs-remote/--gcs-bind set the first vehicle's; with -n, vehicle
  k adds k to each port (0 = any free port stays 0) but the GCS remote, which all share.
-n: vehicle k (0..n-1) starts k x --spacing m east of the world's start, same heading.
A crash (hard touchdown, flipped, a collision) respawns that vehicle at its start, on the
ground, disarmed (links and sysid unchanged). Ctrl-C, SIGTERM or --duration: a normal stop,
exit 0; a part failing (the FMU, the flight stack): exit 1. Outputs: DIR/N/ per vehicle.""",
    "render": """examples:
  cosim render scenarios/bebop2_room_e1.toml --at 0,0,-1,0 --out view.png
  cosim render scenarios/bebop2_room_e2.toml --at 1,0.3,-1.2,20 --depth depth.png
  cosim render scenarios/bebop2_room_oval.toml --at 0,0,-1,90 --attitude 10,-5 --exact
  cosim render scenarios/mambo_seed_track.toml --at 57,95,-1.1,0 --camera down
--at is the body (CoG) pose: north, east, down (m, world NED) and heading (deg); the depth
image is a 16-bit PNG of millimetres along the optical axis (0 = nothing seen).""",
    "teach": """examples:
  cosim teach scenarios/bebop2_vs_e2.toml --out runs/vp-e2          render the key images
  cosim teach scenarios/bebop2_vs_e1.toml --fly --via 1:0.8,0.45,-1 --out runs/vp-e1f
      fly (round the bar) and take each key image in hover
  cosim run scenarios/bebop2_vs_e1.toml --set app.params.visual_path=$PWD/runs/vp-e1f
Without a visual_path, `cosim run` teaches by rendering into the run folder first.""",
    "bench": """examples:
  cosim bench                   full measurement (a few minutes), figures + runs/bench.json
  cosim bench --quick           a short smoke run
  cosim bench --flood           only SIL under a UDP flood (1-2 minutes)
  cosim bench --instructions    instructions per MIL tick, compiled vs Python reference
  cosim bench --live            what the live view (--foxglove) costs the loop
                                (needs Valgrind; 5-8 minutes; noise-free on a shared host)""",
}

EPILOG = """examples:
  cosim run scenarios/mambo_seed_track.toml                 fly the seed mission (MIL)
  cosim run scenarios/mambo_seed_track.toml --mode sil      onboard stack as its own process
  cosim run scenarios/mambo_seed_track.toml --realtime --speed 2 --video
  cosim run scenarios/scripted_square.toml --set seed=3 --out runs/sq3
  cosim validate scenarios/*.toml
  cosim sweep scenarios/mambo_seed_track.toml --set app.alpha=0.002,0.003,0.0038,0.005,0.006
  cosim montecarlo scenarios/mambo_seed_track.toml -n 200 --vary 'wind.n_mps=uniform(0,1.5)'
  cosim sitl --vehicle mambo                                 fly it from QGroundControl
  cosim onboard --vehicle mambo --hil-bind 127.0.0.1:4560   the flight stack alone
  cosim tune mambo                                           loop margins (python-control)
  cosim teach scenarios/bebop2_vs_e2.toml --fly              key images for a visual path
  cosim bench --quick                                        speed of every part
exit status: 0 pass, 1 a pass criterion failed or the run ended in error, 2 bad input."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cosim", description="Co-simulation of vision-based quadrotor flight.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="cmd", required=True)

    def add(name: str, **kw) -> argparse.ArgumentParser:
        return sub.add_parser(name, epilog=EXAMPLES.get(name),
                              formatter_class=argparse.RawDescriptionHelpFormatter, **kw)

    r = add("run", help="fly one scenario")
    r.add_argument("scenario")
    r.add_argument("--mode", choices=("mil", "sil"), default="mil")
    r.add_argument("--hil-transport", choices=("udp", "unix"), default="udp",
                   help="SIL: the simulator link between the processes (unix: a Unix-domain "
                        "socket; the api and gcs links stay UDP; same results)")
    r.add_argument("--hil-exchange", choices=("auto", "typed", "framed"), default="auto",
                   help="MIL: the HIL exchange in this process as the records its MAVLink "
                        "frames decode to (typed) or as the frames (framed, as SIL's); auto: "
                        "typed unless the scenario has [faults] (their hooks act on "
                        "datagrams); same results")
    r.add_argument("--realtime", action="store_true", help="pace against the wall clock")
    r.add_argument("--speed", type=float, default=1.0, help="real-time speed factor (--realtime)")
    r.add_argument("--out", type=Path, help="run folder (default runs/<scenario>-<mode>)")
    r.add_argument("--video", action="store_true", help="save the camera frames as camera.mp4")
    r.add_argument("--png-every", type=int, default=0, metavar="N",
                   help="save every Nth camera frame as PNG")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field, e.g. app.alpha=0.005 or seed=3")
    r.add_argument("--seed", type=int, default=None, help="the scenario seed (= --set seed=N)")
    r.add_argument("--no-plots", action="store_true")
    r.add_argument("--mcap", action="store_true",
                   help="also write run.mcap (Foxglove schemas; opens in Foxglove, PlotJuggler)")
    _add_foxglove(r)
    r.add_argument("--images", choices=("jpeg", "png", "raw"), default="jpeg",
                   help="camera frames in run.mcap and the live view: jpeg (default), png "
                        "(lossless) or raw (rgb8, ~20x the size)")
    r.add_argument("--foxglove-fps", type=float, default=10.0, metavar="HZ",
                   help="the live view's camera frames a second, at most (default 10)")
    r.add_argument("--render-worker", choices=("auto", "on", "off"), default="auto",
                   help="a delayed camera stream: render in a worker (a second process) while "
                        "the loop steps on; auto: when the machine has a free core (the same "
                        "flight every way)")
    r.add_argument("--quiet", action="store_true", help="no progress display")
    add_numerics(r)

    v = add("validate", help="check scenario files")
    v.add_argument("scenarios", nargs="+")

    s = add("sweep", help="many runs of one scenario over parameter values")
    s.add_argument("scenario")
    s.add_argument("--set", action="append", required=True, metavar="KEY=V1,V2,...")
    s.add_argument("--mode", choices=("mil", "sil"), default="mil")
    s.add_argument("--out", type=Path, help="sweep folder (default runs/sweep-<scenario>)")
    # a study (cosim/studies): results.csv, report.md, sweep.png; the same command continues
    from cosim.studies.command import add_montecarlo, add_study_options

    add_study_options(s, default_executor="dask")
    s.add_argument("--resume", action="store_true",
                   help="continue the study in --out (what the same command always does)")
    add_montecarlo(add)

    t = add("sitl", help="vehicles in a world, real time, for ground stations")
    t.add_argument("--vehicle", choices=("mambo", "bebop2"), default="mambo")
    t.add_argument("--world", default="seed", help="a world file or built-in name (seed, ...)")
    t.add_argument("-i", "--instance", type=int, default=0, metavar="N",
                   help="PX4 SITL instance of the (first) vehicle: sysid N+1, ports + N")
    t.add_argument("-n", "--count", type=int, default=1, metavar="COUNT",
                   help="vehicles in one world, one process: instances N .. N+COUNT-1")
    t.add_argument("--spacing", type=float, default=1.0, metavar="M",
                   help="m east between neighbouring vehicles' starts (default 1)")
    t.add_argument("--speed", type=float, default=1.0)
    t.add_argument("--feed", choices=("hil", "truth"), default="hil",
                   help="what the vehicles fly on: hil (default): PX4's sensor messages and "
                        "the onboard estimator; truth: the plant's state as ODOMETRY (motion "
                        "capture)")
    t.add_argument("--duration", type=float, default=86_400.0,
                   help="s of simulated time (default 86400)")
    t.add_argument("--out", type=Path, help="folder (default runs/sitl-<vehicle>); "
                   "instance N writes DIR/N/")
    t.add_argument("--mcap", action="store_true", help="also write run.mcap at the end")
    _add_foxglove(t)
    t.add_argument("--signing-key", type=Path, metavar="FILE",
                   help="MAVLink 2 signing key file (32 bytes, or 64 hex digits): the vehicle "
                        "signs what it sends and rejects unsigned messages on both links")
    t.add_argument("--gcs-remote", metavar="HOST:PORT", help="default 127.0.0.1:14550")
    t.add_argument("--gcs-bind", metavar="HOST:PORT", help="default 127.0.0.1:18570+N")
    t.add_argument("--api-remote", metavar="HOST:PORT", help="default 127.0.0.1:14540+N")
    t.add_argument("--api-bind", metavar="HOST:PORT", help="default 127.0.0.1:14580+N")

    sub.add_parser("onboard", help="the onboard flight stack process (see --help)",
                   add_help=False)
    sub.add_parser("tune", help="controller loop margins and step responses (see --help)",
                   add_help=False)

    g = add("render", help="the camera image (and depth) from a pose, without flying")
    g.add_argument("scenario")
    g.add_argument("--at", required=True, metavar="N,E,D,YAW_DEG",
                   help="body pose: north, east, down (m) and heading (deg)")
    g.add_argument("--attitude", default="0,0", metavar="ROLL_DEG,PITCH_DEG")
    g.add_argument("--out", type=Path, default=Path("view.png"))
    g.add_argument("--depth", type=Path, default=None, metavar="PNG",
                   help="also write the depth image (16-bit PNG, mm; front camera)")
    g.add_argument("--camera", choices=("front", "down"), default=None,
                   help="this camera kind with its defaults instead of the scenario's")
    g.add_argument("--exact", action="store_true",
                   help="the reference ray caster instead of the fast renderer (front)")
    g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")

    te = add("teach", help="teach a visual path (key images) for a visual_servo scenario")
    te.add_argument("scenario")
    te.add_argument("--out", type=Path, default=None,
                    help="the visual path folder (default runs/visual-paths/<scenario>)")
    te.add_argument("--fly", action="store_true",
                    help="fly the key poses and take each image in hover (else render)")
    te.add_argument("--hover-s", type=float, default=2.0, help="s of hover at each key pose")
    te.add_argument("--via", action="append", default=[], metavar="K:N,E,D",
                    help="--fly: pass through N,E,D (m) before key K, e.g. round an obstacle")
    te.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")

    from cosim.regress.command import add_test

    add_test(add)

    b = add("bench", help="measure the speed of every part")
    b.add_argument("--quick", action="store_true", help="fewer repeats (a smoke test)")
    b.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    b.add_argument("--flood", action="store_true",
                   help="only the flood figure: the seed mission in SIL without and with "
                        "70k datagrams/s on the vehicle's GCS port")
    b.add_argument("--instructions", action="store_true",
                   help="only the work per MIL tick in CPU instructions (Valgrind's "
                        "cachegrind), compiled and Python reference, and their ratio")
    b.add_argument("--live", action="store_true",
                   help="only the live view's cost (--foxglove): the seed mission's loop "
                        "without it, with it unwatched, with a client on every topic")
    b.add_argument("--numerics", action="store_true",
                   help="only what the portable numerics cost: the seed mission and E2, native "
                        "and portable in fresh processes, alternately (~1.5 minutes)")
    b.add_argument("--peers", action="store_true",
                   help="only the lead over peers: the seed mission against RotorPy and "
                        "gym-pybullet-drones side by side (pip install '.[peers]'; "
                        "gym-pybullet-drones is not on PyPI: its checkout with pip install "
                        "--no-deps)")
    return p


def _add_foxglove(p: argparse.ArgumentParser) -> None:
    p.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="serve the run live to Foxglove / Lichtblick (Foxglove WebSocket "
                        "protocol) on PORT (default 8765; 0: any free port); see "
                        "docs/viewers.md")
    p.add_argument("--foxglove-host", default="127.0.0.1", metavar="HOST",
                   help="the live view's address (default 127.0.0.1, this machine only)")


def main(argv: list[str] | None = None) -> int:
    if argv is None:     # the cosim command itself: it may start again with other numerics
        cli_checks.ENTRY_ARGV = list(sys.argv[1:])
    try:
        return _main(argv)
    except CompiledError as exc:   # COSIM_COMPILED=1 and a module is not built from its source
        print(f"cosim: {exc}", file=sys.stderr)
        return 1


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "onboard":
        from mav.onboard import main as onboard_main

        return onboard_main(argv[1:])
    if argv and argv[0] == "tune":
        from mav.tune import main as tune_main

        return tune_main(argv[1:])
    args = _parser().parse_args(argv)
    with _sigterm_interrupts() as got:
        try:
            rc = _dispatch(args)
        except ScenarioError as exc:
            print(f"cosim: bad input: {exc}", file=sys.stderr)
            return 2
        except OutputError as exc:      # disk full, read-only, ...: what was written stays
            print(f"cosim: {exc}", file=sys.stderr)
            return 1
        except RecursionError:      # a value nested thousands deep that a check recursed into
            print("cosim: bad input: a value nested too deeply", file=sys.stderr)
            return 2
        except OSError as exc:
            if exc.errno != errno.ENAMETOOLONG:
                raise
            print(f"cosim: bad input: a path name too long ({str(exc.filename)[:80]}...)",
                  file=sys.stderr)
            return 2
        except KeyboardInterrupt:   # outside a run's loop (a run itself ends 'interrupted')
            print("cosim: interrupted", file=sys.stderr)
            rc = 130
    if got:
        print(f"cosim: stopped by signal {got[0]}; what was recorded is written",
              file=sys.stderr)
        return 128 + got[0]
    return rc


@contextlib.contextmanager
def _sigterm_interrupts():
    """SIGTERM ends a run the way Ctrl-C does: the loop stops, the onboard process is closed,
    everything recorded is written; the exit status is then 128 + 15."""
    got: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield got
        return

    def _term(signum, _frame) -> None:
        got.append(signum)
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    try:
        yield got
    finally:
        signal.signal(signal.SIGTERM, old)


# the commands that fly: each first removes the temporary folders of runs that died (SIGKILL,
# the OOM killer) before they could (cosim/tempdirs.py)
FLYING = ("run", "sweep", "montecarlo", "sitl", "teach", "render")


def _dispatch(args) -> int:
    if args.cmd in FLYING:
        from cosim import tempdirs

        tempdirs.sweep()
    if args.cmd == "validate":
        from cosim.load import load_scenario

        bad = 0
        for path in args.scenarios:          # every file checked, each reported
            try:
                sc = load_scenario(path)
            except ScenarioError as exc:
                bad += 1
                where = "" if str(path) in str(exc) else f" (in {path})"
                print(f"cosim: bad input: {exc}{where}", file=sys.stderr)
                continue
            print(f"{path}: ok ({sc.name}: vehicle {sc.vehicle.name}, app {sc.app.name}, "
                  f"t_final {sc.timing.t_final_s:g} s)")
        if bad and len(args.scenarios) > 1:
            print(f"cosim: {bad} of {len(args.scenarios)} files are bad", file=sys.stderr)
        return 2 if bad else 0
    if args.cmd == "run":
        return _run(args)
    if args.cmd == "sweep":
        from cosim.studies.command import sweep

        return sweep(args)
    if args.cmd == "montecarlo":
        from cosim.studies.command import montecarlo

        return montecarlo(args)
    if args.cmd == "sitl":
        from cosim.cli_sitl import sitl

        return sitl(args)
    if args.cmd == "render":
        from cosim.cli_render import render_command

        return render_command(args)
    if args.cmd == "teach":
        from cosim.cli_teach import teach_command

        return teach_command(args)
    if args.cmd == "test":
        from cosim.regress.command import test_command

        return test_command(args)
    if args.cmd == "bench":
        from cosim.bench.command import main as bench_main

        only = [f"--{k}" for k in ("instructions", "flood", "live", "numerics", "peers")
                if getattr(args, k)]
        if len(only) > 1:
            raise ScenarioError("bench", " ".join(only), "one of --instructions, --flood, "
                                "--live, --numerics, --peers")
        if args.json is not None and args.json.is_dir():
            raise ScenarioError("--json", str(args.json), "a file path (this is a folder)")

        return bench_main(quick=args.quick, json_path=args.json, flood_only=args.flood,
                          instructions=args.instructions, live_only=args.live,
                          numerics_only=args.numerics, peers_only=args.peers)
    raise AssertionError(args.cmd)


def _run(args) -> int:
    from cosim.load import load_scenario, with_set
    from cosim.outputs.folder import claim_run_folder
    from cosim.outputs.report import one_screen, write_run
    from cosim.scenario.sets import one_each
    from cosim.sim.master import ExitReason, RunOptions, run_scenario

    sc = load_scenario(args.scenario)
    if args.set:
        sc = with_set(sc, one_each(args.set))
    if args.seed is not None:
        sc = with_set(sc, {"seed": args.seed})
    check_speed(args.speed)
    sc = enter_numerics(args, sc)
    if args.speed != 1.0 and not args.realtime:
        raise ScenarioError("--speed", args.speed, "only with --realtime")
    if args.png_every < 0:
        raise ScenarioError("--png-every", args.png_every, "an integer >= 0")
    if (args.video or args.png_every) and sc.camera is None:
        print(f"cosim: warning: {sc.name} has no [camera]; --video / --png-every save nothing",
              file=sys.stderr)
    elif args.video and (sc.camera.width % 2 or sc.camera.height % 2):
        w, h = sc.camera.width, sc.camera.height   # mp4v (MPEG-4 part 2) takes even sizes
        print(f"cosim: warning: the camera is {w}x{h}; the video keeps {w - w % 2}x{h - h % 2}"
              f" (its encoder drops an odd last column / row); --png-every keeps every pixel",
              file=sys.stderr)
    out = args.out or Path("runs") / f"{sc.name}-{args.mode}"
    check_out_dir(out, "--out")
    if args.hil_transport != "udp" and args.mode != "sil":
        raise ScenarioError("--hil-transport", args.hil_transport, "only with --mode sil")
    if args.hil_exchange == "typed" and (args.mode != "mil" or sc.faults):
        raise ScenarioError("--hil-exchange", args.hil_exchange, "only with --mode mil and a "
                            "scenario without [faults] (they act on the HIL datagrams)")
    if args.foxglove is not None and not args.realtime:
        raise ScenarioError("--foxglove", args.foxglove, "together with --realtime (a live "
                            "view of a run faster than real time shows nothing useful)")
    opts = RunOptions(mode=args.mode, realtime=args.realtime, speed=args.speed,
                      hil_transport=args.hil_transport, hil_exchange=args.hil_exchange,
                      video=args.video, png_every=args.png_every, mcap=args.mcap,
                      images=args.images,
                      progress=not args.quiet and sys.stderr.isatty(), out_dir=out,
                      pipeline={"auto": None, "on": True, "off": False}[args.render_worker])
    with claim_run_folder(out), live_view(args) as live:
        opts.live = live
        res = run_scenario(sc, opts)
        summary = write_run(res, out, plots=not args.no_plots)
    print(one_screen(summary, out))
    for w in summary["warnings"]:
        print(f"cosim: warning: {w}", file=sys.stderr)
    if summary.get("output_errors"):     # e.g. a full disk: the summary says which files
        print(f"cosim: outputs not written in {out}: " + "; ".join(summary["output_errors"]),
              file=sys.stderr)
    if res.exit_reason is ExitReason.COMPONENT_ERROR:
        print(f"cosim: run failed: {res.message}", file=sys.stderr)
    if res.exit_reason is ExitReason.INTERRUPTED:    # Ctrl-C (SIGTERM: 143, below)
        return 130
    return 0 if summary["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
