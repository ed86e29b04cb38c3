# Types Cython reads beside cosim/outputs/tlog.py (plain Python): the log and the tap as C
# fields, their per-datagram calls direct from the compiled tick.

cdef class Tlog:
    cdef public object path, _f, _write, error
    cdef public bytes _stamp
    cdef public long long t_us, count, _stamp_us
    cpdef add(self, data)


cdef class TapLink:
    cdef public object inner
    cdef public Tlog log
    cpdef send(self, data)
    cpdef recv(self)
