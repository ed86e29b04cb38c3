"""`cosim bench --live`: what the live view (`--foxglove`, cosim/outputs/live.py) costs the
lockstep loop. The seed mission in MIL, as fast as it goes (not paced: the cost is what a
tick pays, which real time only hides), three ways: no live view; a live view nobody watches;
a live view with a client subscribed to every topic (a WebSocket client in a thread of this
process reading everything, as a viewer on this machine would). Per way: the loop's wall time
per tick (best of `repeats`), the messages the client got, and whether the run's series is
the same bytes as without a live view.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import numpy as np


class _Watcher:
    """A Foxglove WebSocket client that subscribes to every channel and counts messages."""

    def __init__(self, url: str) -> None:
        from websockets.sync.client import connect

        self.messages = 0
        self.bytes = 0
        self._stop = threading.Event()
        self._conn = connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None)
        self._ws = self._conn.__enter__()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        ws, subs = self._ws, {}                 # channel id -> subscription id
        while not self._stop.is_set():
            try:
                m = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(m, bytes):
                self.messages += 1
                self.bytes += len(m)
                continue
            op = json.loads(m)
            ids = []
            if op.get("op") == "advertise":
                ids = [c["id"] for c in op["channels"] if c["id"] not in subs]
            elif op.get("op") == "status" and "Unknown channel ID" in op.get("message", ""):
                # a channel advertised while being made takes no subscription yet: again
                ids = [int(op["message"].rsplit(":", 1)[1])]
                time.sleep(0.05)
            for cid in ids:
                subs.setdefault(cid, len(subs) + 1)
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": subs[cid], "channelId": cid}]}))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._conn.__exit__(None, None, None)


class _WhenSubscribed:
    """The live view of the watched way: `vehicle` (called before the loop starts) returns
    once the client has subscribed to every topic (at most 5 s), so that it watches from the
    first tick however short the run."""

    def __init__(self, live) -> None:
        self.live = live

    def vehicle(self, *args, **kw):
        v = self.live.vehicle(*args, **kw)
        t = v.topics
        channels = [t.tf, t.pose, t.image, t.calibration, *t.json.values()]
        end = time.monotonic() + 5.0
        while not all(c.has_sinks() for c in channels) and time.monotonic() < end:
            time.sleep(0.01)
        return v


def bench_live(t_final_s: float = 30.0, repeats: int = 3) -> dict[str, Any]:
    from cosim.bench.common import seed_scenario
    from cosim.outputs.live import LiveView
    from cosim.sim.master import RunOptions, run_scenario

    sc = seed_scenario({"timing.t_final_s": t_final_s})      # truth-fed
    out: dict[str, Any] = {"scenario": sc.name, "t_final_s": t_final_s, "repeats": repeats}
    reference = None
    with TemporaryDirectory() as tmp:
        for way in ("none", "unwatched", "watched"):
            best, same, got = float("inf"), True, 0
            for i in range(repeats):
                live = watcher = None
                if way != "none":
                    live = LiveView(port=0)
                    if way == "watched":
                        watcher = _Watcher(live.url)
                        time.sleep(0.2)
                try:
                    res = run_scenario(sc, RunOptions(out_dir=Path(tmp) / f"{way}{i}", live=(
                        _WhenSubscribed(live) if watcher is not None else live)))
                finally:
                    if watcher is not None:
                        time.sleep(0.5)            # let the last messages arrive
                        watcher.close()
                        got = max(got, watcher.messages)
                    if live is not None:
                        live.close()
                series = np.array(res.series)
                if reference is None:
                    reference = series
                same &= bool(np.array_equal(series, reference, equal_nan=True))
                best = min(best, res.loop_wall_s / max(res.ticks, 1))
            out[way] = {"loop_us_per_tick": best * 1e6, "same_series": same,
                        "client_messages": got}
    base = out["none"]["loop_us_per_tick"]
    for way in ("unwatched", "watched"):
        out[way]["extra_us_per_tick"] = out[way]["loop_us_per_tick"] - base
    return out


def format_live(r: dict[str, Any]) -> list[str]:
    lines = [f"live view (--foxglove), {r['scenario']} MIL {r['t_final_s']:g} s unpaced, "
             f"best of {r['repeats']}:"]
    for way, what in (("none", "no live view"), ("unwatched", "live view, no client"),
                      ("watched", "live view, a client on every topic")):
        d = r[way]
        extra = d.get("extra_us_per_tick")
        lines.append(f"  {what:<36s} {d['loop_us_per_tick']:7.1f} us/tick"
                     + (f"  ({extra:+.1f})" if extra is not None else "")
                     + (f"  {d['client_messages']} messages received" if way == "watched"
                        else "")
                     + ("" if d["same_series"] else "  SERIES DIFFERS"))
    lines.append("  (real time gives a tick 5000 us; the series is the same bytes in each way)")
    return lines
