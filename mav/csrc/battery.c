/* The battery model's per-tick step, compiled (included by fastpath.c). The reference is
 * mav.battery.Battery.step; same double operations in the same order (tests/test_fastpath_
 * encoders.py runs both on random packs and commands):
 *   i = p.i_avionics + _k_motor * (u1*u1*u1 + u2*u2*u2 + u3*u3*u3 + u4*u4*u4)
 *   current = i; consumed_mah += i * dt * (1000/3600); energy_j += _v_last * i * dt
 * battery_step(battery, dt, u1, u2, u3, u4) -> None */
static PyObject *n_p, *n_i_avionics, *n_k_motor, *n_current, *n_consumed, *n_energy, *n_v_last;

static int bat_init(void)
{
    n_p = PyUnicode_InternFromString("p");
    n_i_avionics = PyUnicode_InternFromString("i_avionics");
    n_k_motor = PyUnicode_InternFromString("_k_motor");
    n_current = PyUnicode_InternFromString("current");
    n_consumed = PyUnicode_InternFromString("consumed_mah");
    n_energy = PyUnicode_InternFromString("energy_j");
    n_v_last = PyUnicode_InternFromString("_v_last");
    return (n_p && n_i_avionics && n_k_motor && n_current && n_consumed && n_energy && n_v_last)
               ? 0 : -1;
}

static int get_double(PyObject *o, PyObject *name, double *out)
{
    PyObject *v = fast_getattr(o, name);
    if (v == NULL)
        return -1;
    *out = PyFloat_AsDouble(v);
    Py_DECREF(v);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

static int set_double(PyObject *o, PyObject *name, double x)
{
    PyObject *v = PyFloat_FromDouble(x);
    if (v == NULL)
        return -1;
    int rc = fast_setattr(o, name, v);
    Py_DECREF(v);
    return rc;
}

static PyObject *fp_battery_step(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "battery_step(battery, dt, u1, u2, u3, u4)");
        return NULL;
    }
    for (int k = 1; k < 6; k++)      /* not all floats: the reference's own arithmetic */
        if (!PyFloat_CheckExact(args[k]))
            return PyObject_CallMethod(args[0], "step", "OOOOO", args[1], args[2], args[3],
                                       args[4], args[5]);
    double a[5];
    for (int k = 0; k < 5; k++) {
        a[k] = PyFloat_AsDouble(args[k + 1]);
        if (a[k] == -1.0 && PyErr_Occurred())
            return NULL;
    }
    PyObject *bat = args[0];
    const double dt = a[0], u1 = a[1], u2 = a[2], u3 = a[3], u4 = a[4];
    PyObject *p = fast_getattr(bat, n_p);
    if (p == NULL)
        return NULL;
    double i_av, k_motor, consumed, energy, v_last;
    int rc = get_double(p, n_i_avionics, &i_av);
    Py_DECREF(p);
    if (rc < 0 || get_double(bat, n_k_motor, &k_motor) < 0)
        return NULL;
    const double i = i_av + k_motor * (u1 * u1 * u1 + u2 * u2 * u2 + u3 * u3 * u3 + u4 * u4 * u4);
    if (set_double(bat, n_current, i) < 0 || get_double(bat, n_consumed, &consumed) < 0 ||
        set_double(bat, n_consumed, consumed + i * dt * (1000.0 / 3600.0)) < 0 ||
        get_double(bat, n_v_last, &v_last) < 0 || get_double(bat, n_energy, &energy) < 0 ||
        set_double(bat, n_energy, energy + v_last * i * dt) < 0)
        return NULL;
    Py_RETURN_NONE;
}
