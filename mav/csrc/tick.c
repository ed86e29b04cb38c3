/* The vehicle's tick, compiled (included by fastpath.c: one translation unit).
 *
 * Tick(vehicle).run() is `Onboard.poll` (mav/onboard/vehicle.py, the reference) with its
 * `_step_modes`, statement for statement: the same reads and writes of the vehicle's records
 * in the same order, the same Python calls for everything that is not the common path (a HIL
 * datagram that is not an ODOMETRY, a datagram on api/gcs that is not an accepted offboard
 * setpoint, the failsafes, the automatic modes, the blind controller input, telemetry when
 * due), and the compiled pieces for the rest: the ODOMETRY decoder (`wire.decode_odometry`),
 * the offboard setpoint accept (setpoint.c), the controller (whatever `vs.ctrl` is), the battery
 * step (battery.c) and the HIL_ACTUATOR_CONTROLS answer (packed here as wire.HIL_CTRL_PACK
 * does, framed by telemetry.c's frame_on: the HIL link never signs).
 *
 * Integer arithmetic on the clock uses Python ints (PyNumber_*), as the reference does, so any
 * time_usec the decoder accepts behaves the same. The vehicle builds one Tick when the
 * extension is loaded (Onboard.__init__); tests/test_tick.py flies it back to back with the
 * reference (tlog bytes, recorded series and counters) and drives its rare branches.
 */

enum {
    K_rx_hil, K_decode_odometry, K_hil_not_odometry, K_hil_bad_values,
    K_have_state, K_t_us, K_origin, K_link, K_drain, K_dt_us, K_t, K_v_prev, K_vx, K_vy, K_vz,
    K_qw, K_qx, K_qy, K_qz, K_p, K_q, K_r, K_x, K_y, K_z, K_pos_lost_us, K_failsafe,
    K_position_regained, K_position_lost, K_commander, K_set_home, K_hold_here, K_u, K_armed,
    K_landed_state, K_motors_idle, K_own, K_MOT_IDLE_RATIO, K_vehicle, K_u_hover, K_setpoint,
    K_ctrl, K_update, K_blind, K_battery, K_next_due, K_param_queue, K_hb_now, K_ext_now,
    K_home_now, K_mission_now, K_telemetry, K_publish, K_ticks, K_mode, K_of_last_us,
    K_of_loss_us, K_offboard_lost, K_navigator, K_step_takeoff, K_step_land, K_step_loiter,
    K_manual, K_step, K_step_rtl, K_mission, K_up, K_tick, K_gcs_last_us, K_gcs_lost,
    K_check_gcs, K_home, K_GF_MAX_HOR_DIST, K_GF_MAX_VER_DIST, K_check_geofence,
    K_check_position, K_fs_active, K_fs_t0, K_fail_act_us, K_hold_expired, K_ground_since,
    K_detect_air_and_ground, K_consumed_mah, K_lost_mah, K_bat_warn_mah, K_battery_warning,
    K_signed, K_rx_key, K_peer, K_setpoints, K_rotate, K_drain_deferred, K_schedule,
    K_recompute_due, K_streams, K_emit, K_interval_us, K_next_us, K_N
};
static const char *K_STR[K_N] = {
    "rx_hil", "decode_odometry", "_hil_not_odometry", "hil_bad_values",
    "have_state", "t_us", "origin", "link", "drain", "dt_us", "t", "v_prev", "vx", "vy", "vz",
    "qw", "qx", "qy", "qz", "p", "q", "r", "x", "y", "z", "pos_lost_us", "failsafe",
    "position_regained", "position_lost", "commander", "set_home", "hold_here", "u", "armed",
    "landed_state", "motors_idle", "own", "MOT_IDLE_RATIO", "vehicle", "u_hover", "setpoint",
    "ctrl", "update", "_blind", "battery", "next_due", "param_queue", "hb_now", "ext_now",
    "home_now", "mission_now", "telemetry", "publish", "ticks", "mode", "of_last_us",
    "of_loss_us", "offboard_lost", "navigator", "step_takeoff", "step_land", "step_loiter",
    "manual", "step", "step_rtl", "mission", "up", "tick", "gcs_last_us", "gcs_lost",
    "check_gcs", "home", "GF_MAX_HOR_DIST", "GF_MAX_VER_DIST", "check_geofence",
    "check_position", "fs_active", "fs_t0", "fail_act_us", "hold_expired", "ground_since",
    "detect_air_and_ground", "consumed_mah", "lost_mah", "bat_warn_mah", "battery_warning",
    "signed", "rx_key", "peer", "setpoints", "rotate_body_to_world", "drain_deferred",
    "schedule", "recompute_due", "streams", "emit", "interval_us", "next_us"};
static PyObject *K[K_N];
static PyObject *py_micro;       /* 1e-6 */
static PyObject *py_zero_f;      /* 0.0 */
static PyObject *py_zero_l;      /* 0 */

static int tick_init_names(void)
{
    for (int i = 0; i < K_N; i++)
        if ((K[i] = PyUnicode_InternFromString(K_STR[i])) == NULL)
            return -1;
    py_micro = PyFloat_FromDouble(1e-6);
    py_zero_f = PyFloat_FromDouble(0.0);
    py_zero_l = PyLong_FromLong(0);
    return (py_micro && py_zero_f && py_zero_l) ? 0 : -1;
}

/* the constants of mav/onboard/defs.py and mav/wire.py the tick uses, read at construction */
enum { C_POSCTL, C_TAKEOFF, C_LOITER, C_LAND, C_OFFBOARD, C_RTL, C_MISSION, C_ON_GROUND,
       C_FRAME_LOCAL_NED, C_FRAME_BODY_FRD, C_HIL_MODE_ARMED, C_HIL_MODE_DISARMED, C_DRAIN_MAX,
       C_N };
static const char *C_STR[C_N] = {"POSCTL", "TAKEOFF", "LOITER", "LAND", "OFFBOARD", "RTL",
                                 "MISSION", "ON_GROUND", "FRAME_LOCAL_NED", "FRAME_BODY_FRD",
                                 "HIL_MODE_ARMED", "HIL_MODE_DISARMED", "DRAIN_MAX"};

enum { R_VEH, R_VS, R_STATS, R_HIL, R_API, R_GCS, R_INPUT, R_HILMAV, R_SPARGS, R_WIRE, R_DEFS,
       R_HEAPPOP, R_HEAPPUSH, R_NEVER, R_N };

typedef struct {
    PyObject_HEAD
    PyObject *r[R_N];
    long c[C_N];
    long hil_id, hil_extra;
    PyObject *sp_id3;
} Tick;

static int tick_traverse(Tick *self, visitproc visit, void *arg)
{
    for (int i = 0; i < R_N; i++)
        Py_VISIT(self->r[i]);
    return 0;
}

static int tick_clear(Tick *self)
{
    for (int i = 0; i < R_N; i++)
        Py_CLEAR(self->r[i]);
    Py_CLEAR(self->sp_id3);
    return 0;
}

static void tick_dealloc(Tick *self)
{
    PyObject_GC_UnTrack(self);
    tick_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static SlotEntry KG[K_N], KS[K_N];    /* each name's cache for reads and for writes */
static PyObject *attr(PyObject *o, int k) { return getattr_at(&KG[k], o, K[k]); }

/* o.k as a C long (ints and bools), -1 with an error set on failure */
static int attr_long(PyObject *o, int k, long *out)
{
    PyObject *v = attr(o, k);
    if (v == NULL)
        return -1;
    *out = PyLong_AsLong(v);
    Py_DECREF(v);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

/* truth of o.k: 1, 0, or -1 on error */
static int attr_true(PyObject *o, int k)
{
    PyObject *v = attr(o, k);
    if (v == NULL)
        return -1;
    int r = PyObject_IsTrue(v);
    Py_DECREF(v);
    return r;
}

/* the comparison `o.k op b` with Python semantics (b an object): 1, 0 or -1 */
static int attr_cmp(PyObject *o, int k, PyObject *b, int op)
{
    PyObject *v = attr(o, k);
    if (v == NULL)
        return -1;
    int r = PyObject_RichCompareBool(v, b, op);
    Py_DECREF(v);
    return r;
}

/* `o.k op n` for a small int n */
static int attr_cmp_long(PyObject *o, int k, long n, int op)
{
    PyObject *b = PyLong_FromLong(n);
    if (b == NULL)
        return -1;
    int r = attr_cmp(o, k, b, op);
    Py_DECREF(b);
    return r;
}

/* stats[key] += 1 (KeyError if absent, as the reference) */
static int incr(PyObject *stats, PyObject *key)
{
    PyObject *v = PyDict_GetItemWithError(stats, key);
    if (v == NULL) {
        if (!PyErr_Occurred())
            PyErr_SetObject(PyExc_KeyError, key);
        return -1;
    }
    PyObject *nv = PyNumber_Add(v, py_one);
    if (nv == NULL)
        return -1;
    int r = PyDict_SetItem(stats, key, nv);
    Py_DECREF(nv);
    return r;
}

/* getattr(getattr(veh, part), meth)(arg or nothing); the result dropped */
static int call_part(PyObject *veh, int part, int meth, PyObject *arg)
{
    PyObject *p = attr(veh, part);
    if (p == NULL)
        return -1;
    PyObject *r = arg ? PyObject_CallMethodOneArg(p, K[meth], arg)
                      : PyObject_CallMethodNoArgs(p, K[meth]);
    Py_DECREF(p);
    Py_XDECREF(r);
    return r ? 0 : -1;
}

static int set_attr(PyObject *o, int k, PyObject *v) { return setattr_at(&KS[k], o, K[k], v); }

static PyObject *tick_new(PyTypeObject *type, PyObject *args, PyObject *kw)
{
    PyObject *veh;
    if (!PyArg_ParseTuple(args, "O:Tick", &veh))
        return NULL;
    Tick *self = (Tick *)type->tp_alloc(type, 0);
    if (self == NULL)
        return NULL;
    static const char *from_veh[] = {"status", "stats", "_hil", "_api", "_gcs", "input",
                                     "_hil_mav"};
    Py_INCREF(veh);
    self->r[R_VEH] = veh;
    for (int i = 0; i < 7; i++)
        if ((self->r[R_VS + i] = PyObject_GetAttrString(veh, from_veh[i])) == NULL)
            goto fail;
    if ((self->r[R_SPARGS] = PyObject_GetAttrString(self->r[R_INPUT], "_sp_args")) == NULL)
        goto fail;
    if (!PyTuple_Check(self->r[R_SPARGS]) || PyTuple_GET_SIZE(self->r[R_SPARGS]) != 7) {
        PyErr_SetString(PyExc_TypeError, "Tick: LinkInput._sp_args must be a 7-tuple");
        goto fail;
    }
    PyObject *hq = PyImport_ImportModule("heapq");    /* telemetry.py's heappop, heappush */
    if (hq == NULL)
        goto fail;
    self->r[R_HEAPPOP] = PyObject_GetAttrString(hq, "heappop");
    self->r[R_HEAPPUSH] = PyObject_GetAttrString(hq, "heappush");
    Py_DECREF(hq);
    if (self->r[R_HEAPPOP] == NULL || self->r[R_HEAPPUSH] == NULL ||
        (self->r[R_NEVER] = PyLong_FromLongLong(1LL << 62)) == NULL)
        goto fail;
    if ((self->r[R_WIRE] = PyImport_ImportModule("mav.wire")) == NULL ||
        (self->r[R_DEFS] = PyImport_ImportModule("mav.onboard.defs")) == NULL)
        goto fail;
    for (int i = 0; i < C_N; i++) {
        PyObject *v = PyObject_GetAttrString(self->r[R_DEFS], C_STR[i]);
        if (v == NULL)
            goto fail;
        self->c[i] = PyLong_AsLong(v);
        Py_DECREF(v);
        if (self->c[i] == -1 && PyErr_Occurred())
            goto fail;
    }
    if ((self->sp_id3 = PyObject_GetAttrString(self->r[R_DEFS], "SP_ID3")) == NULL)
        goto fail;
    PyObject *m = PyObject_GetAttrString(self->r[R_WIRE], "HIL_ACTUATOR_CONTROLS");
    if (m == NULL)
        goto fail;
    PyObject *id = PyObject_GetAttrString(m, "id"), *ex = PyObject_GetAttrString(m, "crc_extra");
    Py_DECREF(m);
    self->hil_id = id ? PyLong_AsLong(id) : -1;
    self->hil_extra = ex ? PyLong_AsLong(ex) : -1;
    Py_XDECREF(id);
    Py_XDECREF(ex);
    if (PyErr_Occurred())
        goto fail;
    return (PyObject *)self;
fail:
    Py_DECREF(self);
    return NULL;
}

/* LinkInput.drain(ch, data) for a link that does not sign: datagrams that are one accepted
 * offboard setpoint (the 200 Hz case) are applied here; the first other one is handed, with
 * the rest of the drain, to the Python reference (`drain(ch, data, n)`). `data` is borrowed. */
static int tick_drain(Tick *self, PyObject *ch, PyObject *data)
{
    PyObject *stats = self->r[R_STATS], *vs = self->r[R_VS], *sp = self->r[R_SPARGS];
    int sgn = attr_true(ch, K_signed);
    if (sgn < 0)
        return -1;
    if (sgn) {
        PyObject *r = PyObject_CallMethodObjArgs(self->r[R_INPUT], K[K_drain], ch, data, NULL);
        Py_XDECREF(r);
        return r ? 0 : -1;
    }
    PyObject *link = attr(ch, K_link), *rx_key = NULL, *got = NULL;
    int rc = -1;
    if (link == NULL || (rx_key = attr(ch, K_rx_key)) == NULL)
        goto done;
    const char *id3 = PyBytes_AS_STRING(self->sp_id3);
    Py_INCREF(data);
    got = data;
    for (long n = 0; n < self->c[C_DRAIN_MAX]; n++) {
        if (n) {
            Py_DECREF(got);
            got = link_recv(link);
            if (got == NULL)
                goto done;
            if (got == Py_None) {
                rc = 0;
                goto done;
            }
        }
        if (PyBytes_CheckExact(got) && PyBytes_GET_SIZE(got) >= 12) {
            const uint8_t *d = (const uint8_t *)PyBytes_AS_STRING(got);
            if (memcmp(d + 7, id3, 3) == 0 && d[0] == MAGIC_V2) {
                PyObject *a[8] = {got};
                for (int i = 0; i < 7; i++)
                    a[i + 1] = PyTuple_GET_ITEM(sp, i);
                PyObject *ok = fp_setpoint_local_ned(NULL, a, 8);
                if (ok == NULL)
                    PyErr_Clear();     /* the reference repeats it, and counts the error */
                Py_XDECREF(ok);
                if (ok == Py_True) {
                    if (incr(stats, rx_key) < 0)
                        goto done;
                    PyObject *peer = Py_BuildValue("(ii)", d[5], d[6]);
                    if (peer == NULL)
                        goto done;
                    int e = fast_setattr(ch, K[K_peer], peer);
                    Py_DECREF(peer);
                    PyObject *t = e < 0 ? NULL : attr(vs, K_t_us);
                    if (t == NULL)
                        goto done;
                    e = set_attr(vs, K_of_last_us, t);
                    Py_DECREF(t);
                    if (e < 0 || incr(stats, K[K_setpoints]) < 0)
                        goto done;
                    continue;
                }
            }
        }
        PyObject *idx = PyLong_FromLong(n);
        if (idx == NULL)
            goto done;
        PyObject *r = PyObject_CallMethodObjArgs(self->r[R_INPUT], K[K_drain], ch, got, idx,
                                                 NULL);
        Py_DECREF(idx);
        Py_XDECREF(r);
        rc = r ? 0 : -1;
        goto done;
    }
    rc = incr(stats, K[K_drain_deferred]);
done:
    Py_XDECREF(got);
    Py_XDECREF(link);
    Py_XDECREF(rx_key);
    return rc;
}

/* `t - o.since > o.limit` with Python ints: 1, 0 or -1 */
static int elapsed_over(PyObject *o, PyObject *t, int since, int limit)
{
    PyObject *t0 = attr(o, since), *lim = t0 ? attr(o, limit) : NULL;
    PyObject *dt = lim ? PyNumber_Subtract(t, t0) : NULL;
    int over = dt ? PyObject_RichCompareBool(dt, lim, Py_GT) : -1;
    Py_XDECREF(t0);
    Py_XDECREF(lim);
    Py_XDECREF(dt);
    return over;
}

/* Onboard._step_modes(t) */
static int tick_modes(Tick *self, PyObject *t)
{
    PyObject *veh = self->r[R_VEH], *vs = self->r[R_VS];
    const long *c = self->c;
    long mode, armed;
    if (attr_long(vs, K_mode, &mode) < 0)
        return -1;
    if (mode == c[C_OFFBOARD]) {
        int late = elapsed_over(vs, t, K_of_last_us, K_of_loss_us);
        if (late < 0)
            return -1;
        if (late) {
            if (call_part(veh, K_failsafe, K_offboard_lost, t) < 0)
                return -1;
            mode = c[C_LOITER];
        }
    } else {
        if (attr_long(vs, K_armed, &armed) < 0)
            return -1;
        int part = -1, meth = -1;
        if (mode == c[C_TAKEOFF])
            part = K_navigator, meth = K_step_takeoff;
        else if (mode == c[C_LAND])
            part = K_navigator, meth = K_step_land;
        else if (mode == c[C_LOITER])
            part = K_navigator, meth = K_step_loiter;
        else if (mode == c[C_POSCTL])
            part = K_manual, meth = K_step;
        else if (mode == c[C_RTL])
            part = K_navigator, meth = K_step_rtl;
        else if (mode == c[C_MISSION])
            part = K_mission, meth = K_step;
        if (armed && part >= 0 && call_part(veh, part, meth, t) < 0)
            return -1;
    }
    PyObject *mis = attr(veh, K_mission);
    PyObject *up = mis ? attr(mis, K_up) : NULL;
    Py_XDECREF(mis);
    if (up == NULL)
        return -1;
    int uploading = up != Py_None;
    Py_DECREF(up);
    if (uploading && call_part(veh, K_mission, K_tick, t) < 0)
        return -1;
    int g = attr_cmp_long(vs, K_gcs_last_us, 0, Py_GE);
    if (g < 0)
        return -1;
    if (g) {
        int lost = attr_true(vs, K_gcs_lost);
        if (lost < 0 || (!lost && call_part(veh, K_failsafe, K_check_gcs, t) < 0))
            return -1;
    }
    int arm = attr_true(vs, K_armed);
    PyObject *own = arm < 0 ? NULL : attr(vs, K_own);
    if (own == NULL)
        return -1;
    long landed;
    int fence = 0;
    if (arm) {
        if (attr_long(vs, K_landed_state, &landed) < 0)
            goto fail_own;
        if (landed != c[C_ON_GROUND]) {
            PyObject *home = attr(vs, K_home);
            if (home == NULL)
                goto fail_own;
            int have_home = home != Py_None;
            Py_DECREF(home);
            for (int k = K_GF_MAX_HOR_DIST; have_home && !fence && k <= K_GF_MAX_VER_DIST; k++) {
                PyObject *v = PyObject_GetItem(own, K[k]);
                if (v == NULL)
                    goto fail_own;
                fence = PyObject_RichCompareBool(v, py_zero_f, Py_GT);
                Py_DECREF(v);
                if (fence < 0)
                    goto fail_own;
            }
        }
    }
    Py_DECREF(own);
    if (fence && call_part(veh, K_failsafe, K_check_geofence, NULL) < 0)
        return -1;
    int pl = attr_cmp_long(vs, K_pos_lost_us, 0, Py_GE);
    if (pl < 0 || (pl && call_part(veh, K_failsafe, K_check_position, t) < 0))
        return -1;
    int fs = attr_true(vs, K_fs_active);
    if (fs < 0)
        return -1;
    if (fs && mode == c[C_LOITER]) {
        int over = elapsed_over(vs, t, K_fs_t0, K_fail_act_us);
        if (over < 0 || (over && call_part(veh, K_failsafe, K_hold_expired, NULL) < 0))
            return -1;
    }
    if (arm) {
        if (attr_long(vs, K_landed_state, &landed) < 0)
            return -1;
        int ground = landed == c[C_ON_GROUND];
        if (!ground && (ground = attr_cmp_long(vs, K_ground_since, 0, Py_GE)) < 0)
            return -1;
        if (ground && call_part(veh, K_navigator, K_detect_air_and_ground, t) < 0)
            return -1;
    }
    PyObject *b = attr(vs, K_battery);
    if (b == NULL)
        return -1;
    PyObject *used_a = attr(b, K_consumed_mah), *used_b = used_a ? attr(b, K_lost_mah) : NULL;
    Py_DECREF(b);
    PyObject *used = used_b ? PyNumber_Add(used_a, used_b) : NULL;
    Py_XDECREF(used_a);
    Py_XDECREF(used_b);
    int warn = used ? attr_cmp(vs, K_bat_warn_mah, used, Py_LT) : -1;
    Py_XDECREF(used);
    if (warn < 0 || (warn && call_part(veh, K_failsafe, K_battery_warning, NULL) < 0))
        return -1;
    return 0;
fail_own:
    Py_DECREF(own);
    return -1;
}

