"""The vehicle-status record the parts of the onboard stack share (PX4 shares its status
through uORB topics; here one record, updated in place, read and written by the parts).

Who writes what: the vehicle's tick (`vehicle.py`) the clock, the state estimate and the motor
commands; the commander `armed`, `mode`, `landed_state`, `home` and the setpoint in use; the
offboard part the offboard setpoint and its time; the failsafe part its timers; the
parameters part `own` and the derived limits. Telemetry only reads.

A record with a fixed set of fields: a misspelt attribute raises instead of adding a field.
Compiled, the fields are C fields of the object (status.pxd), which the compiled parts read
and write directly.
"""

from __future__ import annotations

from mav.onboard.defs import ON_GROUND, POSCTL
from mav.types import Setpoint, VehicleState


class VehicleStatus:
    __slots__ = ("stats", "ctrl", "battery", "t_us", "have_state", "state", "u", "v_prev", "dt_us",
                 "armed", "mode", "landed_state", "home", "sp", "setpoint", "ground_since",
                 "man_climb", "of", "of_last_us", "fs_active", "fs_t0", "bat_warned",
                 "gcs_last_us", "gcs_lost", "fence_breached", "pos_lost_us", "pos_fs_done",
                 "hb_now", "ext_now", "home_now", "mission_now", "own", "user_params",
                 "of_loss_us", "fail_act_us", "bat_warn_mah")

    def __init__(self, stats: dict[str, int]) -> None:
        self.stats = stats                 # counters (see vehicle.STATS)
        self.ctrl = None                   # the low-level controller in use (mav.control)
        self.battery = None                # the battery model (mav.battery.Battery)
        # ---- clock and estimate
        self.t_us = 0                      # vehicle clock: HIL time_usec of the last tick
        self.have_state = False            # an ODOMETRY has arrived
        self.state = VehicleState()
        self.u = [0.0, 0.0, 0.0, 0.0]      # motor commands
        self.v_prev = (0.0, 0.0, 0.0)      # m/s, NED velocity a tick before
        self.dt_us = 0                     # us, the last tick's length (HIGHRES_IMU's interval)
        # ---- commander
        self.armed = False
        self.mode = POSCTL                 # see defs.MODE_NAMES
        self.landed_state = ON_GROUND      # MAV_LANDED_STATE
        self.home: tuple[float, float, float] | None = None   # NED, m
        self.sp = Setpoint()               # what modes other than OFFBOARD fly
        self.setpoint = self.sp            # the one in use (sp or of)
        self.ground_since = -1             # us, landed after LAND (for COM_DISARM_LAND)
        self.man_climb = False             # POSCTL: the throttle stick asks to climb
        # ---- offboard
        self.of = Setpoint()               # the last valid offboard setpoint
        self.of_last_us = -(1 << 62)       # when it came
        # ---- failsafe
        self.fs_active = False             # holding after an offboard loss
        self.fs_t0 = 0
        self.bat_warned = 0                # 0 none, 1 low, 2 critical, 3 emergency
        self.gcs_last_us = -1              # last HEARTBEAT from a GCS (-1: none heard yet)
        self.gcs_lost = False
        self.fence_breached = False
        self.pos_lost_us = -1              # when the position estimate was lost (-1: valid)
        self.pos_fs_done = False
        # ---- telemetry requests raised by the parts for the end of this tick
        self.hb_now = False                # HEARTBEAT (mode or arming changed)
        self.ext_now = False               # EXTENDED_SYS_STATE (landed state changed)
        self.home_now = False              # HOME_POSITION (home set)
        self.mission_now = False           # MISSION_CURRENT (mission item or state changed)
        # ---- parameters of the stack itself (mav.params.ONBOARD_PARAMS) and what derives
        self.own: dict[str, float] = {}
        self.user_params: dict[str, float] = {}   # what the user set
        self.of_loss_us = 0                # COM_OF_LOSS_T
        self.fail_act_us = 0               # COM_FAIL_ACT_T
        self.bat_warn_mah = 0.0            # consumed charge that raises the next warning
