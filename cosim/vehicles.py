"""Vehicle presets: the physical parameters of each airframe, in one place.

Every field carries its unit. The FMU (`fmus/quadrotor`) takes these as its parameters
(same names), and the onboard controllers (`mav/control.py`) derive their mixer and
feed-forward from them, so plant and controller can never disagree about the airframe.

Rotor numbering and spin follow PX4's quad-X convention (see fmus/quadrotor/readme.md):
1 front-right CCW, 2 rear-left CCW, 3 front-left CW, 4 rear-right CW (viewed from above).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace


@dataclass(frozen=True)
class VehicleParams:
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
    drag_xy: float         # N/(m/s), linear drag of the airframe along body x and y vs. the air
    drag_z: float          # N/(m/s), linear drag along body z
    drag_rot: float        # N m/(rad/s), rotational damping about each body axis
    g: float = 9.81        # m/s^2

    # ---- derived quantities (never stored, always computed) ----
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

    def fmu_parameters(self) -> dict[str, float]:
        """Start values for the Quadrotor FMU's parameters of the same names."""
        d = asdict(self)
        d.pop("name")
        return d

    def with_overrides(self, **kw: float) -> VehicleParams:
        """A copy with some fields replaced (unknown names raise TypeError)."""
        return replace(self, **kw)


# Parrot Mambo: reference/minidrone.md §1 (MathWorks Parrot Minidrone template, vehicleVars.m).
# k_thrust = Ct*rho*A*R^2 = 0.0107*1.184*pi*0.033^2*0.033^2 = 4.72e-8 N s^2
# k_torque = Cq*rho*A*R^3 = 7.83e-4*1.184*pi*0.033^2*0.033^3 = 1.14e-10 N m s^2
# omega_max: template motor command 500 -> w^2 = 13840.8*500 -> 2631 rad/s.
MAMBO = VehicleParams(
    name="mambo",
    mass=0.063,
    Ixx=5.82857e-5,
    Iyy=7.16914e-5,
    Izz=1.0e-4,
    arm_length=0.0624,
    k_thrust=4.72e-8,
    k_torque=1.14e-10,
    motor_tau=0.02,        # provisional; see fmus/quadrotor/readme.md for the cited choice
    omega_max=2631.0,
    drag_xy=0.012,         # provisional; see fmus/quadrotor/readme.md
    drag_z=0.02,
    drag_rot=1.0e-6,
)

# Parrot Bebop 2: provisional values, refined with citations in fmus/quadrotor/readme.md.
BEBOP2 = VehicleParams(
    name="bebop2",
    mass=0.500,
    Ixx=1.86e-3,
    Iyy=2.91e-3,
    Izz=4.90e-3,
    arm_length=0.135,
    k_thrust=2.2e-7,
    k_torque=5.0e-9,
    motor_tau=0.03,
    omega_max=1200.0,
    drag_xy=0.09,
    drag_z=0.15,
    drag_rot=2.0e-5,
)

PRESETS: dict[str, VehicleParams] = {v.name: v for v in (MAMBO, BEBOP2)}


def get_vehicle(name: str) -> VehicleParams:
    """The preset called `name` ('mambo' or 'bebop2'); ValueError names the choices."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown vehicle {name!r}; choose one of {', '.join(sorted(PRESETS))}"
        ) from None
