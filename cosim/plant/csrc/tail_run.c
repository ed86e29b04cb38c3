/* The master's tick after the app, second part (included by tail.c, whose header says what
 * it is): the recorded row, the fast exit test and Tail.run. */

/* the row's bytes: spool.pack(*vals) as struct "<{n}d" packs them (the exact floats packed
 * here, anything else by pack itself, which converts or raises as the reference does) */
static PyObject *tail_row(Tail *self, PyObject *const *vals, Py_ssize_t n)
{
    if (n == self->ncols) {
        PyObject *b = PyBytes_FromStringAndSize(NULL, n * 8);
        if (b == NULL)
            return NULL;
        unsigned char *p = (unsigned char *)PyBytes_AS_STRING(b);
        Py_ssize_t i = 0;
        for (; i < n; i++) {
            PyObject *v = vals[i];
            double x;
            if (PyFloat_CheckExact(v)) {
                x = PyFloat_AS_DOUBLE(v);
            } else if (PyLong_CheckExact(v)) {   /* the phase index */
                x = PyLong_AsDouble(v);
                if (x == -1.0 && PyErr_Occurred()) {
                    PyErr_Clear();                /* pack raises as the reference does */
                    break;
                }
            } else {
                break;
            }
            if (PyFloat_Pack8(x, (char *)p + 8 * i, 1) < 0) {
                Py_DECREF(b);
                return NULL;
            }
        }
        if (i == n)
            return b;
        Py_DECREF(b);
    }
    return PyObject_Vectorcall(self->pack, vals, (size_t)n, NULL);
}

/* seq[i] (a new reference), as the reference's subscript */
static PyObject *item(PyObject *seq, Py_ssize_t i)
{
    if (PyTuple_CheckExact(seq) && i < PyTuple_GET_SIZE(seq))
        return Py_NewRef(PyTuple_GET_ITEM(seq, i));
    PyObject *ix = PyLong_FromSsize_t(i);
    PyObject *v = ix ? PyObject_GetItem(seq, ix) : NULL;
    Py_XDECREF(ix);
    return v;
}

/* the row of the reference: (t, *y, u1..u4, meas[0..2], sp[0] + home_n, sp[1] + home_e,
 * sp[2], pi) appended to the spool's rows; act = (t_ans, u1, u2, u3, u4) */
static int tail_record(Tail *self, PyObject *t, PyObject *y, PyObject *act, PyObject *meas,
                       PyObject *sp, PyObject *pi)
{
    PyObject *stack[ROW_MAX], **v = stack;
    Py_ssize_t n = 0, ny = PyList_GET_SIZE(y);
    if (ny + 12 > ROW_MAX && (v = PyMem_New(PyObject *, ny + 12)) == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    int rc = -1;
    v[n++] = Py_NewRef(t);
    for (Py_ssize_t i = 0; i < ny; i++)
        v[n++] = Py_NewRef(PyList_GET_ITEM(y, i));
    for (Py_ssize_t i = 1; i < 5; i++)
        v[n++] = Py_NewRef(PyTuple_GET_ITEM(act, i));
    for (Py_ssize_t i = 0; i < 3; i++) {
        PyObject *m = item(meas, i);
        if (m == NULL)
            goto done;
        v[n++] = m;
    }
    PyObject *home[2] = {self->home_n, self->home_e};
    for (Py_ssize_t i = 0; i < 3; i++) {
        PyObject *s = item(sp, i);
        if (s == NULL)
            goto done;
        if (i < 2) {
            PyObject *w = PyFloat_CheckExact(s) && PyFloat_CheckExact(home[i])
                ? PyFloat_FromDouble(PyFloat_AS_DOUBLE(s) + PyFloat_AS_DOUBLE(home[i]))
                : PyNumber_Add(s, home[i]);   /* setpoints: local -> world */
            Py_DECREF(s);
            if (w == NULL)
                goto done;
            s = w;
        }
        v[n++] = s;
    }
    v[n++] = Py_NewRef(pi);
    PyObject *b = tail_row(self, v, n);
    if (b != NULL) {
        rc = PyList_Append(self->rows, b);
        Py_DECREF(b);
    }
done:
    for (Py_ssize_t i = 0; i < n; i++)
        Py_DECREF(v[i]);
    if (v != stack)
        PyMem_Free(v);
    return rc;
}

/* y's item i as a double if it is an exact float, else NAN with *ok cleared */
static double yf(PyObject *y, int i, int *ok)
{
    PyObject *v = i < PyList_GET_SIZE(y) ? PyList_GET_ITEM(y, i) : NULL;
    if (v == NULL || !PyFloat_CheckExact(v)) {
        *ok = 0;
        return Py_NAN;
    }
    return PyFloat_AS_DOUBLE(v);
}

/* 1: ExitMonitor.check would return None and change nothing; 0: ask it */
static int tail_quiet(Tail *self, PyObject *y)
{
    if (!PyList_CheckExact(y))
        return 0;
    int ok = 1;
    double d = yf(y, self->iz, &ok), og = yf(y, self->ion, &ok), qx = yf(y, self->iqx, &ok),
           qy = yf(y, self->iqy, &ok), n = yf(y, self->ix, &ok), e = yf(y, self->iy, &ok);
    if (!ok || d - d != 0.0 || self->scene)
        return 0;
    if (!self->airborne && d < self->airborne_z)
        return 0;                                  /* the take-off is noted */
    if (self->airborne && (og > 0.5 || self->ground_ticks != 0))
        return 0;                                  /* touchdown bookkeeping */
    if (qx * qx + qy * qy > self->flip_pre)
        return 0;
    if (self->sitl)
        return 1;
    const double *a = self->box;
    return !(n < a[0] || n > a[1] || e < a[2] || e > a[3] || d < -self->ceiling);
}

/* the reference's step 7a: the app's setpoint and phase (its index, new phases appended) */
static int tail_phase(Tail *self, PyObject **sp, PyObject **pi)
{
    PyObject *ph;
    if (self->app != Py_None) {
        if ((*sp = PyObject_GetAttr(self->app, s_setpoint)) == NULL)
            return -1;
        if ((ph = PyObject_GetAttr(self->app, s_phase)) == NULL)
            return -1;
    } else {
        *sp = Py_NewRef(self->nan3);
        ph = Py_NewRef(self->none_phase);
    }
    PyObject *got = PyDict_GetItemWithError(self->phase_idx, ph);
    Py_XINCREF(got);        /* held: dropping ph below may run Python code */
    if (got == NULL && !PyErr_Occurred()) {
        got = PyLong_FromSsize_t(PyList_GET_SIZE(self->phases));
        if (got != NULL && (PyDict_SetItem(self->phase_idx, ph, got) < 0 ||
                            PyList_Append(self->phases, ph) < 0))
            Py_CLEAR(got);
    }
    Py_DECREF(ph);
    if (got == NULL)
        return -1;
    *pi = got;
    self->phase_index = PyLong_AsSsize_t(got);
    return self->phase_index == -1 && PyErr_Occurred() ? -1 : 0;
}

static PyObject *tail_run(Tail *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (!self->ready) {
        PyErr_SetString(PyExc_TypeError, "Tail: not initialised");
        return NULL;
    }
    if (nargs != 5 || !PyList_CheckExact(args[4])) {
        PyErr_SetString(PyExc_TypeError, "run(k, t_us, t, meas, y: list)");
        return NULL;
    }
    PyObject *k = args[0], *t_us = args[1], *t = args[2], *meas = args[3], *y = args[4];
    PyObject *data = NULL, *ans = NULL, *act = NULL, *sp = NULL, *pi = NULL, *vz = NULL,
             *w = NULL, *ynew = NULL, *ret = NULL;
    /* 5. HIL exchange: ODOMETRY out, HIL_ACTUATOR_CONTROLS stamped t_k back */
    self->stage = "onboard";
    PyObject *a2[2] = {t_us, meas};
    if ((data = PyObject_Vectorcall(self->encode, a2, 2, NULL)) == NULL ||
        (ans = PyObject_CallOneArg(self->exchange, data)) == NULL)
        goto done;
    if (ans == Py_None) {
        tail_raise(self, "onboard", PyUnicode_FromString("no HIL_ACTUATOR_CONTROLS answer"));
        goto done;
    }
    PyObject *dec = PyObject_CallOneArg(self->decode, ans);
    if (dec == NULL)
        goto done;
    if (dec == Py_None) {
        Py_DECREF(dec);
        Py_ssize_t len = PyObject_Size(ans);
        if (len >= 0)
            PyErr_Format(PyExc_ValueError, "not a valid HIL_ACTUATOR_CONTROLS frame (%zd bytes)",
                         len);
        goto done;
    }
    act = unpack_n(dec, 5);
    Py_DECREF(dec);
    if (act == NULL)
        goto done;
    int ne = PyObject_RichCompareBool(PyTuple_GET_ITEM(act, 0), t_us, Py_NE);
    if (ne < 0)
        goto done;
    if (ne) {
        tail_raise(self, "onboard", PyUnicode_FromFormat("HIL answer stamped %S us for %S us",
                                                         PyTuple_GET_ITEM(act, 0), t_us));
        goto done;
    }
    for (;;) {                      /* the master's GCS end: into the tlog */
        PyObject *r = PyObject_CallNoArgs(self->gcs_recv);
        if (r == NULL)
            goto done;
        Py_DECREF(r);
        if (r == Py_None)
            break;
    }
    /* 7a. record the tick (state at t_k, commands held over [t_k, t_k+1)) */
    if (tail_phase(self, &sp, &pi) < 0 || tail_record(self, t, y, act, meas, sp, pi) < 0)
        goto done;
    long long kk = PyLong_AsLongLong(k);
    if (kk == -1 && PyErr_Occurred())
        goto done;
    if ((kk & self->flush_mask) == self->flush_mask) {
        PyObject *r = PyObject_CallNoArgs(self->flush);
        if (r == NULL)
            goto done;
        Py_DECREF(r);
    }
    /* 6. the motor commands -> the plant, stepped to t_k+1 */
    if (self->ivz >= PyList_GET_SIZE(y)) {
        PyErr_SetString(PyExc_IndexError, "list index out of range");
        goto done;
    }
    vz = Py_NewRef(PyList_GET_ITEM(y, self->ivz));
    self->stage = "plant";
    if (self->gusty != Py_None) {
        PyObject *g = PyObject_CallOneArg(self->gusty, k);
        w = g ? unpack_n(g, 3) : NULL;
        Py_XDECREF(g);
        if (w == NULL)
            goto done;
    } else {
        w = Py_NewRef(self->wind);
    }
    PyObject *u[7] = {PyTuple_GET_ITEM(act, 1), PyTuple_GET_ITEM(act, 2),
                      PyTuple_GET_ITEM(act, 3), PyTuple_GET_ITEM(act, 4),
                      PyTuple_GET_ITEM(w, 0), PyTuple_GET_ITEM(w, 1), PyTuple_GET_ITEM(w, 2)};
    if ((ynew = PyObject_Vectorcall(self->plant_step, u, 7, NULL)) == NULL)
        goto done;
    /* 7b. exit conditions on the state at t_k+1 */
    if (tail_quiet(self, ynew)) {
        ret = Py_NewRef(ynew);
        goto done;
    }
    PyObject *u4 = PyTuple_Pack(4, u[0], u[1], u[2], u[3]);
    if (u4 == NULL)
        goto done;
    PyObject *a4[4] = {t, ynew, vz, u4};
    PyObject *ended = PyObject_Vectorcall(self->check, a4, 4, NULL);
    Py_DECREF(u4);
    if (ended == NULL || tail_sync(self) < 0) {
        Py_XDECREF(ended);
        goto done;
    }
    if (ended == Py_None) {
        Py_DECREF(ended);
        ret = Py_NewRef(ynew);
    } else {
        Py_XSETREF(self->ended, ended);
        ret = Py_NewRef(Py_None);
    }
done:
    Py_XDECREF(data);
    Py_XDECREF(ans);
    Py_XDECREF(act);
    Py_XDECREF(sp);
    Py_XDECREF(pi);
    Py_XDECREF(vz);
    Py_XDECREF(w);
    Py_XDECREF(ynew);
    return ret;
}

static PyObject *tail_get_stage(Tail *self, void *c) { return PyUnicode_FromString(self->stage); }
static PyObject *tail_get_ended(Tail *self, void *c)
{
    return Py_NewRef(self->ended ? self->ended : Py_None);
}
static PyObject *tail_get_phase_index(Tail *self, void *c)
{
    return PyLong_FromSsize_t(self->phase_index);
}

static PyMethodDef tail_methods[] = {
    {"run", (PyCFunction)(void (*)(void))tail_run, METH_FASTCALL,
     "run(k, t_us, t, meas, y) -> y, or None when the run ends (see .ended)"},
    {NULL, NULL, 0, NULL}};

static PyGetSetDef tail_getset[] = {
    {"stage", (getter)tail_get_stage, NULL, "the part running when run() raised", NULL},
    {"ended", (getter)tail_get_ended, NULL, "(reason, message) once run() returned None", NULL},
    {"phase_index", (getter)tail_get_phase_index, NULL, "the phase recorded last", NULL},
    {NULL, NULL, NULL, NULL, NULL}};

static PyTypeObject TailType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "cosim.plant._fmi2step.Tail",
    .tp_basicsize = sizeof(Tail),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "The master's tick after the app, compiled (see tail.c).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)tail_init,
    .tp_dealloc = (destructor)tail_dealloc,
    .tp_traverse = (traverseproc)tail_traverse,
    .tp_clear = (inquiry)tail_clear,
    .tp_methods = tail_methods,
    .tp_getset = tail_getset,
};
