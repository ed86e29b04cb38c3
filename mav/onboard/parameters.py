"""Parameters: the controller's and the stack's own (`mav/params.py`) in one table, served over
the MAVLink parameter protocol (PARAM_REQUEST_LIST / _READ / PARAM_SET / PARAM_VALUE), and the
limits that derive from them."""

from __future__ import annotations

import math

from mav import wire
from mav.onboard.defs import M, text_of
from mav.onboard.links import Chan, Outbox
from mav.onboard.status import VehicleStatus
from mav.params import ONBOARD_PARAMS, ParamError, ParamTable, f32, read_param_file


class Parameters:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, chans: list[Chan], for_us) -> None:
        self.vs = vs
        self.out = outbox
        self.chans = chans
        self.for_us = for_us            # (target_system, target_component) -> bool
        self.warnings: list[str] = []
        self.table = ParamTable()

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

    def load_file(self, path: str) -> None:
        """Apply a parameter file; unknown names are noted in `warnings`, bad values raise."""
        unknown = []
        for name, v in read_param_file(path):
            if self.table.index(name) < 0:
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
        ch.send(wire.send_msg(ch.mav, M.MAVLink_param_value_message(
            name.encode(), f32(t.get(name)), M.MAV_PARAM_TYPE_REAL32, len(t), index)))

    def on_request_list(self, ch: Chan, msg) -> None:
        if self.for_us(msg.target_system, msg.target_component):
            ch.param_queue = list(range(len(self.table)))

    def on_request_read(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, msg.target_component):
            return
        idx = msg.param_index
        if idx < 0:
            idx = self.table.index(text_of(msg.param_id))
        if 0 <= idx < len(self.table):
            self.send_value(ch, idx)
        else:
            self.out.warn_rate_limited("param", f"Unknown parameter {text_of(msg.param_id)!r}")

    def on_set(self, ch: Chan, msg) -> None:
        if not self.for_us(msg.target_system, msg.target_component):
            return
        vs = self.vs
        name = text_of(msg.param_id)
        idx = self.table.index(name)
        if idx < 0:
            vs.stats["param_rejected"] += 1
            self.out.warn_rate_limited("param", f"Unknown parameter {name!r}")
            return
        try:
            self.table.set(name, msg.param_value)
            vs.user_params[name] = float(msg.param_value)
            vs.stats["param_sets"] += 1
            if name in vs.own:
                self.apply()
        except ParamError as exc:
            vs.stats["param_rejected"] += 1
            self.out.statustext(f"Param rejected: {exc}", M.MAV_SEVERITY_WARNING)
        for c in self.chans:          # echo the value now in effect on every link
            self.send_value(c, idx)
