/* The per-tick telemetry encoders, compiled (included by fastpath.c).
 *
 * ATTITUDE and LOCAL_POSITION_NED are most of what the vehicle streams (50 Hz each to the
 * offboard app by default, 20 and 10 Hz to a ground station). In Python each is a state read,
 * an Euler conversion, a struct pack and a framing call (mav/onboard/telemetry.py, the
 * reference); here it is one call that reads the VehicleState and the link's MAVLink object
 * (seq, srcSystem, srcComponent; seq advanced as `wire.frame` does) and returns the frame.
 *
 * Same bytes as the reference (tests/test_fastpath.py): the same double operations in the same
 * order (ATTITUDE's Euler angles as wire.euler_from_quat, with its clamp of asin's argument,
 * NaN -> -1), the same libm atan2/asin that Python's math module calls (with math.atan2's
 * special values: py_atan2), and float fields
 * packed by PyFloat_Pack4 as struct's "<f" does (a value too large for a float raises
 * OverflowError, as struct.pack does). A signing link gets None: the reference signs.
 */

enum { TM_ATTITUDE = 0, TM_LOCAL_POSITION_NED = 1, TM_POSITION_TARGET = 2 };
static PyObject *n_seq, *n_src_system, *n_src_component, *n_signing, *n_sign_outgoing;
enum { T_QW, T_QX, T_QY, T_QZ, T_P, T_Q, T_R, T_X, T_Y, T_Z, T_VX, T_VY, T_VZ, T_N };
static const char *T_NAMES[T_N] = {"qw", "qx", "qy", "qz", "p", "q", "r", "x", "y", "z",
                                   "vx", "vy", "vz"};
static PyObject *t_names[T_N];
static SlotEntry t_cache[T_N];
static PyObject *py_thousand, *py_u32_mask, *py_one;
static PyObject *n_state, *n_mav, *n_stats, *n_tx_key, *n_link, *n_setpoint;

static int tm_init(void)
{
    for (int i = 0; i < T_N; i++)
        if ((t_names[i] = PyUnicode_InternFromString(T_NAMES[i])) == NULL)
            return -1;
    n_seq = PyUnicode_InternFromString("seq");
    n_src_system = PyUnicode_InternFromString("srcSystem");
    n_src_component = PyUnicode_InternFromString("srcComponent");
    n_signing = PyUnicode_InternFromString("signing");
    n_sign_outgoing = PyUnicode_InternFromString("sign_outgoing");
    py_thousand = PyLong_FromLong(1000);
    py_one = PyLong_FromLong(1);
    n_state = PyUnicode_InternFromString("state");
    n_mav = PyUnicode_InternFromString("mav");
    n_stats = PyUnicode_InternFromString("stats");
    n_tx_key = PyUnicode_InternFromString("tx_key");
    n_link = PyUnicode_InternFromString("link");
    n_setpoint = PyUnicode_InternFromString("setpoint");
    if (!py_one || !n_state || !n_mav || !n_stats || !n_tx_key || !n_link || !n_setpoint)
        return -1;
    py_u32_mask = PyLong_FromUnsignedLong(0xFFFFFFFFUL);
    if (!n_seq || !n_src_system || !n_src_component || !n_signing || !n_sign_outgoing ||
        !py_thousand || !py_u32_mask)
        return -1;
    return 0;
}

static long get_long_attr(PyObject *o, PyObject *name)
{
    PyObject *v = fast_getattr(o, name);
    if (v == NULL)
        return -1;
    long r = PyLong_AsLong(v);
    Py_DECREF(v);
    return r;
}

/* Python's math.atan2 (CPython's m_atan2): C99's special values, and a NaN argument gives
 * the positive quiet NaN (libm may return the argument's NaN, sign included) */
static double py_atan2(double y, double x)
{
    if (isnan(x) || isnan(y))
        return (double)NAN;
    if (isinf(y)) {
        if (isinf(x))
            return copysign(copysign(1.0, x) == 1.0 ? 0.25 * PI_ : 0.75 * PI_, y);
        return copysign(0.5 * PI_, y);
    }
    if (isinf(x) || y == 0.0)
        return copysign(copysign(1.0, x) == 1.0 ? 0.0 : PI_, y);
    return atan2(y, x);
}

/* 1 if mav signs what it sends (then the Python reference frames it), 0 if not, -1 error */
static int signs_outgoing(PyObject *mav)
{
    PyObject *sg = fast_getattr(mav, n_signing);
    if (sg == NULL)
        return -1;
    PyObject *so = fast_getattr(sg, n_sign_outgoing);
    Py_DECREF(sg);
    if (so == NULL)
        return -1;
    int signing = PyObject_IsTrue(so);
    Py_DECREF(so);
    return signing;
}

/* the frame of payload pl[0:n] on mav (its seq, advanced as wire.frame does; its srcSystem and
 * srcComponent) */
static PyObject *frame_on(PyObject *mav, long msgid, uint8_t extra, const uint8_t *pl,
                          Py_ssize_t n)
{
    long seq = get_long_attr(mav, n_seq);
    if (seq == -1 && PyErr_Occurred())
        return NULL;
    long sys = get_long_attr(mav, n_src_system);
    if (sys == -1 && PyErr_Occurred())
        return NULL;
    long comp = get_long_attr(mav, n_src_component);
    if (comp == -1 && PyErr_Occurred())
        return NULL;
    PyObject *next = PyLong_FromLong((seq + 1) & 0xFF);
    if (next == NULL)
        return NULL;
    int rc = fast_setattr(mav, n_seq, next);
    Py_DECREF(next);
    if (rc < 0)
        return NULL;
    return frame_bytes(seq, sys, comp, msgid, extra, pl, n);
}

/* frame_on(mav, msgid, crc_extra, payload) -> bytes | None: wire.frame(mav, ...) in one call
 * for a link that does not sign (None if it does: the reference signs) */
static PyObject *fp_frame_on(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4 || !PyBytes_Check(args[3])) {
        PyErr_SetString(PyExc_TypeError, "frame_on(mav, msgid, crc_extra, payload: bytes)");
        return NULL;
    }
    long msgid = PyLong_AsLong(args[1]);
    long extra = PyLong_AsLong(args[2]);
    if (PyErr_Occurred())
        return NULL;
    Py_ssize_t n = PyBytes_GET_SIZE(args[3]);
    if (n < 1 || n > 255) {
        PyErr_SetString(PyExc_ValueError, "payload must be 1..255 bytes");
        return NULL;
    }
    int signing = signs_outgoing(args[0]);
    if (signing < 0)
        return NULL;
    if (signing)
        Py_RETURN_NONE;
    return frame_on(args[0], msgid, (uint8_t)extra, (const uint8_t *)PyBytes_AS_STRING(args[3]),
                    n);
}

/* POSITION_TARGET_LOCAL_NED of the Setpoint `sp` (Telemetry.emit_position_target: type_mask
 * from the NaN fields, each then sent as 0; no acceleration; MAV_FRAME_LOCAL_NED), payload
 * "<I11fHB" */
static PyObject *target_msg(long msgid, long extra, PyObject *mav, PyObject *sp,
                            unsigned long tboot)
{
    static const unsigned bits[8] = {1, 2, 4, 8, 16, 32, 1024, 2048};
    double f[8];
    if (read_floats(sp, p_names, p_cache, 8, f) < 0)      /* x y z vx vy vz yaw yaw_rate */
        return NULL;
    unsigned mask = 64 | 128 | 256;
    for (int i = 0; i < 8; i++)
        if (f[i] != f[i]) {
            mask |= bits[i];
            f[i] = 0.0;
        }
    const double v[11] = {f[0], f[1], f[2], f[3], f[4], f[5], 0.0, 0.0, 0.0, f[6], f[7]};
    uint8_t pl[51];
    for (int i = 0; i < 4; i++)
        pl[i] = (uint8_t)((tboot >> (8 * i)) & 0xFF);
    for (int i = 0; i < 11; i++)
        if (PyFloat_Pack4(v[i], (char *)pl + 4 + 4 * i, 1) < 0)
            return NULL;
    pl[48] = (uint8_t)(mask & 0xFF);
    pl[49] = (uint8_t)(mask >> 8);
    pl[50] = 1;                                   /* MAV_FRAME_LOCAL_NED */
    return frame_on(mav, msgid, (uint8_t)extra, pl, (Py_ssize_t)sizeof pl);
}

/* ATTITUDE (kind 0: time_boot_ms, roll, pitch, yaw, p, q, r) or LOCAL_POSITION_NED (kind 1:
 * time_boot_ms, x, y, z, vx, vy, vz) of `state` framed on `mav`, both payloads <I6f, or
 * POSITION_TARGET_LOCAL_NED (kind 2) of the Setpoint passed as `state`, stamped
 * time_boot_ms = (t_us // 1000) & 0xFFFFFFFF (the vehicle clock, us). None on a signing link. */
static PyObject *state_msg(long kind, long msgid, long extra, PyObject *mav, PyObject *state,
                           PyObject *t_us)
{
    /* time_boot_ms with Python's integer semantics */
    PyObject *q = PyNumber_FloorDivide(t_us, py_thousand);
    if (q == NULL)
        return NULL;
    PyObject *w = PyNumber_And(q, py_u32_mask);
    Py_DECREF(q);
    if (w == NULL)
        return NULL;
    unsigned long tboot = PyLong_AsUnsignedLong(w);
    Py_DECREF(w);
    if (PyErr_Occurred())
        return NULL;
    if (kind != TM_ATTITUDE && kind != TM_LOCAL_POSITION_NED && kind != TM_POSITION_TARGET) {
        PyErr_SetString(PyExc_ValueError, "state_msg: kind must be 0, 1 or 2");
        return NULL;
    }
    int signing = signs_outgoing(mav);
    if (signing < 0)
        return NULL;
    if (signing)
        Py_RETURN_NONE;
    if (kind == TM_POSITION_TARGET)
        return target_msg(msgid, extra, mav, state, tboot);

    double v[6];
    if (kind == TM_ATTITUDE) {
        double s[7];
        if (read_floats(state, t_names + T_QW, t_cache + T_QW, 7, s) < 0)
            return NULL;
        const double qw = s[0], qx = s[1], qy = s[2], qz = s[3];
        v[0] = py_atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy));
        const double sp = 2.0 * (qw * qy - qz * qx);
        v[1] = asin((-1.0 < sp && sp < 1.0) ? sp : (sp >= 1.0 ? 1.0 : -1.0));
        v[2] = py_atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
        v[3] = s[4];
        v[4] = s[5];
        v[5] = s[6];
    } else if (read_floats(state, t_names + T_X, t_cache + T_X, 6, v) < 0) {
        return NULL;
    }
    uint8_t pl[28];
    pl[0] = (uint8_t)(tboot & 0xFF);
    pl[1] = (uint8_t)((tboot >> 8) & 0xFF);
    pl[2] = (uint8_t)((tboot >> 16) & 0xFF);
    pl[3] = (uint8_t)((tboot >> 24) & 0xFF);
    for (int i = 0; i < 6; i++)
        if (PyFloat_Pack4(v[i], pl + 4 + 4 * i, 1) < 0)
            return NULL;
    return frame_on(mav, msgid, (uint8_t)extra, pl, (Py_ssize_t)sizeof pl);
}

/* the (kind, msgid, crc_extra) arguments */
static int three_longs(PyObject *const *args, long *k)
{
    for (int i = 0; i < 3; i++)
        k[i] = PyLong_AsLong(args[i]);
    return PyErr_Occurred() ? -1 : 0;
}

/* state_msg(kind, msgid, crc_extra, mav, state, t_us) -> bytes | None (see above) */
static PyObject *fp_state_msg(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError,
                        "state_msg(kind, msgid, crc_extra, mav, state, t_us)");
        return NULL;
    }
    long k[3];
    if (three_longs(args, k) < 0)
        return NULL;
    return state_msg(k[0], k[1], k[2], args[3], args[4], args[5]);
}

/* Chan.send(data): stats[tx_key] += 1; link.send(data) -> its result */
static PyObject *chan_send(PyObject *ch, PyObject *data)
{
    PyObject *stats = fast_getattr(ch, n_stats);
    PyObject *key = stats ? fast_getattr(ch, n_tx_key) : NULL;
    PyObject *old = key ? PyObject_GetItem(stats, key) : NULL;
    PyObject *inc = old ? PyNumber_Add(old, py_one) : NULL;
    int rc = inc ? PyObject_SetItem(stats, key, inc) : -1;
    Py_XDECREF(stats);
    Py_XDECREF(key);
    Py_XDECREF(old);
    Py_XDECREF(inc);
    PyObject *link = rc < 0 ? NULL : fast_getattr(ch, n_link);
    PyObject *r = link ? link_send(link, data) : NULL;
    Py_XDECREF(link);
    return r;
}

/* emit_state(kind, msgid, crc_extra, fallback, vs, ch) -> None: a periodic stream's emit
 * (Telemetry.emit_attitude / emit_local_position, then Chan.send) in one call, bound with
 * functools.partial to all but `ch`: the message of vs.state at vs.t_us on ch.mav, counted in
 * ch.stats[ch.tx_key] and sent on ch.link. A signing link: fallback(ch) (the Python emitter). */
static PyObject *fp_emit_state(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "emit_state(kind, msgid, crc_extra, fallback, vs, ch)");
        return NULL;
    }
    long k[3];
    if (three_longs(args, k) < 0)
        return NULL;
    const long kind = k[0], msgid = k[1], extra = k[2];
    PyObject *vs = args[4], *ch = args[5];
    PyObject *state = fast_getattr(vs, kind == TM_POSITION_TARGET ? n_setpoint : n_state);
    if (state == NULL)
        return NULL;
    PyObject *t_us = fast_getattr(vs, n_t_us);
    PyObject *mav = t_us ? fast_getattr(ch, n_mav) : NULL;
    PyObject *data = mav ? state_msg(kind, msgid, extra, mav, state, t_us) : NULL;
    Py_DECREF(state);
    Py_XDECREF(t_us);
    Py_XDECREF(mav);
    if (data == NULL)
        return NULL;
    if (data == Py_None) {
        Py_DECREF(data);
        return PyObject_CallOneArg(args[3], ch);
    }
    PyObject *r = chan_send(ch, data);
    Py_DECREF(data);
    return r;
}
