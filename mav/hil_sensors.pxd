# Types Cython reads beside mav/hil_sensors.py (plain Python): the codec's framing and frame
# walkers called directly (C calls into mav/wire.py's compiled module).
from mav cimport wire
