# Types Cython reads beside mav/estimator/core.py (plain Python): the estimator's state read as
# C fields in the per-tick path, the sensor bundle's reader and the quaternion as C calls; the
# front itself a C record, so the vehicle's tick (vehicle.pxd) calls its step and reads its
# implementation directly.
from mav cimport hil_sensors as hs
from mav.estimator.template cimport TemplateEstimator
from mav.hil cimport odometry_of, odometry_record, tick_refusal
from mav.rotations cimport quat_from_euler


cdef class Estimator:
    cdef dict __dict__
    cdef public TemplateEstimator impl
    cdef public hs.Bundle bundle
    cdef public dict stats
    cdef public bint enabled, refused
    cpdef bint estimate_parts(self, list parts) except -1
    cpdef bint _estimate(self, hs.Bundle b, long sysid) except -1
    cpdef tuple record(self)
