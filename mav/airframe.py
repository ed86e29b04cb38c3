"""The flight software's knowledge of its airframe (as a PX4 airframe file is): the nominal
values its mixer, feed-forward, take-off logic and loop analysis (`mav.tune`) are built on.

The flight stack stands alone: it imports nothing of the simulator. The true physical values
the plant flies with live with the FMU (`cosim/scenario/vehicles.py`, `fmus/quadrotor/`); for
the shipped airframes the nominal values here are the plant's, field for field
(tests/test_airframes.py), with their sources in fmus/quadrotor/readme.md. A simulator that
flies a changed plant (scenario `vehicle.overrides`) may tell the flight stack through
`Onboard.set_airframe` or the process's `--vehicle-param FIELD=VALUE`.

Rotor numbering and spin: PX4 quad-X (1 front-right CCW, 2 rear-left CCW, 3 front-left CW,
4 rear-right CW, viewed from above).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace


@dataclass(frozen=True)
class Airframe:
    name: str
    mass: float            # kg
    Ixx: float             # kg m^2, body x (forward)
    Iyy: float             # kg m^2, body y (right)
    Izz: float             # kg m^2, body z (down)
    arm_length: float      # m, centre to motor axis (X configuration)
    k_thrust: float        # N s^2/rad^2, thrust per rotor = k_thrust * w^2
    k_torque: float        # N m s^2/rad^2, reaction torque per rotor = k_torque * w^2
    motor_tau: float       # s, first-order motor (rotor speed) time constant
    omega_max: float       # rad/s, rotor speed at u = 1
    drag_xy: float         # N/(m/s), linear drag along body x and y vs. the air
    drag_z: float          # N/(m/s), linear drag along body z
    drag_rot: float        # N m/(rad/s), rotational damping about each body axis
    g: float = 9.81        # m/s^2

    @property
    def weight(self) -> float:
        """Weight, N."""
        return self.mass * self.g

    @property
    def thrust_max(self) -> float:
        """Thrust of one rotor at omega_max, N."""
        return self.k_thrust * self.omega_max**2

    @property
    def omega_hover(self) -> float:
        """Rotor speed at which four rotors carry the weight, rad/s."""
        return math.sqrt(self.weight / (4.0 * self.k_thrust))

    @property
    def u_hover(self) -> float:
        """Normalised motor command (w_cmd = u * omega_max) for hover, dimensionless."""
        return self.omega_hover / self.omega_max

    def values(self) -> dict[str, float]:
        """The numeric fields by name (SI units)."""
        d = asdict(self)
        d.pop("name")
        return d

    def with_overrides(self, **kw: float) -> Airframe:
        """A copy with some fields replaced (unknown names raise TypeError)."""
        return replace(self, **kw)


FIELDS = tuple(f.name for f in fields(Airframe) if f.name != "name")

# Sources for every number: fmus/quadrotor/readme.md, "Parameters per vehicle".
#
# Drag (both vehicles, derived, not identified): Förster 2015 (System Identification of the
# Crazyflie 2.0 Nano Quadrocopter, ETH) identified F_drag = K_aero * sum(omega) * v with
# K_aero = diag(9.1785e-7, 9.1785e-7, 10.311e-7) kg/rad. At the Crazyflie's hover
# (27 g, sum(omega) ~ 6063 rad/s) that is 5.57e-3 / 6.25e-3 N/(m/s), i.e. 0.206 / 0.232 N/(m/s)
# per kg. Both presets scale it by mass (same velocity decay time m/drag ~ 4.9 s):
# drag_xy = 0.206 * m, drag_z = 0.232 * m.
# drag_rot (both, derived): weak damping with I_xx/drag_rot ~ 60 s, negligible against any
# controller; it only keeps an uncontrolled spin from lasting forever.

# Parrot Mambo: reference/minidrone.md §1 (MathWorks Parrot Minidrone template, vehicleVars.m).
# k_thrust = Ct*rho*A*R^2 = 0.0107*1.184*pi*0.033^2*0.033^2 = 4.72e-8 N s^2
# k_torque = Cq*rho*A*R^3 = 7.83e-4*1.184*pi*0.033^2*0.033^3 = 1.14e-10 N m s^2
# omega_max: template motor command 500 -> w^2 = 13840.8*500 -> 2631 rad/s.
# motor_tau: the template has no motor lag; 0.02 s is the middle of the Crazyflie-class
# coreless-motor constants 0.0125 s (up) / 0.025 s (down) used by CrazyS (Silano et al. 2018,
# rotors_description/urdf/crazyflie2.xacro, values after Förster 2015).
MAMBO = Airframe(
    name="mambo",
    mass=0.063,            # kg, vehicleVars.m
    Ixx=5.82857e-5,        # kg m^2, vehicleVars.m
    Iyy=7.16914e-5,        # kg m^2, vehicleVars.m
    Izz=1.0e-4,            # kg m^2, vehicleVars.m
    arm_length=0.0624,     # m, vehicleVars.m
    k_thrust=4.72e-8,      # N s^2/rad^2, derived from Ct, rho, R above
    k_torque=1.14e-10,     # N m s^2/rad^2, derived from Cq, rho, R above
    motor_tau=0.02,        # s, Crazyflie-class (CrazyS / Förster 2015), see above
    omega_max=2631.0,      # rad/s, template motor command 500
    drag_xy=0.013,         # N/(m/s), 0.206 * 0.063 (Förster 2015, mass-scaled)
    drag_z=0.0146,         # N/(m/s), 0.232 * 0.063 (Förster 2015, mass-scaled)
    drag_rot=1.0e-6,       # N m/(rad/s), Ixx/drag_rot = 58 s (derived, see above)
)

# Parrot Bebop 2. Mass, arm, rotor limits and lag: BebopS (Silano, Oppido, Iannelli 2019,
# "Software-in-the-loop simulation for improving flight control system design: a quadrotor
# case study", IEEE SMC; github gsilano/BebopS urdf/bebop_base.urdf.xacro): mass 0.5 kg,
# arm_length 0.12905 m, time_constant_up/down 0.0125 s, max_rot_velocity 1475 rad/s,
# moment_constant 0.016 m. Inertia: TU Braunschweig LADAC Bebop 2 parameters
# (github iff-gsc/LADAC-Examples-Data, LADAC_params/Bebop2/copter_params_Bebop2.m):
# diag(0.00192, 0.00185, 0.00334) kg m^2, propeller "6x3".
# k_thrust (derived): BebopS's motor_constant 8.54858e-6 is the RotorS default of a 1.5 kg
# hexacopter and would give thrust/weight ~15, so we derive it from the 6x3 propeller instead:
# static Ct ~ 0.10 (UIUC propeller data convention T = Ct*rho*n^2*D^4, n in rev/s) ->
# k_thrust = Ct*rho*D^4/(4*pi^2) = 0.10*1.225*0.1524^4/39.48 = 1.674e-6 N s^2/rad^2,
# hover at 856 rad/s (8200 rpm), thrust/weight 2.97 at 1475 rad/s.
# k_torque = moment_constant * k_thrust = 0.016 * 1.674e-6 = 2.68e-8 N m s^2/rad^2.
BEBOP2 = Airframe(
    name="bebop2",
    mass=0.500,            # kg, BebopS / LADAC
    Ixx=1.92e-3,           # kg m^2, LADAC
    Iyy=1.85e-3,           # kg m^2, LADAC
    Izz=3.34e-3,           # kg m^2, LADAC
    arm_length=0.129,      # m, BebopS (0.12905)
    k_thrust=1.674e-6,     # N s^2/rad^2, derived from the 6x3 propeller (see above)
    k_torque=2.68e-8,      # N m s^2/rad^2, BebopS moment_constant 0.016 m * k_thrust
    motor_tau=0.0125,      # s, BebopS time_constant_up/down
    omega_max=1475.0,      # rad/s, BebopS max_rot_velocity
    drag_xy=0.103,         # N/(m/s), 0.206 * 0.5 (Förster 2015, mass-scaled)
    drag_z=0.116,          # N/(m/s), 0.232 * 0.5 (Förster 2015, mass-scaled)
    drag_rot=3.3e-5,       # N m/(rad/s), Ixx/drag_rot = 58 s (derived, see above)
)

AIRFRAMES: dict[str, Airframe] = {a.name: a for a in (MAMBO, BEBOP2)}


def get_airframe(name: str) -> Airframe:
    """The airframe called `name` ('mambo' or 'bebop2'); ValueError names the choices."""
    try:
        return AIRFRAMES[name]
    except KeyError:
        raise ValueError(
            f"unknown vehicle {name!r}; choose one of {', '.join(sorted(AIRFRAMES))}"
        ) from None
