# Types Cython reads beside mav/wire.py (which stays plain Python): a message layout's fields
# as C fields, read directly by the compiled encoders and decoders.

from mav cimport crc as _crc
from mav.fields cimport PyByteArray_AS_STRING, PyBytes_AS_STRING, new_payload


cdef extern from "Python.h":
    object PyBytes_FromStringAndSize(char *v, Py_ssize_t n)


cdef class FastMsg:
    cdef public object cls, name, extra, st, id3, zeros, unpack_from
    cdef public long id, crc_extra
    cdef public Py_ssize_t size


# the framing and the frame walkers, called directly by the compiled modules that cimport them
# (the sensor bundle, mav/hil_sensors.pxd); a payload and a datagram are bytes
cpdef bytes frame(mav, FastMsg m, bytes payload)
cdef Py_ssize_t trimmed_len(bytes payload) except -1
cdef int put_frame(bytearray out, Py_ssize_t at, int seq, int sysid, int compid, FastMsg m,
                   bytes payload, Py_ssize_t n) except -1
cpdef Py_ssize_t frame_end(bytes data, Py_ssize_t i=*) except? -2
cpdef long msgid_of(bytes data, Py_ssize_t i=*) except? -1
cpdef bint frame_ok(FastMsg m, bytes data, Py_ssize_t i, Py_ssize_t end) except -1
cpdef decode_fast(FastMsg m, bytes data, Py_ssize_t i=*, Py_ssize_t end=*)
# the two 50 Hz telemetry messages, encoded by C calls from the compiled telemetry
cpdef bytes encode_attitude(mav, time_boot_ms, roll, pitch, yaw, rollspeed, pitchspeed,
                            yawspeed)
cpdef bytes encode_local_position_ned(mav, time_boot_ms, x, y, z, vx, vy, vz)


cdef class FlatEarth:
    cdef public double lat0_deg, lon0_deg, alt0_m, _dlat_dn, _dlon_de
    cpdef tuple to_geodetic(self, double n_m, double e_m, double d_m)
    cpdef tuple to_int(self, double n_m, double e_m, double d_m)


cpdef double round_even(double x)
