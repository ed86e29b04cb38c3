"""Scenario records: what a scenario file says, typed, with units. Built once at the edge by
`cosim.load` (cosim.scenario.parse and the parsers of the other packages); everything inside
trusts them.

This package imports no other part of the simulator (the world and the camera are built by
their own packages, cosim/load.py hands their parsers in), so any part may import it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cosim.scenario.vehicles import VehicleParams


# why a run ended (a scenario's pass criteria name them; the master sets one)
class ExitReason(enum.Enum):
    MISSION_COMPLETE = "mission_complete"   # the app reached its goal; vehicle down, disarmed
    APP_ABORTED = "app_aborted"             # the app gave up (its reason in the message); down
    LANDED = "landed"                       # down and disarmed, but the app did not finish
    CRASHED = "crashed"                     # hard touchdown or flipped
    LEFT_ARENA = "left_arena"               # outside the world's arena or above the ceiling
    COLLISION = "collision"                 # the body sphere touched a wall, box or column
    TIME_LIMIT = "time_limit"               # timing.t_final_s reached
    COMPONENT_ERROR = "component_error"     # a part failed (plant, onboard, app, camera)
    INTERRUPTED = "interrupted"             # Ctrl-C
    STOPPED = "stopped"                     # cosim sitl: Ctrl-C or SIGTERM, a normal stop

@dataclass(frozen=True)
class Timing:
    tick_s: float = 0.005          # s, HIL / onboard control period (fixed at 5 ms)
    camera_every: int = 40         # ticks between camera frames (Mambo: 40 -> 5 Hz)
    t_final_s: float = 100.0       # s, time limit (the template's TFinal)


@dataclass(frozen=True)
class Start:
    n: float = 0.0                 # m, world NED north of the start (on the floor, z = 0)
    e: float = 0.0                 # m
    yaw_deg: float = 0.0           # deg, heading at start (0 = facing north)


@dataclass(frozen=True)
class SensorNoise:
    pos_std_m: float = 0.0         # m, white noise on ODOMETRY position
    vel_std_mps: float = 0.0       # m/s, on velocity
    att_std_rad: float = 0.0       # rad, small-angle noise on attitude
    rate_std_radps: float = 0.0    # rad/s, on body rates

    @property
    def any(self) -> bool:
        return any(v > 0 for v in (self.pos_std_m, self.vel_std_mps, self.att_std_rad,
                                   self.rate_std_radps))


@dataclass(frozen=True)
class Criteria:
    """Pass criteria; None means not checked."""

    must_complete: bool = True               # the app reports its mission complete and landed
    landing_error_max_m: float | None = None
    path_rms_max_m: float | None = None
    path_max_m: float | None = None
    mission_time_max_s: float | None = None
    position_error_max_m: float | None = None  # scripted apps: max distance to reached waypoints
    final_pose_error_max_m: float | None = None   # taught paths: at the last key (m)
    final_yaw_error_max_deg: float | None = None  # taught paths: at the last key (deg)
    min_clearance_min_m: float | None = None      # 3D worlds: the body sphere's least gap
    coverage_min: float | None = None             # tracks: fraction flown in order (0-1)
    expect_exit: str | None = None                # the exit reason the run must end with
    fault_displacement_max_m: float | None = None  # [faults]: touchdown to where the first
                                                   # fault found the vehicle (m)


@dataclass(frozen=True)
class AppSpec:
    name: str = "none"             # built-in name or 'package.module:Class'
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    seed: int
    vehicle: VehicleParams
    start: Start
    timing: Timing
    world: Any                               # the parsed world (cosim.world.floor.World)
    camera: Any                              # the parsed camera config, chosen by its kind
                                             # (cosim.sensors.camera.CameraConfigAny), or None
    app: AppSpec
    noise: SensorNoise
    wind_ned_mps: tuple[float, float, float]
    criteria: Criteria
    source: str = ""                          # path of the file, for the summary
    raw: dict[str, Any] = field(default_factory=dict, repr=False)  # the TOML, for re-parsing
    world_table: dict[str, Any] = field(default_factory=dict, repr=False)  # [world], file merged
    wind: Any = None                          # cosim.world.wind.WindSpec (mean = wind_ned_mps)
    faults: Any = None                        # cosim.faults.core.FaultSpec ([faults]; falsy: none)
    onboard_params: tuple[tuple[str, float], ...] = ()   # [onboard.params]: set at start
    plant: Any = None                         # cosim.plant.mapping.PlantSpec ([vehicle] fmu
                                              # or fmi = 3); None: the FMI 2.0 plant
    sensors: Any = None                       # cosim.sensors.spec.SensorsSpec ([sensors])
    numerics: str = "native"                  # [run] numerics: "portable" = the same bits on
                                              # every x86-64 CPU (cosim/numerics.py)
