"""The onboard flight stack: a PX4-style MAVLink vehicle around the low-level controller.

`Onboard` (vehicle.py) is the entry point; `main` (process.py) runs it as a process
(`python -m mav.onboard --help`). The parts and how a tick runs through them: vehicle.py and
mav/README.md.
"""

from mav.onboard.config import OnboardConfig
from mav.onboard.defs import (
    CAPABILITIES,
    DRAIN_MAX,
    IN_AIR,
    LAND,
    LANDING,
    LOITER,
    MODE_NAMES,
    OFFBOARD,
    ON_GROUND,
    POSCTL,
    TAKEOFF,
    TAKING_OFF,
    px4_custom_mode,
)
from mav.onboard.process import main
from mav.onboard.vehicle import Onboard

__all__ = [
    "CAPABILITIES", "DRAIN_MAX", "IN_AIR", "LAND", "LANDING", "LOITER", "MODE_NAMES", "OFFBOARD",
    "ON_GROUND", "POSCTL", "TAKEOFF", "TAKING_OFF", "Onboard", "OnboardConfig", "main",
    "px4_custom_mode",
]
