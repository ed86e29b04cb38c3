# Types Cython reads beside mav/types.py (which stays plain Python): the records' fields as C
# doubles in the object, read and written directly by the compiled modules that cimport them.

cdef class VehicleState:
    cdef public double t, x, y, z, vx, vy, vz, qw, qx, qy, qz, p, q, r


cdef class Setpoint:
    cdef public double x, y, z, vx, vy, vz, yaw, yaw_rate, ax, ay
    cdef public object armed
