"""Onboard low-level flight controllers: the Mambo template FCS and a Bebop 2 velocity controller.

Contract (used by the onboard MAVLink vehicle; see mav/README.md, "Controllers"):

    ctrl = make_controller(vehicle, dt=0.005)      # MamboController or Bebop2Controller
    ctrl.update(state, setpoint, out)              # 200 Hz; writes u1..u4 in [0, 1] to out[0:4]

Both are the shared cascade of `mav/cascade.py` (its docstring has the control laws) with
their own parameter tables (MAVLink names, units, ranges) and the gains derived from them.
The Minidrone template's take-off boost is not modelled: with the ramped take-off reference
and its velocity fed forward (mav/onboard/navigator.py) the boost only added overshoot.
"""

from __future__ import annotations

import math

from mav.airframe import Airframe
from mav.cascade import Controller, ParamSpec, QuadCascade
from mav.mixer import mixer_matrix

__all__ = [
    "Bebop2Controller",
    "Controller",
    "MamboController",
    "ParamSpec",
    "make_controller",
    "mixer_matrix",
]

_D2R = math.pi / 180.0


# ===================================================================== Mambo
def _p(name, default, lo, hi, unit, doc, gain=False, own="") -> ParamSpec:
    return ParamSpec(name, float(default), float(lo), float(hi), unit, doc, gain,
                     own_default=own)


# Names (issue 44, mav/params.py): a PX4 name only with PX4's meaning, unit and a range within
# PX4's (mav/px4_params.json, checked by tests/test_px4_params.py); units of PX4 names as
# PX4's metadata writes them ("" where it gives none). The Mambo's template gains are TPL_
# (absolute units: N m per rad, ...), the Bebop 2 cascade's own gains and Parrot-range
# limits CAS_. mav/params.py RENAMED_CTL maps the names used before.
_ROOM = "indoor: a room a few metres across"
_TUNED = ("this cascade's Bebop 2 tuning (mav/README.md, Controllers; its margins: "
          "python -m mav.tune bebop2)")


class MamboController(QuadCascade):
    """The Simulink Parrot Minidrone template flight control system (reference/minidrone.md §2)
    with a position/velocity interface around it. Gains in the template's absolute units."""

    PARAMS = (
        # XY defaults deviate from the template (0.24, 0.1): on our plant the template loop
        # has 28/17 deg phase margin (x/y) and 38/52 % overshoot; 0.2/0.2 gives 52/37 deg and
        # ~1 % (python -m mav.tune mambo --preset template; mav/README.md "Controllers").
        _p("TPL_XY_P", 0.2, 0.0, 2.0, "rad/m",
           "XY position gain, tilt per metre of error (template 0.24)", gain=True),
        _p("TPL_XY_D", 0.2, 0.01, 1.0, "rad/(m/s)",
           "XY velocity damping = velocity-mode P gain (template 0.1)", gain=True),
        _p("TPL_XY_ERR_MAX", 3.0, 0.1, 10.0, "m", "XY position error saturation per axis"),
        _p("TPL_XY_VEL_I", 0.1, 0.0, 5.0, "1/s",
           "horizontal velocity integral, per second of the velocity gain (0: off; wind)"),
        _p("TPL_XY_I_LIM", 0.17, 0.0, 0.5, "rad", "tilt the horizontal integrator may hold"),
        # PX4 0..20 m/s, default 12 (multicopter_position_control_limits_params.yaml)
        _p("MPC_XY_VEL_MAX", 2.0, 0.1, 7.0, "m/s", "horizontal speed limit",
           own=f"{_ROOM}: 2 m/s"),
        # PX4's MPC_TILTMAX_AIR is 20..89 deg; this goes down to 5 deg as the Parrot airframes'
        # MaxTilt, up to the template's 45
        _p("TPL_TILTMAX_AIR", 25.0, 5.0, 45.0, "deg", "tilt (roll/pitch reference) limit"),
        # one limit both ways (PX4 has MPC_Z_VEL_MAX_UP 0.5..8 and MPC_Z_VEL_MAX_DN 0.5..4)
        _p("TPL_Z_VEL_MAX", 1.5, 0.5, 3.0, "m/s", "climb and descent rate limit"),
        _p("TPL_PITCH_P", 0.013, 0.0, 0.1, "N m/rad", "pitch angle P", gain=True),
        _p("TPL_ROLL_P", 0.011, 0.0, 0.1, "N m/rad", "roll angle P", gain=True),
        _p("TPL_RP_I", 0.01, 0.0, 0.1, "N m/(rad s)", "roll and pitch I"),
        _p("TPL_RP_I_LIM", 2.0, 0.0, 10.0, "N m", "roll and pitch integrator limit"),
        _p("TPL_RP_AW", 0.001, 0.0, 1.0, "-", "roll/pitch anti-windup back-calculation gain"),
        _p("TPL_PITCH_D", 0.002, 0.0, 0.02, "N m s/rad", "pitch D on body rate q", gain=True),
        _p("TPL_ROLL_D", 0.003, 0.0, 0.02, "N m s/rad", "roll D on body rate p", gain=True),
        _p("TPL_YAW_P", 0.004, 0.0, 0.05, "N m/rad", "yaw angle P", gain=True),
        _p("TPL_YAW_D", 0.0012, 1e-5, 0.02, "N m s/rad", "yaw D on body rate r", gain=True),
        _p("MC_YAWRATE_MAX", 200.0, 10.0, 720.0, "deg/s", "yaw rate limit"),   # PX4 0..1800
        _p("TPL_Z_P", 0.8, 0.0, 10.0, "N/m", "altitude P", gain=True),
        _p("TPL_Z_I", 0.24, 0.0, 5.0, "N/(m s)", "altitude I (on the altitude error)"),
        _p("TPL_Z_I_LIM", 2.0, 0.0, 10.0, "N", "altitude integrator limit"),
        _p("TPL_Z_D", 0.5, 0.01, 5.0, "N s/m", "altitude D on vz = vertical velocity P", gain=True),
        # PX4 0..1, default 1 (collective thrust limit, normalised)
        _p("MPC_THR_MAX", 0.92, 0.1, 1.0, "norm", "total thrust limit, fraction of 4*T_max",
           own="the Minidrone template's thrust limit, 0.92 of the four rotors' maximum"),
    )
    # The template's exact gains (no limits beyond its own +-3 m error saturation).
    PRESETS = {
        "template": {
            "TPL_XY_P": 0.24, "TPL_XY_D": 0.1, "TPL_XY_ERR_MAX": 3.0, "MPC_XY_VEL_MAX": 7.0,
            "TPL_XY_VEL_I": 0.0,
            "TPL_TILTMAX_AIR": 45.0, "TPL_Z_VEL_MAX": 3.0,
            "TPL_PITCH_P": 0.013, "TPL_ROLL_P": 0.011, "TPL_RP_I": 0.01, "TPL_RP_I_LIM": 2.0,
            "TPL_RP_AW": 0.001, "TPL_PITCH_D": 0.002, "TPL_ROLL_D": 0.003,
            "TPL_YAW_P": 0.004, "TPL_YAW_D": 0.0012, "MC_YAWRATE_MAX": 720.0,
            "TPL_Z_P": 0.8, "TPL_Z_I": 0.24, "TPL_Z_I_LIM": 2.0, "TPL_Z_D": 0.5,
            "MPC_THR_MAX": 0.92,
        },
    }
    YAW_RATE_INTEGRATES = True

    def _gains(self) -> dict[str, float]:
        p = self._p
        v = self.vehicle
        return {
            "pitch_kp": p["TPL_PITCH_P"], "pitch_ki": p["TPL_RP_I"], "pitch_kd": p["TPL_PITCH_D"],
            "roll_kp": p["TPL_ROLL_P"], "roll_ki": p["TPL_RP_I"], "roll_kd": p["TPL_ROLL_D"],
            "att_i_lim": p["TPL_RP_I_LIM"], "att_kb": p["TPL_RP_AW"] * self.dt,
            # template yaw P*e - D*r == D*((P/D)*e - r)
            "k_psi": p["TPL_YAW_P"] / p["TPL_YAW_D"], "k_r": p["TPL_YAW_D"],
            "yawrate_max": p["MC_YAWRATE_MAX"] * _D2R,
            # template altitude P*e + I*int(e) - D*vz == D*((P/D)*e - vz) + I*int(e)
            "k_z": p["TPL_Z_P"] / p["TPL_Z_D"], "k_vz": p["TPL_Z_D"],
            "ki_z_pos": p["TPL_Z_I"], "ki_z_vpos": 0.0,
            # velocity mode: the same integral action expressed on the velocity error
            "ki_z_vel": (p["TPL_Z_I"] * p["TPL_Z_D"] / p["TPL_Z_P"]) if p["TPL_Z_P"] > 0.0 else 0.0,
            "z_i_lim": p["TPL_Z_I_LIM"],
            "vz_max": p["TPL_Z_VEL_MAX"],
            "thrust_max_total": p["MPC_THR_MAX"] * 4.0 * v.thrust_max,
            # template pitch_ref = -P*e_x + D*vx == -D*((P/D)*e_x - vx)
            "k_xy": p["TPL_XY_P"] / p["TPL_XY_D"], "k_vxy": p["TPL_XY_D"],
            # velocity feed-forward also cancels the airframe drag: tilt = drag*v/(m*g)
            "c_drag": v.drag_xy / v.weight,
            "ki_vxy": p["TPL_XY_VEL_I"] * p["TPL_XY_D"], "xy_i_lim": p["TPL_XY_I_LIM"],
            "xy_err_max": p["TPL_XY_ERR_MAX"], "vxy_max": p["MPC_XY_VEL_MAX"],
            "tilt_max": p["TPL_TILTMAX_AIR"] * _D2R,
        }


# ===================================================================== Bebop 2
class Bebop2Controller(QuadCascade):
    """Velocity-commanded low level with Parrot's limits (max tilt, vertical speed, rotation
    speed). Gains are normalised (per unit inertia or mass), so the loop dynamics follow
    the Airframe; the defaults give first-order velocity responses close to the
    identified Bebop 2 model (Pinto et al. 2020): tau_z = 0.25 s, tau_yawrate = 0.21 s."""

    PARAMS = (
        # PX4 names with PX4's meaning, unit and a range within PX4's (mc_pos_control,
        # mc_att_control yaml; PX4's gain yaml gives these gains no unit); the defaults are
        # this cascade's tuning (mav/README.md, Controllers; python -m mav.tune bebop2)
        _p("MPC_XY_P", 1.0, 0.0, 2.0, "", "position -> horizontal velocity gain (1/s)",
           gain=True, own=_TUNED),
        # PX4's MPC_XY_VEL_P_ACC has this meaning but 1.2..5
        _p("CAS_XY_VEL_P", 2.0, 0.1, 10.0, "1/s",
           "horizontal velocity gain (acceleration per velocity error)", gain=True),
        _p("CAS_XY_ERR_MAX", 5.0, 0.1, 20.0, "m", "XY position error saturation per axis"),
        _p("MPC_XY_VEL_I_ACC", 0.4, 0.0, 10.0, "",                        # PX4 0..60
           "horizontal velocity integral (1/s^2: acceleration per m/s of error per s; 0: off; "
           "wind)"),
        _p("CAS_XY_I_LIM", 0.17, 0.0, 0.6, "rad", "tilt the horizontal integrator may hold"),
        _p("MPC_XY_VEL_MAX", 5.0, 0.5, 15.0, "m/s", "horizontal speed limit",
           own="this cascade's Bebop 2 limit, 5 m/s (mav/README.md, Controllers)"),
        # the Parrot settings these emulate keep Parrot's ranges (reference/mavlink.md), which
        # PX4's do not hold (MPC_TILTMAX_AIR 20..89 deg; no single vertical speed limit)
        _p("CAS_TILTMAX_AIR", 20.0, 5.0, 35.0, "deg", "Parrot MaxTilt"),
        _p("MPC_Z_P", 1.5, 0.1, 1.5, "", "altitude -> vertical velocity gain (1/s)",
           gain=True, own=_TUNED),
        # PX4's MPC_Z_VEL_P_ACC (2..15) and MPC_Z_VEL_I_ACC (0.2..3) have these meanings
        _p("CAS_Z_VEL_P", 4.0, 0.5, 20.0, "1/s",
           "vertical velocity gain (acceleration per velocity error)", gain=True),
        _p("CAS_Z_VEL_I", 1.0, 0.0, 10.0, "1/s^2", "vertical velocity integral gain"),
        _p("CAS_Z_VEL_MAX", 1.0, 0.5, 2.5, "m/s", "Parrot MaxVerticalSpeed (up and down)"),
        _p("CAS_RP_P", 100.0, 0.0, 1000.0, "1/s^2", "roll/pitch P (angular accel per rad)",
           gain=True),
        _p("CAS_RP_I", 20.0, 0.0, 1000.0, "1/s^3", "roll/pitch I"),
        _p("CAS_RP_D", 18.0, 0.0, 100.0, "1/s", "roll/pitch D on body rates", gain=True),
        _p("CAS_RP_I_LIM", 5.0, 0.0, 50.0, "rad/s^2", "roll/pitch integrator limit"),
        _p("MC_YAW_P", 2.0, 0.0, 5.0, "", "heading -> yaw rate gain (1/s)", gain=True,
           own=_TUNED),
        # PX4's MC_YAWRATE_P is a normalised torque per rad/s (0..0.6); this one is per inertia
        _p("CAS_YAWRATE_P", 4.73, 0.5, 50.0, "1/s",
           "yaw rate gain (angular accel per rate error)", gain=True),
        _p("MC_YAWRATE_MAX", 100.0, 10.0, 200.0, "deg/s", "Parrot MaxRotationSpeed",
           own="the Bebop 2's MaxRotationSpeed default, 100 deg/s (Parrot's range 10..200)"),
        _p("MPC_THR_MAX", 0.95, 0.1, 1.0, "norm", "total thrust limit, fraction of 4*T_max",
           own="this cascade's Bebop 2 limit since it was written (chosen, not Parrot's)"),
    )
    PRESETS: dict[str, dict[str, float]] = {}
    YAW_RATE_INTEGRATES = False

    def _gains(self) -> dict[str, float]:
        p = self._p
        v = self.vehicle
        g = v.g
        return {
            "pitch_kp": p["CAS_RP_P"] * v.Iyy, "pitch_ki": p["CAS_RP_I"] * v.Iyy,
            "pitch_kd": p["CAS_RP_D"] * v.Iyy,
            "roll_kp": p["CAS_RP_P"] * v.Ixx, "roll_ki": p["CAS_RP_I"] * v.Ixx,
            "roll_kd": p["CAS_RP_D"] * v.Ixx,
            "att_i_lim": p["CAS_RP_I_LIM"] * max(v.Ixx, v.Iyy), "att_kb": 0.0,
            "k_psi": p["MC_YAW_P"], "k_r": p["CAS_YAWRATE_P"] * v.Izz,
            "yawrate_max": p["MC_YAWRATE_MAX"] * _D2R,
            "k_z": p["MPC_Z_P"], "k_vz": p["CAS_Z_VEL_P"] * v.mass,
            "ki_z_pos": 0.0,
            "ki_z_vpos": p["CAS_Z_VEL_I"] * v.mass, "ki_z_vel": p["CAS_Z_VEL_I"] * v.mass,
            "z_i_lim": 0.3 * v.weight,
            "vz_max": p["CAS_Z_VEL_MAX"],
            "thrust_max_total": p["MPC_THR_MAX"] * 4.0 * v.thrust_max,
            "k_xy": p["MPC_XY_P"], "k_vxy": p["CAS_XY_VEL_P"] / g,
            "c_drag": v.drag_xy / v.weight,
            "ki_vxy": p["MPC_XY_VEL_I_ACC"] / g, "xy_i_lim": p["CAS_XY_I_LIM"],
            "xy_err_max": p["CAS_XY_ERR_MAX"], "vxy_max": p["MPC_XY_VEL_MAX"],
            "tilt_max": p["CAS_TILTMAX_AIR"] * _D2R,
        }


def make_controller(vehicle: Airframe, dt: float = 0.005) -> Controller:
    """The low-level controller for `vehicle` ('mambo' -> MamboController, 'bebop2' ->
    Bebop2Controller), with default parameters."""
    if vehicle.name == "mambo":
        return MamboController(vehicle, dt)
    if vehicle.name == "bebop2":
        return Bebop2Controller(vehicle, dt)
    raise ValueError(f"no controller for vehicle {vehicle.name!r}; known: mambo, bebop2")
