"""The plant's vehicles: the flight stack's airframe (mav/airframe.py, where every number and
its source is written once) plus what only the simulator needs (the collision sphere), and the
physical ranges a scenario's `[vehicle]` overrides are checked against.

The FMU (`fmus/quadrotor`) takes the airframe's fields as its parameters (same names), and the
onboard controllers (`mav/control.py`) derive their mixer and feed-forward from the same
`Airframe`, so plant and controller can never disagree about the airframe.

Rotor numbering and spin follow PX4's quad-X convention (see fmus/quadrotor/readme.md):
1 front-right CCW, 2 rear-left CCW, 3 front-left CW, 4 rear-right CW (viewed from above).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from mav import airframe
from mav.airframe import Airframe


@dataclass(frozen=True)
class VehicleParams(Airframe):
    """An `Airframe` (its fields, units and derived quantities) and the simulator's own
    `body_radius`."""

    body_radius: float = 0.1   # m, sphere around the CoG used for collisions (not an FMU input)

    def fmu_parameters(self) -> dict[str, float]:
        """Start values for the Quadrotor FMU's parameters of the same names."""
        d = self.values()
        d.pop("body_radius")
        return d

    def airframe(self) -> Airframe:
        """The flight stack's view: the airframe alone."""
        return Airframe(name=self.name, **self.fmu_parameters())

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


# the simulator's part of each preset: the collision sphere
MAMBO = VehicleParams(**asdict(airframe.MAMBO),
                      body_radius=0.1)   # m, arm 0.0624 + propeller radius 0.033, rounded up
BEBOP2 = VehicleParams(**asdict(airframe.BEBOP2),
                       # m, arm 0.129 + 6" propeller radius 0.076 + margin: the body sphere of
                       # paper 2's E1 (reference/paper2-visual-servoing.md, [ours])
                       body_radius=0.25)

# one preset per airframe, by the same names
PRESETS: dict[str, VehicleParams] = {v.name: v for v in (MAMBO, BEBOP2)}


def get_vehicle(name: str) -> VehicleParams:
    """The preset called `name` ('mambo' or 'bebop2'); ValueError names the choices (the
    airframes', which are the presets')."""
    return PRESETS[airframe.get_airframe(name).name]
