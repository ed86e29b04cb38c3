# Types Cython reads beside cosim/sensors/suite.py (plain Python): the sensor set's per-tick
# parameters and state as C fields, its IMU filters and noise streams as compiled objects.
from cosim.sensors.imu cimport Gauss, Imu3
from mav cimport hil_sensors as hs
from mav cimport wire
from mav.wire cimport FlatEarth


cdef class SensorSuite:
    cdef public object p, spec, mav, home, faults, range_cm
    cdef public FlatEarth geo
    cdef public list n, queue, active, fired
    cdef public set _seen
    cdef public Imu3 acc, gyro
    cdef public Gauss g_baro, g_mag, g_range, g_flow
    cdef public double h, home_n, home_e, ba0, ba1, ba2, bg0, bg1, bg2, acc_max, gyro_max
    cdef public double baro_p0, baro_gain, baro_noise, mag0, mag1, mag2, mag_noise
    cdef public double range_min, range_max, range_noise, flow_noise, flow_max_tilt
    cdef public double flow_max_rate, flow_base, fa0, fa1, fa2, fa3, fa4
    cdef public long range_every, flow_every, flow_n, delay, n_flow, n_echo, n_none, n_gps
    cdef public long long k
    cdef public bint gps
    cpdef bytes encode(self, t_us, y)
    cpdef list messages(self, t_us, y, bint truth)
    cpdef bytes truth_of(self, t_us, y)
    cpdef list read(self, t_us, y)
