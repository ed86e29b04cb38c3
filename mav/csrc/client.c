/* The offboard client's per-tick calls, compiled (included by fastpath.c): its position
 * setpoint, its two 50 Hz telemetry handlers and its poll (below). The setpoint's reference is
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
static PyObject *n_t_, *n_target_system, *n_target_component, *n_tx, *n_signed_c,
    *n_fast_one, *n_fast_handlers, *n_datagram, *n_next_hb, *n_send_hb, *n_rx;

static int client_init(void)
{
    static const char *str[11] = {"t", "target_system", "target_component", "tx", "signed",
                                  "_fast_one", "_fast_handlers", "_datagram", "_next_hb",
                                  "send_heartbeat", "rx"};
    PyObject **dst[11] = {&n_t_, &n_target_system, &n_target_component, &n_tx, &n_signed_c,
                          &n_fast_one, &n_fast_handlers, &n_datagram, &n_next_hb, &n_send_hb,
                          &n_rx};
    for (int i = 0; i < 11; i++)
        if ((*dst[i] = PyUnicode_InternFromString(str[i])) == NULL)
            return -1;
    return 0;
}

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
    PyObject *r = link ? link_send(link, fr) : NULL;
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

/* client_poll(fallback, client, t) -> int: OffboardClient.poll (the reference) in one call:
 * client.t = t, then each datagram on client.link: exactly one valid frame of a fast-decoded
 * message (client._fast_one's one-call decoders) counted and handed to its handler when it is
 * from the target system, anything else to client._datagram; then the HEARTBEAT when due
 * (client.send_heartbeat). A signing client: fallback(t). */

static PyObject *fp_client_poll(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "client_poll(fallback, client, t)");
        return NULL;
    }

    PyObject *c = args[1], *t = args[2];
    PyObject *sg = fast_getattr(c, n_signed_c);
    int signed_ = sg ? PyObject_IsTrue(sg) : -1;
    Py_XDECREF(sg);
    if (signed_ != 0)
        return signed_ < 0 ? NULL : PyObject_CallOneArg(args[0], t);
    if (fast_setattr(c, n_t_, t) < 0)
        return NULL;
    PyObject *link = fast_getattr(c, n_link), *one = NULL, *n = PyLong_FromLong(0), *ret = NULL;
    if (link == NULL || n == NULL || (one = fast_getattr(c, n_fast_one)) == NULL)
        goto done;
    for (;;) {
        PyObject *data = link_recv(link);
        if (data == NULL)
            goto done;
        if (data == Py_None) {
            Py_DECREF(data);
            break;
        }
        PyObject *f = NULL;
        const uint8_t *d = (const uint8_t *)(PyBytes_Check(data) ? PyBytes_AS_STRING(data) : NULL);
        if (one != Py_None && d != NULL && PyBytes_GET_SIZE(data) > 11 && d[0] == MAGIC_V2) {
            PyObject *mid = PyLong_FromLong(d[7] | d[8] << 8 | d[9] << 16);
            PyObject *dec = NULL;             /* one.get(mid) */
            if (mid != NULL && PyDict_CheckExact(one)) {
                dec = PyDict_GetItemWithError(one, mid);
                dec = dec ? Py_NewRef(dec) : (PyErr_Occurred() ? NULL : Py_NewRef(Py_None));
            } else if (mid != NULL) {
                dec = PyObject_CallMethod(one, "get", "O", mid);
            }
            f = (dec && dec != Py_None) ? PyObject_CallOneArg(dec, data) : Py_XNewRef(dec);
            Py_XDECREF(dec);
            if (f != NULL && f != Py_None) {
                PyObject *stats = fast_getattr(c, n_stats), *tsys = NULL, *h = NULL;
                int e = stats ? incr(stats, n_rx) : -1;
                Py_XDECREF(stats);
                PyObject *n2 = e < 0 ? NULL : PyNumber_Add(n, py_one);
                if (n2 != NULL) {
                    Py_SETREF(n, n2);
                    tsys = fast_getattr(c, n_target_system);
                }
                int mine = -1;
                if (tsys != NULL) {
                    PyObject *src = PyLong_FromLong(d[5]);
                    mine = src ? PyObject_RichCompareBool(src, tsys, Py_EQ) : -1;
                    Py_XDECREF(src);
                    Py_DECREF(tsys);
                }
                if (mine > 0) {
                    PyObject *hs = fast_getattr(c, n_fast_handlers);
                    h = hs ? PyObject_GetItem(hs, mid) : NULL;
                    Py_XDECREF(hs);
                    PyObject *comp = h ? PyLong_FromLong(d[6]) : NULL;
                    PyObject *r = comp ? PyObject_CallFunctionObjArgs(h, f, comp, NULL) : NULL;
                    Py_XDECREF(comp);
                    Py_XDECREF(h);
                    mine = r ? 0 : -1;
                    Py_XDECREF(r);
                }
                Py_XDECREF(mid);
                Py_DECREF(f);
                Py_DECREF(data);
                if (mine < 0)
                    goto done;
                continue;
            }
            Py_XDECREF(mid);
            if (f == NULL) {
                Py_DECREF(data);
                goto done;
            }
            Py_DECREF(f);      /* None: not such a frame */
        }
        PyObject *k = PyObject_CallMethodOneArg(c, n_datagram, data);
        Py_DECREF(data);
        PyObject *n2 = k ? PyNumber_Add(n, k) : NULL;
        Py_XDECREF(k);
        if (n2 == NULL)
            goto done;
        Py_SETREF(n, n2);
    }
    PyObject *nh = fast_getattr(c, n_next_hb);
    int due = nh ? PyObject_RichCompareBool(t, nh, Py_GE) : -1;
    Py_XDECREF(nh);
    if (due < 0)
        goto done;
    if (due) {
        PyObject *r = PyObject_CallMethodOneArg(c, n_send_hb, t);
        if (r == NULL)
            goto done;
        Py_DECREF(r);
    }
    ret = Py_NewRef(n);
done:
    Py_XDECREF(link);
    Py_XDECREF(one);
    Py_XDECREF(n);
    return ret;
}
