"""The offboard client apps use: a companion computer's view of the vehicle over the API link.

    client = OffboardClient(link)          # the app's end of the API link (mav/links.py)
    client.poll(t)                         # every app tick, t = simulation time in s
    if client.heartbeat_seen and not client.armed:
        client.arm()
    client.set_position_target(1.0, 0.0, -1.0)        # world NED, m

Nothing here blocks or waits: commands are sent at once and their COMMAND_ACK shows up in
`acks` on a later `poll`. `poll(t)` drains and decodes everything that arrived, and sends this
component's HEARTBEAT (MAV_TYPE_ONBOARD_CONTROLLER) whenever one is due on the caller's clock
(1 Hz). Telemetry lands in plain attributes (world NED, SI units, rad):

    heartbeat_seen, armed, mode ('POSCTL', 'AUTO.TAKEOFF', 'AUTO.LOITER', 'AUTO.LAND',
    'OFFBOARD', ...), landed_state ('ON_GROUND', 'TAKEOFF', 'IN_AIR', 'LANDING', 'UNDEFINED'),
    position (x, y, z), velocity (vx, vy, vz), attitude (roll, pitch, yaw),
    rates (p, q, r), global_position (lat_deg, lon_deg, alt_m, rel_alt_m), home (x, y, z),
    position_target (x, y, z, vx, vy, vz, yaw, yaw_rate; NaN = not in use),
    battery (voltage V, current A, remaining 0..1), statustext [(t, severity, text)],
    acks {command: CommandAck(result, t)}, params {name: value}.

SET_POSITION_TARGET_LOCAL_NED goes out through the fast codec of `mav/wire.py` (apps send it
at up to 200 Hz). With a signing key the client signs everything it sends, with timestamps
derived from `t` (deterministic), and drops unsigned input.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import cython
from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.params import float_as_int32

M = mavlink2
NAN = math.nan

MODE_BY_NAME: dict[str, tuple[int, int]] = {
    "MANUAL": (1, 0), "ALTCTL": (2, 0), "POSCTL": (3, 0),
    "AUTO.TAKEOFF": (4, 2), "AUTO.LOITER": (4, 3), "AUTO.MISSION": (4, 4), "AUTO.RTL": (4, 5),
    "AUTO.LAND": (4, 6), "OFFBOARD": (6, 0), "STABILIZED": (7, 0),
}
_MODE_BY_NUMBERS = {v: k for k, v in MODE_BY_NAME.items()}
LANDED_STATES = {0: "UNDEFINED", 1: "ON_GROUND", 2: "IN_AIR", 3: "TAKEOFF", 4: "LANDING"}

# type_mask bits (set = ignore), MAVLink POSITION_TARGET_TYPEMASK
_IGN_POS = 1 | 2 | 4
_IGN_VEL = 8 | 16 | 32
_IGN_ACC = 64 | 128 | 256
_IGN_YAW = 1024
_IGN_YAW_RATE = 2048
_FRAMES = {"local": M.MAV_FRAME_LOCAL_NED, "body": M.MAV_FRAME_BODY_NED}
_SIGNING_EPOCH_2015 = 1420070400
SIGNING_EPOCH_2024 = 1704067200.0


# telemetry decoded by the fast codec (unsigned MAVLink 2); everything else goes to pymavlink
_SP = cython.declare(wire.FastMsg, wire.SET_POSITION_TARGET_LOCAL_NED)
_SP_PACK = _SP.st.pack
_FAST_RX: dict[int, wire.FastMsg] = {
    m.id: m for m in (wire.LOCAL_POSITION_NED, wire.ATTITUDE, wire.HEARTBEAT,
                      wire.EXTENDED_SYS_STATE, wire.GLOBAL_POSITION_INT,
                      wire.POSITION_TARGET_LOCAL_NED, wire.SYS_STATUS)
}


class CommandAck(NamedTuple):
    result: int      # MAV_RESULT
    t: float         # s, client clock when it arrived


def _fields_of(msg, fm: wire.FastMsg) -> tuple:
    """A pymavlink message's fields in wire order: what the fast decoder gives."""
    return tuple(getattr(msg, name) for name in fm.cls.ordered_fieldnames)


class OffboardClient:
    """A companion computer on the API link. See the module docstring."""

    def __init__(self, link, *, sysid: int = 1, compid: int = M.MAV_COMP_ID_ONBOARD_COMPUTER,
                 target_system: int = 1, target_component: int = M.MAV_COMP_ID_AUTOPILOT1,
                 signing_key: bytes | None = None,
                 signing_epoch_unix_s: float = SIGNING_EPOCH_2024,
                 heartbeat_period_s: float = 1.0) -> None:
        self.link = link
        self.mav = M.MAVLink(None, sysid, compid)
        self.target_system = target_system
        self.target_component = target_component
        self.signed = signing_key is not None
        self._sign_base = int(round((signing_epoch_unix_s - _SIGNING_EPOCH_2015) * 1e5))
        if signing_key is not None:
            if len(signing_key) != 32:
                raise ValueError(f"signing_key: got {len(signing_key)} bytes; need 32")
            sg = self.mav.signing
            sg.secret_key = bytes(signing_key)
            sg.sign_outgoing = True
            sg.link_id = 0
            sg.timestamp = self._sign_base
        self.heartbeat_period_s = heartbeat_period_s
        self.t = 0.0
        self._next_hb = -math.inf
        # telemetry
        self.heartbeat_seen = False
        self.last_heartbeat_t = NAN
        self.armed = False
        self.mode = "UNKNOWN"
        self.custom_mode = 0
        self.system_status = 0
        self.landed_state = "UNDEFINED"
        self.position = (NAN, NAN, NAN)
        self.velocity = (NAN, NAN, NAN)
        self.attitude = (NAN, NAN, NAN)
        self.rates = (NAN, NAN, NAN)
        self.global_position = (NAN, NAN, NAN, NAN)
        self.home: tuple[float, float, float] | None = None
        self.home_global: tuple[float, float, float] | None = None
        self.position_target = (NAN,) * 8
        self.battery = (NAN, NAN, NAN)
        self.statustext: deque[tuple[float, int, str]] = deque(maxlen=200)
        self._text_id = 0          # id of the last STATUSTEXT (chunks of one text share it)
        self.acks: dict[int, CommandAck] = {}
        self.params: dict[str, float] = {}
        self.param_count = -1
        self.stats = {"rx": 0, "tx": 0, "dropped_bad": 0, "unknown": 0, "rejected_unsigned": 0}
        # telemetry with a fast decoder (mav/wire.py): handlers take the fields in wire order;
        # not when signed (the fast codec does not check signatures)
        self._fast_rx = None if self.signed else _FAST_RX
        self._fast_handlers = {
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._on_local_position,
            M.MAVLINK_MSG_ID_ATTITUDE: self._on_attitude,
            M.MAVLINK_MSG_ID_HEARTBEAT: self._on_heartbeat,
            M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._on_ext_state,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._on_global,
            M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: self._on_target,
            M.MAVLINK_MSG_ID_SYS_STATUS: self._on_sys_status,
        }
        self._handlers = {
            M.MAVLINK_MSG_ID_COMMAND_ACK: self._on_ack,
            M.MAVLINK_MSG_ID_STATUSTEXT: self._on_statustext,
            M.MAVLINK_MSG_ID_HOME_POSITION: self._on_home,
            M.MAVLINK_MSG_ID_PARAM_VALUE: self._on_param_value,
        }

    # ------------------------------------------------------------------ receive
    def poll(self, t: float) -> int:
        """Drain the link (decode telemetry), send a HEARTBEAT if due. Returns messages read."""
        self.t = t
        if self.signed:
            ts = self._sign_base + int(t * 1e5)
            sg = self.mav.signing
            if ts > sg.timestamp:
                sg.timestamp = ts
        n = 0
        recv = self.link.recv
        while True:
            data = recv()
            if data is None:
                break
            n += self._datagram(data)
        if t >= self._next_hb:          # heartbeat_due(t), inline on the per-tick path
            self.send_heartbeat(t)
        return n

    @cython.locals(n=cython.long, i=cython.Py_ssize_t, size=cython.Py_ssize_t,
                   end=cython.Py_ssize_t, msgid=cython.long)
    def _datagram(self, data: bytes) -> int:
        st = self.stats
        n = 0
        i, size = 0, len(data)
        fast = self._fast_rx
        while i < size:
            end = wire.frame_end(data, i)
            if end < 0:
                st["dropped_bad"] += 1
                return n
            msgid = wire.msgid_of(data, i)
            if fast is not None and data[i] == wire.MAGIC_V2:
                fm = fast.get(msgid)
                if fm is not None:
                    f = wire.decode_fast(fm, data, i, end)
                    if f is None:
                        st["dropped_bad"] += 1
                    else:
                        st["rx"] += 1
                        n += 1
                        if data[i + 5] == self.target_system:
                            self._fast_handlers[msgid](f, data[i + 6])
                    i = end
                    continue
            try:
                msg = self.mav.decode(bytearray(data[i:end]))
            except Exception as exc:
                if "signature" in str(exc):
                    st["rejected_unsigned"] += 1
                else:
                    st["dropped_bad"] += 1
                i = end
                continue
            i = end
            if isinstance(msg, M.MAVLink_unknown):
                st["unknown"] += 1
                continue
            st["rx"] += 1
            n += 1
            if msg.get_srcSystem() != self.target_system:
                continue
            mid = msg.get_msgId()
            fm = _FAST_RX.get(mid)
            if fm is not None:     # signed or MAVLink 1: the same handler on the same fields
                self._fast_handlers[mid](_fields_of(msg, fm), msg.get_srcComponent())
                continue
            h = self._handlers.get(mid)
            if h is not None:
                h(msg)
        return n

    # handlers of the fast-decoded messages: f = the fields in wire order (wire.py)
    def _on_local_position(self, f: tuple, compid: int) -> None:
        self.position = (f[1], f[2], f[3])
        self.velocity = (f[4], f[5], f[6])

    def _on_attitude(self, f: tuple, compid: int) -> None:
        self.attitude = (f[1], f[2], f[3])
        self.rates = (f[4], f[5], f[6])

    def _on_heartbeat(self, f: tuple, compid: int) -> None:
        # custom_mode, type, autopilot, base_mode, system_status, mavlink_version
        if compid != self.target_component:
            return
        self.heartbeat_seen = True
        self.last_heartbeat_t = self.t
        self.armed = bool(f[3] & M.MAV_MODE_FLAG_SAFETY_ARMED)
        cm = f[0]
        self.custom_mode = cm
        key = ((cm >> 16) & 0xFF, (cm >> 24) & 0xFF)
        self.mode = _MODE_BY_NUMBERS.get(key, f"MODE({key[0]},{key[1]})")
        self.system_status = f[4]

    def _on_ext_state(self, f: tuple, compid: int) -> None:
        self.landed_state = LANDED_STATES.get(f[1], "UNDEFINED")

    def _on_ack(self, msg) -> None:
        self.acks[msg.command] = CommandAck(msg.result, self.t)

    def _on_statustext(self, msg) -> None:
        text = msg.text
        if isinstance(text, bytes | bytearray):
            text = bytes(text).decode("ascii", errors="replace")
        text = text.rstrip("\x00")
        tid, seq = getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0)
        if tid and seq > 0 and self.statustext and self._text_id == tid:
            t0, sev, head = self.statustext.pop()        # a MAVLink 2 chunk: join it
            text = head + text
        self._text_id = tid
        self.statustext.append((self.t, msg.severity, text))

    def _on_global(self, f: tuple, compid: int) -> None:
        # time_boot_ms, lat, lon, alt, relative_alt, vx, vy, vz, hdg
        self.global_position = (f[1] * 1e-7, f[2] * 1e-7, f[3] * 1e-3, f[4] * 1e-3)

    def _on_home(self, msg) -> None:
        self.home = (msg.x, msg.y, msg.z)
        self.home_global = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)

    def _on_target(self, f: tuple, compid: int) -> None:
        # time_boot_ms, x, y, z, vx, vy, vz, afx, afy, afz, yaw, yaw_rate, type_mask, frame
        m = f[12]
        self.position_target = (NAN if m & 1 else f[1], NAN if m & 2 else f[2],
                                NAN if m & 4 else f[3], NAN if m & 8 else f[4],
                                NAN if m & 16 else f[5], NAN if m & 32 else f[6],
                                NAN if m & _IGN_YAW else f[10],
                                NAN if m & _IGN_YAW_RATE else f[11])

    def _on_sys_status(self, f: tuple, compid: int) -> None:
        # voltage_battery (mV), current_battery (cA), battery_remaining (%): fields 4, 5, 12
        self.battery = (f[4] * 1e-3, f[5] * 1e-2, f[12] * 1e-2 if f[12] >= 0 else NAN)

    def _on_param_value(self, msg) -> None:
        name = msg.param_id
        if isinstance(name, bytes | bytearray):
            name = bytes(name).decode("ascii", errors="replace")
        v = msg.param_value
        if msg.param_type == M.MAV_PARAM_TYPE_INT32:      # byte-wise, as PX4 sends it
            v = float(float_as_int32(v))
        self.params[name.rstrip("\x00")] = v
        self.param_count = msg.param_count

    # ------------------------------------------------------------------ send
    def _send(self, data: bytes) -> None:
        self.stats["tx"] += 1
        self.link.send(data)

    def _send_msg(self, msg) -> None:
        self._send(wire.send_msg(self.mav, msg))

    def heartbeat_due(self, t: float) -> bool:
        """True when this component's 1 Hz HEARTBEAT is due at time t (s)."""
        return t >= self._next_hb

    def send_heartbeat(self, t: float) -> None:
        nxt = self._next_hb + self.heartbeat_period_s
        self._next_hb = nxt if nxt > t else t + self.heartbeat_period_s
        self._send(wire.pack(self.mav, wire.HEARTBEAT, 0, M.MAV_TYPE_ONBOARD_CONTROLLER,
                             M.MAV_AUTOPILOT_INVALID, 0, M.MAV_STATE_ACTIVE, 3))

    def command_long(self, command: int, p1: float = 0.0, p2: float = 0.0, p3: float = 0.0,
                     p4: float = 0.0, p5: float = 0.0, p6: float = 0.0, p7: float = 0.0) -> None:
        """Send COMMAND_LONG; its previous ack (if any) is forgotten so `ack()` shows the new."""
        self.acks.pop(command, None)
        self._send_msg(M.MAVLink_command_long_message(
            self.target_system, self.target_component, command, 0, p1, p2, p3, p4, p5, p6, p7))

    def command_int(self, command: int, frame: int, p1: float = 0.0, p2: float = 0.0,
                    p3: float = 0.0, p4: float = 0.0, x: int = 0, y: int = 0,
                    z: float = 0.0) -> None:
        self.acks.pop(command, None)
        self._send_msg(M.MAVLink_command_int_message(
            self.target_system, self.target_component, frame, command, 0, 0, p1, p2, p3, p4,
            x, y, z))

    def ack(self, command: int) -> int | None:
        """MAV_RESULT of the last COMMAND_ACK for `command` since it was sent, or None."""
        a = self.acks.get(command)
        return None if a is None else a.result

    def arm(self) -> None:
        self.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)

    def disarm(self, force: bool = False) -> None:
        """Disarm; the vehicle refuses in flight unless `force` (motors stop: it falls)."""
        self.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 21196.0 if force else 0.0)

    def takeoff(self, alt_m: float) -> None:
        """AUTO.TAKEOFF to `alt_m` m above home (COMMAND_INT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
        current position and heading)."""
        self.command_int(M.MAV_CMD_NAV_TAKEOFF, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 0.0, 0.0, 0.0,
                         NAN, 0, 0, float(alt_m))

    def land(self) -> None:
        self.command_long(M.MAV_CMD_NAV_LAND, 0.0, 0.0, 0.0, NAN, NAN, NAN, NAN)

    def set_mode(self, name: str) -> None:
        """DO_SET_MODE to a PX4 mode by name: 'POSCTL', 'AUTO.TAKEOFF', 'AUTO.LOITER',
        'AUTO.LAND', 'OFFBOARD' (others are sent but the vehicle refuses them)."""
        try:
            main, sub = MODE_BY_NAME[name]
        except KeyError:
            raise ValueError(f"unknown mode {name!r}; choose one of "
                             f"{', '.join(MODE_BY_NAME)}") from None
        self.command_long(M.MAV_CMD_DO_SET_MODE, float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED),
                          float(main), float(sub))

    def set_position_target(self, x: float, y: float, z: float, yaw: float = NAN,
                            vx: float = NAN, vy: float = NAN, vz: float = NAN,
                            yaw_rate: float = NAN) -> None:
        """Position setpoint, world NED (m); optional yaw (rad), velocity feed-forward (m/s;
        vx, vy together and/or vz) and yaw rate (rad/s). NaN = not sent (masked)."""
        mask = _IGN_ACC
        if not (vx == vx and vy == vy):
            mask |= 8 | 16
            vx = vy = 0.0
        if vz != vz:
            mask |= 32
            vz = 0.0
        if yaw != yaw:
            mask |= _IGN_YAW
            yaw = 0.0
        if yaw_rate != yaw_rate:
            mask |= _IGN_YAW_RATE
            yaw_rate = 0.0
        self._setpoint(M.MAV_FRAME_LOCAL_NED, mask, x, y, z, vx, vy, vz, yaw, yaw_rate)

    def set_velocity_target(self, vx: float, vy: float, vz: float, yaw_rate: float = NAN,
                            yaw: float = NAN, frame: str = "local") -> None:
        """Velocity setpoint (m/s): frame 'local' = world NED, 'body' = MAV_FRAME_BODY_NED
        (vx forward, vy right, rotated by the vehicle's heading; vz down). Optional yaw rate
        (rad/s) or yaw (rad)."""
        try:
            fr = _FRAMES[frame]
        except KeyError:
            raise ValueError(f"frame: got {frame!r}; allowed: local, body") from None
        mask = _IGN_POS | _IGN_ACC
        if yaw != yaw:
            mask |= _IGN_YAW
            yaw = 0.0
        if yaw_rate != yaw_rate:
            mask |= _IGN_YAW_RATE
            yaw_rate = 0.0
        self._setpoint(fr, mask, 0.0, 0.0, 0.0, vx, vy, vz, yaw, yaw_rate)

    def set_relative_move(self, dx: float, dy: float, dz: float, dyaw: float = 0.0) -> None:
        """A relative move (Parrot's moveBy): dx forward, dy right, dz down (m) in the
        vehicle's heading frame from where it is when the message arrives, and a heading
        change dyaw (rad); SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_BODY_OFFSET_NED with
        the offsets and the yaw offset. A new move replaces the one in progress."""
        self._setpoint(M.MAV_FRAME_BODY_OFFSET_NED, _IGN_VEL | _IGN_ACC | _IGN_YAW_RATE,
                       dx, dy, dz, 0.0, 0.0, 0.0, dyaw, 0.0)

    def _setpoint(self, frame: int, mask: int, x: float, y: float, z: float, vx: float,
                  vy: float, vz: float, yaw: float, yaw_rate: float) -> None:
        # wire.encode_set_position_target_local_ned
        pl = _SP_PACK(int(self.t * 1000.0) & 0xFFFFFFFF, x, y, z, vx, vy, vz, 0.0, 0.0, 0.0, yaw,
                      yaw_rate, mask, self.target_system, self.target_component, frame)
        self.stats["tx"] += 1             # _send, inline on the 200 Hz path
        self.link.send(wire.frame(self.mav, _SP, pl))

    def request_message(self, msgid: int) -> None:
        self.command_long(M.MAV_CMD_REQUEST_MESSAGE, float(msgid))

    def set_message_interval(self, msgid: int, hz: float) -> None:
        """Stream `msgid` at `hz` on this link (0: off)."""
        self.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, float(msgid),
                          1e6 / hz if hz > 0 else -1.0)

    def set_param(self, name: str, value: float) -> None:
        """PARAM_SET typed REAL32 (the vehicle reads it by value, an INT32 parameter too);
        the vehicle's PARAM_VALUE echo updates `params[name]` (an INT32 decoded byte-wise)."""
        self._send_msg(M.MAVLink_param_set_message(
            self.target_system, self.target_component, name.encode(), float(value),
            M.MAV_PARAM_TYPE_REAL32))

    def request_params(self) -> None:
        """PARAM_REQUEST_LIST: the vehicle streams every PARAM_VALUE into `params`."""
        self._send_msg(M.MAVLink_param_request_list_message(self.target_system,
                                                             self.target_component))
