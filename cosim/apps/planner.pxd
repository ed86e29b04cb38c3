# Types Cython reads beside cosim/apps/planner.py (plain Python): the line follower's planner
# state as C fields, so its per-tick setpoint (200 Hz) is C arithmetic on C doubles; the
# rest of its state in its __dict__.

cdef class MissionLogic:
    cdef dict __dict__
    cdef object __weakref__
    cdef public object params, state, reason, _lost_xy, transitions, _land_hist
    cdef public double t_start, t_state, _z_lo, _z_hi, _hold_x, _hold_y, _off_n, _off_e
    cdef public double _cos, _sin, _der_x, _der_y, _der_x_until, _der_y_until
    cdef public double _prev_ex, _prev_ey, _t_hold
    cdef public bint _servo
    cdef public long _k
    cpdef tuple setpoint(self, double t, est_xyz)
