# Types Cython reads beside cosim/sim/estimate.py (plain Python): the frame walker as a C call
# into mav/wire.py's compiled module (the answer split, per tick).
from mav cimport wire
from cosim.outputs.series cimport pack10
from mav.fields cimport Layout, PyBytes_AS_STRING, get_f, get_i
from mav.wire cimport PyBytes_FromStringAndSize
from mav.rotations cimport euler_from_quat
