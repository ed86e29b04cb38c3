"""The flight software: the onboard stack, its controllers, its MAVLink codec and client.

The modules below are compiled by Cython when built (`python -m onesource.build`); the same sources
run interpreted otherwise. onesource/switch.py is the switch (COSIM_COMPILED).
"""

from pathlib import Path as _Path

from onesource import switch as _compiled

__version__ = "0.1.0"

# the per-tick path: what runs compiled when built
COMPILED = [
    "mav.crc", "mav.fields", "mav.wire", "mav.rotations", "mav.types", "mav.cascade",
    "mav.control", "mav.mixer", "mav.battery", "mav.hil", "mav.links", "mav.client",
    "mav.onboard.vehicle", "mav.onboard.channels", "mav.onboard.telemetry", "mav.onboard.status",
    "mav.onboard.commander", "mav.onboard.navigator", "mav.onboard.offboard",
    "mav.onboard.failsafe", "mav.onboard.mission", "mav.onboard.manual", "mav.onboard.leg",
    "mav.onboard.moveby",
    # the onboard estimator and PX4's simulator messages (TPL_EST_TYPE 1-2, sensor-fed runs)
    "mav.hil_sensors", "mav.estimator.core", "mav.estimator.template", "mav.estimator.release",
    "mav.estimator.link",
]
_compiled.register(_Path(__file__).parent, COMPILED)
