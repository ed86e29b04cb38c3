"""`cosim bench`, issue 14 item 9: the seed mission in SIL without and with a UDP flood on the
vehicle's GCS port, in one bench run: what the flood costs the lockstep (real-time factor),
whether the heartbeats and the HIL answers keep their rate, and what the vehicle shed.

Two pairs of runs, each without then with the flood, the same flight in both:
- lockstep as fast as it goes (as `cosim run --mode sil`): the mission, flooded from its
  first tick for `flood_wall_s` of wall clock (30 s; or to its last tick if that comes first:
  the rest of the mission then runs unflooded). Its figures are over that window of ticks,
  the same ticks in both runs;
- real time at speed 1 (`cosim run --mode sil --realtime`, paced as `cosim sitl` is): the
  first `realtime_s` of the mission, flooded throughout. Here the wall clock is what a ground
  station lives by: a heartbeat gap in wall time is what it would see.

The flood is another OS process sending `FLOOD_RATE_HZ` datagrams a second (wall clock), round
robin from a seeded pool: a third garbage (random bytes, some behind a magic byte), a third
CRC-valid frames addressed to another system (commands, setpoints, parameters, mission,
mode, sticks for system 7), a third heartbeats of another vehicle and of a ground station.
It runs on the same machine: its own CPU use (reported) is part of what the runs compete with.

The vehicle's ports are found as the master finds them: the SIL process binds port 0 and
prints its ports; a `Hooks` object (cosim/sim/hooks.py) is handed the master's links to the
vehicle when the run is built (each link's `remote` is the vehicle's port). The same object
listens on the master's GCS socket, where the vehicle sends what a ground station gets, and
stamps each HEARTBEAT there with the tick's simulated time and with the wall clock; it also
times every tick. Both runs of a pair carry the same hooks, so their cost is in both.

No figure is pass/fail (shared machines); `answered_all` and `same_flight` are facts of the
run: every HIL tick had its answer (the master ends a run with `component_error` otherwise),
and the recorded series of the flooded run equals the unflooded one bit for bit.
"""

from __future__ import annotations

import dataclasses
import random
import resource
import select
import socket
import statistics
import subprocess
import sys
import time
from array import array
from typing import Any

from cosim.bench.common import seed_scenario
from mav import wire

FLOOD_RATE_HZ = 70_000        # datagrams per second (wall clock), issue 14's flood
FLOOD_WALL_S = 30.0           # s wall clock, the longest flood of the lockstep pair
REALTIME_S = 5.0              # s of the mission in the real-time pair
POOL_SIZE = 1536              # distinct datagrams, sent round robin
OTHER_SYSID = 7               # the system the flood's frames are addressed to (not ours)


# ------------------------------------------------------------------ the flood
def flood_pool(seed: int = 14, n: int = POOL_SIZE) -> list[bytes]:
    """`n` datagrams, a third of each kind (module docstring), seeded."""
    from pymavlink.dialects.v20 import common as M

    rng = random.Random(seed)
    other = M.MAVLink(None, 2, 1)              # another vehicle
    gcs = M.MAVLink(None, 255, 190)            # a ground station
    ts = OTHER_SYSID

    def addressed() -> bytes:
        f = rng.uniform
        msgs = (
            M.MAVLink_command_long_message(ts, 1, rng.choice((400, 22, 21, 176, 511)), 0,
                                           1.0, 21196.0, f(-9, 9), 0, 0, 0, 0),
            M.MAVLink_command_int_message(ts, 1, 6, 192, 0, 0, -1, 0, 0, 0,
                                          rng.randrange(1 << 24), rng.randrange(1 << 24), 5),
            M.MAVLink_set_position_target_local_ned_message(
                rng.randrange(1 << 31), ts, 1, 1, 0xDF8, f(-50, 50), f(-50, 50), f(-5, 0),
                0, 0, 0, 0, 0, 0, 0, 0),
            M.MAVLink_param_set_message(ts, 1, b"TPL_LAND_SPEED", f(0, 3), 9),
            M.MAVLink_param_request_list_message(ts, 1),
            M.MAVLink_mission_count_message(ts, 1, rng.randrange(1, 100), 0),
            M.MAVLink_set_mode_message(ts, 1, rng.choice((4 << 16 | 6 << 24, 6 << 16))),
            M.MAVLink_manual_control_message(ts, 0, 0, 1000, 0, 0),
        )
        return wire.send_msg(gcs, rng.choice(msgs))

    def heartbeat() -> bytes:
        if rng.random() < 0.5:
            return wire.send_msg(other, M.MAVLink_heartbeat_message(2, 12, 129, 0, 4, 3))
        return wire.send_msg(gcs, M.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))

    def garbage() -> bytes:
        b = bytes(rng.randrange(256) for _ in range(rng.randrange(8, 280)))
        return bytes((wire.MAGIC_V2,)) + b if rng.random() < 0.3 else b

    makers = (garbage, addressed, heartbeat)
    return [makers[i % 3]() for i in range(n)]


def _flood(port: int, rate: int, pool: list[bytes], stopped) -> tuple[int, int, float]:
    """Send `rate` datagrams/s to 127.0.0.1:`port` until `stopped()`; (sent, failed sends,
    wall s). Behind schedule (no CPU), it catches up at most 10 ms of datagrams per pass, so
    what it achieved is what it reports."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setblocking(False)
    dest, send, clock = ("127.0.0.1", port), sock.sendto, time.perf_counter
    k, n, failed, burst_max = len(pool), 0, 0, max(1, rate // 100)
    t0 = clock()
    while not stopped():
        burst = min(int((clock() - t0) * rate) - n, burst_max)
        for _ in range(burst):
            try:
                send(pool[n % k], dest)
            except OSError:           # a full send buffer, ICMP port unreachable
                failed += 1
            n += 1
        if burst < burst_max:
            time.sleep(0.0005)
    sock.close()
    return n, failed, clock() - t0


def main(argv: list[str] | None = None) -> int:
    """The flood process: `python -m cosim.bench.flood PORT RATE`. Prints READY,
    floods until its stdin ends, prints `SENT n FAILED n WALL s CPU s`."""
    port, rate = (int(a) for a in (argv if argv is not None else sys.argv[1:]))
    pool = flood_pool()
    print("READY", flush=True)
    fd = sys.stdin.fileno()

    def stopped() -> bool:
        return bool(select.select([fd], [], [], 0)[0])      # a byte or the end of stdin
    n, failed, wall = _flood(port, rate, pool, stopped)
    ru = resource.getrusage(resource.RUSAGE_SELF)
    print(f"SENT {n} FAILED {failed} WALL {wall!r} CPU {ru.ru_utime + ru.ru_stime!r}",
          flush=True)
    return 0


class Flood:
    """The flood process at 127.0.0.1:`port`, sending once this returns; `stop()` from the
    loop (it only closes a pipe), `close()` after the run: {sent, failed_sends, wall_s,
    rate_hz, cpu_s}."""

    def __init__(self, port: int, rate: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cosim.bench.flood", str(port), str(rate)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "READY":
            self.close()
            raise RuntimeError("the flood process did not start")

    def stop(self) -> None:
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()

    def close(self) -> dict[str, float]:
        self.stop()
        try:
            self.proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        assert self.proc.stdout is not None
        w = self.proc.stdout.read().split()        # a few bytes: the pipe never fills
        self.proc.stdout.close()
        if len(w) < 8 or w[0] != "SENT":
            return {"sent": 0, "failed_sends": 0, "wall_s": 0.0, "rate_hz": 0.0, "cpu_s": 0.0}
        sent, failed, wall, cpu = int(w[1]), int(w[3]), float(w[5]), float(w[7])
        return {"sent": sent, "failed_sends": failed, "wall_s": wall,
                "rate_hz": sent / wall if wall > 0 else 0.0, "cpu_s": cpu}


# ------------------------------------------------------------------ the probe (run hooks)
def _heartbeats(data: bytes, sysid: int) -> int:
    """HEARTBEATs from `sysid` in one datagram."""
    n = i = 0
    while i < len(data):
        end = wire.frame_end(data, i)
        if end < 0:
            break
        if wire.msgid_of(data, i) == 0 and wire.header_of(data, i)[1] == sysid:
            n += 1
        i = end
    return n


class _Listener:
    """The master's GCS socket, seen through: every HEARTBEAT of the vehicle is stamped."""

    __slots__ = ("inner", "probe")

    def __init__(self, inner, probe: FloodProbe) -> None:
        self.inner, self.probe = inner, probe

    def send(self, data: bytes) -> None:
        self.inner.send(data)

    def recv(self) -> bytes | None:
        data = self.inner.recv()
        if data is not None and _heartbeats(data, self.probe.sysid):
            self.probe.heartbeat()
        return data

    def close(self) -> None:
        self.inner.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class FloodProbe:
    """Run hooks (cosim.sim.hooks.Hooks) that change nothing in the run: start the flood at
    the vehicle's `target` port ('gcs' or 'api'; `rate` 0: no flood) when the links are
    built, stop it at tick `stop_k` or `wall_s` after the first tick, whichever comes first
    (`flood_end_k`: the first tick without it), stamp the vehicle's heartbeats on the GCS link
    and time every tick (wall clock)."""

    odometry_lost = False

    def __init__(self, rate: int, stop_k: int, wall_s: float, tick_us: int,
                 target: str = "gcs", sysid: int = 1) -> None:
        self.rate, self.stop_k, self.wall_s, self.tick_us = rate, stop_k, wall_s, tick_us
        self.target, self.sysid = target, sysid
        self.flood: Flood | None = None
        self.flood_end_k: int | None = None
        self.t_us = 0
        self.hb_t_us: list[int] = []            # simulated time of the tick it came in
        self.hb_wall: list[float] = []          # s, perf_counter when it was read
        self.tick_wall = array("d")             # s, tick k: from its start to tick k+1's
        self._t0 = self._last = 0.0

    def wrap_link(self, name: str, link):
        if name == self.target and self.rate > 0:
            self.flood = Flood(link.remote[1], self.rate)
        return _Listener(link, self) if name == "gcs" else link

    def heartbeat(self) -> None:
        self.hb_t_us.append(self.t_us)
        self.hb_wall.append(time.perf_counter())

    def on_odometry(self, t_us: int, meas: tuple) -> tuple:
        now = time.perf_counter()
        if t_us:
            self.tick_wall.append(now - self._last)
        else:
            self._t0 = now
        self._last = now
        self.t_us = t_us
        if self.flood is not None and self.flood_end_k is None and (
                t_us >= self.stop_k * self.tick_us or now - self._t0 >= self.wall_s):
            self.flood.stop()
            self.flood_end_k = t_us // self.tick_us
        return meas

    def on_frame(self, t_us: int, img):
        return img

    def on_actuators(self, t_us: int, u: tuple) -> tuple:
        return u

    def fired(self) -> list[tuple[float, str]]:
        return []

    def close(self) -> dict[str, float] | None:
        return self.flood.close() if self.flood is not None else None


# ------------------------------------------------------------------ the figure
def _run(sc, rate: int, stop_k: int, wall_s: float, target: str, realtime: bool):
    from cosim.sim.master import RunOptions, run_scenario

    probe = FloodProbe(rate, stop_k, wall_s, round(sc.timing.tick_s * 1e6), target)
    try:
        res = run_scenario(sc, RunOptions(mode="sil", hooks=probe, realtime=realtime))
    finally:
        flood = probe.close()
    return probe, res, flood


def _figures(probe: FloodProbe, res, flood: dict | None, k1: int, target: str
             ) -> dict[str, Any]:
    """One run's figures; those of the window are over its ticks [0, k1)."""
    h_us = probe.tick_us
    st = res.onboard_stats
    k1 = max(1, min(k1, len(probe.tick_wall)))
    tw = sorted(probe.tick_wall[:k1])
    hb = [(t, w) for t, w in zip(probe.hb_t_us, probe.hb_wall, strict=True) if t < k1 * h_us]
    gaps_sim = [(b[0] - a[0]) * 1e-6 for a, b in zip(hb, hb[1:], strict=False)]
    gaps_wall = [b[1] - a[1] for a, b in zip(hb, hb[1:], strict=False)]
    d: dict[str, Any] = {
        "rtf": res.loop_real_time_factor, "sim_time_s": res.t_end_s, "ticks": res.ticks,
        "exit_reason": res.exit_reason.value, "hil_ticks_handled": st.get("ticks", 0),
        "answered_all": res.exit_reason.value != "component_error"
        and st.get("ticks", 0) == res.ticks,
        "realtime_stalls": res.realtime_stalls,
        "window_s": k1 * h_us * 1e-6,
        "window_rtf": k1 * h_us * 1e-6 / sum(tw),
        "window_heartbeats": len(hb),
        "hb_gap_max_sim_s": max(gaps_sim, default=0.0),
        "hb_gap_max_wall_s": max(gaps_wall, default=0.0),
        "tick_wall_median_us": 1e6 * statistics.median(tw),
        "tick_wall_p99_us": 1e6 * tw[min(len(tw) - 1, int(0.99 * len(tw)))],
        "tick_wall_max_ms": 1e3 * tw[-1],
        "onboard_stats": dict(st),
    }
    if flood is not None:
        d["sender"] = flood
        # every datagram sent is handled, dropped by the kernel, or still queued at the exit
        d["left_queued_at_exit"] = (flood["sent"] - flood["failed_sends"]
                                    - st.get("rx_" + target, 0)
                                    - st.get("dropped_kernel_" + target, 0))
    return d


def _pair(sc, rate: int, wall_s: float, target: str, realtime: bool) -> dict[str, Any]:
    """The mission without, then with the flood (from the first tick, for `wall_s` or to the
    last tick of the unflooded run); the figures of both over the flooded window."""
    import numpy as np

    p0, r0, _ = _run(sc, 0, 0, 0.0, target, realtime)
    p1, r1, flood = _run(sc, rate, r0.ticks - 1, wall_s, target, realtime)
    k1 = p1.flood_end_k if p1.flood_end_k is not None else r1.ticks
    none, flooded = _figures(p0, r0, None, k1, target), _figures(p1, r1, flood, k1, target)
    return {"none": none, "flood": flooded,
            "rtf_ratio": flooded["window_rtf"] / none["window_rtf"],
            "same_flight": bool(np.array_equal(r1.series, r0.series, equal_nan=True))}


def bench_flood(t_final_s: float | None = None, flood_wall_s: float = FLOOD_WALL_S,
                realtime_s: float = REALTIME_S, rate: int = FLOOD_RATE_HZ,
                target: str = "gcs") -> dict[str, Any]:
    """The seed mission in SIL without and with a flood at the vehicle's `target` port:
    lockstep as fast as it goes (flooded for at most `flood_wall_s` of wall clock;
    `t_final_s` shortens the mission) and, unless `realtime_s` is 0, its first `realtime_s`
    in real time. See the module docstring."""
    sc = seed_scenario()       # truth-fed, as the flood figures were first taken

    def cut(t: float):
        return dataclasses.replace(sc, timing=dataclasses.replace(sc.timing, t_final_s=t))
    out: dict[str, Any] = {"target": target, "rate_asked_hz": rate, "pool": POOL_SIZE,
                           "flood_wall_s": flood_wall_s}
    out["lockstep"] = _pair(cut(t_final_s) if t_final_s else sc, rate, flood_wall_s, target,
                            False)
    if realtime_s > 0:
        out["realtime"] = _pair(cut(realtime_s), rate, 1e9, target, True)
    return out


def format_flood(d: dict[str, Any]) -> list[str]:
    """The figure's lines for `cosim bench`."""
    def k(n: float) -> str:
        return f"{n / 1e3:.1f}k" if n >= 1e4 else f"{n:.0f}"

    lines = [f"flood on the vehicle's {d['target']} port (issue 14 item 9): {k(d['rate_asked_hz'])}"
             f" datagrams/s asked (garbage, frames for system {OTHER_SYSID}, heartbeats), from "
             "another process; the seed mission in SIL without / with it"]
    for name, title in (("lockstep", "lockstep as fast as it goes"), ("realtime",
                                                                       "real time, speed 1")):
        if name not in d:
            continue
        p = d[name]
        a, b = p["none"], p["flood"]
        f = b.get("sender", {})
        st = b["onboard_stats"]
        lines.append(
            f" {title}: {b['window_s']:.1f} s of {b['sim_time_s']:.1f} s simulated flooded "
            f"({f.get('wall_s', 0):.1f} s wall, {k(f.get('rate_hz', 0))} datagrams/s sent, the "
            f"sender using {f.get('cpu_s', 0):.1f} s CPU); exit {a['exit_reason']} / "
            f"{b['exit_reason']}; figures over the flooded ticks")
        lines.append(f"  {'':<40s}{'no flood':>14s}{'flood':>14s}")

        def row(label: str, x: str, y: str) -> None:
            lines.append(f"  {label:<40s}{x:>14s}{y:>14s}")
        row("real time (flooded window)", f"{a['window_rtf']:.2f}x", f"{b['window_rtf']:.2f}x")
        row("tick wall time, median / p99 (us)",
            f"{a['tick_wall_median_us']:.0f} / {a['tick_wall_p99_us']:.0f}",
            f"{b['tick_wall_median_us']:.0f} / {b['tick_wall_p99_us']:.0f}")
        row("longest tick (ms wall)", f"{a['tick_wall_max_ms']:.1f}",
            f"{b['tick_wall_max_ms']:.1f}")
        row("HEARTBEATs on the GCS link", str(a["window_heartbeats"]),
            str(b["window_heartbeats"]))
        row("  largest gap, vehicle time (s)", f"{a['hb_gap_max_sim_s']:.3f}",
            f"{b['hb_gap_max_sim_s']:.3f}")
        row("  largest gap, wall clock (s)", f"{a['hb_gap_max_wall_s']:.3f}",
            f"{b['hb_gap_max_wall_s']:.3f}")
        row("HIL ticks answered (whole run)", f"{a['hil_ticks_handled']}/{a['ticks']}",
            f"{b['hil_ticks_handled']}/{b['ticks']}")
        if name == "realtime":
            row("real-time stalls skipped (> 0.2 s late)", str(a["realtime_stalls"]),
                str(b["realtime_stalls"]))
        ticks = max(1, round(b["window_s"] / 0.005))
        rx = st.get("rx_" + d["target"], 0)
        lines.append(
            f"  real time flood / none {p['rtf_ratio']:.2f}; every HIL tick answered: "
            f"{'yes' if b['answered_all'] else 'NO'}; the same flight (recorded series bit for "
            f"bit): {'yes' if p['same_flight'] else 'NO'}")
        lines.append(
            f"  the {k(f.get('sent', 0))} datagrams sent: handled {k(rx)} (rx_{d['target']}; "
            f"~{rx / ticks:.0f} a flooded tick; {st.get('drain_deferred', 0)} ticks left some "
            f"for the next: drain_deferred), dropped by the kernel, socket buffer full "
            f"{k(st.get('dropped_kernel_' + d['target'], 0))} (dropped_kernel_{d['target']}), "
            f"never read {k(b.get('left_queued_at_exit', 0))}")
        lines.append(
            f"  of those handled: garbage / bad CRC {k(st.get('dropped_bad_' + d['target'], 0))}"
            f", for another system {k(st.get('not_for_us', 0) + st.get('sp_reject_target', 0))}"
            f", unknown ids {k(st.get('unknown_msgs', 0))}, unhandled "
            f"{k(st.get('unhandled_msgs', 0))}, handler errors {st.get('handler_errors', 0)}")
    return lines


if __name__ == "__main__":
    sys.exit(main())
