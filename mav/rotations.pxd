# Types Cython reads beside mav/rotations.py (plain Python): the scalar rotations as C calls
# for compiled callers (the controller, the estimator, telemetry), C doubles inside.
cpdef tuple quat_from_euler(double roll, double pitch, double yaw)
cpdef tuple euler_from_quat(double qw, double qx, double qy, double qz)
cpdef double yaw_from_quat(double qw, double qx, double qy, double qz) except? -1.0
cpdef double tilt_cos(double qw, double qx, double qy, double qz) except? -1.0
cpdef tuple rotate_body_to_world(double qw, double qx, double qy, double qz, double bx,
                                 double by, double bz)
cpdef (double, double, double) euler_to_world(double roll, double pitch, double yaw, double x,
                                             double y, double z)
cpdef double wrap_pi(double a)
