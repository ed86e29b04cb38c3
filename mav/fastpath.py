"""The onboard stack's compiled hot path (`mav/csrc/fastpath.c`, built by ``python -m
mav.build``), or None.

`lib` is the extension module when it is built and not disabled; the parts that have a
compiled form (the controller, `mav.cascade`; MAVLink framing, frame checks and one-frame
decoders, `mav.wire`; the offboard setpoint path; the state telemetry; the battery step; the
in-memory link and tlog tap; the UDP receive; the vehicle's tick: mav/README.md lists the C
files) use it then and their Python reference otherwise, with bit-identical results
(tests/test_fastpath*.py, tests/test_links_memory.py, tests/test_links_udp.py,
tests/test_tick.py). Set the environment variable ``MAV_FASTPATH=0`` to run the Python
reference (read at import: set it before starting), or `mav.reference.python()` in-process.
"""

from __future__ import annotations

import os
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

