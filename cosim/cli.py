"""`cosim`: run, validate, sweep, montecarlo, sitl, render, teach, onboard, tune, bench."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from pathlib import Path

from cosim.errors import OutputError, ScenarioError
from mav.compiled import CompiledError

EXAMPLES = {
    "run": """examples:
  cosim run scenarios/mambo_seed_track.toml
  cosim run scenarios/mambo_seed_track.toml --mode sil --out runs/seed-sil
  cosim run scenarios/mambo_turns.toml --set app.alpha=0.008 --set seed=3
  cosim run scenarios/mambo_seed_track.toml --realtime --speed 2 --video --png-every 5
  cosim run scenarios/mambo_seed_track.toml --mcap      run.mcap for Foxglove / PlotJuggler""",
    "validate": """examples:
  cosim validate scenarios/mambo_seed_track.toml
  cosim validate scenarios/*.toml""",
    "sweep": """examples:
  cosim sweep scenarios/mambo_seed_track.toml --set app.alpha=0.002,0.0038,0.006,0.008,0.010
  cosim sweep scenarios/mambo_textured.toml --set seed=0,1,2,3 --set app.k_t=100,150
  cosim sweep scenarios/scripted_square.toml --set seed=0,1 --executor serial
  cosim sweep scenarios/mambo_turns.toml --set app.alpha=0.004,0.006,0.008 --executor dask
study options (--executor dask, --scheduler, --resume, --keep-runs, --retry-failed, --limit):
  the run goes through the study engine (cosim/studies): results.csv streamed and resumable
  with the same command, report.md with statistics; see `cosim montecarlo --help`.""",
    "sitl": """examples:
  cosim sitl                                  then connect QGroundControl (UDP 14550)
  cosim sitl --vehicle bebop2 --world turns   MAVSDK / scripts on UDP 14540
  cosim sitl -i 1                             a second vehicle (own process, own world):
                                              sysid 2, API to 14541, GCS bound on 18571
  cosim sitl -n 3                             three vehicles in one world: sysid 1, 2, 3
  cosim sitl --gcs-remote 127.0.0.1:14551 --gcs-bind 127.0.0.1:18571
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
    r.add_argument("--quiet", action="store_true", help="no progress display")

    v = add("validate", help="check scenario files")
    v.add_argument("scenarios", nargs="+")

    s = add("sweep", help="many runs of one scenario over parameter values")
    s.add_argument("scenario")
    s.add_argument("--set", action="append", required=True, metavar="KEY=V1,V2,...")
    s.add_argument("--mode", choices=("mil", "sil"), default="mil")
    s.add_argument("--out", type=Path, help="sweep folder (default runs/sweep-<scenario>)")
    # issue 15: studies at scale (cosim/studies); the plain form below is unchanged
    from cosim.studies.command import add_montecarlo, add_study_options

    add_study_options(s, default_executor="local")
    s.add_argument("--resume", action="store_true",
                   help="through the study engine: continue the study in --out")
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
    t.add_argument("--duration", type=float, default=86_400.0,
                   help="s of simulated time (default 86400)")
    t.add_argument("--out", type=Path, help="folder (default runs/sitl-<vehicle>); "
                   "instance N writes DIR/N/")
    t.add_argument("--mcap", action="store_true", help="also write run.mcap at the end")
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

    b = add("bench", help="measure the speed of every part")
    b.add_argument("--quick", action="store_true", help="fewer repeats (a smoke test)")
    b.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    b.add_argument("--flood", action="store_true",
                   help="only the flood figure: the seed mission in SIL without and with "
                        "70k datagrams/s on the vehicle's GCS port")
    b.add_argument("--instructions", action="store_true",
                   help="only the work per MIL tick in CPU instructions (Valgrind's "
                        "cachegrind), compiled and Python reference, and their ratio")
    return p


def main(argv: list[str] | None = None) -> int:
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


def _dispatch(args) -> int:
    if args.cmd == "validate":
        from cosim.scenario.parse import load_scenario

        for path in args.scenarios:
            sc = load_scenario(path)
            print(f"{path}: ok ({sc.name}: vehicle {sc.vehicle.name}, app {sc.app.name}, "
                  f"t_final {sc.timing.t_final_s:g} s)")
        return 0
    if args.cmd == "run":
        return _run(args)
    if args.cmd == "sweep":
        from cosim.studies.command import sweep, uses_study_engine

        return sweep(args) if uses_study_engine(args) else _sweep(args)
    if args.cmd == "montecarlo":
        from cosim.studies.command import montecarlo

        return montecarlo(args)
    if args.cmd == "sitl":
        return _sitl(args)
    if args.cmd == "render":
        from cosim.sensors.view import render_command

        return render_command(args)
    if args.cmd == "teach":
        from cosim.apps.vs.teach import teach_command

        return teach_command(args)
    if args.cmd == "bench":
        from cosim.studies.bench import main as bench_main

        if args.instructions and args.flood:
            raise ScenarioError("bench", "--instructions --flood", "one of the two")
        if args.json is not None and args.json.is_dir():
            raise ScenarioError("--json", str(args.json), "a file path (this is a folder)")

        return bench_main(quick=args.quick, json_path=args.json, flood_only=args.flood,
                          instructions=args.instructions)
    raise AssertionError(args.cmd)


def _run(args) -> int:
    from cosim.outputs.folder import claim_run_folder
    from cosim.outputs.report import one_screen, write_run
    from cosim.scenario.parse import load_scenario, with_set
    from cosim.sim.master import ExitReason, RunOptions, run_scenario
    from cosim.studies.sweep import parse_sets

    sc = load_scenario(args.scenario)
    if args.set:
        sc = with_set(sc, {k: v[0] for k, v in parse_sets(args.set, multi=False).items()})
    if args.seed is not None:
        sc = with_set(sc, {"seed": args.seed})
    _check_speed(args.speed)
    if args.speed != 1.0 and not args.realtime:
        raise ScenarioError("--speed", args.speed, "only with --realtime")
    if args.png_every < 0:
        raise ScenarioError("--png-every", args.png_every, "an integer >= 0")
    if (args.video or args.png_every) and sc.camera is None:
        print(f"cosim: warning: {sc.name} has no [camera]; --video / --png-every save nothing",
              file=sys.stderr)
    out = args.out or Path("runs") / f"{sc.name}-{args.mode}"
    _check_out_dir(out, "--out")
    if args.hil_transport != "udp" and args.mode != "sil":
        raise ScenarioError("--hil-transport", args.hil_transport, "only with --mode sil")
    opts = RunOptions(mode=args.mode, realtime=args.realtime, speed=args.speed,
                      hil_transport=args.hil_transport,
                      video=args.video, png_every=args.png_every, mcap=args.mcap,
                      progress=not args.quiet and sys.stderr.isatty(), out_dir=out)
    with claim_run_folder(out):
        res = run_scenario(sc, opts)
        summary = write_run(res, out, plots=not args.no_plots)
    print(one_screen(summary, out))
    if res.exit_reason is ExitReason.COMPONENT_ERROR:
        print(f"cosim: run failed: {res.message}", file=sys.stderr)
    return 0 if summary["passed"] else 1


def _sweep(args) -> int:
    from cosim.scenario.parse import load_scenario, with_set
    from cosim.studies.sweep import (
        EXECUTORS,
        make_jobs,
        parse_sets,
        plot_sweep,
        run_job,
        write_table,
    )

    sc = load_scenario(args.scenario)
    grid = parse_sets(args.set, multi=True)
    for key, values in grid.items():  # validate every value before starting any run
        for v in values:
            with_set(sc, {key: v})
    if args.workers is not None and args.workers < 1:
        raise ScenarioError("--workers", args.workers, "an integer >= 1")
    out = args.out or Path("runs") / f"sweep-{sc.name}"
    _check_out_dir(out, "--out")
    out.mkdir(parents=True, exist_ok=True)
    jobs = make_jobs(args.scenario, grid, out, args.mode)
    print(f"sweep: {len(jobs)} runs of {sc.name} ({args.executor} executor)", file=sys.stderr)
    results = EXECUTORS[args.executor](args.workers).map(run_job, jobs)
    keys = list(grid)
    table = write_table(results, keys, out)
    plot_sweep(results, keys[0], out)
    print(table.read_text())
    print(f"sweep outputs in {out}")
    return 0 if all(r["passed"] for r in results) else 1


def _sitl(args) -> int:
    from cosim.outputs.folder import claim_run_folder
    from cosim.scenario.parse import parse_scenario
    from cosim.sim.fleet import (
        MAX_INSTANCE,
        SitlOptions,
        instance_links,
        run_fleet,
        stop_on_signals,
        write_fleet,
    )
    from cosim.sim.master import ExitReason

    def hp(s: str | None, name: str) -> tuple[str, int] | None:
        if s is None:
            return None
        host, _, port = s.rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ScenarioError(name, s, "HOST:PORT with a port in 0..65535")
        return host, int(port)

    _check_speed(args.speed)
    if not 0 <= args.instance <= MAX_INSTANCE:
        raise ScenarioError("--instance", args.instance, f"0..{MAX_INSTANCE} (sysid N+1)")
    if not 1 <= args.count <= MAX_INSTANCE + 1 - args.instance:
        raise ScenarioError("--count", args.count, f"1..{MAX_INSTANCE + 1 - args.instance} "
                            f"(the last sysid is at most {MAX_INSTANCE + 1})")
    if not (args.spacing >= 0 and args.spacing < 1e3):
        raise ScenarioError("--spacing", args.spacing, "m in [0, 1000)")
    given = {f: hp(getattr(args, f), "--" + f.replace("_", "-"))
             for f in ("api_bind", "api_remote", "gcs_bind", "gcs_remote")}
    links = tuple(instance_links(args.instance + k, k, **given) for k in range(args.count))
    for name, (bind, remote) in links[-1].items():   # an explicit port + k still a port
        for what, (_, port) in (("bind", bind), ("remote", remote)):
            if port > 65535:
                raise ScenarioError(f"--{name}-{what}", port - args.count + 1,
                                    f"a port that leaves room for {args.count} vehicles")
    key = read_signing_key(args.signing_key, "--signing-key") if args.signing_key else None
    sc = parse_scenario({
        "name": f"sitl-{args.vehicle}",
        "vehicle": {"preset": args.vehicle},
        "world": _world_table(args.world),
        "timing": {"t_final_s": args.duration},
        "criteria": {"must_complete": False},
    }, source=str(Path.cwd() / "sitl.toml"))
    out = args.out or Path("runs") / sc.name
    _check_out_dir(out, "--out")
    so = SitlOptions(out_dir=out, instance=args.instance, count=args.count,
                     spacing_m=args.spacing, speed=args.speed, links=links, signing_key=key)
    _check_spawns(sc, so)
    print(f"cosim sitl: {args.count} x {args.vehicle} in world {args.world}; Ctrl-C to stop",
          file=sys.stderr, flush=True)
    folders = [out / str(args.instance + k) for k in range(args.count)]
    with contextlib.ExitStack() as held, stop_on_signals() as stop:
        for f in folders:
            held.enter_context(claim_run_folder(f))
        fr = run_fleet(sc, so, stop)
        lines = write_fleet(fr, mcap=args.mcap)
    print("\n".join(lines))
    if fr.exit_reason is ExitReason.COMPONENT_ERROR:
        print(f"cosim sitl: failed: {fr.message}", file=sys.stderr)
        return 1
    if fr.exit_reason is ExitReason.STOPPED:
        names = "/".join(signal.Signals(s).name for s in stop.signals[:1])
        print(f"cosim sitl: {fr.message}" + (f" ({names})" if names else ""))
    else:
        print(f"cosim sitl: {fr.message}")
    return 0


def _check_spawns(sc, so) -> None:
    """Every vehicle's start clear of walls, boxes and columns (3D worlds)."""
    from cosim.sim.fleet import start_offset

    scene = sc.world.scene
    if scene is None or scene.empty:
        return
    for k in range(so.count):
        e = sc.start.e + start_offset(k, so.spacing_m)
        gap, what = scene.clearance(sc.start.n, e, 0.0, sc.vehicle.body_radius)
        if gap < 0.0:
            raise ScenarioError("--count" if k else "--world", so.count if k else sc.name,
                                f"vehicles whose starts are clear: vehicle {k} would start at "
                                f"N {sc.start.n:.2f} E {e:.2f} m, in the {what}")


def read_signing_key(path: Path, flag: str) -> bytes:
    """A MAVLink 2 signing key from a file: 32 raw bytes, or 64 hex digits (whitespace ok)."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise ScenarioError(flag, str(path), f"a readable key file ({exc.strerror})") from None
    if len(raw) == 32:
        return raw
    try:
        key = bytes.fromhex(raw.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != 32:
        raise ScenarioError(flag, str(path), "a file of 32 bytes or 64 hex digits")
    return key


def _check_speed(speed: float) -> None:
    if not (speed > 0 and speed < float("inf")):
        raise ScenarioError("--speed", speed, "a finite number > 0")


def _check_out_dir(out: Path, flag: str) -> None:
    if out.exists() and not out.is_dir():
        raise ScenarioError(flag, str(out), "a folder (this path is a file)")


def _world_table(world: str) -> dict:
    """The [world] table naming a world file or a built-in world (its start pose is the
    vehicle's: the scenario parser takes it from the world)."""
    p = Path(world)
    if not p.suffix:
        p = Path(__file__).resolve().parent.parent / "scenarios" / "worlds" / f"{world}.toml"
    if not p.is_file():
        raise ScenarioError("--world", world, "a world file or a built-in world name")
    return {"file": str(p.resolve())}


if __name__ == "__main__":
    sys.exit(main())
