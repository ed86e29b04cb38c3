/* The vehicle's tick, compiled: its telemetry when something is due (included by fastpath.c
 * between tick.c and tick_run.c). The reference is mav/onboard/telemetry.py: `publish` and its
 * `_emit_due`. The common case runs here: no link signs, no event message raised by the parts
 * (HEARTBEAT, EXTENDED_SYS_STATE, HOME_POSITION, MISSION_CURRENT) and no PARAM_VALUE queued;
 * then publish only emits the streams due on each link, in order, which emit_due does as
 * _emit_due does (the same heap of (next_us, index) and the same heapq functions, the due
 * streams sorted, each stream's `emit(ch)` called: compiled or Python). Anything else calls
 * the Python publish. Tested with the tick (tests/test_tick.py: stream rates changed, streams
 * turned off and on, signed links).
 */

/* Telemetry._emit_due(ch, t) */
static int emit_due(Tick *self, PyObject *ch, PyObject *t)
{
    PyObject *sched = attr(ch, K_schedule), *due = NULL, *streams = NULL;
    int rc = -1;
    if (sched == NULL)
        return -1;
    if (sched == Py_None) {
        Py_DECREF(sched);
        PyObject *r = PyObject_CallMethodNoArgs(ch, K[K_recompute_due]);
        if (r == NULL)
            return -1;
        Py_DECREF(r);
        if ((sched = attr(ch, K_schedule)) == NULL)
            return -1;
    }
    if (!PyList_Check(sched)) {
        PyErr_SetString(PyExc_TypeError, "Chan.schedule must be a list");
        goto done;
    }
    if ((due = PyList_New(0)) == NULL)
        goto done;
    while (PyList_GET_SIZE(sched) > 0) {
        PyObject *top = PyList_GET_ITEM(sched, 0);
        PyObject *when = PySequence_GetItem(top, 0);
        int now = when ? PyObject_RichCompareBool(when, t, Py_LE) : -1;
        Py_XDECREF(when);
        if (now < 0)
            goto done;
        if (!now)
            break;
        PyObject *item = PyObject_CallOneArg(self->r[R_HEAPPOP], sched);
        PyObject *idx = item ? PySequence_GetItem(item, 1) : NULL;
        Py_XDECREF(item);
        int e = idx ? PyList_Append(due, idx) : -1;
        Py_XDECREF(idx);
        if (e < 0)
            goto done;
    }
    if (PyList_GET_SIZE(due) > 1 && PyList_Sort(due) < 0)
        goto done;
    if ((streams = attr(ch, K_streams)) == NULL)
        goto done;
    for (Py_ssize_t k = 0; k < PyList_GET_SIZE(due); k++) {
        PyObject *i = PyList_GET_ITEM(due, k);
        PyObject *s = PyObject_GetItem(streams, i);
        if (s == NULL)
            goto done;
        PyObject *r = PyObject_CallMethodOneArg(s, K[K_emit], ch);
        PyObject *iv = r ? attr(s, K_interval_us) : NULL, *nu = iv ? attr(s, K_next_us) : NULL;
        Py_XDECREF(r);
        PyObject *nxt = nu ? PyNumber_Add(nu, iv) : NULL;
        Py_XDECREF(nu);
        int late = nxt ? PyObject_RichCompareBool(nxt, t, Py_LE) : -1;
        if (late > 0) {
            Py_DECREF(nxt);
            nxt = PyNumber_Add(t, iv);
        }
        Py_XDECREF(iv);
        PyObject *pair = (late >= 0 && nxt) ? PyTuple_Pack(2, nxt, i) : NULL;
        int e = pair ? set_attr(s, K_next_us, nxt) : -1;
        Py_DECREF(s);
        Py_XDECREF(nxt);
        PyObject *pr = e < 0 ? NULL : PyObject_CallFunctionObjArgs(self->r[R_HEAPPUSH], sched,
                                                                    pair, NULL);
        Py_XDECREF(pair);
        if (pr == NULL)
            goto done;
        Py_DECREF(pr);
    }
    if (PyList_GET_SIZE(sched) > 0) {
        PyObject *when = PySequence_GetItem(PyList_GET_ITEM(sched, 0), 0);
        if (when == NULL)
            goto done;
        rc = set_attr(ch, K_next_due, when);
        Py_DECREF(when);
    } else {
        rc = set_attr(ch, K_next_due, self->r[R_NEVER]);
    }
done:
    Py_DECREF(sched);
    Py_XDECREF(due);
    Py_XDECREF(streams);
    return rc;
}

/* Telemetry.publish(t) when something is due (tick_due) */
static int tick_publish(Tick *self, PyObject *t)
{
    PyObject *ch[2] = {self->r[R_API], self->r[R_GCS]};
    static const int flags[4] = {K_hb_now, K_ext_now, K_home_now, K_mission_now};
    int other = 0;
    for (int i = 0; i < 2 && !other; i++) {
        if ((other = attr_true(ch[i], K_signed)) == 0)
            other = attr_true(ch[i], K_param_queue);
    }
    for (int i = 0; i < 4 && !other; i++)
        other = attr_true(self->r[R_VS], flags[i]);
    if (other < 0)
        return -1;
    if (other)
        return call_part(self->r[R_VEH], K_telemetry, K_publish, t);
    for (int i = 0; i < 2; i++) {
        int d = attr_cmp(ch[i], K_next_due, t, Py_LE);
        if (d < 0 || (d && emit_due(self, ch[i], t) < 0))
            return -1;
    }
    return 0;
}
