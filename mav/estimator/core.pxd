# Types Cython reads beside mav/estimator/core.py (plain Python): the estimator's state read as
# C fields in the per-tick path, the sensor bundle's reader and the quaternion as C calls.
from mav cimport hil_sensors as hs
from mav.estimator.template cimport TemplateEstimator
from mav.hil cimport odometry_of, odometry_record, tick_refusal
from mav.rotations cimport quat_from_euler

