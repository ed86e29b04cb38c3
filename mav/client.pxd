# Types Cython reads beside mav/client.py (plain Python): the codec's framing and frame
# walkers called directly (C calls into mav/wire.py's compiled module), not looked up on the
# module every setpoint and every telemetry datagram; the client's per-tick path (poll, a
# datagram read, a setpoint sent) as C calls on its C fields, the rest in its __dict__.
from mav cimport wire


cdef class OffboardClient:
    cdef dict __dict__
    cdef object __weakref__
    cdef public object link, mav, _fast_rx, t, _next_hb, target_system, target_component
    cdef public dict stats, _fast_handlers, _handlers
    cpdef poll(self, t)
    cpdef _datagram(self, data)
    cpdef _setpoint(self, frame, mask, x, y, z, vx, vy, vz, yaw, yaw_rate)
    cpdef set_position_target(self, x, y, z, yaw=*, vx=*, vy=*, vz=*, yaw_rate=*)
