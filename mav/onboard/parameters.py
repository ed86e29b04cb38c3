"""Parameters: the controller's and the stack's own (`mav/params.py`) in one table, served over
the MAVLink parameter protocol (PARAM_REQUEST_LIST / _READ / PARAM_SET / PARAM_VALUE /
PARAM_ERROR), the rule for changes while armed, and the limits that derive from them.

Refusals are answered the way clients understand them. PX4 (mavlink_parameters.cpp) answers an
unknown name with a STATUSTEXT only and does not check ranges, so MAVSDK retries a refused set
until its timeout. Here the asking link first gets PARAM_ERROR (#345; DOES_NOT_EXIST,
VALUE_OUT_OF_RANGE, PERMISSION_DENIED), which MAVSDK >= 4 turns into that result at once
(sent after the echo it would first resend once), then every link the PARAM_VALUE of the value
in effect (the MAVLink parameter protocol's echo, what QGroundControl and MAVProxy read), and a
STATUSTEXT says why. ArduPilot answers with PARAM_ERROR the same way (GCS_Param.cpp).
Types: each parameter's param_type is PX4's (REAL32, or INT32 where PX4's metadata says int32:
mav/px4_params.json). An INT32 value travels byte-wise in the float field, as PX4 sends it
(MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, which this vehicle declares; QGroundControl
and MAVSDK decode it so). A PARAM_SET typed INT32 is read byte-wise; one typed REAL32 is read
by value (a client that sends every parameter as REAL32, as pymavlink's and ours do).
"""

from __future__ import annotations

import math

from mav import wire
from mav.onboard.channels import Chan, Outbox
from mav.onboard.defs import M, text_of
from mav.onboard.status import VehicleStatus
from mav.params import (
    ONBOARD_PARAMS,
    ParamError,
    ParamTable,
    f32,
    flight_envelope,
    float_as_int32,
    int32_as_float,
    read_param_file,
    renamed_to,
)

FLT_MIN = 1.1754943508222875e-38      # the smallest normal float32 (IEEE 754)


class Parameters:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, chans: list[Chan], for_us) -> None:
        self.vs = vs
        self.out = outbox
        self.chans = chans
        self.for_us = for_us            # (target_system, target_component) -> bool
        self.warnings: list[str] = []
        self.table = ParamTable()
        self.hover_fraction = 0.5       # hover thrust / max thrust of the airframe (the vehicle
        #                                 sets it; the thrust limit's flight envelope uses it)

    def build(self) -> None:
        """The table for the controller in use plus the stack's own parameters (defaults)."""
        t = ParamTable()
        vs = self.vs
        for spec in vs.ctrl.param_table():
            def _get(n=spec.name) -> float:
                return vs.ctrl.get_param(n)

            def _set(v: float, n=spec.name) -> None:
                vs.ctrl.set_param(n, v)

            t.add(spec, _get, _set)
        own = vs.own
        own.clear()
        t.add_store(ONBOARD_PARAMS, own)
        self.table = t

    def rebuild_keeping_user_values(self) -> None:
        """After a new controller: the same own values, and what the user set re-applied."""
        vs = self.vs
        own = dict(vs.own)
        self.build()
        vs.own.update(own)
        for name, v in vs.user_params.items():
            try:
                self.table.set(name, v)
            except ParamError as exc:
                self.warnings.append(str(exc))
        self.apply()

    def apply(self) -> None:
        """Recompute what derives from the stack's own parameters."""
        vs = self.vs
        own = vs.own
        vs.of_loss_us = int(round(own["COM_OF_LOSS_T"] * 1e6))
        vs.fail_act_us = int(round(own["COM_FAIL_ACT_T"] * 1e6))
        vs.battery.configure(own["BAT1_CAPACITY"], own["BAT1_R_INTERNAL"])
        cap = vs.battery.capacity_mah
        if vs.bat_warned < 3:
            thr = own[("BAT_LOW_THR", "BAT_CRIT_THR", "BAT_EMERGEN_THR")[vs.bat_warned]]
            vs.bat_warn_mah = (1.0 - thr) * cap
        else:
            vs.bat_warn_mah = math.inf

    # ------------------------------------------------------------------ changes while armed
    def envelope(self, name: str) -> tuple[float, float] | None:
        """The values `name` may take while armed (mav/params.py flight_envelope), or None."""
        return flight_envelope(self.table.spec(name), self.hover_fraction)

    def outside_envelope(self, name: str, value: float) -> tuple[float, float] | None:
        """The envelope `value` is outside of (compared in single precision, as sent), or None."""
        env = self.envelope(name)
        if env is None or not math.isfinite(value):
            return None
        v = f32(value)
        return env if v < f32(env[0]) or v > f32(env[1]) else None

    def arming_problem(self) -> str | None:
        """Why the vehicle must not arm: a parameter outside its flight envelope (commander)."""
        t = self.table
        for i in range(len(t)):
            name = t.name_at(i)
            env = self.outside_envelope(name, t.get(name))
            if env is not None:
                return f"{name} {t.get(name):g} outside its flight range {env[0]:.3g}..{env[1]:.3g}"
        return None

    def load_file(self, path: str) -> None:
        """Apply a parameter file; unknown names are noted in `warnings`, bad values raise."""
        unknown = []
        for name, v in read_param_file(path):
            if self.table.index(name) < 0:
                new = renamed_to(name, self.table.names())
                if new:   # PX4's name, with PX4's meaning in a PX4 file: not ours
                    self.warnings.append(f"{path}: ignored {name} (PX4's; not this vehicle's "
                                         f"{new}, which has another meaning or range)")
                else:
                    unknown.append(name)
                continue
            try:
                self.table.set(name, v)
            except ParamError as exc:
                raise ValueError(f"{path}: {exc}") from None
            self.vs.user_params[name] = v
        if unknown:
            self.warnings.append(f"{path}: ignored {len(unknown)} unknown parameter(s): "
                                 + ", ".join(unknown[:8]) + (" ..." if len(unknown) > 8 else ""))

    # ------------------------------------------------------------------ the protocol
    def send_value(self, ch: Chan, index: int) -> None:
        t = self.table
        name = t.name_at(index)
        if t.spec(name).ptype == "INT32":
            value, ptype = int32_as_float(int(t.get(name))), M.MAV_PARAM_TYPE_INT32
        else:
            value, ptype = f32(t.get(name)), M.MAV_PARAM_TYPE_REAL32
        ch.send(wire.send_msg(ch.mav, M.MAVLink_param_value_message(
            name.encode(), value, ptype, len(t), index)))

    def on_request_list(self, ch: Chan, msg) -> None:
        if self.for_us(msg.target_system, msg.target_component):
            ch.param_queue = list(range(len(self.table)))

    def send_error(self, ch: Chan, name: str, index: int, error: int) -> None:
        """PARAM_ERROR to whoever asked on `ch` (index -1: the name identifies it)."""
        peer = ch.peer or (0, 0)
        ch.send(wire.send_msg(ch.mav, M.MAVLink_param_error_message(
            peer[0], peer[1], name.encode("ascii", errors="replace")[:16], index, error)))

    def on_request_read(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, msg.target_component):
            return
        idx = msg.param_index
        if idx < 0:
            idx = self.table.index(text_of(msg.param_id))
        if 0 <= idx < len(self.table):
            self.send_value(ch, idx)
        else:
            name = text_of(msg.param_id)
            self.send_error(ch, name, msg.param_index if msg.param_index >= 0 else -1,
                            M.MAV_PARAM_ERROR_DOES_NOT_EXIST)
            self.out.warn_rate_limited("param", f"Unknown parameter {name!r}")

    def on_set(self, ch: Chan, msg) -> None:
        """PARAM_SET: applied at once, or refused with PARAM_ERROR (to the asker), the echo of
        the value in effect (every link) and a STATUSTEXT. While armed, a value outside the
        parameter's flight envelope is refused (PERMISSION_DENIED: allowed when disarmed)."""
        if not self.for_us(msg.target_system, msg.target_component):
            return
        vs = self.vs
        name = text_of(msg.param_id)
        idx = self.table.index(name)
        if idx < 0:
            vs.stats["param_rejected"] += 1
            self.send_error(ch, name, -1, M.MAV_PARAM_ERROR_DOES_NOT_EXIST)
            self.out.warn_rate_limited("param", f"Unknown parameter {name!r}")
            return
        value = float(msg.param_value)
        int32 = msg.param_type == M.MAV_PARAM_TYPE_INT32
        if int32:               # byte-wise (PX4's encoding); by value when typed REAL32
            value = float(float_as_int32(value))
        env = self.outside_envelope(name, value)
        error = text = None
        if not int32 and value != 0.0 and abs(value) < FLT_MIN:
            # a subnormal float32 (< 1.18e-38 in magnitude) is no setting of any parameter
            # (a corrupted or hostile value; as a capacity or a timeout it acts as 0 or
            # divides into infinity): refused like a value out of range
            error = M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
            text = f"Param rejected: {name}: {value:g} is a subnormal number"
        elif env is not None and vs.armed:
            vs.stats["param_denied_armed"] += 1
            error = M.MAV_PARAM_ERROR_PERMISSION_DENIED
            text = (f"{name} {value:g} refused while armed: in flight "
                    f"{env[0]:.3g}..{env[1]:.3g}; disarm to set it")
        else:
            try:
                self.table.set(name, value)
                vs.user_params[name] = value
                vs.stats["param_sets"] += 1
                if name in vs.own:
                    self.apply()
                if env is not None:
                    self.out.statustext(f"{name} {value:g} is outside its flight range "
                                        f"{env[0]:.3g}..{env[1]:.3g}: arming refused until "
                                        "it is back", M.MAV_SEVERITY_WARNING)
            except ParamError as exc:
                error = M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
                text = f"Param rejected: {exc}"
        if error is not None:
            vs.stats["param_rejected"] += 1
            self.send_error(ch, name, -1, error)     # first: MAVSDK ends the request on it
            self.out.statustext(text, M.MAV_SEVERITY_WARNING)
        for c in self.chans:          # echo the value now in effect on every link
            self.send_value(c, idx)
