# Types Cython reads beside mav/estimator/release.py (plain Python): the release's filter
# states as C doubles. ReleaseEstimator extends TemplateEstimator's fields (template.pxd).

from mav.estimator.template cimport TemplateEstimator, _finite
from mav.rotations cimport euler_to_world, wrap_pi
from mav.hil_sensors cimport Payload


cdef class Lti:
    cdef readonly int n
    cdef double b[6]
    cdef double a[6]
    cdef double z[6]
    cpdef double step(self, double x)
    cpdef reset(self)


cdef class ReleaseEstimator(TemplateEstimator):
    cdef public Lti fir0, fir1, fir2, chp, chq, chr, bw_prs, bw_son
    cdef public double ka0, ka1, pz_ss, pv_ss, kv, c0, c1, c2
    cdef public double zpr, vpr, z_prev, z_son, z_prs, fx, fy, bx, by, bx_out, by_out
    cdef public double pf_prev, qf_prev, sx, sy
    cdef public bint son_ok, of_ok
    cdef public object son_us, of_us
    cpdef _restart(self)
    cdef _sonar(self, Payload m)
    cdef bint _of(self, Payload m) except -1
    cdef _step(self, Payload m, double dt, t_us, bint new_flow)
