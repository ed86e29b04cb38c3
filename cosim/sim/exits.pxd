# Types Cython reads beside cosim/sim/exits.py (plain Python): the monitor's state as C fields
# and its per-tick check callable directly from the compiled tick.

cdef class ExitMonitor:
    cdef dict __dict__
    cdef public object arena, arena_box, app, seq, t_touch, touchdown, scene, min_clearance
    cdef public double h, body_radius
    cdef public bint sitl, airborne
    cdef public long ground_ticks, rest_ticks, disarmed_ticks
    cpdef check(self, double t, y, double vz_before, u)
