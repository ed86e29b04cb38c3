# Types Cython reads beside mav/onboard/vehicle.py (plain Python): the parts the tick touches
# as C fields of the vehicle (the rest in its __dict__), so `poll` reaches the shared status
# record, the state and the setpoint directly, and calls the HIL checks and f32 as C functions,
# its links' input and telemetry as C calls.
from mav.estimator.core cimport Estimator
from mav.fields cimport f32
from mav.hil cimport tick_refusal
from mav.onboard.channels cimport Chan, LinkInput
from mav.onboard.telemetry cimport Telemetry
from mav.onboard.status cimport VehicleStatus
from mav.types cimport Setpoint, VehicleState


cdef class Onboard:
    cdef dict __dict__
    cdef object __weakref__
    cdef public VehicleStatus status
    cdef public VehicleState _blind_state
    cdef public object _hil, _hil_mav, failsafe, commander
    cdef public Chan _api, _gcs
    cdef public LinkInput input
    cdef public Telemetry telemetry
    cdef public object navigator, manual, mission, vehicle, origin, stats
    cdef public object _decode_hil
    cdef public Estimator estimator
    cdef bint _tick(self, tuple od, bint own, long sysid) except -1
    cpdef _step_modes(self, long long t)
