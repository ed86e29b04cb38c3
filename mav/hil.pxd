# Types Cython reads beside mav/hil.py (plain Python): the framing called directly (a C call
# into mav/wire.py's compiled module).
from mav cimport wire
from mav.fields cimport Layout, copy_of, done, f32, put_f, put_i

cpdef bytes odometry_of(mav, t_us, double x, double y, double z, double qw, double qx,
                        double qy, double qz, double vx, double vy, double vz, double p,
                        double q, double r, bint lost)
cpdef tuple odometry_record(t_us, double x, double y, double z, double qw, double qx,
                            double qy, double qz, double vx, double vy, double vz, double p,
                            double q, double r, bint lost)
cpdef tick_refusal(sysid, t_us, last_us)
