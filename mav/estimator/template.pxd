# Types Cython reads beside mav/estimator/template.py (which stays plain Python): the
# estimator's state as C doubles, its per-tick steps as C methods. The times (us) stay Python
# ints: time_usec is a uint64 on the wire, and any value must behave as in Python.

from mav.hil_sensors cimport Payload
from mav.rotations cimport euler_to_world, wrap_pi

cpdef bint _finite(double s)


cdef class TemplateEstimator:
    cdef public dict stats
    cdef public long n, nb, resets
    cdef public object t_us, aid_us, rng_us, gps_us, rng_rej_since, noaid_us, imu_us, gps_rej_since
    cdef public double x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r
    cdef public double bg0, bg1, bg2, alp0, alp1, alp2
    cdef public double p0_hpa, pzz, pzv, pvv, pzb, pvb, pbb, bz, pvx, pvy
    cdef public bint lost
    cdef public double tr_tilt, tr_vel, tr_hgt, sg2
    cdef double ra0, ra1, ra2, rg0, rg1, rg2      # the reading _imu_ok passed
    cdef long rfields
    cdef public long fail
    cdef public double w_acc, acc_gate, w_mag, decl, q_acc, q_ab, abl_lim, r_baro, baro_gate
    cdef public double r_rng
    cdef public double rng_gate, of_q, of_r, of_qmin, of_gate, w_gps
    cpdef update(self, imu, flow, rng, gps, geo, t_us)
    cdef double _dt(self, t_us) except? -1.0
    cdef _health(self, t_us)
    cdef bint _imu_ok(self, Payload m) except -1
    cdef _watch_tilt(self, double a0, double a1, double a2)
    cdef _imu(self, Payload m, double dt)
    cdef _z_fuse(self, double zm, double r)
    cpdef _reset(self)
    cdef _range(self, Payload m, t_us)
    cdef bint _flow(self, Payload m, t_us) except -1
    cdef _gps(self, Payload m, geo, t_us)
