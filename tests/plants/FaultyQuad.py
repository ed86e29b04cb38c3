"""The PythonFMU test plant (EnuQuad.py) with a fault in its doStep: a user's FMU that crashes
or hangs (tests/test_plant_isolation.py).

`pythonfmu build -f FaultyQuad.py EnuQuad.py` exports it. Its Integer parameter `fault` picks
what its doStep does once the time reaches its Real parameter `fault_at_s`: 0 nothing (it
flies as EnuQuad does), 1 a segmentation fault (a read of address 0), 2 it never returns.
Before it hangs it creates the file named by the environment variable FAULTY_QUAD_HANGS (when
set), so a test knows the hang has begun.
"""

import ctypes
import os
import time

from EnuQuad import EnuQuad
from pythonfmu import Fmi2Causality, Fmi2Variability, Integer, Real


class FaultyQuad(EnuQuad):
    author = "cosim tests"
    description = "EnuQuad whose doStep crashes or hangs at a given time (test plant)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.fault = 0
        self.fault_at_s = 1.0
        self.register_variable(Integer("fault", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed))
        self.register_variable(Real("fault_at_s", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed))

    def do_step(self, current_time, step_size):
        if self.fault and current_time >= self.fault_at_s:
            if self.fault == 1:
                ctypes.string_at(0)                 # SIGSEGV
            marker = os.environ.get("FAULTY_QUAD_HANGS")
            if marker:
                open(marker, "w").close()
            while True:
                time.sleep(1.0)
        return super().do_step(current_time, step_size)
