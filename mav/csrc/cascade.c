/* The controller compiled (included by fastpath.c: one translation unit).
 *
 * One source of truth per control law: mav/cascade.py (`QuadCascade.update`) is the readable
 * model, used for analysis (`mav.tune`) and as the reference; this file is the same law,
 * statement for statement, in C. The two are tested back to back for bit identity
 * (tests/test_fastpath.py): same IEEE-754 double operations in the same order (no -ffast-math,
 * no FMA contraction: -ffp-contract=off), the same libm (atan2, asin, sin, cos, sqrt, fmod)
 * that CPython's math module calls, and Python's float semantics where they differ from C's
 * (`%` takes the sign of the divisor, `min` keeps the first of equals, NaN tests as x != x).
 *
 * Cascade: `Cascade()`, `.set_gains(tuple)` (the 47 fields of mav.cascade.Gains in order),
 * `.reset()`, `.update(state, setpoint, out)` reading the attributes of a VehicleState and a
 * Setpoint (mav/types.py) and writing u1..u4 to out[0:4], `.integrators()` for the tests.
 */

#define N_GAINS 47

typedef struct {
    double pitch_kp, pitch_ki, pitch_kd, roll_kp, roll_ki, roll_kd, att_i_lim, att_kb;
    double k_psi, k_r, yawrate_max;
    double k_z, k_vz, ki_z_pos, ki_z_vpos, ki_z_vel, z_i_lim, vz_max, thrust_max_total;
    double k_xy, k_vxy, c_drag, ki_vxy, xy_i_lim, xy_err_max, vxy_max, tilt_max;
    double weight, inv_g;
    double m0t, m0m, m0l, m1t, m1m, m1l, m2t, m2m, m2l, m3t, m3m, m3l, my;
    double t_max, c_u, arm_a, dt;
    int integ;
} Gains;

typedef struct {
    PyObject_HEAD
    Gains g;
    int have_gains;
    double i_p, i_r, i_z, i_n, i_e, yaw_ref;
    long long n;
} Cascade;

/* interned attribute names, indexed by the enums below */
enum { S_QW, S_QX, S_QY, S_QZ, S_VX, S_VY, S_VZ, S_X, S_Y, S_Z, S_P, S_Q, S_R, S_N };
static const char *S_NAMES[S_N] = {"qw", "qx", "qy", "qz", "vx", "vy", "vz", "x", "y", "z",
                                   "p", "q", "r"};
enum { P_X, P_Y, P_Z, P_VX, P_VY, P_VZ, P_YAW, P_YAW_RATE, P_AX, P_AY, P_N };
static const char *P_NAMES[P_N] = {"x", "y", "z", "vx", "vy", "vz", "yaw", "yaw_rate", "ax",
                                   "ay"};
static PyObject *s_names[S_N], *p_names[P_N], *name_armed;
static SlotEntry s_cache[S_N], p_cache[P_N];

static const double PI_ = 3.141592653589793;
static const double TWO_PI_ = 6.283185307179586;

/* Python's float `a % b` (the result has the sign of b) */
static double py_mod(double a, double b)
{
    double m = fmod(a, b);
    if (m != 0.0) {
        if ((b < 0.0) != (m < 0.0))
            m += b;
    } else {
        m = copysign(0.0, b);
    }
    return m;
}

/* obj.<names[i]> as doubles, through the names' caches (`cache[i]`, slots.c) */
static int read_floats(PyObject *obj, PyObject **names, SlotEntry *cache, int n, double *out)
{
    for (int i = 0; i < n; i++) {
        PyObject *v = getattr_at(&cache[i], obj, names[i]);
        if (v == NULL)
            return -1;
        double d = PyFloat_CheckExact(v) ? PyFloat_AS_DOUBLE(v) : PyFloat_AsDouble(v);
        Py_DECREF(v);
        if (d == -1.0 && PyErr_Occurred())
            return -1;
        out[i] = d;
    }
    return 0;
}

static int set_out(PyObject *out, Py_ssize_t i, double v)
{
    PyObject *f = PyFloat_FromDouble(v);
    if (f == NULL)
        return -1;
    if (PyList_CheckExact(out) && i < PyList_GET_SIZE(out)) {
        PyObject *old = PyList_GET_ITEM(out, i);
        PyList_SET_ITEM(out, i, f);
        Py_XDECREF(old);
        return 0;
    }
    int rc = PySequence_SetItem(out, i, f);
    Py_DECREF(f);
    return rc;
}

static void cascade_reset_state(Cascade *c)
{
    c->i_p = c->i_r = c->i_z = 0.0;
    c->i_n = c->i_e = 0.0;
    c->yaw_ref = 0.0;
    c->n = 0;
}

static PyObject *Cascade_new(PyTypeObject *type, PyObject *args, PyObject *kw)
{
    Cascade *c = (Cascade *)type->tp_alloc(type, 0);
    if (c != NULL) {
        memset(&c->g, 0, sizeof c->g);
        c->have_gains = 0;
        cascade_reset_state(c);
    }
    return (PyObject *)c;
}

static PyObject *Cascade_set_gains(Cascade *c, PyObject *arg)
{
    PyObject *seq = PySequence_Fast(arg, "set_gains: a sequence of 47 numbers");
    if (seq == NULL)
        return NULL;
    if (PySequence_Fast_GET_SIZE(seq) != N_GAINS) {
        PyErr_Format(PyExc_ValueError, "set_gains: %d values expected, got %zd", N_GAINS,
                     PySequence_Fast_GET_SIZE(seq));
        Py_DECREF(seq);
        return NULL;
    }
    double v[N_GAINS - 1];
    for (int i = 0; i < N_GAINS - 1; i++) {
        v[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, i));
        if (v[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(seq);
            return NULL;
        }
    }
    int integ = PyObject_IsTrue(PySequence_Fast_GET_ITEM(seq, N_GAINS - 1));
    Py_DECREF(seq);
    if (integ < 0)
        return NULL;
    Gains *g = &c->g;
    double *dst[N_GAINS - 1] = {
        &g->pitch_kp, &g->pitch_ki, &g->pitch_kd, &g->roll_kp, &g->roll_ki, &g->roll_kd,
        &g->att_i_lim, &g->att_kb, &g->k_psi, &g->k_r, &g->yawrate_max,
        &g->k_z, &g->k_vz, &g->ki_z_pos, &g->ki_z_vpos, &g->ki_z_vel, &g->z_i_lim,
        &g->vz_max, &g->thrust_max_total,
        &g->k_xy, &g->k_vxy, &g->c_drag, &g->ki_vxy, &g->xy_i_lim, &g->xy_err_max,
        &g->vxy_max, &g->tilt_max, &g->weight, &g->inv_g,
        &g->m0t, &g->m0m, &g->m0l, &g->m1t, &g->m1m, &g->m1l, &g->m2t, &g->m2m, &g->m2l,
        &g->m3t, &g->m3m, &g->m3l, &g->my, &g->t_max, &g->c_u, &g->arm_a, &g->dt};
    for (int i = 0; i < N_GAINS - 1; i++)
        *dst[i] = v[i];
    g->integ = integ;
    c->have_gains = 1;
    Py_RETURN_NONE;
}

static PyObject *Cascade_reset(Cascade *c, PyObject *unused)
{
    cascade_reset_state(c);
    Py_RETURN_NONE;
}

static PyObject *Cascade_integrators(Cascade *c, PyObject *unused)
{
    return Py_BuildValue("(ddddddL)", c->i_p, c->i_r, c->i_z, c->i_n, c->i_e, c->yaw_ref,
                         c->n);
}

/* One control tick: mav/cascade.py QuadCascade.update, statement for statement. */
static PyObject *Cascade_update(Cascade *c, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "update(state, setpoint, out)");
        return NULL;
    }
    if (!c->have_gains) {
        PyErr_SetString(PyExc_RuntimeError, "update before set_gains");
        return NULL;
    }
    PyObject *so = args[0], *spo = args[1], *out = args[2];
    PyObject *a = fast_getattr(spo, name_armed);
    if (a == NULL)
        return NULL;
    int armed = PyObject_IsTrue(a);
    Py_DECREF(a);
    if (armed < 0)
        return NULL;
    if (!armed) {
        for (int i = 0; i < 4; i++)
            if (set_out(out, i, 0.0) < 0)
                return NULL;
        if (c->n)
            cascade_reset_state(c);
        Py_RETURN_NONE;
    }
    double s[S_N], sp[P_N];
    if (read_floats(so, s_names, s_cache, S_N, s) < 0 ||
        read_floats(spo, p_names, p_cache, P_N, sp) < 0)
        return NULL;
    const Gains *g = &c->g;
    const double v_max = g->vxy_max, e_max = g->xy_err_max, tilt_max = g->tilt_max;
    double f;

    /* attitude (ZYX Euler) from the quaternion */
    const double qw = s[S_QW], qx = s[S_QX], qy = s[S_QY], qz = s[S_QZ];
    const double r33 = 1.0 - 2.0 * (qx * qx + qy * qy);
    const double roll = atan2(2.0 * (qw * qx + qy * qz), r33);
    const double sp_ = 2.0 * (qw * qy - qz * qx);
    const double pitch = asin(sp_ > 1.0 ? 1.0 : (sp_ < -1.0 ? -1.0 : sp_));
    const double yaw = atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
    const double cy = cos(yaw);
    const double sy = sin(yaw);

    const long long n = c->n;
    if (n == 0)
        c->yaw_ref = yaw;

    /* horizontal: position -> velocity -> tilt, in the body-yaw frame (F, R) */
    const double vx = s[S_VX], vy = s[S_VY];
    const double vxb = cy * vx + sy * vy;
    const double vyb = cy * vy - sy * vx;
    double fx = sp[P_VX], fy = sp[P_VY];
    if (fx != fx)
        fx = 0.0;
    if (fy != fy)
        fy = 0.0;
    double fxb = cy * fx + sy * fy;
    double fyb = cy * fy - sy * fx;
    double v2 = fxb * fxb + fyb * fyb;
    if (v2 > v_max * v_max) {
        f = v_max / sqrt(v2);
        fxb *= f;
        fyb *= f;
    }
    const double px = sp[P_X], py = sp[P_Y];
    double vcx, vcy;
    if (px == px && py == py) {
        const double ex = px - s[S_X];
        const double ey = py - s[S_Y];
        double exb = cy * ex + sy * ey;
        double eyb = cy * ey - sy * ex;
        if (exb > e_max)
            exb = e_max;
        else if (exb < -e_max)
            exb = -e_max;
        if (eyb > e_max)
            eyb = e_max;
        else if (eyb < -e_max)
            eyb = -e_max;
        vcx = g->k_xy * exb + fxb;
        vcy = g->k_xy * eyb + fyb;
    } else {
        vcx = fxb;
        vcy = fyb;
    }
    v2 = vcx * vcx + vcy * vcy;
    if (v2 > v_max * v_max) {
        f = v_max / sqrt(v2);
        vcx *= f;
        vcy *= f;
    }
    double i_n = c->i_n, i_e = c->i_e;
    const double ixb = cy * i_n + sy * i_e;
    const double iyb = cy * i_e - sy * i_n;
    double pitch_ref = -(g->k_vxy * (vcx - vxb) + g->c_drag * fxb + ixb);
    double roll_ref = g->k_vxy * (vcy - vyb) + g->c_drag * fyb + iyb;
    const double ax = sp[P_AX];
    if (ax == ax) {
        const double ay = sp[P_AY];
        pitch_ref -= (cy * ax + sy * ay) * g->inv_g;
        roll_ref += (cy * ay - sy * ax) * g->inv_g;
    }
    const double t2 = pitch_ref * pitch_ref + roll_ref * roll_ref;
    const int tilt_sat = t2 > tilt_max * tilt_max;
    if (tilt_sat) {
        f = tilt_max / sqrt(t2);
        pitch_ref *= f;
        roll_ref *= f;
    }
    if (g->ki_vxy > 0.0 && !tilt_sat) {
        const double evx = vcx - vxb, evy = vcy - vyb;
        i_n += g->ki_vxy * g->dt * (cy * evx - sy * evy);
        i_e += g->ki_vxy * g->dt * (sy * evx + cy * evy);
        const double i2 = i_n * i_n + i_e * i_e;
        if (i2 > g->xy_i_lim * g->xy_i_lim) {
            f = g->xy_i_lim / sqrt(i2);
            i_n *= f;
            i_e *= f;
        }
        c->i_n = i_n;
        c->i_e = i_e;
    }

    /* vertical: altitude -> climb rate -> thrust (NED: up is -z) */
    const double vz = s[S_VZ];
    double fz = sp[P_VZ];
    if (fz != fz)
        fz = 0.0;
    const double zr = sp[P_Z];
    const int pos_mode = zr == zr;
    double ez, vzc;
    if (pos_mode) {
        ez = zr - s[S_Z];
        vzc = g->k_z * ez + fz;
    } else {
        ez = 0.0;
        vzc = fz;
    }
    int limited = 0;
    if (vzc > g->vz_max) {
        vzc = g->vz_max;
        limited = 1;
    } else if (vzc < -g->vz_max) {
        vzc = -g->vz_max;
        limited = 1;
    }
    double i_z = c->i_z;
    double thrust = g->weight + g->k_vz * (vz - vzc) + i_z;
    if (r33 > 0.5)
        thrust /= r33;
    else
        thrust *= 2.0;
    int t_sat = 0;
    if (thrust > g->thrust_max_total) {
        thrust = g->thrust_max_total;
        t_sat = 1;
    } else if (thrust < 0.0) {
        thrust = 0.0;
        t_sat = -1;
    }

    /* attitude PID (D on body rates) -> pitch / roll torques */
    const double e_p = pitch_ref - pitch;
    const double e_r = roll_ref - roll;
    double i_p = c->i_p;
    double i_r = c->i_r;
    const double tq_m = g->pitch_kp * e_p + i_p - g->pitch_kd * s[S_Q];
    const double tq_l = g->roll_kp * e_r + i_r - g->roll_kd * s[S_P];

    /* heading */
    const double r_max = g->yawrate_max;
    const double yr = sp[P_YAW], rr = sp[P_YAW_RATE];
    double yref, r_ff;
    if (yr == yr) {
        yref = yr;
        r_ff = 0.0;
    } else if (rr == rr) {
        r_ff = rr > r_max ? r_max : (rr < -r_max ? -r_max : rr);
        if (g->integ) {
            yref = c->yaw_ref + r_ff * g->dt;
            if (yref > PI_ || yref < -PI_)
                yref = py_mod(yref + PI_, TWO_PI_) - PI_;
        } else {
            yref = yaw;
        }
    } else {
        yref = c->yaw_ref;
        r_ff = 0.0;
    }
    c->yaw_ref = yref;
    double e_psi = yref - yaw;
    if (e_psi > PI_ || e_psi < -PI_)
        e_psi = py_mod(e_psi + PI_, TWO_PI_) - PI_;
    double rc = g->k_psi * e_psi + r_ff;
    if (rc > r_max)
        rc = r_max;
    else if (rc < -r_max)
        rc = -r_max;
    const double tq_n = g->k_r * (rc - s[S_R]);

    /* mixer: thrust, pitch, roll first; yaw gets the remaining headroom */
    const double t_max = g->t_max;
    double b1 = g->m0t * thrust + g->m0m * tq_m + g->m0l * tq_l;
    double b2 = g->m1t * thrust + g->m1m * tq_m + g->m1l * tq_l;
    double b3 = g->m2t * thrust + g->m2m * tq_m + g->m2l * tq_l;
    double b4 = g->m3t * thrust + g->m3m * tq_m + g->m3l * tq_l;
    b1 = b1 > t_max ? t_max : (b1 > 0.0 ? b1 : 0.0); /* NaN -> 0 */
    b2 = b2 > t_max ? t_max : (b2 > 0.0 ? b2 : 0.0);
    b3 = b3 > t_max ? t_max : (b3 > 0.0 ? b3 : 0.0);
    b4 = b4 > t_max ? t_max : (b4 > 0.0 ? b4 : 0.0);
    double d = g->my * tq_n; /* rotors 1, 2 get +d, rotors 3, 4 get -d */
    double h;
    if (d > 0.0) {
        /* Python's min(a, b, c, d): the first of the smallest */
        h = t_max - b1;
        if (t_max - b2 < h) h = t_max - b2;
        if (b3 < h) h = b3;
        if (b4 < h) h = b4;
        if (d > h)
            d = h;
    } else if (d < 0.0) {
        h = b1;
        if (b2 < h) h = b2;
        if (t_max - b3 < h) h = t_max - b3;
        if (t_max - b4 < h) h = t_max - b4;
        if (-d > h)
            d = -h;
    } else {
        d = 0.0; /* also for NaN */
    }
    b1 += d;
    b2 += d;
    b3 -= d;
    b4 -= d;
    const double c_u = g->c_u;
    if (set_out(out, 0, sqrt(b1 * c_u)) < 0 || set_out(out, 1, sqrt(b2 * c_u)) < 0 ||
        set_out(out, 2, sqrt(b3 * c_u)) < 0 || set_out(out, 3, sqrt(b4 * c_u)) < 0)
        return NULL;

    /* integrators (forward Euler; back-calculation on the achieved torque) */
    const double i_lim = g->att_i_lim;
    i_p += g->dt * g->pitch_ki * e_p + g->att_kb * (g->arm_a * (b1 - b2 + b3 - b4) - tq_m);
    i_r += g->dt * g->roll_ki * e_r + g->att_kb * (g->arm_a * (b2 + b3 - b1 - b4) - tq_l);
    c->i_p = i_p > i_lim ? i_lim : (i_p < -i_lim ? -i_lim : i_p);
    c->i_r = i_r > i_lim ? i_lim : (i_r < -i_lim ? -i_lim : i_r);
    double di;
    if (pos_mode)
        di = limited ? g->ki_z_vpos * (vz - vzc) : g->ki_z_vpos * (vz - vzc) - g->ki_z_pos * ez;
    else
        di = g->ki_z_vel * (vz - vzc);
    di *= g->dt;
    if (!((t_sat > 0 && di > 0.0) || (t_sat < 0 && di < 0.0))) {
        i_z += di;
        const double zi_lim = g->z_i_lim;
        c->i_z = i_z > zi_lim ? zi_lim : (i_z < -zi_lim ? -zi_lim : i_z);
    }
    c->n = n + 1;
    Py_RETURN_NONE;
}

static PyMethodDef Cascade_methods[] = {
    {"set_gains", (PyCFunction)Cascade_set_gains, METH_O,
     "set_gains(gains): the 47 fields of mav.cascade.Gains, in order"},
    {"reset", (PyCFunction)Cascade_reset, METH_NOARGS, "clear the integrators and heading"},
    {"integrators", (PyCFunction)Cascade_integrators, METH_NOARGS,
     "(i_p, i_r, i_z, i_n, i_e, yaw_ref, n): the controller's state"},
    {"update", (PyCFunction)(void (*)(void))Cascade_update, METH_FASTCALL,
     "update(state, setpoint, out): one control tick (mav.cascade.QuadCascade.update)"},
    {NULL, NULL, 0, NULL}};

static PyTypeObject CascadeType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "mav._fastpath.Cascade",
    .tp_basicsize = sizeof(Cascade),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The shared quad cascade and mixer (mav/cascade.py), compiled",
    .tp_new = Cascade_new,
    .tp_methods = Cascade_methods,
};
