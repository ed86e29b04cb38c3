# Types Cython reads beside mav/wire.py (which stays plain Python): a message layout's fields
# as C fields, read directly by the compiled encoders and decoders.

cdef class FastMsg:
    cdef public object cls, name, extra, st, id3, zeros
    cdef public long id, crc_extra
    cdef public Py_ssize_t size
