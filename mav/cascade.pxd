# Types Cython reads beside mav/cascade.py (which stays plain Python): the cascade's state as C
# fields of the object; `update`'s arguments and locals are typed in the .py (annotations and
# @cython.locals).
from mav.rotations cimport euler_from_quat, tilt_cos
from mav.types cimport Setpoint, VehicleState


cdef class Gains:
    cdef public double pitch_kp, pitch_ki, pitch_kd, roll_kp, roll_ki, roll_kd, att_i_lim, att_kb
    cdef public double k_psi, k_r, yawrate_max, k_z, k_vz, ki_z_pos, ki_z_vpos, ki_z_vel, z_i_lim
    cdef public double vz_max, thrust_max_total, k_xy, k_vxy, c_drag, ki_vxy, xy_i_lim, xy_err_max
    cdef public double vxy_max, tilt_max, weight, inv_g, m0t, m0m, m0l, m1t, m1m, m1l, m2t, m2m
    cdef public double m2l, m3t, m3m, m3l, my, t_max, c_u, arm_a, dt
    cdef public bint integ


cdef class QuadCascade:
    cdef dict __dict__
    cdef public object vehicle, _specs, _p, _A, _Ainv
    cdef public Gains _g
    cdef public double dt, _i_p, _i_r, _i_z, _i_n, _i_e, _yaw_ref
    cdef public long _n
