/* GLOBAL_POSITION_INT, compiled (included by fastpath.c after telemetry.c). The reference is
 * mav/onboard/telemetry.py `Telemetry.emit_global_position`: the state's position through the
 * vehicle's FlatEarth (`wire.FlatEarth.to_int`: lat/lon in 1e-7 deg and altitude in mm,
 * rounded half to even as Python's round), the height above home in mm, the velocity in cm/s
 * and the heading in cdeg (`wire.clamp_int`: NaN -> 0, saturated, else rounded), the same
 * double operations in the same order (math.degrees is x * (180 / pi); Python's float `%`).
 *
 * emit_global(fallback, geo, vs, msgid, crc_extra, ch) -> None, bound with functools.partial
 * to all but `ch`: the message framed on ch.mav, counted in ch.stats[ch.tx_key] and sent on
 * ch.link. What the reference would raise on or sign (a value that does not round or fit its
 * field, a home that is not three floats, a signing link) goes to fallback(ch) before anything
 * is changed. Tested byte for byte against the reference (tests/test_fastpath_encoders.py).
 */
static PyObject *n_lat0, *n_lon0, *n_alt0, *n_dlat, *n_dlon, *n_home;

static int gp_init(void)
{
    n_lat0 = PyUnicode_InternFromString("lat0_deg");
    n_lon0 = PyUnicode_InternFromString("lon0_deg");
    n_alt0 = PyUnicode_InternFromString("alt0_m");
    n_dlat = PyUnicode_InternFromString("_dlat_dn");
    n_dlon = PyUnicode_InternFromString("_dlon_de");
    n_home = PyUnicode_InternFromString("home");
    return (n_lat0 && n_lon0 && n_alt0 && n_dlat && n_dlon && n_home) ? 0 : -1;
}

/* wire.clamp_int */
static long long clamp_round(double v, long long lo, long long hi)
{
    if (v != v)
        return 0;
    if (v >= (double)hi)
        return hi;
    if (v <= (double)lo)
        return lo;
    return (long long)nearbyint(v);
}

/* round(v) as an int32 field: 1 and *out, or 0 when Python would raise or struct would not
 * pack it */
static int round_i32(double v, long long *out)
{
    if (!(fabs(v) < 3.0e9))
        return 0;
    double r = nearbyint(v);
    if (r < -2147483648.0 || r > 2147483647.0)
        return 0;
    *out = (long long)r;
    return 1;
}

static void put_le(uint8_t *p, unsigned long long v, int n)
{
    for (int i = 0; i < n; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static PyObject *fp_emit_global(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "emit_global(fallback, geo, vs, msgid, crc_extra, ch)");
        return NULL;
    }
    PyObject *geo = args[1], *vs = args[2], *ch = args[5];
    long msgid = PyLong_AsLong(args[3]), extra = PyLong_AsLong(args[4]);
    if (PyErr_Occurred())
        return NULL;
    double g[5], s[13], hz = 0.0;
    PyObject *gn[5] = {n_lat0, n_lon0, n_alt0, n_dlat, n_dlon};
    static SlotEntry gc[5];
    if (read_floats(geo, gn, gc, 5, g) < 0)
        return NULL;
    PyObject *state = fast_getattr(vs, n_state);
    int rc = state ? read_floats(state, t_names, t_cache, T_N, s) : -1;   /* qw..r, x..vz */
    Py_XDECREF(state);
    if (rc < 0)
        return NULL;
    PyObject *home = fast_getattr(vs, n_home);
    if (home == NULL)
        return NULL;
    int have_home = home != Py_None, ok = 1;
    if (have_home) {
        PyObject *h2 = (PyTuple_CheckExact(home) && PyTuple_GET_SIZE(home) == 3)
                           ? PyTuple_GET_ITEM(home, 2) : NULL;
        ok = h2 != NULL && PyFloat_CheckExact(h2);
        if (ok)
            hz = PyFloat_AS_DOUBLE(h2);
    }
    Py_DECREF(home);
    const double qw = s[T_QW], qx = s[T_QX], qy = s[T_QY], qz = s[T_QZ];
    const double n = s[T_X], e = s[T_Y], d = s[T_Z];
    /* FlatEarth.to_geodetic, then to_int */
    double lon = g[1] + e * g[4];
    lon = py_mod(lon + 180.0, 360.0) - 180.0;
    const double lat = g[0] + n * g[3], alt = g[2] - d;
    long long lat_e7 = 0, lon_e7 = 0, alt_mm = 0;
    ok = ok && round_i32(lat * 1e7, &lat_e7) && round_i32(lon * 1e7, &lon_e7) &&
         round_i32(alt * 1000.0, &alt_mm);
    PyObject *mav = ok ? fast_getattr(ch, n_mav) : NULL;
    int signing = mav ? signs_outgoing(mav) : 0;
    if (signing < 0) {
        Py_DECREF(mav);
        return NULL;
    }
    if (!ok || signing) {
        Py_XDECREF(mav);
        return PyObject_CallOneArg(args[0], ch);
    }
    const double agl = have_home ? hz - d : 0.0;
    const long long rel = clamp_round(agl * 1000.0, -(1LL << 31), (1LL << 31) - 1);
    const double yaw = py_atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
    const long long hdg = clamp_round(py_mod(yaw * (180.0 / PI_), 360.0) * 100.0, 0, 35999);
    const long long v0 = clamp_round(s[T_VX] * 100.0, -32768, 32767);
    const long long v1 = clamp_round(s[T_VY] * 100.0, -32768, 32767);
    const long long v2 = clamp_round(s[T_VZ] * 100.0, -32768, 32767);
    PyObject *t_us = fast_getattr(vs, n_t_us);
    PyObject *q = t_us ? PyNumber_FloorDivide(t_us, py_thousand) : NULL;
    Py_XDECREF(t_us);
    PyObject *w = q ? PyNumber_And(q, py_u32_mask) : NULL;
    Py_XDECREF(q);
    unsigned long tboot = w ? PyLong_AsUnsignedLong(w) : 0;
    Py_XDECREF(w);
    if (w == NULL || PyErr_Occurred()) {
        Py_DECREF(mav);
        return NULL;
    }
    uint8_t pl[28];
    put_le(pl, tboot, 4);
    put_le(pl + 4, (unsigned long long)lat_e7, 4);
    put_le(pl + 8, (unsigned long long)lon_e7, 4);
    put_le(pl + 12, (unsigned long long)alt_mm, 4);
    put_le(pl + 16, (unsigned long long)rel, 4);
    put_le(pl + 20, (unsigned long long)v0, 2);
    put_le(pl + 22, (unsigned long long)v1, 2);
    put_le(pl + 24, (unsigned long long)v2, 2);
    put_le(pl + 26, (unsigned long long)hdg, 2);
    PyObject *data = frame_on(mav, msgid, (uint8_t)extra, pl, (Py_ssize_t)sizeof pl);
    Py_DECREF(mav);
    if (data == NULL)
        return NULL;
    PyObject *r = chan_send(ch, data);      /* Chan.send */
    Py_DECREF(data);
    return r;
}
