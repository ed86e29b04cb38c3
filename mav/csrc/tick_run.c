/* The vehicle's tick, compiled, second part (included by fastpath.c after tick.c, whose
 * header says what the tick is and how it is tested): the controller's input and output, the
 * battery step, the telemetry test, the HIL answer, the ODOMETRY handling and `Tick.run`.
 */

/* u[0] = u[1] = u[2] = u[3] = v */
static int set_u4(PyObject *u, PyObject *v)
{
    for (Py_ssize_t i = 0; i < 4; i++)
        if (PySequence_SetItem(u, i, v) < 0)
            return -1;
    return 0;
}

/* HIL_ACTUATOR_CONTROLS of (t_us, u, mode), packed as wire.HIL_CTRL_PACK ("<QQ4f48xB"), framed
 * on the HIL link's MAVLink object and sent */
static int tick_answer(Tick *self, PyObject *t_us, PyObject *u, long mode)
{
    uint8_t pl[81];
    memset(pl, 0, sizeof pl);
    unsigned long long t = PyLong_AsUnsignedLongLong(t_us);
    if (t == (unsigned long long)-1 && PyErr_Occurred())
        return -1;
    for (int i = 0; i < 8; i++) {
        pl[i] = (uint8_t)(t >> (8 * i));
        pl[8 + i] = i == 0 ? 1 : 0;
    }
    for (Py_ssize_t k = 0; k < 4; k++) {
        PyObject *v = PySequence_GetItem(u, k);
        if (v == NULL)
            return -1;
        double x = PyFloat_AsDouble(v);
        Py_DECREF(v);
        if ((x == -1.0 && PyErr_Occurred()) || PyFloat_Pack4(x, (char *)pl + 16 + 4 * k, 1) < 0)
            return -1;
    }
    pl[80] = (uint8_t)mode;
    PyObject *fr = frame_on(self->r[R_HILMAV], self->hil_id, (uint8_t)self->hil_extra, pl, 81);
    if (fr == NULL)
        return -1;
    PyObject *r = link_send(self->r[R_HIL], fr);
    Py_DECREF(fr);
    Py_XDECREF(r);
    return r ? 0 : -1;
}

/* set o.<names[i]> = vals[i] for i < n, in order */
static int set_attrs(PyObject *o, const int *names, PyObject *const *vals, int n)
{
    for (int i = 0; i < n; i++)
        if (set_attr(o, names[i], vals[i]) < 0)
            return -1;
    return 0;
}

/* the controller's input and output: Onboard.poll's step 3 after the modes */
static int tick_control(Tick *self, PyObject *s, int lost)
{
    PyObject *veh = self->r[R_VEH], *vs = self->r[R_VS];
    PyObject *u = attr(vs, K_u);
    if (u == NULL)
        return -1;
    int rc = -1, arm = attr_true(vs, K_armed);
    if (arm < 0)
        goto done;
    if (!arm) {
        rc = set_u4(u, py_zero_f);
        goto done;
    }
    long landed;
    if (attr_long(vs, K_landed_state, &landed) < 0)
        goto done;
    int idle = 0;
    if (landed == self->c[C_ON_GROUND]) {
        PyObject *cmd = attr(veh, K_commander);
        PyObject *r = cmd ? PyObject_CallMethodNoArgs(cmd, K[K_motors_idle]) : NULL;
        Py_XDECREF(cmd);
        idle = r ? PyObject_IsTrue(r) : -1;
        Py_XDECREF(r);
        if (idle < 0)
            goto done;
    }
    if (idle) {
        PyObject *own = attr(vs, K_own), *ratio = own ? PyObject_GetItem(own, K[K_MOT_IDLE_RATIO]) : NULL;
        PyObject *av = ratio ? attr(veh, K_vehicle) : NULL;
        PyObject *uh = av ? attr(av, K_u_hover) : NULL;
        PyObject *v = uh ? PyNumber_Multiply(ratio, uh) : NULL;
        Py_XDECREF(own);
        Py_XDECREF(ratio);
        Py_XDECREF(av);
        Py_XDECREF(uh);
        if (v != NULL)
            rc = set_u4(u, v);
        Py_XDECREF(v);
        goto done;
    }
    PyObject *sp = attr(vs, K_setpoint);
    if (sp == NULL)
        goto done;
    PyObject *ctrl = NULL, *meth = NULL, *in = NULL;
    if (set_attr(sp, K_armed, Py_True) < 0 || (ctrl = attr(vs, K_ctrl)) == NULL ||
        (meth = attr(ctrl, K_update)) == NULL)
        goto done_sp;
    if (lost)
        in = PyObject_CallMethodObjArgs(veh, K[K_blind], s, sp, NULL);
    else
        in = Py_NewRef(s);
    if (in != NULL) {
        PyObject *a[3] = {in, sp, u};
        PyObject *r = PyObject_Vectorcall(meth, a, 3, NULL);
        Py_XDECREF(r);
        rc = r ? 0 : -1;
    }
done_sp:
    Py_DECREF(sp);
    Py_XDECREF(ctrl);
    Py_XDECREF(meth);
    Py_XDECREF(in);
done:
    Py_DECREF(u);
    return rc;
}

/* Battery.step over the tick (battery.c), after the controller: `if dt_us > 0` */
static int tick_battery(Tick *self, PyObject *dt_us)
{
    PyObject *vs = self->r[R_VS];
    int pos = PyObject_RichCompareBool(dt_us, py_zero_l, Py_GT);
    if (pos <= 0)
        return pos;
    PyObject *a[6] = {NULL};
    int rc = -1;
    if ((a[0] = attr(vs, K_battery)) == NULL || (a[1] = PyNumber_Multiply(dt_us, py_micro)) == NULL)
        goto done;
    PyObject *u = attr(vs, K_u);
    if (u == NULL)
        goto done;
    for (Py_ssize_t k = 0; k < 4; k++)
        if ((a[2 + k] = PySequence_GetItem(u, k)) == NULL)
            break;
    Py_DECREF(u);
    if (a[5] != NULL) {
        PyObject *r = fp_battery_step(NULL, a, 6);
        Py_XDECREF(r);
        rc = r ? 0 : -1;
    }
done:
    for (int k = 0; k < 6; k++)
        Py_XDECREF(a[k]);
    return rc;
}

/* Onboard.poll's step 4 test: anything due on the links or raised by the parts */
static int tick_due(Tick *self, PyObject *t_us)
{
    PyObject *ch[2] = {self->r[R_API], self->r[R_GCS]};
    for (int i = 0; i < 2; i++) {
        int d = attr_cmp(ch[i], K_next_due, t_us, Py_LE);
        if (d != 0)
            return d;
    }
    for (int i = 0; i < 2; i++) {
        int d = attr_true(ch[i], K_param_queue);
        if (d != 0)
            return d;
    }
    static const int flags[4] = {K_hb_now, K_ext_now, K_home_now, K_mission_now};
    for (int i = 0; i < 4; i++) {
        int d = attr_true(self->r[R_VS], flags[i]);
        if (d != 0)
            return d;
    }
    return 0;
}

enum { O_T, O_X_, O_Y_, O_Z_, O_QW, O_QX, O_QY, O_QZ, O_VX_, O_VY_, O_VZ_, O_P, O_Q, O_R,
       O_FRAME, O_CHILD, O_QUALITY, O_NFIELDS };

/* the ODOMETRY part of Onboard.poll after the datagram was decoded: False if its values are
 * not usable, else the rest of the tick; `od` the decoded 17-tuple */
static PyObject *tick_odometry(Tick *self, PyObject *od)
{
    PyObject *veh = self->r[R_VEH], *vs = self->r[R_VS], *stats = self->r[R_STATS];
    const long *c = self->c;
    PyObject *const *f = &PyTuple_GET_ITEM(od, 0);
    double chk = 0.0;
    for (int i = O_X_; i <= O_R; i++) {
        double v = PyFloat_AsDouble(f[i]);
        if (v == -1.0 && PyErr_Occurred())
            return NULL;
        chk = i == O_X_ ? v : chk + v;
    }
    long frame_id = PyLong_AsLong(f[O_FRAME]), child = PyLong_AsLong(f[O_CHILD]);
    if (PyErr_Occurred())
        return NULL;
    if (chk - chk != 0.0 || frame_id != c[C_FRAME_LOCAL_NED] ||
        (child != c[C_FRAME_LOCAL_NED] && child != c[C_FRAME_BODY_FRD])) {
        if (incr(stats, K[K_hil_bad_values]) < 0)
            return NULL;
        Py_RETURN_FALSE;
    }
    PyObject *t_us = f[O_T];
    int have = attr_true(vs, K_have_state);
    if (have < 0)
        return NULL;
    if (!have) {
        if (set_attr(vs, K_t_us, t_us) < 0)
            return NULL;
        PyObject *org = PyTuple_Pack(2, f[O_X_], f[O_Y_]);
        int e = org ? set_attr(veh, K_origin, org) : -1;
        Py_XDECREF(org);
        if (e < 0)
            return NULL;
    }
    /* 1. the offboard and GCS links, at the clock of the previous tick */
    PyObject *chans[2] = {self->r[R_API], self->r[R_GCS]};
    for (int i = 0; i < 2; i++) {
        PyObject *link = attr(chans[i], K_link);
        PyObject *data = link ? link_recv(link) : NULL;
        Py_XDECREF(link);
        if (data == NULL)
            return NULL;
        int e = data == Py_None ? 0 : tick_drain(self, chans[i], data);
        Py_DECREF(data);
        if (e < 0)
            return NULL;
    }
    /* 2. clock and estimator (ground truth from ODOMETRY) */
    PyObject *dt_us = NULL, *s = NULL, *tmp = NULL, *ret = NULL;
    if ((tmp = attr(vs, K_t_us)) == NULL || (dt_us = PyNumber_Subtract(t_us, tmp)) == NULL)
        goto done;
    Py_CLEAR(tmp);
    if (set_attr(vs, K_t_us, t_us) < 0 || (s = fast_getattr(vs, n_state)) == NULL)
        goto done;
    if ((tmp = PyNumber_Multiply(t_us, py_micro)) == NULL || set_attr(s, K_t, tmp) < 0)
        goto done;
    Py_CLEAR(tmp);
    {
        PyObject *v[3] = {NULL, NULL, NULL};
        v[0] = attr(s, K_vx);
        v[1] = v[0] ? attr(s, K_vy) : NULL;
        v[2] = v[1] ? attr(s, K_vz) : NULL;
        tmp = v[2] ? PyTuple_Pack(3, v[0], v[1], v[2]) : NULL;
        for (int i = 0; i < 3; i++)
            Py_XDECREF(v[i]);
        if (tmp == NULL || set_attr(vs, K_v_prev, tmp) < 0)
            goto done;
        Py_CLEAR(tmp);
    }
    static const int att_names[4] = {K_qw, K_qx, K_qy, K_qz}, rate_names[3] = {K_p, K_q, K_r};
    if (set_attr(vs, K_dt_us, dt_us) < 0 || set_attrs(s, att_names, f + O_QW, 4) < 0 ||
        set_attrs(s, rate_names, f + O_P, 3) < 0)
        goto done;
    int lost = 0;
    {
        int neg = PyObject_RichCompareBool(f[O_QUALITY], py_zero_l, Py_LT);
        if (neg < 0 || (neg && (lost = attr_true(vs, K_have_state)) < 0))
            goto done;
    }
    if (!lost) {
        PyObject *org = attr(veh, K_origin), *ox = NULL, *oy = NULL, *xy[3] = {NULL, NULL, NULL};
        if (org == NULL)
            goto done;
        PyObject *seq = PySequence_Fast(org, "cannot unpack the origin");
        Py_DECREF(org);
        if (seq == NULL)
            goto done;
        if (PySequence_Fast_GET_SIZE(seq) != 2) {
            PyErr_SetString(PyExc_ValueError, "the origin must be (x, y)");
            Py_DECREF(seq);
            goto done;
        }
        ox = PySequence_Fast_GET_ITEM(seq, 0);
        oy = PySequence_Fast_GET_ITEM(seq, 1);
        xy[0] = PyNumber_Subtract(f[O_X_], ox);
        xy[1] = xy[0] ? PyNumber_Subtract(f[O_Y_], oy) : NULL;
        Py_DECREF(seq);
        static const int pos_names[3] = {K_x, K_y, K_z};
        int e = -1;
        if (xy[1] != NULL) {
            xy[2] = Py_NewRef(f[O_Z_]);
            e = set_attrs(s, pos_names, xy, 3);
        }
        for (int i = 0; i < 3; i++)
            Py_XDECREF(xy[i]);
        if (e < 0)
            goto done;
        static const int vel_names[3] = {K_vx, K_vy, K_vz};
        if (child == c[C_FRAME_LOCAL_NED]) {
            if (set_attrs(s, vel_names, f + O_VX_, 3) < 0)
                goto done;
        } else {   /* body FRD velocity -> world NED */
            PyObject *rot = fast_getattr(self->r[R_DEFS], K[K_rotate]);
            PyObject *w = rot ? PyObject_Vectorcall(rot, f + O_QW, 7, NULL) : NULL;
            Py_XDECREF(rot);
            PyObject *ws = w ? PySequence_Fast(w, "rotate_body_to_world") : NULL;
            Py_XDECREF(w);
            if (ws == NULL)
                goto done;
            e = PySequence_Fast_GET_SIZE(ws) == 3
                    ? set_attrs(s, vel_names, PySequence_Fast_ITEMS(ws), 3) : -1;
            if (e < 0 && !PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "rotate_body_to_world: 3 values expected");
            Py_DECREF(ws);
            if (e < 0)
                goto done;
        }
        int pl = attr_cmp_long(vs, K_pos_lost_us, 0, Py_GE);
        if (pl < 0 || (pl && call_part(veh, K_failsafe, K_position_regained, NULL) < 0))
            goto done;
    } else {
        int pl = attr_cmp_long(vs, K_pos_lost_us, 0, Py_LT);
        if (pl < 0 || (pl && call_part(veh, K_failsafe, K_position_lost, t_us) < 0))
            goto done;
    }
    if ((have = attr_true(vs, K_have_state)) < 0)
        goto done;
    if (!have && (set_attr(vs, K_have_state, Py_True) < 0 ||
                  call_part(veh, K_commander, K_set_home, NULL) < 0 ||
                  call_part(veh, K_commander, K_hold_here, NULL) < 0))
        goto done;
    /* 3. modes, failsafes, ground detection, controller, battery */
    if (tick_modes(self, t_us) < 0 || tick_control(self, s, lost) < 0 ||
        tick_battery(self, dt_us) < 0)
        goto done;
    /* 4. telemetry when due, then the HIL answer */
    int due = tick_due(self, t_us);
    if (due < 0 || (due && tick_publish(self, t_us) < 0))
        goto done;
    {
        int arm = attr_true(vs, K_armed);
        PyObject *u = arm < 0 ? NULL : attr(vs, K_u);
        if (u == NULL)
            goto done;
        int e = tick_answer(self, t_us, u, arm ? c[C_HIL_MODE_ARMED] : c[C_HIL_MODE_DISARMED]);
        Py_DECREF(u);
        if (e < 0 || incr(stats, K[K_ticks]) < 0)
            goto done;
    }
    ret = Py_NewRef(Py_True);
done:
    Py_XDECREF(dt_us);
    Py_XDECREF(s);
    Py_XDECREF(tmp);
    return ret;
}

/* Tick.run(): Onboard.poll */
static PyObject *tick_run(Tick *self, PyObject *unused)
{
    PyObject *data = link_recv(self->r[R_HIL]);
    if (data == NULL)
        return NULL;
    if (data == Py_None) {
        Py_DECREF(data);
        Py_RETURN_FALSE;
    }
    PyObject *od = NULL, *ret = NULL;
    if (incr(self->r[R_STATS], K[K_rx_hil]) < 0)
        goto done;
    PyObject *dec = fast_getattr(self->r[R_WIRE], K[K_decode_odometry]);
    if (dec == NULL)
        goto done;
    od = PyObject_CallOneArg(dec, data);
    Py_DECREF(dec);
    if (od == NULL) {   /* defensive, as the reference: never crash here */
        if (!PyErr_ExceptionMatches(PyExc_Exception))
            goto done;
        PyErr_Clear();
    }
    if (od == NULL || od == Py_None || !PyTuple_Check(od) ||
        PyTuple_GET_SIZE(od) != O_NFIELDS) {
        if (od != NULL && od != Py_None) {
            PyErr_SetString(PyExc_TypeError, "decode_odometry: a 17-tuple or None expected");
            goto done;
        }
        PyObject *r = PyObject_CallMethodOneArg(self->r[R_VEH], K[K_hil_not_odometry], data);
        if (r == NULL)
            goto done;
        Py_DECREF(r);
        ret = Py_NewRef(Py_False);
        goto done;
    }
    ret = tick_odometry(self, od);
done:
    Py_DECREF(data);
    Py_XDECREF(od);
    return ret;
}

static PyMethodDef tick_methods[] = {
    {"run", (PyCFunction)tick_run, METH_NOARGS,
     "run() -> bool: Onboard.poll compiled (see tick.c)"},
    {NULL, NULL, 0, NULL}};

static PyTypeObject TickType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "mav._fastpath.Tick",
    .tp_basicsize = sizeof(Tick),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "Tick(vehicle): the vehicle's tick compiled; run() is Onboard.poll (tick.c)",
    .tp_new = tick_new,
    .tp_dealloc = (destructor)tick_dealloc,
    .tp_traverse = (traverseproc)tick_traverse,
    .tp_clear = (inquiry)tick_clear,
    .tp_methods = tick_methods,
};
