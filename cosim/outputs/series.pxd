# Types Cython reads beside cosim/outputs/series.py (plain Python): the spool's fields as C
# fields, and a tick's row written as float64 by C calls (struct's own packer, PyFloat_Pack8)
# from the compiled tick, without a tuple of its values.
from mav.fields cimport PyBytes_AS_STRING, PyFloat_Pack8
from mav.wire cimport PyBytes_FromStringAndSize

cdef int pack10(char *p, double a, double b, double c, double d, double e, double f, double g,
                double h, double i, double j) except -1


cdef class SeriesSpool:
    cdef public object path, pack, append, error, _f
    cdef public Py_ssize_t ncols
    cdef public object rows, held
    cdef public long long ticks, held_bytes
    cpdef bytes row(self, t, y, u1, u2, u3, u4, m0, m1, m2, s0, s1, s2, ph)
