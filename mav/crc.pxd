# Types Cython reads beside mav/crc.py (plain Python): the frame checksum as a C call for the
# compiled codec (mav/wire.pxd cimports it).

cpdef long crc_of(bytes data, Py_ssize_t start, Py_ssize_t end, long extra) except -1
