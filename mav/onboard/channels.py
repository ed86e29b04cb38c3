"""The vehicle's MAVLink links (api and gcs): per-link codec, signing and streams (`Chan`),
bounded input handling (`LinkInput`: decode, guard, dispatch to the parts' handlers) and
output shared by every part (`Outbox`: STATUSTEXT, signing timestamps).

Everything parsed from a link is guarded: a bad datagram is counted in `stats`, never raised,
and never delays the HIL answer.
"""

from __future__ import annotations

import heapq
import sys
import traceback
from collections.abc import Callable

import cython

from mav import wire
from mav.onboard.defs import (
    DRAIN_MAX,
    FRAMES_MAX,
    REJECT_TEXT_EVERY_US,
    SIGNING_EPOCH_2015,
    SP_ID3,
    M,
)
from mav.onboard.status import VehicleStatus

_MAGIC2, _MAGIC1 = bytes([wire.MAGIC_V2]), bytes([wire.MAGIC_V1])
_M_SP = cython.declare(wire.FastMsg, wire.SET_POSITION_TARGET_LOCAL_NED)   # the 200 Hz message


class Stream:
    """One periodic telemetry message on one link."""

    __slots__ = ("msgid", "default_us", "interval_us", "next_us", "emit")

    def __init__(self, msgid: int, default_us: int, emit: Callable) -> None:
        self.msgid = msgid
        self.default_us = default_us      # -1: off by default
        self.interval_us = default_us
        self.next_us = 0
        self.emit = emit


class Chan:
    """One MAVLink link of the vehicle (api or gcs): codec state, streams, pending params."""

    __slots__ = ("name", "link", "mav", "streams", "by_msgid", "next_due", "param_queue",
                 "signed", "peer", "stats", "tx_key", "rx_key", "bad_key", "schedule")

    def __init__(self, name: str, link, mav, stats: dict[str, int]) -> None:
        self.name = name
        self.stats = stats
        self.tx_key = "tx_" + name
        self.rx_key = "rx_" + name
        self.bad_key = "dropped_bad_" + name
        self.link = link
        self.mav = mav
        self.streams: list[Stream] = []
        self.by_msgid: dict[int, Stream] = {}
        self.next_due = 0
        # (next_us, index in streams) of the streams that are on, a heap: the streams due
        # at a tick come off its top (Telemetry.publish); None: to be built
        self.schedule: list[tuple[int, int]] | None = None
        self.param_queue: list[int] = []
        self.signed = False
        self.peer: tuple[int, int] | None = None   # (sysid, compid) of the last sender

    def send(self, data: bytes) -> None:
        self.stats[self.tx_key] += 1
        self.link.send(data)

    def recompute_due(self) -> None:
        """After a stream's interval or next time changed (or streams were added)."""
        sched = [(s.next_us, i) for i, s in enumerate(self.streams) if s.interval_us > 0]
        heapq.heapify(sched)
        self.schedule = sched
        self.next_due = sched[0][0] if sched else 1 << 62


class Outbox:
    """What any part may send on every link: STATUSTEXT; and the links' signing clocks."""

    def __init__(self, vs: VehicleStatus, chans: list[Chan], signing_epoch_unix_s: float
                 ) -> None:
        self.vs = vs
        self.chans = chans
        self._sign_base = int(round((signing_epoch_unix_s - SIGNING_EPOCH_2015) * 1e5))
        self._reject_text_us: dict[str, int] = {}
        self._text_id = 0          # the last chunked STATUSTEXT's id (1..65535)

    def signing_ts(self, t_us: int) -> int:
        """Signing timestamp (10 us units since 2015-01-01) at vehicle time t_us."""
        return self._sign_base + t_us // 10

    def sync_signing(self, ch: Chan) -> None:
        sg = ch.mav.signing
        ts = self.signing_ts(self.vs.t_us)
        if ts > sg.timestamp:
            sg.timestamp = ts

    def statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """Send a STATUSTEXT on the api and gcs links. Up to 50 characters: one message
        (id 0). Longer: MAVLink 2 chunks of 50 with one non-zero id and chunk_seq 0, 1, ...;
        the last chunk is shorter than 50 (an empty one when the text fills the last), so a
        receiver knows where the text ends (QGroundControl and MAVProxy join them)."""
        raw = text.encode("ascii", errors="replace")[:50 * 8]
        if len(raw) <= 50:
            chunks, tid = [raw], 0
        else:
            chunks = [raw[i:i + 50] for i in range(0, len(raw), 50)]
            if len(chunks[-1]) == 50:
                chunks.append(b"")
            self._text_id = tid = self._text_id % 65535 + 1
        for ch in self.chans:
            if ch.signed:
                self.sync_signing(ch)
            for seq, part in enumerate(chunks):
                ch.send(wire.send_msg(ch.mav, M.MAVLink_statustext_message(
                    severity, part, tid, seq)))

    def warn_rate_limited(self, kind: str, text: str) -> None:
        """A STATUSTEXT warning about rejected input, at most once a second per kind."""
        t = self.vs.t_us
        last = self._reject_text_us.get(kind)
        if last is None or t - last >= REJECT_TEXT_EVERY_US:
            self._reject_text_us[kind] = t
            self.statustext(text, M.MAV_SEVERITY_WARNING)


class LinkInput:
    """Drains a link at HIL time and hands each decoded message to its handler.

    `handlers`: msgid -> handler(ch, msg) (pymavlink message objects); `on_setpoint(ch, f)`
    gets SET_POSITION_TARGET_LOCAL_NED in wire order from the fast decoder (unsigned MAVLink 2,
    the 200 Hz case).
    """

    def __init__(self, vs: VehicleStatus, outbox: Outbox, handlers: dict[int, Callable],
                 on_setpoint: Callable) -> None:
        self.vs = vs
        self.stats = vs.stats
        self.outbox = outbox
        self.handlers = handlers
        self.on_setpoint = on_setpoint

    def drain(self, ch: Chan, data: bytes | None = None) -> None:
        """Handle what is queued on ch's link (at most DRAIN_MAX datagrams). `data`: the first
        datagram when the caller has already received it (the vehicle's tick looks first, so
        an idle link costs no call here)."""
        recv = ch.link.recv
        if data is None:
            data = recv()
            if data is None:       # the common case: nothing arrived since the last tick
                return
        st = self.stats
        rx_key = ch.rx_key
        if ch.signed:
            self.outbox.sync_signing(ch)
        for n in range(DRAIN_MAX):
            if n:
                data = recv()
                if data is None:
                    return
            st[rx_key] += 1
            try:
                self.handle_datagram(ch, data)
            except Exception:   # a handler bug must not take the vehicle down: count it
                st[ch.bad_key] += 1
                if st["handler_errors"] < 5:
                    traceback.print_exc(file=sys.stderr)
                st["handler_errors"] += 1
        st["drain_deferred"] += 1

    def handle_datagram(self, ch: Chan, data: bytes) -> None:
        n = len(data)
        # a datagram that is one unsigned-link MAVLink 2 SET_POSITION_TARGET_LOCAL_NED frame
        # (what the loop below does with it, minus the loop)
        if not ch.signed and n > 12 and data[0] == wire.MAGIC_V2 and data[7:10] == SP_ID3:
            if wire.frame_end(data, 0) == n:
                f = wire.decode_fast(_M_SP, data, 0, n)
                if f is None:
                    self.stats[ch.bad_key] += 1
                else:
                    ch.peer = (data[5], data[6])
                    self.on_setpoint(ch, f)
                return
        st = self.stats
        i = 0
        frames = 0
        bad_key = ch.bad_key
        while i < n and frames < FRAMES_MAX:
            end = wire.frame_end(data, i)
            if end < 0:
                # garbage or truncated: count once and resync at the next magic byte
                st[bad_key] += 1
                a = data.find(_MAGIC2, i + 1)
                b = data.find(_MAGIC1, i + 1)
                i = n if a < 0 and b < 0 else (a if b < 0 or 0 <= a < b else b)
                continue
            frames += 1
            msgid = wire.msgid_of(data, i)
            if (msgid == M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED and not ch.signed
                    and data[i] == wire.MAGIC_V2):
                f = wire.decode_fast(_M_SP, data, i, end)
                if f is None:
                    st[bad_key] += 1
                else:
                    _, sysid, compid = wire.header_of(data, i)
                    ch.peer = (sysid, compid)
                    self.on_setpoint(ch, f)
                i = end
                continue
            frame = bytearray(data[i:end])
            i = end
            try:
                msg = ch.mav.decode(frame)
            except Exception as exc:
                if "signature" in str(exc):
                    if frame[0] == wire.MAGIC_V2 and frame[2] & wire.IFLAG_SIGNED:
                        st["badsig_rejected"] += 1
                    else:
                        st["unsigned_rejected"] += 1
                else:
                    st[bad_key] += 1
                continue
            if isinstance(msg, M.MAVLink_unknown):
                st["unknown_msgs"] += 1
                continue
            h = self.handlers.get(msg.get_msgId())
            if h is None:
                st["unhandled_msgs"] += 1
                continue
            ch.peer = (msg.get_srcSystem(), msg.get_srcComponent())
            h(ch, msg)
        if i < n:
            st[bad_key] += 1      # more frames than FRAMES_MAX: the rest is dropped
