# Types Cython reads beside cosim/sim/tick.py (plain Python): the tick's parts as C fields, so
# the calls into the compiled log, monitor and links are direct.
from cosim.outputs.series cimport SeriesSpool
from cosim.outputs.tlog cimport Tlog
from cosim.sim.exits cimport ExitMonitor


cdef class Tick:
    cdef dict __dict__
    cdef public list y, phases, frame_y
    cdef public dict phase_idx
    cdef public object plant_step, measure, encode, encode_lost, decode, exchange, gcs_recv
    cdef public object app, stream, ctx, hooks, stage
    cdef public SeriesSpool spool
    cdef public tuple sinks
    cdef public Tlog tlog
    cdef public ExitMonitor monitor
    cdef public long long h_us
    cdef public long cam_every, record_every, phase
    cdef public double home_n, home_e
    cpdef _run(self, long long k, wind)
    cpdef _camera_and_app(self, long long k, long long t_us, double t, list y)
