"""Run the Python reference of the onboard fast path instead of its compiled copy
(mav/fastpath.py): for back-to-back tests and the bench's before/after figures."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from mav import fastpath, wire


@contextmanager
def python() -> Iterator[None]:
    """Run the Python reference instead of the compiled path inside the block: in this process
    (controllers made inside it, every frame encoded or checked) and in the onboard processes
    started inside it (MAV_FASTPATH=0). For back-to-back tests and the bench's before/after."""
    saved = (fastpath.lib, wire._fp_frame, wire._fp_check, wire._fp_frame_on,
             wire.decode_odometry, wire.decode_hil_actuator_controls,
             os.environ.get("MAV_FASTPATH"))
    fastpath.lib = wire._fp_frame = wire._fp_check = wire._fp_frame_on = None
    wire.decode_odometry = wire.one_frame_decoder(wire.ODOMETRY, wire.ODOMETRY_USED)
    wire.decode_hil_actuator_controls = wire.one_frame_decoder(
        wire.HIL_ACTUATOR_CONTROLS, wire.HIL_ACTUATOR_CONTROLS_USED)
    os.environ["MAV_FASTPATH"] = "0"
    try:
        yield
    finally:
        (fastpath.lib, wire._fp_frame, wire._fp_check, wire._fp_frame_on, wire.decode_odometry,
         wire.decode_hil_actuator_controls, env) = saved
        if env is None:
            os.environ.pop("MAV_FASTPATH", None)
        else:
            os.environ["MAV_FASTPATH"] = env
