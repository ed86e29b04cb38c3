"""Commands and requests: COMMAND_LONG / COMMAND_INT (each answered with COMMAND_ACK),
SET_MODE, message intervals and legacy data streams, and the small protocol answers (TIMESYNC,
PING, FTP). The mission protocol's messages go to `mission.py`.

To add a command: a branch in `Commands.command` returning a MAV_RESULT (and, to send a message
right after the ACK, its id).
"""

from __future__ import annotations

import math

from mav import wire
from mav.onboard.channels import Chan, Outbox
from mav.onboard.commander import Commander
from mav.onboard.defs import (
    DATA_STREAM_GROUPS,
    FORCE_DISARM_MAGIC,
    LAND,
    LOITER,
    ON_GROUND,
    RTL,
    STREAMS,
    TAKEOFF,
    M,
    hz_to_us,
)
from mav.onboard.navigator import Navigator, speed_range
from mav.onboard.status import VehicleStatus
from mav.onboard.telemetry import Telemetry

# MAVLink FTP (https://mavlink.io/en/services/ftp.html): opcodes and error codes used here
FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS = 1, 2
FTP_FILE_OPS = frozenset({3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14, 15, 16, 17})  # list, open,
# read, create, write, remove, truncate, open-write, create/remove dir, rename, crc, burst
FTP_ACK, FTP_NAK = 128, 129
FTP_ERR_UNKNOWN_COMMAND, FTP_ERR_FILE_NOT_FOUND = 7, 10


class Commands:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander,
                 navigator: Navigator, telemetry: Telemetry, sysid: int, compid: int,
                 mission) -> None:
        self.vs = vs
        self.mission = mission
        self.out = outbox
        self.cmd = commander
        self.nav = navigator
        self.tel = telemetry
        self.sysid, self.compid = sysid, compid

    def for_us(self, target_system: int, target_component: int | None = None,
               allow_broadcast: bool = True) -> bool:
        ok = target_system == self.sysid or (allow_broadcast and target_system == 0)
        if ok and target_component is not None:
            ok = target_component in (0, self.compid)
        if not ok:
            self.vs.stats["not_for_us"] += 1
        return ok

    # ------------------------------------------------------------------ commands
    def on_command_long(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, msg.target_component):
            return
        self.command(ch, msg.command, msg.param1, msg.param2, msg.param3, msg.param4,
                     msg.param5, msg.param6, msg.param7, None)

    def on_command_int(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, msg.target_component):
            return
        self.command(ch, msg.command, msg.param1, msg.param2, msg.param3, msg.param4,
                     msg.x, msg.y, msg.z, msg.frame)

    def command(self, ch: Chan, cmd: int, p1: float, p2: float, p3: float, p4: float,
                p5: float, p6: float, p7: float, frame: int | None) -> None:
        """One COMMAND_LONG (frame None) or COMMAND_INT (p5, p6 = x, y ints; p7 = z)."""
        vs = self.vs
        vs.stats["commands"] += 1
        after = None
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            if p1 == 1.0:
                res = self.cmd.arm()
            elif p1 == 0.0:
                if vs.armed and vs.landed_state != ON_GROUND and p2 != FORCE_DISARM_MAGIC:
                    self.out.statustext("Disarming denied: not landed", M.MAV_SEVERITY_CRITICAL)
                    res = M.MAV_RESULT_DENIED
                else:
                    self.cmd.disarm("Disarmed (forced)" if p2 == FORCE_DISARM_MAGIC
                                    else "Disarmed")
                    res = M.MAV_RESULT_ACCEPTED
            else:
                res = M.MAV_RESULT_DENIED
        elif cmd == M.MAV_CMD_NAV_TAKEOFF:
            res = (M.MAV_RESULT_TEMPORARILY_REJECTED if self.cmd.position_denied(TAKEOFF)
                   else self.nav.cmd_takeoff(p4, p7, frame))
        elif cmd == M.MAV_CMD_NAV_LAND:
            self.cmd.set_mode(LAND)
            res = M.MAV_RESULT_ACCEPTED
        elif cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            res = self.cmd.try_mode(RTL)
        elif cmd == M.MAV_CMD_DO_REPOSITION and self.cmd.position_denied(LOITER):
            res = M.MAV_RESULT_TEMPORARILY_REJECTED
        elif cmd == M.MAV_CMD_DO_REPOSITION:
            # ground speed: the cruise parameter's range; below it (1e-30), the default
            lo, hi = speed_range(0)
            speed = min(p1, hi) if math.isfinite(p1) and p1 >= lo else math.nan
            res = self.nav.reposition(speed, p2, p4, p5, p6, p7, frame)
        elif cmd == M.MAV_CMD_DO_CHANGE_SPEED:
            res = self.nav.change_speed(p1, p2)
        elif cmd == M.MAV_CMD_DO_SET_MISSION_CURRENT:
            res = self.mission.set_current(p1)
        elif cmd == M.MAV_CMD_MISSION_START:
            res = self.mission.start_command(p1, p2)
        elif cmd == M.MAV_CMD_DO_SET_MODE:
            res = self.cmd.request_mode(p1, p2, p3)
        elif cmd == M.MAV_CMD_REQUEST_MESSAGE:
            msgid = int(p1) if math.isfinite(p1) else -1
            res, after = self.tel.request_message(msgid)
        elif cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            res, after = M.MAV_RESULT_ACCEPTED, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        elif cmd == M.MAV_CMD_GET_HOME_POSITION:
            res, after = self.tel.request_message(M.MAVLINK_MSG_ID_HOME_POSITION)
        elif cmd == M.MAV_CMD_REQUEST_PROTOCOL_VERSION:      # ACK, then PROTOCOL_VERSION (#300)
            res, after = self.tel.request_message(300)
        elif cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            res = self.set_interval(ch, p1, p2)
        elif cmd == M.MAV_CMD_GET_MESSAGE_INTERVAL:
            res = self.get_interval(ch, p1)
        elif cmd == M.MAV_CMD_INJECT_FAILURE:   # the simulator's, on HIL only (inject.py)
            res = M.MAV_RESULT_DENIED
            vs.stats["inject_denied"] += 1
        else:
            res = M.MAV_RESULT_UNSUPPORTED
            vs.stats["commands_unsupported"] += 1
        peer = ch.peer or (0, 0)
        ch.send(wire.send_msg(ch.mav, M.MAVLink_command_ack_message(
            cmd, res, 0, 0, peer[0], peer[1])))
        if after is not None:
            self.tel.emitter(after)(ch)

    def on_set_mode(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, None, allow_broadcast=False):
            return
        cm = msg.custom_mode
        self.cmd.request_mode(float(msg.base_mode), float((cm >> 16) & 0xFF),
                              float((cm >> 24) & 0xFF))

    # ------------------------------------------------------------------ stream rates
    def set_interval(self, ch: Chan, p1: float, p2: float) -> int:
        if not (math.isfinite(p1) and math.isfinite(p2)):
            return M.MAV_RESULT_DENIED
        st = ch.by_msgid.get(int(p1))
        if st is None:
            return M.MAV_RESULT_UNSUPPORTED
        iv = int(p2)
        if iv == 0:
            st.interval_us = st.default_us
        elif iv == -1:
            st.interval_us = -1
        elif iv > 0:
            st.interval_us = iv
        else:
            return M.MAV_RESULT_DENIED
        st.next_us = self.vs.t_us
        ch.recompute_due()
        return M.MAV_RESULT_ACCEPTED

    def get_interval(self, ch: Chan, p1: float) -> int:
        """MESSAGE_INTERVAL for message id p1: its interval (us), -1 if off, 0 if not here."""
        if not (math.isfinite(p1) and 0 <= p1 <= 65535):
            return M.MAV_RESULT_DENIED
        msgid = int(p1)
        st = ch.by_msgid.get(msgid)
        iv = (min(st.interval_us, (1 << 31) - 1) if st.interval_us > 0 else -1) if st else 0
        ch.send(wire.send_msg(ch.mav, M.MAVLink_message_interval_message(msgid, iv)))
        return M.MAV_RESULT_ACCEPTED

    def on_request_data_stream(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, msg.target_component):
            return
        names = DATA_STREAM_GROUPS.get(msg.req_stream_id)
        if names is None:
            return
        for n in names:
            st = ch.by_msgid[STREAMS[n]]
            if msg.start_stop and msg.req_message_rate > 0:
                st.interval_us = hz_to_us(float(msg.req_message_rate))
                st.next_us = self.vs.t_us
            elif not msg.start_stop:
                st.interval_us = -1
        ch.recompute_due()

    # ------------------------------------------------------------------ small protocols
    def on_timesync(self, ch: Chan, msg) -> None:
        if msg.tc1 == 0:
            ch.send(wire.send_msg(ch.mav, M.MAVLink_timesync_message(self.vs.t_us * 1000,
                                                                     msg.ts1)))

    def on_ping(self, ch: Chan, msg) -> None:
        if msg.target_system == 0 and msg.target_component == 0:
            peer = ch.peer or (0, 0)
            ch.send(wire.send_msg(ch.mav, M.MAVLink_ping_message(
                msg.time_usec, msg.seq, peer[0], peer[1])))

    def on_ftp(self, ch: Chan, msg) -> None:
        """MAVLink FTP: no file system here. Every file request gets the proper NAK at once
        (FileNotFound; UnknownCommand for what is not a file operation), session resets an
        ACK, so a client (MAVProxy fetching @PARAM/param.pck) falls back to the parameter
        protocol at once instead of waiting for its FTP timeout."""
        if not self.for_us(msg.target_system, 0) or len(msg.payload) < 12:
            return
        p = bytes(msg.payload)
        seq = int.from_bytes(p[0:2], "little")
        session, opcode = p[2], p[3]
        if opcode in (FTP_ACK, FTP_NAK, 0):
            return
        if opcode in (FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS):
            reply, size, data = FTP_ACK, 0, b""
        else:
            err = FTP_ERR_FILE_NOT_FOUND if opcode in FTP_FILE_OPS else FTP_ERR_UNKNOWN_COMMAND
            reply, size, data = FTP_NAK, 1, bytes([err])
        out = ((seq + 1) & 0xFFFF).to_bytes(2, "little") + bytes(
            [session, reply, size, opcode, 0, 0]) + (0).to_bytes(4, "little") + data
        peer = ch.peer or (0, 0)
        ch.send(wire.send_msg(ch.mav, M.MAVLink_file_transfer_protocol_message(
            msg.target_network, peer[0], peer[1], list(out.ljust(251, b"\0")))))

    def ignore(self, ch: Chan, msg) -> None:
        """HEARTBEAT, COMMAND_ACK, SYSTEM_TIME: the peer is noted, nothing else to do (links do
        not time out in lockstep)."""

    def handlers(self, on_setpoint_msg, params, manual) -> dict[int, object]:
        """msgid -> handler(ch, msg) for every message the vehicle understands."""
        return {
            M.MAVLINK_MSG_ID_HEARTBEAT: self.ignore,
            M.MAVLINK_MSG_ID_COMMAND_LONG: self.on_command_long,
            M.MAVLINK_MSG_ID_COMMAND_INT: self.on_command_int,
            M.MAVLINK_MSG_ID_SET_MODE: self.on_set_mode,
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: on_setpoint_msg,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: params.on_request_list,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_READ: params.on_request_read,
            M.MAVLINK_MSG_ID_PARAM_SET: params.on_set,
            M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: self.mission.on_request_list,
            M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: self.mission.on_clear_all,
            M.MAVLINK_MSG_ID_MISSION_COUNT: self.mission.on_count,
            M.MAVLINK_MSG_ID_MISSION_ITEM_INT: self.mission.on_item_int,
            M.MAVLINK_MSG_ID_MISSION_ITEM: self.mission.on_item,
            M.MAVLINK_MSG_ID_MISSION_REQUEST_INT: self.mission.on_request_int,
            M.MAVLINK_MSG_ID_MISSION_REQUEST: self.mission.on_request,
            M.MAVLINK_MSG_ID_MISSION_ACK: self.mission.on_ack,
            M.MAVLINK_MSG_ID_MISSION_SET_CURRENT: self.mission.on_set_current,
            M.MAVLINK_MSG_ID_MANUAL_CONTROL: manual.on_manual_control,
            M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: self.on_request_data_stream,
            M.MAVLINK_MSG_ID_TIMESYNC: self.on_timesync,
            M.MAVLINK_MSG_ID_PING: self.on_ping,
            M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self.on_ftp,
            M.MAVLINK_MSG_ID_COMMAND_ACK: self.ignore,
            M.MAVLINK_MSG_ID_SYSTEM_TIME: self.ignore,
        }
