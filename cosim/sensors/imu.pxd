# Types Cython reads beside cosim/sensors/imu.py (plain Python): the noise stream's position
# and the IMU filter's coefficients and states as C fields.

cdef class Gauss:
    cdef public object rng
    cdef public double[::1] buf       # the block of draws (imu.py: _block)
    cdef public Py_ssize_t i
    cpdef Py_ssize_t at(self, Py_ssize_t n) except -1
    cpdef list take(self, Py_ssize_t n)


cdef class Imu3:
    cdef public double b0, b1, b2, a1, a2
    cdef public double x10, x20, y10, y20, x11, x21, y11, y21, x12, x22, y12, y22
    cdef public double sc0, sc1, sc2, ns0, ns1, ns2, o0, o1, o2
    cdef public Gauss gauss
    cpdef read(self, double u0, double u1, double u2, double bias0, double bias1,
                     double bias2, double lim)
