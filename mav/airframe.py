"""The flight software's knowledge of its airframe (as a PX4 airframe file is): the nominal
values its mixer, feed-forward, take-off logic and loop analysis (`mav.tune`) are built on.

The flight stack stands alone: it imports nothing of the simulator. The true physical values
the plant flies with live with the FMU (`cosim/plant/vehicles.py`, `fmus/quadrotor/`); for
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

# Values and their sources: fmus/quadrotor/readme.md, "Parameters per vehicle".
MAMBO = Airframe(
    name="mambo",
    mass=0.063,            # kg, Minidrone template vehicleVars.m
    Ixx=5.82857e-5,        # kg m^2, vehicleVars.m
    Iyy=7.16914e-5,        # kg m^2, vehicleVars.m
    Izz=1.0e-4,            # kg m^2, vehicleVars.m
    arm_length=0.0624,     # m, vehicleVars.m
    k_thrust=4.72e-8,      # N s^2/rad^2, from the template's Ct, rho, R
    k_torque=1.14e-10,     # N m s^2/rad^2, from the template's Cq, rho, R
    motor_tau=0.02,        # s, Crazyflie-class (CrazyS / Förster 2015)
    omega_max=2631.0,      # rad/s, template motor command 500
    drag_xy=0.013,         # N/(m/s), Förster 2015, mass-scaled
    drag_z=0.0146,         # N/(m/s), Förster 2015, mass-scaled
    drag_rot=1.0e-6,       # N m/(rad/s), Ixx/drag_rot = 58 s
)

BEBOP2 = Airframe(
    name="bebop2",
    mass=0.500,            # kg, BebopS / LADAC
    Ixx=1.92e-3,           # kg m^2, LADAC
    Iyy=1.85e-3,           # kg m^2, LADAC
    Izz=3.34e-3,           # kg m^2, LADAC
    arm_length=0.129,      # m, BebopS (0.12905)
    k_thrust=1.674e-6,     # N s^2/rad^2, from the 6x3 propeller
    k_torque=2.68e-8,      # N m s^2/rad^2, BebopS moment_constant 0.016 m * k_thrust
    motor_tau=0.0125,      # s, BebopS time_constant_up/down
    omega_max=1475.0,      # rad/s, BebopS max_rot_velocity
    drag_xy=0.103,         # N/(m/s), Förster 2015, mass-scaled
    drag_z=0.116,          # N/(m/s), Förster 2015, mass-scaled
    drag_rot=3.3e-5,       # N m/(rad/s), Ixx/drag_rot = 58 s
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
