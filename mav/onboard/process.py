"""The onboard stack as an OS process (SIL): `python -m mav.onboard`, `cosim onboard`."""

from __future__ import annotations

import argparse
import math
import select
import signal
import sys
import threading
import time
import traceback

from mav.airframe import Airframe, get_airframe
from mav.onboard.config import OnboardConfig
from mav.onboard.vehicle import Onboard


def _hostport(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    try:
        p = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port of {text!r} is not a number") from None
    if not 0 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port {p} out of 0..65535")
    return host, p


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mav.onboard",
        description="The onboard flight stack as a process: a PX4-style MAVLink vehicle in "
                    "HIL lockstep with a simulator (ODOMETRY in, HIL_ACTUATOR_CONTROLS out).",
        epilog="examples:\n"
               "  python -m mav.onboard --vehicle mambo\n"
               "  python -m mav.onboard --hil-bind 127.0.0.1:0 --api-bind 127.0.0.1:0 "
               "--gcs-bind 127.0.0.1:0   # prints 'PORTS hil=.. api=.. gcs=..' first\n"
               "  python -m mav.onboard --params my.params --signing-key $(openssl rand -hex 32)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--vehicle", default="mambo", choices=("mambo", "bebop2"))
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--hil-bind", type=_hostport, default=("127.0.0.1", 4560), metavar="HOST:PORT",
                   help="simulator link; answers whoever sent the ODOMETRY (default "
                        "127.0.0.1:4560; port 0 = any free port)")
    p.add_argument("--hil-unix", metavar="PATH",
                   help="simulator link on a Unix-domain datagram socket bound at PATH instead "
                        "of UDP (--hil-bind is then unused; PORTS reports hil=0)")
    p.add_argument("--api-bind", type=_hostport, default=("127.0.0.1", 0), metavar="HOST:PORT",
                   help="offboard API link local address (default 127.0.0.1:0)")
    p.add_argument("--api-remote", type=_hostport, default=("127.0.0.1", 14540),
                   metavar="HOST:PORT", help="where the API link sends (default 127.0.0.1:14540)")
    p.add_argument("--gcs-bind", type=_hostport, default=("127.0.0.1", 0), metavar="HOST:PORT",
                   help="ground station link local address (default 127.0.0.1:0)")
    p.add_argument("--gcs-remote", type=_hostport, default=("127.0.0.1", 14550),
                   metavar="HOST:PORT", help="where the GCS link sends (default 127.0.0.1:14550)")
    p.add_argument("--params", metavar="FILE", help="parameter file: NAME VALUE per line "
                   "(QGroundControl .params accepted)")
    p.add_argument("--signing-key", metavar="HEX", help="MAVLink 2 signing key, 64 hex digits: "
                   "sign the api/gcs links and reject unsigned messages on them")
    p.add_argument("--signing-epoch", default="2024", metavar="2024|now",
                   help="signing timestamps start at 2024-01-01 + vehicle time (deterministic, "
                        "default) or at the wall clock 'now' (for GCSs that check freshness)")
    p.add_argument("--origin", metavar="LAT,LON,ALT",
                   help="geodetic origin of the local frame, deg,deg,m AMSL "
                        "(default 42.299886,-71.350447,71.3232)")
    p.add_argument("--vehicle-param", action="append", default=[], metavar="FIELD=VALUE",
                   help="override an airframe value of the preset (a mav.airframe."
                        "Airframe field, SI units), e.g. mass=0.07; repeatable")
    p.add_argument("--hil-spin-us", type=float, default=0.0, metavar="US",
                   help="after each tick, poll the HIL link this long (us, wall clock) before "
                        "sleeping in the kernel: a lockstep simulator on another CPU answers "
                        "sooner than a wake-up (default 0: sleep at once)")
    p.add_argument("--hil-timeout", type=float, default=10.0, metavar="SECONDS",
                   help="exit (code 0) when the simulator is silent this long, wall clock "
                        "(default 10)")
    return p


def _vehicle_with_overrides(parser, name: str, items: list[str]) -> Airframe:
    """The preset with FIELD=VALUE overrides; parser.error (exit 2) names a bad one."""
    vp = get_airframe(name)
    fields = set(vp.values())
    kw = {}
    for it in items:
        key, sep, val = it.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            parser.error(f"--vehicle-param: got {it!r}; expected FIELD=VALUE with FIELD one of "
                         f"{', '.join(sorted(fields))}")
        try:
            v = float(val)
        except ValueError:
            v = math.nan
        if not (math.isfinite(v) and (v > 0.0 or (key == "drag_rot" and v == 0.0))):
            parser.error(f"--vehicle-param {key}: got {val!r}; expected a finite number > 0")
        kw[key] = v
    return vp.with_overrides(**kw)


def main(argv: list[str] | None = None) -> int:
    """Entry point of `python -m mav.onboard` and `cosim onboard`. Returns the exit code."""
    from mav.links import SpinPolicy, UdpLink, UnixLink

    parser = _build_parser()
    args = parser.parse_args(argv)
    kw: dict = {"vehicle": args.vehicle, "sysid": args.sysid, "param_file": args.params}
    if args.signing_key:
        try:
            kw["signing_key"] = bytes.fromhex(args.signing_key)
        except ValueError:
            parser.error("--signing-key: expected 64 hex digits")
    if args.signing_epoch == "now":
        kw["signing_epoch_unix_s"] = time.time()
    elif args.signing_epoch != "2024":
        parser.error("--signing-epoch: expected 2024 or now")
    if args.origin:
        try:
            lat, lon, alt = (float(v) for v in args.origin.split(","))
        except ValueError:
            parser.error("--origin: expected LAT,LON,ALT")
        kw.update(origin_lat_deg=lat, origin_lon_deg=lon, origin_alt_m=alt)
    if not (args.hil_timeout > 0):
        parser.error("--hil-timeout: expected seconds > 0")
    if not 0.0 <= args.hil_spin_us <= 1e6:
        parser.error("--hil-spin-us: expected 0..1e6 microseconds")
    try:
        cfg = OnboardConfig(**kw)
    except ValueError as exc:
        parser.error(str(exc))
    vehicle = _vehicle_with_overrides(parser, args.vehicle, args.vehicle_param)
    try:
        hil = UnixLink(args.hil_unix) if args.hil_unix else UdpLink(args.hil_bind)
        api = UdpLink(args.api_bind, args.api_remote)
        gcs = UdpLink(args.gcs_bind, args.gcs_remote)
    except OSError as exc:
        print(f"onboard: cannot bind: {exc}", file=sys.stderr)
        return 1
    try:
        onboard = Onboard(cfg, hil, api, gcs)
        if args.vehicle_param:
            onboard.set_airframe(vehicle)
    except (ValueError, OSError) as exc:
        print(f"onboard: {exc}", file=sys.stderr)
        return 2
    for w in onboard.warnings:
        print(f"onboard: {w}", file=sys.stderr)
    print(f"PORTS hil={0 if args.hil_unix else hil.local_address[1]} api={api.local_address[1]} "
          f"gcs={gcs.local_address[1]}", flush=True)

    stop = []
    if threading.current_thread() is threading.main_thread():
        def _stop(signum, _frame) -> None:
            stop.append(signum)

        old = {s: signal.signal(s, _stop) for s in (signal.SIGTERM, signal.SIGINT)}
    else:
        old = {}
    code = 0
    # one poll() per readable event: a further datagram already queued makes the next wait
    # return at once, and no recvfrom is spent on finding the socket empty
    poller = select.poll()
    poller.register(hil.sock.fileno(), select.POLLIN)
    wait = poller.poll
    last_rx = time.monotonic()
    spin = SpinPolicy(round(1000 * args.hil_spin_us) if args.hil_spin_us > 0 else 0)
    clock = time.perf_counter_ns
    try:
        while not stop:
            if spin.ns:     # poll for the next tick's datagram before sleeping
                deadline = clock() + spin.ns
                got = onboard.poll()
                while not got and clock() <= deadline:
                    got = onboard.poll()
                spin.record(got)
                if got:
                    last_rx = time.monotonic()
                    continue
            elif spin.spin_ns:
                spin.record(False)     # backing off: counts down to the next try
            try:
                r = wait(100)
            except InterruptedError:
                continue
            now = time.monotonic()
            if r:
                last_rx = now
                onboard.poll()
            elif now - last_rx > args.hil_timeout:
                print(f"onboard: no HIL input for {args.hil_timeout:g} s, exiting",
                      file=sys.stderr)
                break
    except Exception:
        traceback.print_exc(file=sys.stderr)
        code = 1
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        onboard.count_kernel_drops()      # what the sockets' full buffers shed, once
        for link in (hil, api, gcs):
            link.close()
        st = {k: v for k, v in onboard.stats.items() if v}
        print(f"onboard: exit {code}; stats {st}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
