"""`cosim sitl`'s command line: vehicles for ground stations and scripts (the loop itself is
cosim/sim/fleet.py). Called by cosim/cli.py."""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
from pathlib import Path

from cosim.cli_checks import check_out_dir, check_speed, live_view
from cosim.errors import ScenarioError


def sitl(args) -> int:
    from cosim.load import parse_scenario
    from cosim.outputs.folder import claim_run_folder
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

    check_speed(args.speed)
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
        # on the sensors and the onboard estimator, as PX4 SITL's vehicles fly on EKF2;
        # --feed truth: the plant's state as ODOMETRY (motion capture)
        "sensors": {"feed": args.feed},
        "criteria": {"must_complete": False},
    }, source=str(Path.cwd() / "sitl.toml"))
    out = args.out or Path("runs") / sc.name
    check_out_dir(out, "--out")
    so = SitlOptions(out_dir=out, instance=args.instance, count=args.count,
                     spacing_m=args.spacing, speed=args.speed, links=links, signing_key=key)
    _check_spawns(sc, so)
    print(f"cosim sitl: {args.count} x {args.vehicle} in world {args.world}; Ctrl-C to stop",
          file=sys.stderr, flush=True)
    folders = [out / str(args.instance + k) for k in range(args.count)]
    with contextlib.ExitStack() as held, stop_on_signals() as stop:
        for f in folders:
            held.enter_context(claim_run_folder(f))
        so = dataclasses.replace(so, live=held.enter_context(live_view(args)))
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


def _world_table(world: str) -> dict:
    """The [world] table naming a world file or a built-in world (its start pose is the
    vehicle's: the scenario parser takes it from the world)."""
    p = Path(world)
    if not p.suffix:
        p = Path(__file__).resolve().parent.parent / "scenarios" / "worlds" / f"{world}.toml"
    if not p.is_file():
        raise ScenarioError("--world", world, "a world file or a built-in world name")
    return {"file": str(p.resolve())}
