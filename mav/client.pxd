# Types Cython reads beside mav/client.py (plain Python): the codec's framing and frame
# walkers called directly (C calls into mav/wire.py's compiled module), not looked up on the
# module every setpoint and every telemetry datagram.
from mav cimport wire
