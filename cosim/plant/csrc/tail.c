/* The master's tick after the app, compiled (included by fmi2step.c: the simulator's compiled
 * side is one extension). The reference is the loop of cosim/sim/master.py, steps 5 to 7b,
 * which stays: the tests fly missions both ways and compare the series, the tlog and the
 * exit (tests/test_master_tail.py), and the loop runs it whenever fault hooks are set.
 *
 * Tail(encode, exchange, decode, gcs_recv, app, phase_idx, phases, spool, plant_step, gusty,
 *      wind, home, monitor, consts, component_error)
 *   encode      encode_odometry(t_us, meas) -> bytes
 *   exchange    exchange(data) -> bytes, or None when the vehicle did not answer
 *   decode      decode_actuators(ans) -> (t_us, u1, u2, u3, u4), or None
 *   gcs_recv    the master's GCS end: recv() until None (the tlog tap)
 *   app         the app (its .setpoint and .phase are recorded), or None
 *   phase_idx, phases   the run's phase name -> index dict and index -> name list
 *   spool       the SeriesSpool: its rows list, flush(), pack(), ncols
 *   plant_step  plant_step(u1, u2, u3, u4, wind_n, wind_e, wind_d) -> y
 *   gusty       gusty(k) -> (wind_n, wind_e, wind_d), or None: `wind` every tick
 *   home        (n, e): the vehicle's local origin in world NED
 *   monitor     the ExitMonitor; its `check` runs whenever the fast test below cannot say
 *               "nothing to report" on its own
 *   consts      (Y_Z, Y_ON_GROUND, Y_QX, Y_QY, Y_X, Y_Y, Y_VZ, AIRBORNE_Z_M, FLIP_PRECHECK,
 *               CEILING_M, FLUSH_MASK): cosim's constants, one source of truth
 *
 * run(k, t_us, t, meas, y) -> y to go on, or None when an exit condition is met (`.ended` is
 * then (reason, message)). `.stage` names the part that was running when it raised ("onboard"
 * or "plant", as the reference names them); `.phase_index` the phase recorded last.
 *
 * The fast exit test decides "nothing to report" exactly when ExitMonitor.check would return
 * None without changing its state: finite height, no take-off to note, not on the ground
 * after flying, not tilted past the flip pre-check, no 3D scene, inside the arena (or `sitl`).
 * Anything else calls check, and the monitor's `airborne` and `ground_ticks` (which only
 * check changes) are read back after it.
 */

#define ROW_MAX 64           /* columns of a row built on the stack (wider: on the heap) */

typedef struct {
    PyObject_HEAD
    PyObject *encode, *exchange, *decode, *gcs_recv, *app, *phase_idx, *phases, *rows,
        *flush, *pack, *plant_step, *gusty, *wind, *home_n, *home_e, *monitor, *check,
        *cerr, *ended, *nan3, *none_phase;
    Py_ssize_t ncols, ny, phase_index;
    int iz, ion, iqx, iqy, ix, iy, ivz;
    double airborne_z, flip_pre, ceiling, box[4];
    long long flush_mask;
    int sitl, scene, airborne, ready;
    long ground_ticks;
    const char *stage;
} Tail;

static PyObject *s_setpoint, *s_phase, *s_airborne, *s_ground_ticks, *s_rows, *s_flush,
    *s_pack, *s_ncols, *s_check, *s_arena_box, *s_sitl, *s_scene;

static int tail_names(void)
{
    static const char *names[] = {"setpoint", "phase", "airborne", "ground_ticks", "rows",
                                  "flush", "pack", "ncols", "check", "arena_box", "sitl",
                                  "scene"};
    PyObject **slots[] = {&s_setpoint, &s_phase, &s_airborne, &s_ground_ticks, &s_rows,
                          &s_flush, &s_pack, &s_ncols, &s_check, &s_arena_box, &s_sitl,
                          &s_scene};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if ((*slots[i] = PyUnicode_InternFromString(names[i])) == NULL)
            return -1;
    return 0;
}

#define TAIL_OBJS(X) X(encode) X(exchange) X(decode) X(gcs_recv) X(app) X(phase_idx) \
    X(phases) X(rows) X(flush) X(pack) X(plant_step) X(gusty) X(wind) X(home_n) X(home_e) \
    X(monitor) X(check) X(cerr) X(ended) X(nan3) X(none_phase)

static int tail_traverse(Tail *self, visitproc visit, void *arg)
{
#define VISIT(f) Py_VISIT(self->f);
    TAIL_OBJS(VISIT)
#undef VISIT
    return 0;
}

static int tail_clear(Tail *self)
{
#define CLEAR(f) Py_CLEAR(self->f);
    TAIL_OBJS(CLEAR)
#undef CLEAR
    return 0;
}

static void tail_dealloc(Tail *self)
{
    PyObject_GC_UnTrack(self);
    tail_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* the monitor's airborne and ground_ticks, after its check ran (or at the start) */
static int tail_sync(Tail *self)
{
    PyObject *a = PyObject_GetAttr(self->monitor, s_airborne);
    int air = a ? PyObject_IsTrue(a) : -1;
    Py_XDECREF(a);
    PyObject *g = air < 0 ? NULL : PyObject_GetAttr(self->monitor, s_ground_ticks);
    long gt = g ? PyLong_AsLong(g) : -1;
    Py_XDECREF(g);
    if (gt == -1 && PyErr_Occurred())
        return -1;
    self->airborne = air;
    self->ground_ticks = gt;
    return 0;
}

static int tail_init(Tail *self, PyObject *args, PyObject *kw)
{
    PyObject *spool, *wind, *home, *consts, *o[11];
    if (self->encode != NULL) {
        PyErr_SetString(PyExc_TypeError, "Tail: already initialised");
        return -1;
    }
    if (!PyArg_ParseTuple(args, "OOOOOO!O!OOOO!O!OO!O", &o[0], &o[1], &o[2], &o[3], &o[4],
                          &PyDict_Type, &o[5], &PyList_Type, &o[6], &spool, &o[7], &o[8],
                          &PyTuple_Type, &wind, &PyTuple_Type, &home, &o[9], &PyTuple_Type,
                          &consts, &o[10]))
        return -1;
    PyObject **dst[] = {&self->encode, &self->exchange, &self->decode, &self->gcs_recv,
                        &self->app, &self->phase_idx, &self->phases, &self->plant_step,
                        &self->gusty, &self->monitor, &self->cerr};
    for (int i = 0; i < 11; i++)
        *dst[i] = Py_NewRef(o[i]);
    if (PyTuple_GET_SIZE(wind) != 3 || PyTuple_GET_SIZE(home) != 2 ||
        PyTuple_GET_SIZE(consts) != 11) {
        PyErr_SetString(PyExc_ValueError, "Tail: wind (3), home (2), consts (11)");
        return -1;
    }
    self->wind = Py_NewRef(wind);
    self->home_n = Py_NewRef(PyTuple_GET_ITEM(home, 0));
    self->home_e = Py_NewRef(PyTuple_GET_ITEM(home, 1));
    int *idx[] = {&self->iz, &self->ion, &self->iqx, &self->iqy, &self->ix, &self->iy,
                  &self->ivz};
    for (int i = 0; i < 7; i++) {
        long v = PyLong_AsLong(PyTuple_GET_ITEM(consts, i));
        if (v == -1 && PyErr_Occurred())
            return -1;
        if (v < 0 || v > 4096) {
            PyErr_SetString(PyExc_ValueError, "Tail: an output index out of range");
            return -1;
        }
        *idx[i] = (int)v;
    }
    double *dst_f[3] = {&self->airborne_z, &self->flip_pre, &self->ceiling};
    for (int i = 0; i < 3; i++)
        if ((*dst_f[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(consts, 7 + i))) == -1.0 &&
            PyErr_Occurred())
            return -1;
    self->flush_mask = PyLong_AsLongLong(PyTuple_GET_ITEM(consts, 10));
    if (self->flush_mask == -1 && PyErr_Occurred())
        return -1;
    PyObject *nc = PyObject_GetAttr(spool, s_ncols);
    if (nc == NULL)
        return -1;
    self->ncols = PyLong_AsSsize_t(nc);
    Py_DECREF(nc);
    if (self->ncols == -1 && PyErr_Occurred())
        return -1;
    if ((self->rows = PyObject_GetAttr(spool, s_rows)) == NULL ||
        (self->flush = PyObject_GetAttr(spool, s_flush)) == NULL ||
        (self->pack = PyObject_GetAttr(spool, s_pack)) == NULL ||
        (self->check = PyObject_GetAttr(self->monitor, s_check)) == NULL)
        return -1;
    if (!PyList_CheckExact(self->rows)) {
        PyErr_SetString(PyExc_TypeError, "Tail: spool.rows must be a list");
        return -1;
    }
    /* the row: t, y, u1..u4, est x y z, setpoint x y z, phase */
    self->ny = self->ncols - 12;
    if (self->ny <= 0) {
        PyErr_SetString(PyExc_ValueError, "Tail: spool.ncols too small for a row");
        return -1;
    }
    PyObject *box = PyObject_GetAttr(self->monitor, s_arena_box);
    PyObject *bt = box ? PySequence_Tuple(box) : NULL;
    Py_XDECREF(box);
    if (bt == NULL)
        return -1;
    int ok = PyTuple_GET_SIZE(bt) == 4;
    for (int i = 0; ok && i < 4; i++)
        if ((self->box[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(bt, i))) == -1.0 &&
            PyErr_Occurred())
            ok = 0;
    Py_DECREF(bt);
    if (!ok && !PyErr_Occurred())
        PyErr_SetString(PyExc_ValueError, "Tail: monitor.arena_box must have 4 values");
    if (PyErr_Occurred())
        return -1;
    PyObject *sitl = PyObject_GetAttr(self->monitor, s_sitl);
    self->sitl = sitl ? PyObject_IsTrue(sitl) : -1;
    Py_XDECREF(sitl);
    PyObject *scene = self->sitl < 0 ? NULL : PyObject_GetAttr(self->monitor, s_scene);
    Py_XDECREF(scene);
    if (scene == NULL)
        return -1;
    self->scene = scene != Py_None;
    double nan = Py_NAN;
    PyObject *n = PyFloat_FromDouble(nan);
    self->nan3 = n ? PyTuple_Pack(3, n, n, n) : NULL;
    Py_XDECREF(n);
    self->none_phase = PyUnicode_InternFromString("none");
    if (self->nan3 == NULL || self->none_phase == NULL)
        return -1;
    self->stage = "onboard";
    self->phase_index = -1;
    if (tail_sync(self) < 0)
        return -1;
    self->ready = 1;
    return 0;
}

/* raise component_error(part, message) */
static void tail_raise(Tail *self, const char *part, PyObject *msg)
{
    if (msg == NULL)
        return;
    PyObject *e = PyObject_CallFunction(self->cerr, "sO", part, msg);
    Py_DECREF(msg);
    if (e != NULL) {
        PyErr_SetObject((PyObject *)Py_TYPE(e), e);
        Py_DECREF(e);
    }
}

/* `a, b, ... = seq` for n names: a new tuple of n items, or NULL with Python's error (the
 * items are taken from the iterator, at most n + 1 of them, as the unpacking does) */
static PyObject *unpack_n(PyObject *seq, Py_ssize_t n)
{
    if (PyTuple_CheckExact(seq) && PyTuple_GET_SIZE(seq) == n)
        return Py_NewRef(seq);
    PyObject *it = PyObject_GetIter(seq);
    if (it == NULL) {
        if (PyErr_ExceptionMatches(PyExc_TypeError)) {
            PyErr_Clear();
            PyErr_Format(PyExc_TypeError, "cannot unpack non-iterable %.200s object",
                         Py_TYPE(seq)->tp_name);
        }
        return NULL;
    }
    PyObject *t = PyTuple_New(n);
    Py_ssize_t got = 0;
    for (; t != NULL && got <= n; got++) {
        PyObject *v = PyIter_Next(it);
        if (v == NULL)
            break;
        if (got == n) {
            Py_DECREF(v);
            Py_CLEAR(t);
            PyErr_Format(PyExc_ValueError, "too many values to unpack (expected %zd)", n);
            break;
        }
        PyTuple_SET_ITEM(t, got, v);
    }
    Py_DECREF(it);
    if (t != NULL && PyErr_Occurred())
        Py_CLEAR(t);
    else if (t != NULL && got < n) {
        Py_CLEAR(t);
        PyErr_Format(PyExc_ValueError, "not enough values to unpack (expected %zd, got %zd)",
                     n, got);
    }
    return t;
}

#include "tail_run.c"
