# Types Cython reads beside mav/onboard/telemetry.py (plain Python): the codec's framing and
# the rotations called directly (C calls into the compiled mav/wire.py and mav/rotations.py),
# not looked up on their modules for every message sent.
from mav cimport wire
from mav.rotations cimport euler_from_quat, rotate_body_to_world
