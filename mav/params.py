"""The onboard parameter table: the controller's parameters plus the vehicle's own.

One flat, name-sorted table (like PX4's) served over the MAVLink parameter protocol, each
with PX4's param_type (REAL32, or INT32 byte-wise where PX4's metadata says int32). Every entry
has a spec (name <= 16 chars, default, min, max, unit, doc, type) and a getter/setter;
setting checks finiteness, range (and a whole number for INT32) here, then the owner
(controller or onboard) may still refuse with ValueError. A set takes effect at once.

Parameter files (`--params FILE`): one `NAME VALUE` per line; QGroundControl's `.params`
export (`sysid compid NAME VALUE TYPE`, tab separated) is read too. `#` starts a comment.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable
from pathlib import Path

from mav.cascade import ParamSpec

_F32 = struct.Struct("<f")


def f32(v: float) -> float:
    """`v` rounded to IEEE single precision, as PARAM_VALUE carries it."""
    return _F32.unpack(_F32.pack(v))[0]


_I32 = struct.Struct("<i")


def int32_as_float(v: int) -> float:
    """The float whose four bytes are int32 `v`: PX4's byte-wise encoding of an INT32
    parameter in PARAM_VALUE / PARAM_SET (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)."""
    return _F32.unpack(_I32.pack(v))[0]


def float_as_int32(f: float) -> int:
    """The int32 whose four bytes are float32 `f` (decodes `int32_as_float`)."""
    return _I32.unpack(_F32.pack(f))[0]


# The vehicle's own parameters. A PX4 name only with PX4's meaning, type (param_type INT32
# where PX4's metadata says int32), unit and a range within PX4's (mav/px4_params.json holds
# PX4's metadata with the file of each; tests/test_px4_params.py checks every PX4 name against
# it); where the default is not PX4's, `own_default` says why (the room's or the airframe's own
# value, as PX4's airframe files set theirs). Every other parameter has a name of ours:
# TPL_ (the Minidrone template stack's own: its estimator's tuning, the Mambo controller's
# template gains, and the indoor values PX4's ranges do not allow), CAS_ (the Bebop 2
# controller's own: the cascade's gains per unit inertia or mass, and Parrot's piloting
# settings it emulates with Parrot's ranges; mav/control.py) or MB_ (Parrot's moveBy limits).
# RENAMED and RENAMED_CTL map the names used before.
# TPL_EST_TYPE's values (mav/estimator/core.py): the vehicle on the simulator's ODOMETRY, the
# template's filters with this stack's additions (template.py), paper 1's release (release.py)
EST_TRUTH, EST_OURS, EST_RELEASE = 0.0, 1.0, 2.0
_ROOM = "indoor: a room a few metres across and high, a 60-200 g vehicle"
ONBOARD_PARAMS: tuple[ParamSpec, ...] = (
    # PX4: min 0 m, default 2.5 (navigator/mission_params.yaml)
    ParamSpec("MIS_TAKEOFF_ALT", 1.0, 0.2, 10.0, "m",
              "AUTO.TAKEOFF height above home when MAV_CMD_NAV_TAKEOFF gives none",
              own_default=f"{_ROOM}: the template's 1 m hover height"),
    # PX4's MPC_TKO_SPEED (min 1 m/s) cannot hold the Mambo's 0.8 m/s climb
    ParamSpec("TPL_TKO_SPEED", 0.8, 0.1, 3.0, "m/s", "climb speed of AUTO.TAKEOFF"),
    # PX4's MPC_LAND_SPEED (min 0.6 m/s) cannot hold 0.4 m/s
    ParamSpec("TPL_LAND_SPEED", 0.4, 0.2, 2.0, "m/s", "descent speed of AUTO.LAND"),
    # PX4: no bounds, default 2 s (<= 0: never); here always disarms, 0 = at once
    ParamSpec("COM_DISARM_LAND", 0.5, 0.0, 20.0, "s",
              "time on the ground after a landing before the motors are disarmed",
              own_default="short flights in a room: disarmed 0.5 s after the touchdown"),
    # PX4 0..60 s; 0 would fire between two setpoints
    ParamSpec("COM_OF_LOSS_T", 1.0, 0.1, 60.0, "s",
              "offboard setpoint silence that triggers the failsafe (hold position)"),
    # PX4 0..25 s (commander_params.yaml)
    ParamSpec("COM_FAIL_ACT_T", 5.0, 0.0, 25.0, "s",
              "failsafe hold time before the vehicle lands if offboard does not resume"),
    # not a PX4 parameter (PX4 has PWM/DShot idle values instead)
    ParamSpec("TPL_IDLE_RATIO", 0.3, 0.0, 0.9, "1",
              "armed-on-ground motor command as a fraction of the hover command"),
    # PX4 battery module.yaml: capacity -1..100000 mAh, internal resistance -1..0.2 Ohm;
    # battery_params_common.c: low 0.12..0.4, critical 0.05..0.1, emergency 0.03..0.07
    ParamSpec("BAT1_CAPACITY", -1.0, -1.0, 100000.0, "mAh",
              "battery capacity (-1: the vehicle preset's)"),
    ParamSpec("BAT1_R_INTERNAL", -1.0, -1.0, 0.2, "Ohm",
              "battery internal resistance (-1: the vehicle preset's)"),
    ParamSpec("BAT_LOW_THR", 0.15, 0.12, 0.4, "norm", "remaining charge that warns"),
    ParamSpec("BAT_CRIT_THR", 0.07, 0.05, 0.1, "norm", "remaining charge that warns critically"),
    ParamSpec("BAT_EMERGEN_THR", 0.05, 0.03, 0.07, "norm",
              "remaining charge of the emergency level (PX4's default)"),
    ParamSpec("COM_LOW_BAT_ACT", 0.0, 0.0, 3.0, "",
              "battery failsafe: 0 warn, 2 land at critical, 3 return at critical and land "
              "at emergency (PX4)", ptype="INT32"),
    ParamSpec("NAV_DLL_ACT", 0.0, 0.0, 3.0, "",
              "GCS link loss failsafe: 0 off, 1 hold, 2 return, 3 land (PX4)", ptype="INT32"),
    ParamSpec("COM_DL_LOSS_T", 10.0, 5.0, 300.0, "s",
              "GCS heartbeat silence that counts as a lost link (PX4)", ptype="INT32"),
    # PX4 removed COM_POS_FS_DELAY (release notes 1.16)
    ParamSpec("TPL_POS_FS_DELAY", 1.0, 1.0, 100.0, "s",
              "position estimate lost this long while flying: land"),
    ParamSpec("GF_ACTION", 2.0, 0.0, 5.0, "",
              "geofence breach: 0 none, 1 warn, 2 hold, 3 return, 5 land (PX4; 4, terminate, "
              "holds instead)", ptype="INT32"),
    # the onboard estimator (mav/estimator/): the Minidrone template's filters, not EKF2, so
    # their tuning has names of ours; PX4's EKF2_* only where the meaning is EKF2's
    ParamSpec("TPL_EST_TYPE", 0.0, 0.0, 2.0, "",
              "estimator: 0 fly on HIL ODOMETRY (truth, like motion capture), 1 the "
              "template's filters with this stack's additions on HIL_SENSOR, flow, range "
              "(and GPS), 2 paper 1's released estimator (no GPS); read at start"),
    ParamSpec("TPL_ACC_W", 0.001, 0.0, 0.5, "1",
              "attitude: weight per tick of the accelerometer's roll and pitch"),
    ParamSpec("TPL_ACC_GATE", 0.5, 0.0, 5.0, "m/s^2",
              "attitude: accelerometer used only within this of g (low-passed)"),
    ParamSpec("TPL_MAG_W", 0.002, 0.0, 0.5, "1", "heading: weight per tick of the compass"),
    # PX4: no bounds, default 0 (ekf2/params_volatile.yaml; PX4 learns it from GPS)
    ParamSpec("EKF2_MAG_DECL", -14.3, -180.0, 180.0, "deg", "magnetic declination",
              own_default="the site's: WMM2020 at the template's origin (Natick, MA), "
                          "cosim/sensors/spec.py"),
    ParamSpec("TPL_ACC_NOISE", 0.7, 0.01, 10.0, "m/s^2",
              "altitude filter: acceleration process noise"),
    ParamSpec("EKF2_ACC_B_NOISE", 0.003, 0.0, 0.01, "m/s^3",
              "altitude filter: process noise of the accelerometer bias (PX4's default)"),
    ParamSpec("EKF2_ABL_LIM", 0.4, 0.0, 0.8, "m/s^2",
              "accelerometer bias learned: at most this (PX4's default)"),
    ParamSpec("TPL_BARO_NOISE", 0.15, 0.01, 10.0, "m",
              "altitude filter: barometer altitude noise"),
    ParamSpec("TPL_BARO_GATE", 0.8, 0.05, 100.0, "m",
              "barometer reading this far from the estimate: rejected (template)"),
    ParamSpec("TPL_RNG_NOISE", 0.02, 0.001, 10.0, "m", "altitude filter: range finder noise"),
    ParamSpec("TPL_RNG_GATE", 0.3, 0.05, 100.0, "m",
              "range reading this far from the estimate: rejected (template)"),
    ParamSpec("TPL_OF_Q", 0.09, 0.0001, 100.0, "(m/s)^2",
              "flow velocity filter: process noise per tick (template)"),
    ParamSpec("TPL_OF_R", 5.0, 0.0001, 1000.0, "(m/s)^2",
              "flow velocity filter: measurement noise (template)"),
    ParamSpec("EKF2_OF_QMIN", 1.0, 0.0, 255.0, "", "flow quality below this: rejected",
              ptype="INT32"),
    ParamSpec("TPL_OF_GATE", 5.0, 0.1, 100.0, "m/s",
              "flow velocity this far from the estimate: rejected (template)"),
    ParamSpec("TPL_NOAID_TOUT", 1.0, 0.1, 60.0, "s",
              "no flow or GPS fused this long while flying: position estimate lost"),
    ParamSpec("TPL_GPS_W", 0.02, 0.0, 1.0, "1", "position: weight per fix of the GPS"),
    ParamSpec("GF_MAX_HOR_DIST", 0.0, 0.0, 10000.0, "m",
              "geofence radius about home (0: no horizontal limit)"),
    ParamSpec("GF_MAX_VER_DIST", 0.0, 0.0, 10000.0, "m",
              "geofence height above home (0: no vertical limit)"),
    # automatic flight to a point (missions, RTL, go-to). PX4's names and meanings where PX4's
    # range holds a 60 g indoor vehicle's value (PX4's defaults are for outdoor multicopters:
    # MPC_JERK_AUTO 4 m/s^3, MPC_Z_V_AUTO_UP 3 m/s, _DN 1.5, NAV_ACC_RAD 10 m, NAV_MC_ALT_RAD
    # 0.8 m, RTL_RETURN_ALT 60 m, RTL_DESCEND_ALT 30 m, MPC_MAN_Y_MAX 150 deg/s); TPL_ names
    # where it does not (PX4's MPC_XY_CRUISE min 3 m/s, MPC_ACC_HOR min 2 m/s^2,
    # MPC_VEL_MANUAL min 3 m/s; multicopter_autonomous_params.yaml, _position_mode_params.yaml)
    ParamSpec("TPL_XY_CRUISE", 1.0, 0.1, 20.0, "m/s",
              "horizontal speed of missions, RTL and go-to (DO_CHANGE_SPEED overrides)"),
    ParamSpec("TPL_ACC_HOR", 1.0, 0.2, 15.0, "m/s^2",
              "acceleration of the automatic modes' reference along a leg"),
    ParamSpec("MPC_JERK_AUTO", 2.0, 1.0, 80.0, "m/s^3",
              "jerk limit of the automatic modes' reference", own_default=_ROOM),
    ParamSpec("MPC_Z_V_AUTO_UP", 0.8, 0.5, 8.0, "m/s", "climb speed of the automatic modes",
              own_default=_ROOM),
    ParamSpec("MPC_Z_V_AUTO_DN", 0.6, 0.5, 4.0, "m/s",
              "descent speed of the automatic modes (above the landing)", own_default=_ROOM),
    ParamSpec("NAV_ACC_RAD", 0.3, 0.05, 200.0, "m",
              "horizontal acceptance radius of a waypoint (an item's param2 overrides)",
              own_default=_ROOM),
    ParamSpec("NAV_MC_ALT_RAD", 0.2, 0.05, 200.0, "m", "vertical acceptance of a waypoint",
              own_default=_ROOM),
    ParamSpec("RTL_RETURN_ALT", 1.5, 0.3, 150.0, "m",
              "RTL: climb to this height above home (if lower) before returning",
              own_default=_ROOM),
    ParamSpec("RTL_DESCEND_ALT", 1.0, 0.3, 100.0, "m",
              "RTL: height above home to descend to before the landing delay",
              own_default=_ROOM),
    ParamSpec("RTL_LAND_DELAY", 0.0, -1.0, 300.0, "s",
              "RTL: hover this long above home before landing (-1: hover, never land)"),
    ParamSpec("TPL_VEL_MANUAL", 1.0, 0.1, 20.0, "m/s",
              "POSCTL: horizontal speed at full stick (MANUAL_CONTROL)"),
    ParamSpec("MPC_MAN_Y_MAX", 90.0, 0.0, 400.0, "deg/s", "POSCTL: yaw rate at full stick",
              own_default=_ROOM),
    # PX4's MPC_HOLD_DZ is gone (MAN_DEADZONE now, of the manual_control module)
    ParamSpec("TPL_HOLD_DZ", 0.1, 0.0, 1.0, "1",
              "POSCTL: stick deadzone; inside it the vehicle holds position or height"),
    ParamSpec("COM_RC_LOSS_T", 0.5, 0.0, 35.0, "s",
              "POSCTL: MANUAL_CONTROL silence after which the sticks count as centred"),
    # relative moves (SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_BODY_OFFSET_NED, Parrot's
    # moveBy; mav/onboard/moveby.py): the firmware's autonomous-flight maxima
    # (ardrone3 PilotingSettings setAutonomousFlightMax*, "only used during autonomous
    # flights such as moveBy"). Parrot publishes no default values: MB_Z_VEL_MAX and
    # MB_YAW_RATE_MAX take the Bebop 2's MaxVerticalSpeed (1 m/s) and MaxRotationSpeed
    # (100 deg/s) this stack uses for its velocity loop; the others are chosen (not Parrot's
    # numbers), to be calibrated on paper 2's E1/E2 with the camera stream's delay. Not PX4
    # parameters (PX4 has no moveBy).
    ParamSpec("MB_XY_VEL_MAX", 1.0, 0.05, 5.0, "m/s",
              "relative move: horizontal speed limit (chosen)"),
    # 2 m/s^2: fitted on paper 2's E1 and E2 times only (0.5, 1, 2, 4 m/s^2 with the Bebop 2
    # stream's 0.12 s latency; python -m cosim.apps.vs.calibrate fit), then frozen for E3/E4
    # (docs/papers/visual-servoing.md, "Calibrate, then predict")
    ParamSpec("MB_XY_ACC_MAX", 2.0, 0.05, 10.0, "m/s^2",
              "relative move: horizontal acceleration limit (fitted on paper 2's E1/E2)"),
    ParamSpec("MB_Z_VEL_MAX", 1.0, 0.05, 2.5, "m/s",
              "relative move: vertical speed limit (Bebop 2 MaxVerticalSpeed)"),
    ParamSpec("MB_Z_ACC_MAX", 1.0, 0.05, 10.0, "m/s^2",
              "relative move: vertical acceleration limit (chosen)"),
    ParamSpec("MB_YAW_RATE_MAX", 100.0, 1.0, 400.0, "deg/s",
              "relative move: heading rate limit (Bebop 2 MaxRotationSpeed)"),
    ParamSpec("MB_YAW_ACC_MAX", 180.0, 10.0, 2000.0, "deg/s^2",
              "relative move: heading acceleration limit (chosen)"),
)

# The names these parameters had before issue 44 (PX4's names with other meanings, or no
# longer PX4's): a scenario or a parameter file that uses one gets an error naming the new one.
RENAMED: dict[str, str] = {
    "EKF2_TYPE": "TPL_EST_TYPE", "EKF2_ACC_W": "TPL_ACC_W", "EKF2_ACC_GATE": "TPL_ACC_GATE",
    "EKF2_MAG_W": "TPL_MAG_W", "EKF2_ACC_NOISE": "TPL_ACC_NOISE",
    "EKF2_BARO_NOISE": "TPL_BARO_NOISE", "EKF2_BARO_GATE": "TPL_BARO_GATE",
    "EKF2_RNG_NOISE": "TPL_RNG_NOISE", "EKF2_RNG_GATE": "TPL_RNG_GATE",
    "EKF2_OF_Q": "TPL_OF_Q", "EKF2_OF_R": "TPL_OF_R", "EKF2_OF_GATE": "TPL_OF_GATE",
    "EKF2_NOAID_TOUT": "TPL_NOAID_TOUT", "EKF2_GPS_W": "TPL_GPS_W",
    "MPC_TKO_SPEED": "TPL_TKO_SPEED", "MPC_LAND_SPEED": "TPL_LAND_SPEED",
    "MOT_IDLE_RATIO": "TPL_IDLE_RATIO", "COM_POS_FS_DELAY": "TPL_POS_FS_DELAY",
    "MPC_XY_CRUISE": "TPL_XY_CRUISE", "MPC_ACC_HOR": "TPL_ACC_HOR",
    "MPC_VEL_MANUAL": "TPL_VEL_MANUAL", "MPC_HOLD_DZ": "TPL_HOLD_DZ",
}
# ... and the controllers' (mav/control.py), per vehicle: one old name (MC_RP_I, say) became
# the Mambo's TPL_ and the Bebop 2's CAS_ parameter.
RENAMED_CTL: dict[str, dict[str, str]] = {
    "mambo": {
        "MC_XY_P": "TPL_XY_P", "MC_XY_D": "TPL_XY_D", "MC_XY_ERR_MAX": "TPL_XY_ERR_MAX",
        "MC_XY_VEL_I": "TPL_XY_VEL_I", "MC_XY_I_LIM": "TPL_XY_I_LIM",
        "MPC_TILTMAX_AIR": "TPL_TILTMAX_AIR", "MPC_Z_VEL_MAX": "TPL_Z_VEL_MAX",
        "MC_PITCH_P": "TPL_PITCH_P", "MC_ROLL_P": "TPL_ROLL_P", "MC_RP_I": "TPL_RP_I",
        "MC_RP_I_LIM": "TPL_RP_I_LIM", "MC_RP_AW": "TPL_RP_AW", "MC_PITCH_D": "TPL_PITCH_D",
        "MC_ROLL_D": "TPL_ROLL_D", "MC_YAW_P": "TPL_YAW_P", "MC_YAW_D": "TPL_YAW_D",
        "MC_Z_P": "TPL_Z_P", "MC_Z_I": "TPL_Z_I", "MC_Z_I_LIM": "TPL_Z_I_LIM",
        "MC_Z_D": "TPL_Z_D", "MC_THR_MAX": "MPC_THR_MAX",
    },
    "bebop2": {
        "MPC_XY_VEL_P": "CAS_XY_VEL_P", "MPC_XY_ERR_MAX": "CAS_XY_ERR_MAX",
        "MPC_XY_I_LIM": "CAS_XY_I_LIM", "MPC_TILTMAX_AIR": "CAS_TILTMAX_AIR",
        "MPC_Z_VEL_P": "CAS_Z_VEL_P", "MPC_Z_VEL_I": "CAS_Z_VEL_I",
        "MPC_Z_VEL_MAX": "CAS_Z_VEL_MAX", "MC_RP_P": "CAS_RP_P", "MC_RP_I": "CAS_RP_I",
        "MC_RP_D": "CAS_RP_D", "MC_RP_I_LIM": "CAS_RP_I_LIM", "MC_YAWRATE_P": "CAS_YAWRATE_P",
        "MC_THR_MAX": "MPC_THR_MAX",
    },
}


def renamed_to(name: str, have: Iterable[str] | None = None) -> str | None:
    """The name a parameter this stack used before issue 44 has now, or None. `have`: the
    names of one vehicle's table, to name only its own (without: "A or B" where the vehicles
    differ)."""
    new = [RENAMED[name]] if name in RENAMED else []
    new += sorted({m[name] for m in RENAMED_CTL.values() if name in m} - set(new))
    if have is not None:
        have = set(have)
        new = [n for n in new if n in have]
    return " or ".join(new) or None


def renamed_error(name: str, have: Iterable[str] | None = None) -> str | None:
    """The message for a parameter name this stack used before issue 44, or None."""
    new = renamed_to(name, have)
    if new is None:
        return None
    return (f"{name} is now {new} (this stack's {name} had not PX4's meaning, type or "
            f"range: mav/README.md, Parameters); set {new}")


# ---- what may change while armed (issue 14, item 6)
# A change in flight is refused (not deferred) when it would leave the flight envelope of a
# parameter the vehicle cannot fly without: the loop gains (the proportional, derivative and
# velocity gains of both controllers; not integral gains, whose output their limits bound,
# nor speed/tilt limits, which only slow the vehicle) must stay within a factor GAIN_FACTOR of
# their defaults, and the thrust limit at least THRUST_HEADROOM times the hover thrust (what
# climbing and attitude control need on top of hovering; MPC_THR_MAX = 0.1 brought a flying
# Mambo down). Disarmed, any value in range is stored, but arming is refused while one is
# outside its envelope, so a vehicle never takes off with it.
THRUST_LIMIT = "MPC_THR_MAX"
GAIN_FACTOR = 4.0          # in flight a gain stays within [default / 4, 4 x default]
THRUST_HEADROOM = 1.5      # in flight MPC_THR_MAX >= 1.5 x hover thrust / max thrust


def flight_envelope(spec, hover_fraction: float) -> tuple[float, float] | None:
    """The values parameter `spec` may take while the vehicle is armed (inside its range), or
    None when every value of its range may be set in flight. `hover_fraction`: the hover
    thrust as a fraction of the four rotors' maximum (weight / (4 T_max))."""
    if spec.flight_gain:
        lo, hi = spec.default / GAIN_FACTOR, spec.default * GAIN_FACTOR
    elif spec.name == THRUST_LIMIT:
        lo, hi = min(1.0, THRUST_HEADROOM * hover_fraction), spec.max
    else:
        return None
    return max(lo, spec.min), min(hi, spec.max)


class ParamError(ValueError):
    """A parameter name or value was refused; the message names the parameter."""


class UnknownParamError(ParamError):
    """No parameter of that name."""


class _Entry:
    __slots__ = ("spec", "get", "set")

    def __init__(self, spec, get: Callable[[], float], set_: Callable[[float], None]) -> None:
        self.spec = spec
        self.get = get
        self.set = set_


class ParamTable:
    """Name-sorted parameters with MAVLink indices (0..count-1)."""

    def __init__(self) -> None:
        self._entries: list[_Entry] = []
        self._by_name: dict[str, int] = {}

    def add(self, spec, get: Callable[[], float], set_: Callable[[float], None]) -> None:
        """Register one parameter (`spec` has name, default, min, max, unit, doc)."""
        name = spec.name
        if not name or len(name) > 16 or not name.isascii():
            raise ValueError(f"parameter name {name!r}: need 1..16 ASCII characters")
        if name in self._by_name:
            raise ValueError(f"parameter {name!r} registered twice")
        self._entries.append(_Entry(spec, get, set_))
        self._entries.sort(key=lambda e: e.spec.name)
        self._by_name = {e.spec.name: i for i, e in enumerate(self._entries)}

    def add_store(self, specs: Iterable, store: dict[str, float]) -> None:
        """Register plain stored parameters; `store` holds the values (filled with defaults)."""
        for spec in specs:
            store[spec.name] = float(spec.default)

            def _get(n=spec.name) -> float:
                return store[n]

            def _set(v: float, n=spec.name) -> None:
                store[n] = v

            self.add(spec, _get, _set)

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> list[str]:
        return [e.spec.name for e in self._entries]

    def index(self, name: str) -> int:
        """Index of `name`, or -1."""
        return self._by_name.get(name, -1)

    def name_at(self, index: int) -> str:
        return self._entries[index].spec.name

    def spec(self, name: str):
        i = self._by_name.get(name)
        if i is None:
            raise UnknownParamError(renamed_error(name, self._by_name)
                                   or f"unknown parameter {name!r}")
        return self._entries[i].spec

    def get(self, name: str) -> float:
        i = self._by_name.get(name)
        if i is None:
            raise UnknownParamError(renamed_error(name, self._by_name)
                                   or f"unknown parameter {name!r}")
        return float(self._entries[i].get())

    def set(self, name: str, value: float) -> float:
        """Set and return the value now in effect; ParamError (a ValueError) names the fault."""
        i = self._by_name.get(name)
        if i is None:
            raise UnknownParamError(renamed_error(name, self._by_name)
                                   or f"unknown parameter {name!r}")
        e = self._entries[i]
        v = float(value)
        lo, hi = e.spec.min, e.spec.max
        if not math.isfinite(v):
            raise ParamError(f"{name}: got {v!r}; must be finite")
        if e.spec.ptype == "INT32" and v != int(v):
            raise ParamError(f"{name}: got {v:g}; must be a whole number (PX4's int32)")
        # compare in single precision: a GCS echoes the float32 it was sent
        if v < lo and f32(v) < f32(lo) or v > hi and f32(v) > f32(hi):
            raise ParamError(f"{name}: got {v:g}; allowed {lo:g}..{hi:g} {e.spec.unit}".rstrip())
        v = min(max(v, lo), hi)
        try:
            e.set(v)
        except ValueError as exc:
            raise ParamError(f"{name}: {exc}") from None
        return float(e.get())


def read_param_file(path: str | Path) -> list[tuple[str, float]]:
    """Parse a parameter file into (name, value) pairs, in file order.

    Lines: `NAME VALUE` or QGC's `SYSID COMPID NAME VALUE TYPE`; blank lines and `#` comments
    are skipped. A line that fits neither raises ValueError naming the file and line.
    """
    out: list[tuple[str, float]] = []
    text = Path(path).read_text()
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tok = line.replace(",", " ").split()
        if len(tok) == 2:
            name, val = tok
        elif len(tok) >= 4 and tok[0].isdigit() and tok[1].isdigit():
            name, val = tok[2], tok[3]
        else:
            raise ValueError(f"{path}:{lineno}: expected 'NAME VALUE' or "
                             f"'SYSID COMPID NAME VALUE TYPE', got {raw.strip()!r}")
        try:
            v = float(val)
        except ValueError:
            raise ValueError(f"{path}:{lineno}: {name}: value {val!r} is not a number") from None
        out.append((name, v))
    return out


def vehicle_table(vehicle: str) -> ParamTable:
    """`vehicle`'s parameter table (the controller's and the stack's own), values not bound:
    the names, specs and range checks only."""
    from mav.airframe import get_airframe
    from mav.control import make_controller

    t = ParamTable()
    for spec in make_controller(get_airframe(vehicle)).param_table():
        t.add(spec, lambda: 0.0, lambda v: None)
    t.add_store(ONBOARD_PARAMS, {})
    return t


def check_values(vehicle: str, values: Iterable[tuple[str, float]]) -> list[tuple[str, float]]:
    """Check parameter values for `vehicle`'s flight stack before it starts (a scenario's
    `[onboard.params]`): every name known (the controller's and the stack's own), every value
    finite and within its bounds. Returns the pairs as floats; ParamError names the first
    fault. The stack applies them as it applies a parameter file (`--params`)."""
    t = vehicle_table(vehicle)
    out = []
    for name, v in values:
        t.set(name, v)
        out.append((name, float(v)))
    return out


def write_param_file(path: str | Path, values: Iterable[tuple[str, float]]) -> None:
    """`NAME VALUE` lines that `read_param_file` reads back exactly (repr of the float)."""
    Path(path).write_text("".join(f"{n} {float(v)!r}\n" for n, v in values))
