/* The offboard client's position setpoint, compiled (included by fastpath.c). The reference is
 * mav.client.OffboardClient.set_position_target (and its _setpoint): the type_mask from the
 * NaN arguments, SET_POSITION_TARGET_LOCAL_NED packed ("<I11fHBBB", time_boot_ms =
 * int(client.t * 1000.0) & 0xFFFFFFFF), framed on client.mav, counted in client.stats["tx"]
 * and sent on client.link.
 *
 * client_setpoint(fallback, client, x, y, z, yaw=nan, vx=nan, vy=nan, vz=nan, yaw_rate=nan)
 *
 * Only the per-tick case runs here: positional float arguments, a finite clock, targets in
 * 0..255 and a link that does not sign. Anything else returns fallback(x, y, z, ...) (the
 * reference, with the keywords as given) before anything is changed. Floats are packed by
 * PyFloat_Pack4 as struct's "<f" is (too large: OverflowError, and nothing is sent or
 * counted, as the reference). Tested byte for byte against the reference
 * (tests/test_fastpath_encoders.py).
 */
#define CS_MSGID 84
#define CS_CRC_EXTRA 143
#define CS_PAYLOAD 53
static PyObject *n_t_, *n_target_system, *n_target_component, *n_tx, *n_send_c;

static PyObject *client_fallback(PyObject *const *args, Py_ssize_t nargs, PyObject *kwnames)
{
    return PyObject_Vectorcall(args[0], args + 2, (size_t)(nargs - 2), kwnames);
}

static int cs_attr_u8(PyObject *o, PyObject *name, long *out)
{
    PyObject *v = fast_getattr(o, name);
    if (v == NULL)
        return -1;
    *out = PyLong_Check(v) ? PyLong_AsLong(v) : -1;
    Py_DECREF(v);
    if (*out == -1 && PyErr_Occurred())
        PyErr_Clear();
    return 0;
}

static PyObject *fp_client_setpoint(PyObject *mod, PyObject *const *args, Py_ssize_t nargsf,
                                    PyObject *kwnames)
{
    Py_ssize_t nargs = PyVectorcall_NARGS(nargsf);
    if (nargs < 2) {
        PyErr_SetString(PyExc_TypeError, "client_setpoint(fallback, client, x, y, z, ...)");
        return NULL;
    }
    if (n_t_ == NULL && ((n_t_ = PyUnicode_InternFromString("t")) == NULL ||
                         (n_target_system = PyUnicode_InternFromString("target_system")) == NULL ||
                         (n_target_component = PyUnicode_InternFromString("target_component"))
                             == NULL || (n_tx = PyUnicode_InternFromString("tx")) == NULL ||
                         (n_send_c = PyUnicode_InternFromString("send")) == NULL))
        return NULL;
    Py_ssize_t n = nargs - 2;
    if (kwnames != NULL || n < 3 || n > 8)
        return client_fallback(args, nargs, kwnames);
    double v[8] = {0, 0, 0, Py_NAN, Py_NAN, Py_NAN, Py_NAN, Py_NAN};  /* x y z yaw vx vy vz rate */
    for (Py_ssize_t i = 0; i < n; i++) {
        if (!PyFloat_Check(args[2 + i]))
            return client_fallback(args, nargs, kwnames);
        v[i] = PyFloat_AS_DOUBLE(args[2 + i]);
    }
    PyObject *c = args[1];
    PyObject *t = fast_getattr(c, n_t_);
    if (t == NULL)
        return NULL;
    double ms = PyFloat_Check(t) ? PyFloat_AS_DOUBLE(t) * 1000.0 : Py_NAN;
    Py_DECREF(t);
    long tsys, tcomp;
    if (cs_attr_u8(c, n_target_system, &tsys) < 0 || cs_attr_u8(c, n_target_component, &tcomp) < 0)
        return NULL;
    if (!(fabs(ms) < 9.0e18) || tsys < 0 || tsys > 255 || tcomp < 0 || tcomp > 255)
        return client_fallback(args, nargs, kwnames);
    PyObject *mav = fast_getattr(c, n_mav);
    if (mav == NULL)
        return NULL;
    int signing = signs_outgoing(mav);
    if (signing != 0) {
        Py_DECREF(mav);
        return signing < 0 ? NULL : client_fallback(args, nargs, kwnames);
    }
    /* set_position_target's mask and zeros, in its order */
    double x = v[0], y = v[1], z = v[2], yaw = v[3], vx = v[4], vy = v[5], vz = v[6];
    double rate = v[7];
    unsigned mask = 64 | 128 | 256;
    if (!(vx == vx && vy == vy)) {
        mask |= 8 | 16;
        vx = vy = 0.0;
    }
    if (vz != vz) {
        mask |= 32;
        vz = 0.0;
    }
    if (yaw != yaw) {
        mask |= 1024;
        yaw = 0.0;
    }
    if (rate != rate) {
        mask |= 2048;
        rate = 0.0;
    }
    uint8_t pl[CS_PAYLOAD];
    uint32_t tb = (uint32_t)((unsigned long long)(long long)ms & 0xFFFFFFFFULL);
    for (int i = 0; i < 4; i++)
        pl[i] = (uint8_t)(tb >> (8 * i));
    const double f[11] = {x, y, z, vx, vy, vz, 0.0, 0.0, 0.0, yaw, rate};
    for (int i = 0; i < 11; i++)
        if (PyFloat_Pack4(f[i], (char *)pl + 4 + 4 * i, 1) < 0) {
            Py_DECREF(mav);
            return NULL;
        }
    pl[48] = (uint8_t)(mask & 0xFF);
    pl[49] = (uint8_t)(mask >> 8);
    pl[50] = (uint8_t)tsys;
    pl[51] = (uint8_t)tcomp;
    pl[52] = 1;                                   /* MAV_FRAME_LOCAL_NED */
    PyObject *stats = fast_getattr(c, n_stats);
    int rc = stats ? incr(stats, n_tx) : -1;
    Py_XDECREF(stats);
    PyObject *fr = rc < 0 ? NULL : frame_on(mav, CS_MSGID, CS_CRC_EXTRA, pl, CS_PAYLOAD);
    Py_DECREF(mav);
    if (fr == NULL)
        return NULL;
    PyObject *link = fast_getattr(c, n_link);
    PyObject *r = link ? PyObject_CallMethodOneArg(link, n_send_c, fr) : NULL;
    Py_XDECREF(link);
    Py_DECREF(fr);
    if (r == NULL)
        return NULL;
    Py_DECREF(r);
    Py_RETURN_NONE;
}

/* set_halves(obj, name_a, name_b, f, compid): obj.name_a = f[1:4], obj.name_b = f[4:7] (the
 * same float objects, new tuples), for the client's ATTITUDE and LOCAL_POSITION_NED handlers
 * (mav.client.OffboardClient._on_attitude / _on_local_position, the reference) */
static PyObject *fp_set_halves(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5 || !PyTuple_Check(args[3]) || PyTuple_GET_SIZE(args[3]) < 7) {
        PyErr_SetString(PyExc_TypeError, "set_halves(obj, name_a, name_b, f: tuple, compid)");
        return NULL;
    }
    PyObject *f = args[3];
    for (int h = 0; h < 2; h++) {
        PyObject *t = PyTuple_Pack(3, PyTuple_GET_ITEM(f, 1 + 3 * h), PyTuple_GET_ITEM(f, 2 + 3 * h),
                                   PyTuple_GET_ITEM(f, 3 + 3 * h));
        if (t == NULL)
            return NULL;
        int rc = fast_setattr(args[0], args[1 + h], t);
        Py_DECREF(t);
        if (rc < 0)
            return NULL;
    }
    Py_RETURN_NONE;
}
