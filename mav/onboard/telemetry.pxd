# Types Cython reads beside mav/onboard/telemetry.py (plain Python): the codec's framing and
# the rotations called directly (C calls into the compiled mav/wire.py and mav/rotations.py),
# not looked up on their modules for every message sent; the shared status record and the link
# as C types, so a message reads the state's doubles and sends on the link by C calls.
from mav cimport wire
from mav.onboard.channels cimport Chan, Stream
from mav.onboard.status cimport VehicleStatus
from mav.rotations cimport euler_from_quat, rotate_body_to_world


cdef class Telemetry:
    cdef dict __dict__
    cdef public VehicleStatus vs
    cdef public object chans, out, cmd, params, geo, sysid, origin_alt_m, mission, g_mps2
    cdef public object estimator, _emitters
    cpdef publish(self, t)
    cpdef _time_boot_ms(self)
    cpdef emit_heartbeat(self, Chan ch)
    cpdef emit_sys_status(self, Chan ch)
    cpdef emit_attitude(self, Chan ch)
    cpdef emit_local_position(self, Chan ch)
    cpdef emit_global_position(self, Chan ch)
    cpdef emit_home_position(self, Chan ch)
    cpdef emit_extended_sys_state(self, Chan ch)
    cpdef emit_position_target(self, Chan ch)
    cpdef emit_battery_status(self, Chan ch)
    cpdef emit_vfr_hud(self, Chan ch)
    cpdef emit_autopilot_version(self, Chan ch)
    cpdef emit_protocol_version(self, Chan ch)
    cpdef emit_gps_raw_int(self, Chan ch)
    cpdef emit_odometry(self, Chan ch)
    cpdef emit_estimator_status(self, Chan ch)
    cpdef emit_highres_imu(self, Chan ch)
