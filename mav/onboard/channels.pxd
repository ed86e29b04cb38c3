# Types Cython reads beside mav/onboard/channels.py (plain Python): the codec's frame walkers
# called directly (C calls into mav/wire.py's compiled module) for every datagram read.
from mav cimport wire
