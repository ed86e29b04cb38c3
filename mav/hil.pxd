# Types Cython reads beside mav/hil.py (plain Python): the framing called directly (a C call
# into mav/wire.py's compiled module).
from mav cimport wire
