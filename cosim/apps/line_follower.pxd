# Types Cython reads beside cosim/apps/line_follower.py (plain Python): the app's per-tick
# path (200 Hz: the client's poll, the planner's setpoint, the setpoint sent) as C calls on
# C fields; the rest of its state in its __dict__.
from cosim.apps.planner cimport MissionLogic
from mav.client cimport OffboardClient


cdef class LineFollowerApp:
    cdef dict __dict__
    cdef object __weakref__
    cdef public OffboardClient client
    cdef public MissionLogic logic
    cdef public object seq, phase, events, setpoint
    cdef public long every, _k
    cdef public bint done, _following_logged
    cpdef on_tick(self, double t)
