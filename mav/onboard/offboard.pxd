# Types Cython reads beside mav/onboard/offboard.py (plain Python): the shared status record as
# a C type, so a setpoint (200 Hz from an app) is checked in C doubles and written into the
# offboard setpoint's C fields; the angle wrap a C call.
from mav.onboard.channels cimport Chan
from mav.onboard.status cimport VehicleStatus
from mav.rotations cimport wrap_pi
from mav.types cimport Setpoint


cdef class Offboard:
    cdef dict __dict__
    cdef public VehicleStatus vs
    cdef public object out, cmd, sysid, compid, geo, moveby
    cpdef on_setpoint(self, Chan ch, tuple f)
