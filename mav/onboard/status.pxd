# Types Cython reads beside mav/onboard/status.py (plain Python): the shared record's fields
# as C fields of the object, read and written directly by the compiled parts.
from mav.battery cimport Battery
from mav.types cimport Setpoint, VehicleState


cdef class VehicleStatus:
    cdef public dict stats, own, user_params
    cdef public object ctrl, home, v_prev
    cdef public Battery battery
    cdef public list u
    cdef public VehicleState state
    cdef public Setpoint sp, setpoint, of
    cdef public long long t_us, dt_us, ground_since, of_last_us, fs_t0, gcs_last_us
    cdef public long long pos_lost_us, of_loss_us, fail_act_us
    cdef public int mode, landed_state, bat_warned
    cdef public bint have_state, armed, man_climb, fs_active, gcs_lost, fence_breached
    cdef public bint pos_fs_done, hb_now, ext_now, home_now, mission_now
    cdef public double bat_warn_mah
