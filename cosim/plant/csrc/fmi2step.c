/* cosim.plant._fmi2step: one FMI 2.0 co-simulation tick (set inputs, doStep, get outputs) in
 * one call from Python, without ctypes argument marshalling (`python -m onesource.build`, `make build`
 * builds it; cosim/plant/fmu.py uses it when it is there).
 *
 * Generic FMI 2.0: it calls the FMU's own fmi2SetReal, fmi2DoStep, fmi2GetReal and
 * fmi2GetBoolean through the function pointers fmpy loaded (passed in as addresses), or the
 * FMU's fused `quadrotorSetStepGet` (the same four calls in one, fmus/quadrotor/fmi2.c) when it
 * has one. The communication point is k * h in double arithmetic, as the Python path computes
 * it, so both paths give the same bits (tests/test_plant_stepper.py).
 *
 * Stepper(fns, comp, in_vr, out_vr, bool_vr, h, y, on_error):
 *   fns      (set_real, do_step, get_real, get_bool, fused or 0): function addresses
 *   comp     the fmi2Component (address)
 *   in_vr, out_vr, bool_vr   value references (tuples of ints); len(in_vr) <= 16
 *   h        the communication step size, s
 *   y        a list of len(out_vr) + len(bool_vr) floats, updated in place by step()
 *   on_error callable(status, what) called when a call returns a status other than fmi2OK;
 *            if it raises, step() raises that exception.
 *   names    (optional) the inputs' names, so step() also takes them as keywords
 * .step(u1, ..., un) with the inputs in in_vr order (missing trailing ones are 0.0):
 *   advance k -> k+1 and return y.  .k: the tick counter (read/write).
 *
 * Misuse raises, never crashes: step() on a Stepper whose __init__ has not succeeded raises
 * RuntimeError; a failed __init__ (again) leaves the Stepper as it was; a y list resized
 * behind its back raises IndexError (tests/test_compiled_misuse.py). The function and
 * component addresses are trusted, as ctypes trusts them: cosim/plant/fmu.py passes fmpy's.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MAX_IN 16

typedef int (*set_real_f)(void *, const unsigned int *, size_t, const double *);
typedef int (*do_step_f)(void *, double, double, int);
typedef int (*get_real_f)(void *, const unsigned int *, size_t, double *);
typedef int (*get_bool_f)(void *, const unsigned int *, size_t, int *);
typedef int (*fused_f)(void *, const unsigned int *, size_t, const double *, double, double,
                       const unsigned int *, size_t, double *, const unsigned int *, size_t,
                       int *);

typedef struct {
    PyObject_HEAD
    set_real_f set_real;
    do_step_f do_step;
    get_real_f get_real;
    get_bool_f get_bool;
    fused_f fused;
    void *comp;
    unsigned int in_vr[MAX_IN];
    size_t n_in;
    unsigned int *out_vr, *bool_vr;
    size_t n_out, n_bool;
    double in_val[MAX_IN];
    double *out_val;
    int *bool_val;
    double h;
    long long k;
    PyObject *y;
    PyObject *on_error;
    PyObject *names;        /* tuple of the inputs' keyword names (or NULL: positional only) */
} Stepper;

static void Stepper_dealloc(Stepper *self)
{
    free(self->out_vr);
    free(self->bool_vr);
    free(self->out_val);
    free(self->bool_val);
    Py_XDECREF(self->y);
    Py_XDECREF(self->on_error);
    Py_XDECREF(self->names);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static void *address(PyObject *o)
{
    return PyLong_AsVoidPtr(o);
}

static unsigned int *read_vrs(PyObject *seq, size_t *n, const char *what)
{
    PyObject *fast = PySequence_Fast(seq, what);
    if (fast == NULL)
        return NULL;
    Py_ssize_t m = PySequence_Fast_GET_SIZE(fast);
    unsigned int *out = calloc(m > 0 ? (size_t)m : 1, sizeof(unsigned int));
    if (out == NULL) {
        Py_DECREF(fast);
        PyErr_NoMemory();
        return NULL;
    }
    for (Py_ssize_t i = 0; i < m; i++) {
        unsigned long v = PyLong_AsUnsignedLong(PySequence_Fast_GET_ITEM(fast, i));
        if (v == (unsigned long)-1 && PyErr_Occurred()) {
            free(out);
            Py_DECREF(fast);
            return NULL;
        }
        out[i] = (unsigned int)v;
    }
    Py_DECREF(fast);
    *n = (size_t)m;
    return out;
}

static int Stepper_init(Stepper *self, PyObject *args, PyObject *kw)
{
    PyObject *fns, *comp, *in_vr, *out_vr, *bool_vr, *y, *on_error, *names = NULL;
    double h;
    if (!PyArg_ParseTuple(args, "O!OOOOdO!O|O!", &PyTuple_Type, &fns, &comp, &in_vr, &out_vr,
                          &bool_vr, &h, &PyList_Type, &y, &on_error, &PyTuple_Type, &names))
        return -1;
    if (PyTuple_GET_SIZE(fns) != 5) {
        PyErr_SetString(PyExc_ValueError, "fns: (set_real, do_step, get_real, get_bool, fused)");
        return -1;
    }
    void *p[5];
    for (int i = 0; i < 5; i++) {
        p[i] = address(PyTuple_GET_ITEM(fns, i));
        if (PyErr_Occurred())
            return -1;
    }
    if (p[0] == NULL || p[1] == NULL || p[2] == NULL || p[3] == NULL) {
        PyErr_SetString(PyExc_ValueError, "fns: set_real, do_step, get_real, get_bool needed");
        return -1;
    }
    void *c = address(comp);
    if (PyErr_Occurred())
        return -1;
    if (!PyCallable_Check(on_error)) {
        PyErr_SetString(PyExc_TypeError, "on_error: a callable(status, what)");
        return -1;
    }
    /* everything read into locals first: a failure leaves the Stepper as it was */
    size_t n_in = 0, n_out = 0, n_bool = 0;
    unsigned int *vin = NULL, *vout = NULL, *vbool = NULL;
    double *out_val = NULL;
    int *bool_val = NULL;
    vin = read_vrs(in_vr, &n_in, "in_vr: a sequence of ints");
    if (vin == NULL)
        goto fail;
    if (n_in > MAX_IN) {
        PyErr_Format(PyExc_ValueError, "in_vr: at most %d inputs", MAX_IN);
        goto fail;
    }
    vout = read_vrs(out_vr, &n_out, "out_vr: a sequence of ints");
    if (vout == NULL)
        goto fail;
    vbool = read_vrs(bool_vr, &n_bool, "bool_vr: a sequence of ints");
    if (vbool == NULL)
        goto fail;
    if ((size_t)PyList_GET_SIZE(y) != n_out + n_bool) {
        PyErr_SetString(PyExc_ValueError, "y: a list of len(out_vr) + len(bool_vr) floats");
        goto fail;
    }
    if (names != NULL && (size_t)PyTuple_GET_SIZE(names) != n_in) {
        PyErr_SetString(PyExc_ValueError, "names: one per input");
        goto fail;
    }
    out_val = calloc(n_out + 1, sizeof(double));
    bool_val = calloc(n_bool + 1, sizeof(int));
    if (out_val == NULL || bool_val == NULL) {
        PyErr_NoMemory();
        goto fail;
    }
    self->set_real = (set_real_f)p[0];
    self->do_step = (do_step_f)p[1];
    self->get_real = (get_real_f)p[2];
    self->get_bool = (get_bool_f)p[3];
    self->fused = (fused_f)p[4];
    self->comp = c;
    memcpy(self->in_vr, vin, n_in * sizeof(unsigned int));
    free(vin);
    self->n_in = n_in;
    free(self->out_vr);
    free(self->bool_vr);
    free(self->out_val);
    free(self->bool_val);
    self->out_vr = vout;
    self->bool_vr = vbool;
    self->out_val = out_val;
    self->bool_val = bool_val;
    self->n_out = n_out;
    self->n_bool = n_bool;
    self->h = h;
    self->k = 0;
    Py_INCREF(y);
    Py_XSETREF(self->y, y);
    Py_INCREF(on_error);
    Py_XSETREF(self->on_error, on_error);
    Py_XINCREF(names);
    Py_XSETREF(self->names, names);
    return 0;
fail:
    free(vin);
    free(vout);
    free(vbool);
    free(out_val);
    free(bool_val);
    return -1;
}

/* a status other than fmi2OK: on_error(status, what) decides (it raises to stop the tick,
 * as the Python path's _check does); 0 to go on, -1 with the exception set */
static int failed(Stepper *self, int status, const char *what)
{
    PyObject *r = PyObject_CallFunction(self->on_error, "is", status, what);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}

static int as_double(PyObject *a, double *out)
{
    double v = PyFloat_CheckExact(a) ? PyFloat_AS_DOUBLE(a) : PyFloat_AsDouble(a);
    if (v == -1.0 && PyErr_Occurred())
        return -1;
    *out = v;
    return 0;
}

static PyObject *Stepper_step(Stepper *self, PyObject *const *args, Py_ssize_t nargs,
                              PyObject *kwnames)
{
    if (self->y == NULL) {
        PyErr_SetString(PyExc_RuntimeError,
                        "Stepper used before a successful __init__ or after close()");
        return NULL;
    }
    if ((size_t)nargs > self->n_in) {
        PyErr_Format(PyExc_TypeError, "step() takes at most %zd inputs", (Py_ssize_t)self->n_in);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < nargs; i++)
        if (as_double(args[i], &self->in_val[i]) < 0)
            return NULL;
    for (size_t i = (size_t)nargs; i < self->n_in; i++)
        self->in_val[i] = 0.0;
    if (kwnames != NULL) {         /* inputs by name (the Python signature's keywords) */
        for (Py_ssize_t j = 0; j < PyTuple_GET_SIZE(kwnames); j++) {
            PyObject *key = PyTuple_GET_ITEM(kwnames, j);
            Py_ssize_t at = -1;
            for (Py_ssize_t i = 0; self->names != NULL && i < (Py_ssize_t)self->n_in; i++) {
                int eq = PyUnicode_Compare(key, PyTuple_GET_ITEM(self->names, i));
                if (eq == 0) {
                    at = i;
                    break;
                }
            }
            if (at < 0 || at < nargs) {
                PyErr_Format(PyExc_TypeError, at < 0 ? "step() got an unexpected keyword "
                             "argument '%U'" : "step() got multiple values for '%U'", key);
                return NULL;
            }
            if (as_double(args[nargs + j], &self->in_val[at]) < 0)
                return NULL;
        }
    }
    /* the order of the Python path (fmu.py Plant.step): k advances after the doStep, so an
     * error in getReal / getBoolean is reported at the new time */
    double t = (double)self->k * self->h;
    void *c = self->comp;
    int st;
    if (self->fused != NULL) {
        st = self->fused(c, self->in_vr, self->n_in, self->in_val, t, self->h, self->out_vr,
                         self->n_out, self->out_val, self->bool_vr, self->n_bool,
                         self->bool_val);
        if (st != 0 && failed(self, st, "quadrotorSetStepGet (fmi2SetReal, fmi2DoStep, "
                                        "fmi2GetReal, fmi2GetBoolean)") < 0)
            return NULL;
        self->k += 1;
    } else {
        st = self->set_real(c, self->in_vr, self->n_in, self->in_val);
        if (st != 0 && failed(self, st, "fmi2SetReal") < 0)
            return NULL;
        st = self->do_step(c, t, self->h, 1);
        if (st != 0 && failed(self, st, "fmi2DoStep") < 0)
            return NULL;
        self->k += 1;
        st = self->get_real(c, self->out_vr, self->n_out, self->out_val);
        if (st != 0 && failed(self, st, "fmi2GetReal") < 0)
            return NULL;
        st = self->get_bool(c, self->bool_vr, self->n_bool, self->bool_val);
        if (st != 0 && failed(self, st, "fmi2GetBoolean") < 0)
            return NULL;
    }
    PyObject *y = self->y;
    for (size_t i = 0; i < self->n_out + self->n_bool; i++) {
        double v = i < self->n_out ? self->out_val[i] : (self->bool_val[i - self->n_out] ? 1.0
                                                                                  : 0.0);
        PyObject *f = PyFloat_FromDouble(v);
        /* steals f (also on failure), drops the old item; IndexError if y was shrunk */
        if (f == NULL || PyList_SetItem(y, (Py_ssize_t)i, f) < 0)
            return NULL;
    }
    Py_INCREF(y);
    return y;
}

/* close(): the FMU instance is about to be freed; step() raises from now on (a bound
 * `step` kept elsewhere must not call into freed memory) */
static PyObject *Stepper_close(Stepper *self, PyObject *unused)
{
    Py_CLEAR(self->y);
    return Py_NewRef(Py_None);
}

static PyObject *Stepper_get_k(Stepper *self, void *closure)
{
    return PyLong_FromLongLong(self->k);
}

static int Stepper_set_k(Stepper *self, PyObject *v, void *closure)
{
    if (v == NULL) {
        PyErr_SetString(PyExc_AttributeError, "k cannot be deleted");
        return -1;
    }
    long long k = PyLong_AsLongLong(v);
    if (k == -1 && PyErr_Occurred())
        return -1;
    self->k = k;
    return 0;
}

static PyMethodDef Stepper_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Stepper_step, METH_FASTCALL | METH_KEYWORDS,
     "step(u1, ..., un) -> y: one co-simulation tick with the inputs in in_vr order."},
    {"close", (PyCFunction)Stepper_close, METH_NOARGS,
     "close(): no more steps (the FMU instance is being freed)."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Stepper_getset[] = {
    {"k", (getter)Stepper_get_k, (setter)Stepper_set_k, "the tick counter", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject StepperType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "cosim.plant._fmi2step.Stepper",
    .tp_basicsize = sizeof(Stepper),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "One FMI 2.0 co-simulation tick per call (see the module source).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Stepper_init,
    .tp_dealloc = (destructor)Stepper_dealloc,
    .tp_methods = Stepper_methods,
    .tp_getset = Stepper_getset,
};

static struct PyModuleDef fmi2step_module = {
    PyModuleDef_HEAD_INIT, "_fmi2step",
    "One FMI 2.0 co-simulation tick per call, without ctypes marshalling.", -1, NULL,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__fmi2step(void)
{
    if (PyType_Ready(&StepperType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&fmi2step_module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddObjectRef(m, "Stepper", (PyObject *)&StepperType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
