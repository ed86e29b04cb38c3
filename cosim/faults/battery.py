"""Battery faults of the `[faults]` table: sent to the flight stack as MAVLink on the HIL link.

    [[faults.battery]]
    kind = "sag"               # sag: the voltage sags under load over [start_s, end_s)
    start_s = 20.0
    end_s = 30.0               # optional: the run's end
    r_factor = 3.0             # the pack's internal resistance x this (1..1000) ...
    drop_v = 0.0               # ... and a further fixed drop, V (0..100); at least one of them

    [[faults.battery]]
    kind = "drain"             # drain: at start_s the state of charge drops to `remaining`
    start_s = 40.0             #   (a failed cell, capacity lost); the charge stays lost
    remaining = 0.06           # 0..1, required

The battery model lives in the flight stack (`mav/battery.py`), as PX4's battery simulator lives
in PX4, so the master cannot change it in place: at the first tick at or after a fault's time,
the HIL link wrapper (`HilInjector`, from `FaultHooks.wrap_link("hil", ...)`) sends a
COMMAND_LONG MAV_CMD_INJECT_FAILURE just before that tick's ODOMETRY (`mav.hil.
encode_inject_failure`; the message and the vehicle's side: `mav/onboard/inject.py`): a drain
is FAILURE_TYPE_OFF with param4 = remaining; at every start and end of a sag the net sag of the
sags active then (resistance factors multiplied, drops added) is FAILURE_TYPE_WRONG with param4
= factor, param5 = drop, or FAILURE_TYPE_OK when none is left. The same bytes at the same
simulated time in MIL and SIL; nothing is random. The vehicle's battery failsafes answer a drain
through their normal path (warnings, COM_LOW_BAT_ACT); a sag shows in the voltage telemetry
only (the failsafes compare charge, not voltage).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from cosim.errors import ScenarioError
from cosim.scenario.validate import REQUIRED, no_unknown, number, string
from mav.hil import INJECT_COMPID, MAX_R_SCALE, MAX_V_DROP, SIM_SYSID, encode_inject_failure

M = mavlink2
END = 1e12                     # s, no end (faults.END)


@dataclass(frozen=True)
class BatteryFault:
    kind: str                  # sag | drain
    start_s: float
    end_s: float               # sag: the end of the window (END: the run's); drain: END
    r_factor: float = 1.0      # sag: internal resistance x this
    drop_v: float = 0.0        # sag: V, a further fixed drop
    remaining: float = 1.0     # drain: the state of charge left, 0..1

    def describe(self) -> str:
        if self.kind == "drain":
            return f"battery drain to {100.0 * self.remaining:g}%"
        what = [f"resistance x{self.r_factor:g}"] if self.r_factor != 1.0 else []
        if self.drop_v:
            what.append(f"-{self.drop_v:g} V")
        return "battery sag: " + ", ".join(what)


def parse_battery(entries: list[tuple[str, dict]], window) -> tuple[BatteryFault, ...]:
    """The `[[faults.battery]]` entries ((dotted path, table) pairs) -> BatteryFaults; a bad
    field raises ScenarioError naming it. `window(e, w)`: (start_s, end_s) of an entry."""
    out = []
    for w, e in entries:
        kind = string(e, "kind", w, choices=("sag", "drain"))
        if kind == "sag":
            no_unknown(e, {"kind", "start_s", "end_s", "r_factor", "drop_v"}, w)
            start, end = window(e, w)
            r = number(e, "r_factor", w, 1.0, lo=1.0, hi=MAX_R_SCALE)
            drop = number(e, "drop_v", w, 0.0, lo=0.0, hi=MAX_V_DROP)
            if r == 1.0 and drop == 0.0:
                raise ScenarioError(w, e, "r_factor > 1 or drop_v > 0 for kind = 'sag'")
            out.append(BatteryFault(kind, start, end, r_factor=r, drop_v=drop))
        else:
            no_unknown(e, {"kind", "start_s", "remaining"}, w)
            start, end = window(e, w)
            out.append(BatteryFault(kind, start, end,
                                    remaining=number(e, "remaining", w, REQUIRED, lo=0.0,
                                                     hi=1.0)))
    return tuple(out)


def schedule(faults: tuple[BatteryFault, ...]
             ) -> list[tuple[float, int, float, float, tuple[str, ...]]]:
    """The commands to send, in time order: (at s, failure type, param4, param5, the faults
    that take effect with it, for `fired()`). At one time: the sag first, then the drains.
    Overlapping sags beyond the vehicle's limits are clamped to them (MAX_R_SCALE, MAX_V_DROP)."""
    out = []
    sags = [(i, f) for i, f in enumerate(faults) if f.kind == "sag"]
    for t in sorted({f.start_s for _, f in sags} | {f.end_s for _, f in sags if f.end_s < END}):
        active = [f for _, f in sags if f.start_s <= t < f.end_s]
        started = tuple(f"{f.describe()} (fault {i})" for i, f in sags if f.start_s == t)
        if active:
            out.append((t, -1, M.FAILURE_TYPE_WRONG,
                        min(math.prod(f.r_factor for f in active), MAX_R_SCALE),
                        min(sum(f.drop_v for f in active), MAX_V_DROP), started))
        else:
            out.append((t, -1, M.FAILURE_TYPE_OK, 0.0, 0.0, ()))
    for i, f in enumerate(faults):
        if f.kind == "drain":
            out.append((f.start_s, i, M.FAILURE_TYPE_OFF, f.remaining, 0.0,
                        (f"{f.describe()} (fault {i})",)))
    out.sort(key=lambda c: (c[0], c[1]))
    return [(t, kind, p4, p5, what) for t, _, kind, p4, p5, what in out]


class HilInjector:
    """The master's end of the HIL link with battery faults: `send` (a tick's ODOMETRY) first
    sends the failure commands due at the tick (`clock()`: its time, integer us)."""

    def __init__(self, inner, clock, faults: tuple[BatteryFault, ...], note) -> None:
        self.inner = inner
        self._clock = clock
        self._note = note                   # note(t s, what): the fault took effect
        self._due = schedule(faults)
        self._next = self._due[0][0] if self._due else math.inf
        self._mav = M.MAVLink(None, SIM_SYSID, INJECT_COMPID)
        self.sent = 0                       # commands sent

    def send(self, data: bytes) -> None:
        t = self._clock() * 1e-6
        if t >= self._next:
            due = self._due
            while due and due[0][0] <= t:
                t0, kind, p4, p5, what = due.pop(0)
                self.inner.send(encode_inject_failure(self._mav, kind, p4, p5))
                self.sent += 1
                for w in what:
                    self._note(t0, w)
            self._next = due[0][0] if due else math.inf
        self.inner.send(data)

    def __getattr__(self, name: str) -> Any:     # recv, sock, close, ... of the link
        return getattr(self.inner, name)
