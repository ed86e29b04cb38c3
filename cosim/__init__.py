"""The simulator: the master algorithm, the plant, sensors, worlds, apps, outputs, studies.

The modules below run compiled when built (`python -m onesource.build`), as the flight software's
do (mav/__init__.py, the switch: onesource/switch.py); the FMI stepper is a hand-written C binding
used only then (cosim/plant/fmu.py falls back to ctypes).
"""

from pathlib import Path as _Path

import mav  # noqa: F401  (the flight software lists its compiled modules first)
from onesource import switch as _compiled

__version__ = "0.1.0"

_HERE = _Path(__file__).resolve().parent
# the per-tick path of the master
COMPILED = [
    "cosim.sim.tick", "cosim.sim.exits", "cosim.sim.onboard", "cosim.outputs.series",
    "cosim.outputs.tlog", "cosim.plant.fmu", "cosim.sensors.odometry",
    # sensor-fed runs: the sensor models and the master's end of their HIL link
    "cosim.sensors.imu", "cosim.sensors.suite", "cosim.sim.estimate",
    # 3D worlds: the collision check's clearance, every tick
    "cosim.world.clearance",
    # the line follower's per-tick path (its planner's setpoint, the app's tick)
    "cosim.apps.planner", "cosim.apps.line_follower",
]
BINDINGS = {
    "cosim.plant._fmi2step": (_HERE / "plant" / "csrc" / "fmi2step.c",
                              _HERE / "plant" / ("_fmi2step" + _compiled.SUFFIX)),
}
_compiled.register(_HERE, COMPILED, BINDINGS)
