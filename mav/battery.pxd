# Types Cython reads beside mav/battery.py (plain Python): the pack's state as C doubles, so
# its per-tick step (the vehicle's, a C call) is C arithmetic.

cdef class Battery:
    cdef public object p
    cdef public double u_hover, capacity_mah, r_internal, _k_motor, _i_avionics, consumed_mah
    cdef public double energy_j, current, _v_last, lost_mah, r_scale, v_drop
    cpdef step(self, double dt, double u1, double u2, double u3, double u4)
