"""Missions: the MAVLink mission protocol (https://mavlink.io/en/services/mission.html) and
AUTO.MISSION, as PX4 runs them.

Protocol (mission type MISSION; FENCE and RALLY are answered with count 0 and refuse items):
upload MISSION_COUNT -> MISSION_REQUEST_INT(seq) -> MISSION_ITEM_INT ... -> MISSION_ACK;
download MISSION_REQUEST_LIST -> MISSION_COUNT -> MISSION_REQUEST_INT / MISSION_REQUEST ->
MISSION_ITEM_INT / MISSION_ITEM; MISSION_CLEAR_ALL; MISSION_SET_CURRENT and
MAV_CMD_DO_SET_MISSION_CURRENT; MAV_CMD_MISSION_START. An upload replaces the mission only
when complete and valid: a cancelled, timed-out or refused upload keeps the old one. An item
out of sequence is not stored; the expected one is requested again. Each item is checked as it
arrives (command, frame, finite parameters, position within reach) and a bad one ends the
upload with the MAV_MISSION_RESULT that names it.

Items flown: NAV_WAYPOINT (hold param1 s, acceptance radius param2, yaw param4 deg, NaN: face
the leg), NAV_LOITER_UNLIM, NAV_LOITER_TIME (param1 s), NAV_TAKEOFF, NAV_LAND, NAV_DELAY
(param1 s), NAV_RETURN_TO_LAUNCH, DO_CHANGE_SPEED. Latitude and longitude both 0 (or NaN in
MISSION_ITEM) mean the vehicle's position, as PX4 reads them for take-off and land. Armed on
the ground, the mission first climbs to MIS_TAKEOFF_ALT (or the first take-off item's height),
as PX4 does. Progress: MISSION_CURRENT (seq, total, mission_state) at 1 Hz and on change,
MISSION_ITEM_REACHED(seq) when a position item is reached. After the last item the vehicle
holds there in AUTO.MISSION (PX4: "mission finished, loitering") or, after a land item, is on
the ground; re-entering AUTO.MISSION after the end starts the mission over.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mav import wire
from mav.onboard.channels import Chan, Outbox
from mav.onboard.defs import IN_AIR, LOITER, MISSION, ON_GROUND, M
from mav.onboard.status import VehicleStatus

REQUEST_RETRY_US = 500_000          # the vehicle asks again for an item not received
UPLOAD_TIMEOUT_US = 5_000_000       # and gives the upload up after this much silence
MAX_ITEMS = 500                     # PX4 stores 500 on most boards (dataman)

C = M  # MAV_CMD_* names
NAV_POSITION = frozenset({C.MAV_CMD_NAV_WAYPOINT, C.MAV_CMD_NAV_LOITER_UNLIM,
                          C.MAV_CMD_NAV_LOITER_TIME, C.MAV_CMD_NAV_TAKEOFF, C.MAV_CMD_NAV_LAND})
SUPPORTED = NAV_POSITION | {C.MAV_CMD_NAV_RETURN_TO_LAUNCH, C.MAV_CMD_NAV_DELAY,
                            C.MAV_CMD_DO_CHANGE_SPEED}
GLOBAL_FRAMES = frozenset({M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                           M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
FLOAT_TO_INT_FRAME = {M.MAV_FRAME_GLOBAL: M.MAV_FRAME_GLOBAL_INT,
                      M.MAV_FRAME_GLOBAL_RELATIVE_ALT: M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
INT_TO_FLOAT_FRAME = {v: k for k, v in FLOAT_TO_INT_FRAME.items()}

# MISSION_CURRENT.mission_state (MISSION_STATE)
NO_MISSION, NOT_STARTED, ACTIVE, PAUSED, COMPLETE = 1, 2, 3, 4, 5
# what the current item is doing
ST_START, ST_CLIMB, ST_LEG, ST_HOLD, ST_LAND, ST_RTL, ST_END = range(7)


@dataclass(frozen=True, slots=True)
class Item:
    """One stored mission item (MISSION_ITEM_INT's fields; x, y in deg * 1e7)."""

    seq: int
    frame: int
    command: int
    autocontinue: int
    p1: float
    p2: float
    p3: float
    p4: float
    x: int
    y: int
    z: float


@dataclass(slots=True)
class Upload:
    ch: Chan
    peer: tuple[int, int]
    count: int
    items: list
    last_us: int
    asked_us: int


class Mission:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander, navigator,
                 sysid: int, compid: int) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.nav = navigator
        self.sysid, self.compid = sysid, compid
        self.items: list[Item] = []
        self.current = 0
        self.state = NO_MISSION
        self.up: Upload | None = None
        self.st = ST_START
        self.hold_until = 0

    # ------------------------------------------------------------------ protocol
    def _for_us(self, msg) -> bool:
        ok = msg.target_system == self.sysid and msg.target_component in (0, self.compid)
        if not ok:
            self.vs.stats["not_for_us"] += 1
        return ok

    def _ack(self, ch: Chan, peer: tuple[int, int], result: int, mtype: int = 0) -> None:
        ch.send(wire.send_msg(ch.mav, M.MAVLink_mission_ack_message(
            peer[0], peer[1], result, mtype)))

    def _request(self, up: Upload) -> None:
        seq = len(up.items)
        up.ch.send(wire.send_msg(up.ch.mav, M.MAVLink_mission_request_int_message(
            up.peer[0], up.peer[1], seq, M.MAV_MISSION_TYPE_MISSION)))
        up.asked_us = self.vs.t_us

    def on_count(self, ch: Chan, msg) -> None:
        if not self._for_us(msg):
            return
        peer = ch.peer or (0, 0)
        mtype = msg.mission_type
        if self.up is not None and (self.up.ch is not ch or self.up.peer != peer):
            return self._ack(ch, peer, M.MAV_MISSION_DENIED, mtype)   # another one is busy
        self.up = None
        if mtype != M.MAV_MISSION_TYPE_MISSION:
            res = M.MAV_MISSION_ACCEPTED if msg.count == 0 else M.MAV_MISSION_UNSUPPORTED
            return self._ack(ch, peer, res, mtype)
        if msg.count > MAX_ITEMS:
            return self._ack(ch, peer, M.MAV_MISSION_NO_SPACE, mtype)
        if msg.count == 0:
            self._replace([])
            return self._ack(ch, peer, M.MAV_MISSION_ACCEPTED, mtype)
        self.up = Upload(ch, peer, msg.count, [], self.vs.t_us, self.vs.t_us)
        self._request(self.up)

    def on_item_int(self, ch: Chan, msg) -> None:
        self._on_item(ch, msg, msg.x, msg.y, msg.frame)

    def on_item(self, ch: Chan, msg) -> None:
        """Legacy MISSION_ITEM (float lat/lon): stored as MISSION_ITEM_INT would carry it."""
        x, y = msg.x, msg.y
        xi = round(x * 1e7) if math.isfinite(x) and abs(x) <= 90.0 else 0
        yi = round(y * 1e7) if math.isfinite(y) and abs(y) <= 180.0 else 0
        frame = FLOAT_TO_INT_FRAME.get(msg.frame, msg.frame)
        bad_xy = msg.command in NAV_POSITION and frame in GLOBAL_FRAMES and not (
            math.isfinite(x) and math.isfinite(y))
        self._on_item(ch, msg, xi, yi, frame, bad_xy=bad_xy)

    def _on_item(self, ch: Chan, msg, x: int, y: int, frame: int, bad_xy: bool = False) -> None:
        if not self._for_us(msg):
            return
        up = self.up
        peer = ch.peer or (0, 0)
        if msg.mission_type != M.MAV_MISSION_TYPE_MISSION:
            return self._ack(ch, peer, M.MAV_MISSION_UNSUPPORTED, msg.mission_type)
        if up is None or up.ch is not ch or up.peer != peer:
            self.vs.stats["mission_unexpected"] = self.vs.stats.get("mission_unexpected", 0) + 1
            return
        up.last_us = self.vs.t_us
        if msg.seq != len(up.items):
            self.vs.stats["mission_out_of_seq"] = self.vs.stats.get("mission_out_of_seq", 0) + 1
            return self._request(up)
        item = Item(msg.seq, frame, msg.command, msg.autocontinue, msg.param1, msg.param2,
                    msg.param3, msg.param4, x, y, msg.z)
        res = M.MAV_MISSION_INVALID_PARAM5_X if bad_xy else self._check(item)
        if res != M.MAV_MISSION_ACCEPTED:
            self.up = None
            self.out.statustext(f"Mission rejected: item {item.seq} (result {res})",
                                M.MAV_SEVERITY_WARNING)
            return self._ack(ch, peer, res)
        up.items.append(item)
        if len(up.items) < up.count:
            return self._request(up)
        self.up = None
        self._replace(up.items)
        self._ack(ch, peer, M.MAV_MISSION_ACCEPTED)
        self.out.statustext(f"Mission uploaded: {len(self.items)} items", M.MAV_SEVERITY_INFO)

    def _check(self, it: Item) -> int:
        """MAV_MISSION_ACCEPTED or the MAV_MISSION_RESULT that names what is wrong."""
        cmd = it.command
        if cmd not in SUPPORTED:
            return M.MAV_MISSION_UNSUPPORTED
        if cmd in NAV_POSITION:
            if it.frame not in GLOBAL_FRAMES:
                return M.MAV_MISSION_UNSUPPORTED_FRAME
            if not (abs(it.x) <= 900_000_000 and abs(it.y) <= 1_800_000_000):
                return M.MAV_MISSION_INVALID_PARAM5_X
            if not math.isfinite(it.z) and cmd != C.MAV_CMD_NAV_LAND:
                return M.MAV_MISSION_INVALID_PARAM7
            if self._target(it) is None:
                return M.MAV_MISSION_INVALID_PARAM5_X
        if cmd in (C.MAV_CMD_NAV_LOITER_TIME, C.MAV_CMD_NAV_DELAY) and not (
                math.isfinite(it.p1) and it.p1 >= 0.0):
            return M.MAV_MISSION_INVALID_PARAM1
        if cmd == C.MAV_CMD_NAV_WAYPOINT and not (
                math.isfinite(it.p1) and it.p1 >= 0.0 and math.isfinite(it.p2)):
            return M.MAV_MISSION_INVALID_PARAM1
        if cmd == C.MAV_CMD_DO_CHANGE_SPEED and not (
                math.isfinite(it.p1) and math.isfinite(it.p2)):
            return M.MAV_MISSION_INVALID_PARAM2
        return M.MAV_MISSION_ACCEPTED

    def _replace(self, items: list[Item]) -> None:
        self.items = list(items)
        self.current = 0
        self.state = NOT_STARTED if self.items else NO_MISSION
        self.st = ST_START
        self.vs.mission_now = True

    def on_request_list(self, ch: Chan, msg) -> None:
        if not self._for_us(msg):
            return
        peer = ch.peer or (0, 0)
        n = len(self.items) if msg.mission_type == M.MAV_MISSION_TYPE_MISSION else 0
        ch.send(wire.send_msg(ch.mav, M.MAVLink_mission_count_message(
            peer[0], peer[1], n, msg.mission_type)))

    def on_request_int(self, ch: Chan, msg) -> None:
        self._send_item(ch, msg, as_int=True)

    def on_request(self, ch: Chan, msg) -> None:
        self._send_item(ch, msg, as_int=False)

    def _send_item(self, ch: Chan, msg, as_int: bool) -> None:
        if not self._for_us(msg):
            return
        peer = ch.peer or (0, 0)
        if msg.mission_type != M.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(self.items):
            return self._ack(ch, peer, M.MAV_MISSION_INVALID_SEQUENCE, msg.mission_type)
        it = self.items[msg.seq]
        cur = 1 if it.seq == self.current else 0
        if as_int:
            m = M.MAVLink_mission_item_int_message(
                peer[0], peer[1], it.seq, it.frame, it.command, cur, it.autocontinue, it.p1,
                it.p2, it.p3, it.p4, it.x, it.y, it.z, M.MAV_MISSION_TYPE_MISSION)
        else:
            m = M.MAVLink_mission_item_message(
                peer[0], peer[1], it.seq, INT_TO_FLOAT_FRAME.get(it.frame, it.frame),
                it.command, cur, it.autocontinue, it.p1, it.p2, it.p3, it.p4, it.x * 1e-7,
                it.y * 1e-7, it.z, M.MAV_MISSION_TYPE_MISSION)
        ch.send(wire.send_msg(ch.mav, m))

    def on_ack(self, ch: Chan, msg) -> None:
        """A client's MISSION_ACK: the end of a download (nothing to do) or, during an upload
        from that client, its cancellation."""
        if not self._for_us(msg):
            return
        up = self.up
        if up is not None and up.ch is ch and up.peer == (ch.peer or (0, 0)):
            self.up = None
            self.out.statustext("Mission upload cancelled", M.MAV_SEVERITY_INFO)

    def on_clear_all(self, ch: Chan, msg) -> None:
        if not self._for_us(msg):
            return
        peer = ch.peer or (0, 0)
        if msg.mission_type in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_ALL):
            self.up = None
            self._replace([])
            if self.vs.mode == MISSION:
                self.cmd.set_mode(LOITER)
        self._ack(ch, peer, M.MAV_MISSION_ACCEPTED, msg.mission_type)

    def on_set_current(self, ch: Chan, msg) -> None:
        if self._for_us(msg):
            self.set_current(msg.seq)

    def set_current(self, seq: float) -> int:
        """MISSION_SET_CURRENT / MAV_CMD_DO_SET_MISSION_CURRENT: continue from item seq."""
        if not (math.isfinite(seq) and 0 <= seq < len(self.items)):
            self.out.statustext(f"Mission: no item {seq:g}", M.MAV_SEVERITY_WARNING)
            self.vs.mission_now = True
            return M.MAV_RESULT_DENIED
        self.current = int(seq)
        self.st = ST_START
        if self.state == COMPLETE:
            self.state = ACTIVE if self.vs.mode == MISSION else NOT_STARTED
        self.vs.mission_now = True
        return M.MAV_RESULT_ACCEPTED

    def start_command(self, first: float, last: float) -> int:
        """MAV_CMD_MISSION_START: AUTO.MISSION from item `first` (NaN or 0: the current)."""
        if math.isfinite(first) and first > 0 and self.set_current(first) != M.MAV_RESULT_ACCEPTED:
            return M.MAV_RESULT_DENIED
        return self.cmd.try_mode(MISSION)

    def tick(self, t: int) -> None:
        """Upload timers: ask again, or give the upload up."""
        up = self.up
        if up is None:
            return
        if t - up.last_us > UPLOAD_TIMEOUT_US:
            self.up = None
            self._ack(up.ch, up.peer, M.MAV_MISSION_OPERATION_CANCELLED)
            self.out.statustext("Mission upload timed out", M.MAV_SEVERITY_WARNING)
        elif t - up.asked_us >= REQUEST_RETRY_US:
            self._request(up)

    # ------------------------------------------------------------------ telemetry
    def emit_current(self, ch: Chan) -> None:
        n = len(self.items)
        ch.send(wire.pack(ch.mav, wire.MISSION_CURRENT, self.current if n else 0,
                          n if n else 0xFFFF, self.state, 1 if self.vs.mode == MISSION else 0))

    def reached(self, seq: int) -> None:
        for ch in self.out.chans:
            ch.send(wire.send_msg(ch.mav, M.MAVLink_mission_item_reached_message(seq)))

    # ------------------------------------------------------------------ flying it
    def can_start(self) -> bool:
        if not self.items:
            self.out.statustext("Mission denied: no mission uploaded", M.MAV_SEVERITY_WARNING)
            return False
        return True

    def enter(self) -> None:
        if self.state == COMPLETE:
            self.current = 0
        self.state = ACTIVE if self.items else NO_MISSION
        self.st = ST_START
        self.vs.mission_now = True
        self.cmd.hold_here()
        self.out.statustext("Mission started" if self.current == 0
                            else f"Mission resumed at item {self.current}", M.MAV_SEVERITY_INFO)

    def _target(self, it: Item) -> tuple[float, float, float] | None:
        z = it.z if math.isfinite(it.z) else math.nan
        return self.nav.global_to_local(it.x, it.y, z, it.frame, int_xy=True)

    def step(self, t: int) -> None:
        """AUTO.MISSION's tick (armed)."""
        vs = self.vs
        nav = self.nav
        if self.state != ACTIVE or not self.items:
            return
        if vs.landed_state == ON_GROUND and self.st not in (ST_CLIMB, ST_LAND, ST_END):
            first = self.items[self.current]
            alt = vs.own["MIS_TAKEOFF_ALT"]
            if first.command == C.MAV_CMD_NAV_TAKEOFF:
                tgt = self._target(first)
                if tgt is not None:
                    alt = max(alt, vs.home[2] - tgt[2])
            nav.climb_to(alt)
            self.st = ST_CLIMB
        if self.st == ST_CLIMB:
            if nav.climb(t):
                self.cmd.set_landed(IN_AIR)
                if self.items[self.current].command == C.MAV_CMD_NAV_TAKEOFF:
                    self._item_done(self.current, reached=True)
                else:
                    self.st = ST_START
            return
        if self.st == ST_START:
            self._start_item(t)
        it = self.items[self.current]
        if self.st == ST_LEG:
            if nav.step_leg(t):
                self.reached(it.seq)
                hold = it.p1 if it.command in (C.MAV_CMD_NAV_WAYPOINT,
                                               C.MAV_CMD_NAV_LOITER_TIME) else 0.0
                if it.command == C.MAV_CMD_NAV_LOITER_UNLIM:
                    hold = math.inf
                if it.command == C.MAV_CMD_NAV_LAND:
                    self.st = ST_LAND
                    nav.begin_land(vs.sp.x, vs.sp.y, vs.sp.yaw)
                else:
                    self.st = ST_HOLD
                    self.hold_until = t + int(hold * 1e6) if math.isfinite(hold) else 1 << 62
        if self.st == ST_HOLD and t >= self.hold_until:
            self._item_done(it.seq, reached=False)
        elif self.st == ST_LAND:
            nav.step_land(t)
            if vs.landed_state == ON_GROUND:
                self._item_done(it.seq, reached=False)
        elif self.st == ST_RTL:
            if nav.step_rtl(t):
                self._item_done(it.seq, reached=True)

    def _start_item(self, t: int) -> None:
        vs = self.vs
        nav = self.nav
        it = self.items[self.current]
        cmd = it.command
        self.vs.mission_now = True
        if cmd == C.MAV_CMD_DO_CHANGE_SPEED:
            nav.change_speed(it.p1, it.p2)
            return self._item_done(it.seq, reached=False)
        if cmd == C.MAV_CMD_NAV_DELAY:
            self.st = ST_HOLD
            self.hold_until = t + int(it.p1 * 1e6)
            return
        if cmd == C.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self.st = ST_RTL
            nav.enter_rtl()
            return
        tgt = self._target(it)
        if tgt is None:        # checked at upload; the home may have moved since
            self.out.statustext(f"Mission: item {it.seq} unreachable, holding",
                                M.MAV_SEVERITY_CRITICAL)
            self.cmd.set_mode(LOITER)
            return
        x, y, z = tgt
        if cmd == C.MAV_CMD_NAV_LAND:
            z = vs.state.z              # fly over the landing point at this height
        yaw = math.radians(it.p4) if math.isfinite(it.p4) else math.nan
        accept = it.p2 if cmd == C.MAV_CMD_NAV_WAYPOINT and it.p2 > 0.0 else 0.0
        nav.fly_to(x, y, z, yaw=yaw, accept_m=accept)
        self.st = ST_LEG

    def _item_done(self, seq: int, reached: bool) -> None:
        if reached:
            self.reached(seq)
        self.vs.mission_now = True
        if seq + 1 < len(self.items):
            self.current = seq + 1
            self.st = ST_START
            return
        self.state = COMPLETE
        self.st = ST_END
        landed = self.vs.landed_state == ON_GROUND
        self.out.statustext("Mission finished, landed" if landed
                            else "Mission finished, loitering", M.MAV_SEVERITY_INFO)

