"""Failsafes: lost offboard setpoints (hold, then land, as PX4's COM_OF_LOSS_T /
COM_FAIL_ACT_T), and battery warnings (BAT_LOW_THR, BAT_CRIT_THR). GCS-link loss, battery
actions and the geofence go here too."""

from __future__ import annotations

from mav.onboard.commander import Commander
from mav.onboard.defs import LAND, LOITER, ON_GROUND, M
from mav.onboard.links import Outbox
from mav.onboard.status import VehicleStatus


class Failsafe:
    def __init__(self, vs: VehicleStatus, outbox: Outbox, commander: Commander,
                 apply_params) -> None:
        self.vs = vs
        self.out = outbox
        self.cmd = commander
        self.apply_params = apply_params   # recomputes the limits that derive from params

    def offboard_lost(self, t: int) -> None:
        """OFFBOARD without a setpoint for COM_OF_LOSS_T: hold position."""
        self.out.statustext("Failsafe: offboard setpoints lost, holding position",
                            M.MAV_SEVERITY_CRITICAL)
        self.cmd.set_mode(LOITER)
        self.vs.fs_active, self.vs.fs_t0 = True, t

    def hold_expired(self) -> None:
        """Held COM_FAIL_ACT_T after the loss and offboard did not come back: land."""
        vs = self.vs
        vs.fs_active = False
        if vs.landed_state != ON_GROUND:
            self.out.statustext("Failsafe: offboard not back, landing", M.MAV_SEVERITY_CRITICAL)
            self.cmd.set_mode(LAND)

    def battery_warning(self) -> None:
        vs = self.vs
        vs.bat_warned += 1
        low = vs.bat_warned == 1
        self.out.statustext(f"Battery {'low' if low else 'critical'}: "
                            f"{100.0 * vs.battery.remaining:.0f}% remaining",
                            M.MAV_SEVERITY_WARNING if low else M.MAV_SEVERITY_CRITICAL)
        self.apply_params()
