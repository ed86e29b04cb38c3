# Types Cython reads beside mav/crc.py (plain Python): the frame checksum as a C call for the
# compiled codec (mav/wire.pxd cimports it).

cdef extern from "Python.h":
    char *PyBytes_AS_STRING(object b)
    char *PyByteArray_AS_STRING(object b)

cpdef long crc_of(object data, Py_ssize_t start, Py_ssize_t end, long extra) except -1
