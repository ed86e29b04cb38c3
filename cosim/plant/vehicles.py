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
    body_radius: float = 0.1   # m, sphere around the CoG used for collisions (not an FMU input)

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
        d.pop("body_radius")
        return d

    def with_overrides(self, **kw: float) -> VehicleParams:
        """A copy with some fields replaced (unknown names raise TypeError)."""
        return replace(self, **kw)

    def physical_problem(self) -> str | None:
        """Why these parameters are not a multirotor that can fly (DERIVED_RANGES), or None."""
        for what, value, (lo, hi), unit in (
                ("thrust/weight at omega_max", 4.0 * self.thrust_max / self.weight,
                 DERIVED_RANGES["thrust_to_weight"], ""),
                ("moment constant k_torque/k_thrust", self.k_torque / self.k_thrust,
                 DERIVED_RANGES["moment_constant"], " m")):
            if not lo <= value <= hi:
                return f"{what} {value:.3g}{unit} (allowed {lo:g}..{hi:g})"
        return None


# Physical ranges of every parameter (issue 31): from the smallest flying quadrotors to
# heavy multirotors, so a value outside is a typo or a unit error, never an airframe. Anchors:
# Crazyflie 2.0, 27 g, arm 46 mm, Ixx 1.4e-5 kg m^2, k_thrust 2.88e-8 N s^2, k_torque
# 7.24e-10 N m s^2, ~2600 rad/s (Förster 2015, ETH); the Mambo and Bebop 2 above; DJI Matrice
# 600 (15.1 kg max take-off, arm ~0.57 m; DJI specifications); motor time constants from
# 12.5 ms (coreless, CrazyS) to a few hundred ms (large propellers). g: the Moon 1.62 to
# Jupiter 24.8 m/s^2 (NASA planetary fact sheet). The drag terms may be 0 (none).
PHYSICAL_RANGES: dict[str, tuple[float, float]] = {
    "mass": (0.01, 100.0),            # kg
    "Ixx": (1e-7, 100.0), "Iyy": (1e-7, 100.0), "Izz": (1e-7, 100.0),   # kg m^2
    "arm_length": (0.01, 2.0),        # m
    "k_thrust": (1e-10, 1e-2),        # N s^2/rad^2
    "k_torque": (1e-13, 1e-3),        # N m s^2/rad^2
    "motor_tau": (1e-3, 1.0),         # s (the FMU integrates it with the 5 ms tick)
    "omega_max": (10.0, 1e4),         # rad/s
    "drag_xy": (0.0, 100.0), "drag_z": (0.0, 100.0),    # N/(m/s)
    "drag_rot": (0.0, 10.0),          # N m/(rad/s)
    "g": (1.0, 30.0),                 # m/s^2
    "body_radius": (0.01, 2.0),       # m
}
# Combinations: a multirotor must lift its weight (hobby guidance is >= 2; racing quads reach
# 10-15) and its rotors' torque-to-thrust ratio (moment constant: Crazyflie 0.025 m, BebopS
# 0.016 m, the Mambo 0.0024 m) must give yaw authority without swamping roll and pitch.
DERIVED_RANGES: dict[str, tuple[float, float]] = {
    "thrust_to_weight": (1.05, 100.0),
    "moment_constant": (1e-4, 0.5),
}


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
MAMBO = VehicleParams(
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
    body_radius=0.1,       # m, arm 0.0624 + propeller radius 0.033, rounded up
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
BEBOP2 = VehicleParams(
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
    body_radius=0.25,      # m, arm 0.129 + 6" propeller radius 0.076 + margin: the body
                           #   sphere of reference/paper2-visual-servoing.md E1 ([ours])
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
