# Types Cython reads beside mav/cascade.py (which stays plain Python): the cascade's state as C
# fields of the object; `update`'s arguments and locals are typed in the .py (annotations and
# @cython.locals).
from mav.rotations cimport euler_from_quat, tilt_cos
from mav.types cimport Setpoint, VehicleState


cdef class QuadCascade:
    cdef dict __dict__
    cdef public object vehicle, _specs, _p, _A, _Ainv, _g
    cdef public double dt, _i_p, _i_r, _i_z, _i_n, _i_e, _yaw_ref
    cdef public long _n
