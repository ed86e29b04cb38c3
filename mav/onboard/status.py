"""The vehicle-status record the parts of the onboard stack share (PX4 shares its status
through uORB topics; here one record, updated in place, read and written by the parts).

Who writes what: the vehicle's tick (`vehicle.py`) the clock, the state estimate and the motor
commands; the commander `armed`, `mode`, `landed_state`, `home` and the setpoint in use; the
offboard part the offboard setpoint and its time; the failsafe part its timers; the
parameters part `own` and the derived limits. Telemetry only reads.

A dataclass with __slots__: a misspelt attribute raises instead of adding a field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mav.onboard.defs import ON_GROUND, POSCTL
from mav.types import Setpoint, VehicleState


@dataclass(eq=False, slots=True)
class VehicleStatus:
    stats: dict[str, int]                  # counters (see vehicle.STATS)
    ctrl: Any = None                       # the low-level controller in use (mav.control)
    battery: Any = None                    # the battery model (mav.battery.Battery)
    # ---- clock and estimate
    t_us: int = 0                          # vehicle clock: HIL time_usec of the last tick
    have_state: bool = False               # an ODOMETRY has arrived
    state: VehicleState = field(default_factory=VehicleState)
    u: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])  # motor commands
    v_prev: tuple[float, float, float] = (0.0, 0.0, 0.0)   # m/s, NED velocity a tick before
    dt_us: int = 0                         # us, the last tick's length (HIGHRES_IMU's interval)
    # ---- commander
    armed: bool = False
    mode: int = POSCTL                     # see defs.MODE_NAMES
    landed_state: int = ON_GROUND          # MAV_LANDED_STATE
    home: tuple[float, float, float] | None = None   # NED, m
    sp: Setpoint = field(default_factory=Setpoint)   # what modes other than OFFBOARD fly
    setpoint: Setpoint | None = None       # the one in use (sp or of)
    ground_since: int = -1                 # us, landed after LAND (for COM_DISARM_LAND)
    man_climb: bool = False                # POSCTL: the throttle stick asks to climb
    # ---- offboard
    of: Setpoint = field(default_factory=Setpoint)   # the last valid offboard setpoint
    of_last_us: int = -(1 << 62)           # when it came
    # ---- failsafe
    fs_active: bool = False                # holding after an offboard loss
    fs_t0: int = 0
    bat_warned: int = 0                    # 0 none, 1 low, 2 critical, 3 emergency
    gcs_last_us: int = -1                  # last HEARTBEAT from a GCS (-1: none heard yet)
    gcs_lost: bool = False
    fence_breached: bool = False
    pos_lost_us: int = -1                  # when the position estimate was lost (-1: valid)
    pos_fs_done: bool = False
    # ---- telemetry requests raised by the parts for the end of this tick
    hb_now: bool = False                   # HEARTBEAT (mode or arming changed)
    ext_now: bool = False                  # EXTENDED_SYS_STATE (landed state changed)
    home_now: bool = False                 # HOME_POSITION (home set)
    mission_now: bool = False              # MISSION_CURRENT (mission item or state changed)
    # ---- parameters of the stack itself (mav.params.ONBOARD_PARAMS) and what derives
    own: dict[str, float] = field(default_factory=dict)
    user_params: dict[str, float] = field(default_factory=dict)   # what the user set
    of_loss_us: int = 0                    # COM_OF_LOSS_T
    fail_act_us: int = 0                   # COM_FAIL_ACT_T
    bat_warn_mah: float = 0.0              # consumed charge that raises the next warning

    def __post_init__(self) -> None:
        if self.setpoint is None:
            self.setpoint = self.sp
