# Types Cython reads beside mav/onboard/channels.py (plain Python): the codec's frame walkers
# called directly (C calls into mav/wire.py's compiled module) for every datagram read; a link's
# record and its streams as C fields, and its send a C call from the compiled telemetry.
from mav cimport wire
from mav.onboard.status cimport VehicleStatus


cdef class Stream:
    cdef public object msgid, default_us, interval_us, next_us, emit


cdef class Chan:
    cdef public object name, link, mav, next_due, schedule, signed, peer, streams, param_queue
    cdef public dict by_msgid, stats
    cdef public str tx_key, rx_key, bad_key
    cpdef send(self, data)


cdef class LinkInput:
    cdef dict __dict__
    cdef public VehicleStatus vs
    cdef public dict stats, handlers
    cdef public object outbox, on_setpoint
    cpdef drain(self, Chan ch, data=*)
    cpdef handle_datagram(self, Chan ch, data)
