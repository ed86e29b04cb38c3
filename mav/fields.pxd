# Types Cython reads beside mav/fields.py (plain Python): a payload's layout as C arrays and
# its fields written and read as C calls (struct's own float packers from Python.h).

from libc.string cimport memset

cdef extern from "Python.h":
    int PyFloat_Pack4(double x, char *p, int le) except -1
    int PyFloat_Pack8(double x, char *p, int le) except -1
    double PyFloat_Unpack4(const char *p, int le) except? -1.0
    double PyFloat_Unpack8(const char *p, int le) except? -1.0
    char *PyByteArray_AS_STRING(object b)
    Py_ssize_t PyByteArray_GET_SIZE(object b)
    bytearray PyByteArray_FromStringAndSize(char *v, Py_ssize_t n)
    bytes PyBytes_FromStringAndSize(char *v, Py_ssize_t n)
    char *PyBytes_AS_STRING(object b)


cdef class Layout:
    cdef public object fmt
    cdef public Py_ssize_t n, size
    cdef Py_ssize_t off[96]
    cdef int code[96]


cpdef bytearray new_payload(Py_ssize_t n)
cpdef bytearray copy_of(bytes template)
cpdef bytes done(object buf)
cpdef int put_f(object out, Layout lay, Py_ssize_t k, double v) except -1
cpdef int put_i(object out, Layout lay, Py_ssize_t k, long long v) except -1
cpdef double get_f(object data, Py_ssize_t p0, Py_ssize_t plen, Layout lay,
                   Py_ssize_t k) except? -1.0
cpdef long long get_i(object data, Py_ssize_t p0, Py_ssize_t plen, Layout lay,
                      Py_ssize_t k) except? -1
cpdef double f32(double v) except? -1.0
cdef int _writable(object out) except -1
cdef int _readable(object data) except -1
