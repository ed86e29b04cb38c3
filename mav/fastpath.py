"""The onboard stack's compiled hot path (`mav/csrc/fastpath.c`, built by ``python -m
mav.build``), or None.

`lib` is the extension module when it is built and not disabled; the parts that have a
compiled form (the controller, `mav.cascade`; MAVLink framing and frame checks, `mav.wire`)
use it then and their Python reference otherwise, with bit-identical results
(tests/test_fastpath.py). Set the environment variable ``MAV_FASTPATH=0`` to run the Python
reference (read at import: set it before starting), or use `reference()` in-process.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType


def _load() -> ModuleType | None:
    if os.environ.get("MAV_FASTPATH", "1") == "0":
        return None
    try:
        from mav import _fastpath
    except ImportError:
        return None
    return _fastpath


lib: ModuleType | None = _load()


def describe() -> str:
    """One line for reports: which implementation runs."""
    if lib is not None:
        return "compiled (mav/_fastpath)"
    if os.environ.get("MAV_FASTPATH", "1") == "0":
        return "Python reference (MAV_FASTPATH=0)"
    return "Python reference (mav/_fastpath not built: python -m mav.build)"


@contextmanager
def reference() -> Iterator[None]:
    """Run the Python reference instead of the compiled path inside the block: in this process
    (controllers made inside it, every frame encoded or checked) and in the onboard processes
    started inside it (MAV_FASTPATH=0). For back-to-back tests and the bench's before/after."""
    global lib
    from mav import wire

    saved = (lib, wire._fp_frame, wire._fp_check, wire.decode_odometry,
             wire.decode_hil_actuator_controls, os.environ.get("MAV_FASTPATH"))
    lib = wire._fp_frame = wire._fp_check = None
    wire.decode_odometry = wire._one_frame_decoder(wire.ODOMETRY, wire.ODOMETRY_USED)
    wire.decode_hil_actuator_controls = wire._one_frame_decoder(
        wire.HIL_ACTUATOR_CONTROLS, wire.HIL_ACTUATOR_CONTROLS_USED)
    os.environ["MAV_FASTPATH"] = "0"
    try:
        yield
    finally:
        (lib, wire._fp_frame, wire._fp_check, wire.decode_odometry,
         wire.decode_hil_actuator_controls, env) = saved
        if env is None:
            os.environ.pop("MAV_FASTPATH", None)
        else:
            os.environ["MAV_FASTPATH"] = env
