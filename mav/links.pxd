# Types Cython reads beside mav/links.py (plain Python): the in-memory link's fields as C
# fields, and its send/recv callable directly from other compiled modules.

cdef class MemoryLink:
    cdef public object _inbox
    cdef public MemoryLink _peer
    cdef public long long sent_bytes
    cpdef send(self, data)
    cpdef recv(self)
