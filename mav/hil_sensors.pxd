# Types Cython reads beside mav/hil_sensors.py (plain Python): the codec's framing and frame
# walkers called directly (C calls into mav/wire.py's compiled module), and the sensor
# messages' packers as C functions for the simulator's sensor models (cosim/sensors/suite.pxd).
from mav cimport wire
from mav.wire cimport FastMsg
from mav.fields cimport Layout, done, get_f, get_i, new_payload, put_f, put_i

cpdef bytes stamped(mav, FastMsg m, t_us, bytes rest)
cpdef bytes stamp(FastMsg m, t_us, bytes rest)
cpdef list stamp_all(list parts, t_us, list out)
cpdef bytes frames(mav, list parts)
cpdef bytes hil_sensor_rest(double ax, double ay, double az, double gx, double gy, double gz,
                            double mx, double my, double mz, double abs_hpa, double p_alt,
                            double temp_c, long fields_updated)
cpdef bytes flow_rest(long long dt_us, double ix, double iy, double gx, double gy, double gz,
                      long quality)
cpdef bytes distance_rest(long min_cm, long max_cm, long cur_cm, long quality,
                          long covariance)
cpdef bytes truth_payload(t_us, double qw, double qx, double qy, double qz, double p,
                          double q, double r, long long lat_e7, long long lon_e7,
                          long long alt_mm, long vn_cms, long ve_cms, long vd_cms)


cdef class Payload:
    cdef public Layout lay
    cdef public bytes data
    cdef public Py_ssize_t p0, plen, at, end
    cpdef double f(self, Py_ssize_t k) except? -1.0
    cpdef long long i(self, Py_ssize_t k) except? -1


cdef class Bundle:
    cdef public Payload imu, flow, rng, gps
    cdef public long bad, foreign
    cpdef read(self, bytes data)
    cpdef take(self, list parts)


cpdef tuple decode_bundle(bytes data)
cpdef bint is_sensor_bundle(bytes data) except -1
