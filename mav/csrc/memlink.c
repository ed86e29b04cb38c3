/* MemoryLink compiled (included by fastpath.c): one end of an in-memory datagram pipe, the
 * link MIL runs on. The same contract as the Python reference `mav.links.MemoryLink`
 * (tests/test_links_memory.py runs both through the same script): `pair()` makes two
 * connected ends; `send(data)` queues bytes(data) at the peer and adds len(data) to
 * `sent_bytes`; `recv()` returns the oldest queued datagram or None; `pending()` the number
 * queued; `close()` drops what is queued. The per-tick links are called ~12 times a MIL tick:
 * as C methods they cost a fraction of Python ones.
 *
 * The queue is a ring of strong references that doubles when full. Two ends refer to each
 * other, so the type takes part in the cyclic garbage collector.
 */

typedef struct MemLink {
    PyObject_HEAD
    PyObject **ring;
    Py_ssize_t cap, head, count;
    struct MemLink *peer;
    long long sent_bytes;
} MemLink;

static PyTypeObject MemLinkType;

static int ml_traverse(MemLink *self, visitproc visit, void *arg)
{
    Py_VISIT(self->peer);
    for (Py_ssize_t i = 0; i < self->count; i++)
        Py_VISIT(self->ring[(self->head + i) % self->cap]);
    return 0;
}

static void ml_drop_queue(MemLink *self)
{
    while (self->count > 0) {
        PyObject *o = self->ring[self->head];
        self->ring[self->head] = NULL;
        self->head = (self->head + 1) % self->cap;
        self->count--;
        Py_DECREF(o);
    }
    self->head = 0;
}

static int ml_clear(MemLink *self)
{
    Py_CLEAR(self->peer);
    if (self->ring != NULL)
        ml_drop_queue(self);
    return 0;
}

static void ml_dealloc(MemLink *self)
{
    PyObject_GC_UnTrack(self);
    ml_clear(self);
    PyMem_Free(self->ring);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyObject *ml_new(PyTypeObject *type, PyObject *args, PyObject *kw)
{
    if (PyTuple_GET_SIZE(args) != 0 || (kw != NULL && PyDict_GET_SIZE(kw) != 0)) {
        PyErr_SetString(PyExc_TypeError, "MemoryLink() takes no arguments");
        return NULL;
    }
    MemLink *self = (MemLink *)type->tp_alloc(type, 0);
    if (self == NULL)
        return NULL;
    self->cap = 8;
    self->ring = PyMem_Calloc((size_t)self->cap, sizeof(PyObject *));
    if (self->ring == NULL) {
        Py_DECREF(self);
        return PyErr_NoMemory();
    }
    return (PyObject *)self;
}

static int ml_push(MemLink *self, PyObject *o)
{
    if (self->count == self->cap) {
        Py_ssize_t ncap = self->cap * 2;
        PyObject **nr = PyMem_Calloc((size_t)ncap, sizeof(PyObject *));
        if (nr == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        for (Py_ssize_t i = 0; i < self->count; i++)
            nr[i] = self->ring[(self->head + i) % self->cap];
        PyMem_Free(self->ring);
        self->ring = nr;
        self->cap = ncap;
        self->head = 0;
    }
    Py_INCREF(o);
    self->ring[(self->head + self->count) % self->cap] = o;
    self->count++;
    return 0;
}

static PyObject *ml_send(MemLink *self, PyObject *data)
{
    Py_ssize_t n = PyObject_Size(data);       /* len(data), as the reference counts it */
    if (n < 0)
        return NULL;
    if (self->peer == NULL) {
        PyErr_SetString(PyExc_AttributeError, "MemoryLink.send: this end has no peer");
        return NULL;
    }
    PyObject *b;
    if (PyBytes_CheckExact(data)) {
        Py_INCREF(data);
        b = data;
    } else {                                  /* bytes(data), as the reference stores it */
        b = PyObject_CallOneArg((PyObject *)&PyBytes_Type, data);
        if (b == NULL)
            return NULL;
    }
    self->sent_bytes += n;
    int rc = ml_push(self->peer, b);
    Py_DECREF(b);
    if (rc < 0)
        return NULL;
    Py_RETURN_NONE;
}

static PyObject *ml_recv(MemLink *self, PyObject *unused)
{
    if (self->count == 0)
        Py_RETURN_NONE;
    PyObject *o = self->ring[self->head];      /* the queue's reference passes to the caller */
    self->ring[self->head] = NULL;
    self->head = (self->head + 1) % self->cap;
    self->count--;
    return o;
}

static PyObject *ml_pending(MemLink *self, PyObject *unused)
{
    return PyLong_FromSsize_t(self->count);
}

static PyObject *ml_close(MemLink *self, PyObject *unused)
{
    ml_drop_queue(self);
    Py_RETURN_NONE;
}

static PyObject *ml_pair(PyObject *cls, PyObject *unused)
{
    PyObject *empty = PyTuple_New(0);
    if (empty == NULL)
        return NULL;
    MemLink *a = (MemLink *)ml_new((PyTypeObject *)cls, empty, NULL);
    MemLink *b = a ? (MemLink *)ml_new((PyTypeObject *)cls, empty, NULL) : NULL;
    Py_DECREF(empty);
    if (b == NULL) {
        Py_XDECREF(a);
        return NULL;
    }
    Py_INCREF(b);
    a->peer = b;
    Py_INCREF(a);
    b->peer = a;
    PyObject *t = PyTuple_Pack(2, (PyObject *)a, (PyObject *)b);
    Py_DECREF(a);
    Py_DECREF(b);
    return t;
}

static PyObject *ml_get_sent(MemLink *self, void *closure)
{
    return PyLong_FromLongLong(self->sent_bytes);
}

static int ml_set_sent(MemLink *self, PyObject *v, void *closure)
{
    if (v == NULL) {
        PyErr_SetString(PyExc_AttributeError, "cannot delete sent_bytes");
        return -1;
    }
    long long x = PyLong_AsLongLong(v);
    if (x == -1 && PyErr_Occurred())
        return -1;
    self->sent_bytes = x;
    return 0;
}

static PyMethodDef ml_methods[] = {
    {"send", (PyCFunction)ml_send, METH_O, "queue bytes(data) at the peer"},
    {"recv", (PyCFunction)ml_recv, METH_NOARGS, "the oldest queued datagram, or None"},
    {"pending", (PyCFunction)ml_pending, METH_NOARGS, "datagrams waiting at this end"},
    {"close", (PyCFunction)ml_close, METH_NOARGS, "drop what is queued at this end"},
    {"pair", (PyCFunction)ml_pair, METH_NOARGS | METH_CLASS, "two connected ends"},
    {NULL, NULL, 0, NULL}};

static PyGetSetDef ml_getset[] = {
    {"sent_bytes", (getter)ml_get_sent, (setter)ml_set_sent, "bytes sent from this end", NULL},
    {NULL, NULL, NULL, NULL, NULL}};

static PyTypeObject MemLinkType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "mav._fastpath.MemoryLink",
    .tp_basicsize = sizeof(MemLink),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "One end of an in-memory datagram pipe (mav.links.MemoryLink, compiled)",
    .tp_new = ml_new,
    .tp_dealloc = (destructor)ml_dealloc,
    .tp_traverse = (traverseproc)ml_traverse,
    .tp_clear = (inquiry)ml_clear,
    .tp_methods = ml_methods,
    .tp_getset = ml_getset,
};

/* TapLink compiled: the reference is cosim.outputs.tlog.TapLink. It wraps a link (`inner`,
 * replaceable) and appends every datagram sent or received to a Tlog (`log`): the 8-byte
 * big-endian stamp `log.t_us` and the bytes, through `log._write`, and `log.count` += 1, as
 * Tlog.add does. */
typedef struct {
    PyObject_HEAD
    PyObject *inner, *log;
} Tap;

static PyObject *n_recv, *n_send, *n_close, *n_t_us, *n_write, *n_count, *n_add;

static int tap_init_names(void)
{
    n_recv = PyUnicode_InternFromString("recv");
    n_send = PyUnicode_InternFromString("send");
    n_close = PyUnicode_InternFromString("close");
    n_t_us = PyUnicode_InternFromString("t_us");
    n_write = PyUnicode_InternFromString("_write");
    n_count = PyUnicode_InternFromString("count");
    n_add = PyUnicode_InternFromString("add");
    return (n_recv && n_send && n_close && n_t_us && n_write && n_count && n_add) ? 0 : -1;
}

static int tap_traverse(Tap *self, visitproc visit, void *arg)
{
    Py_VISIT(self->inner);
    Py_VISIT(self->log);
    return 0;
}

static int tap_clear(Tap *self)
{
    Py_CLEAR(self->inner);
    Py_CLEAR(self->log);
    return 0;
}

static void tap_dealloc(Tap *self)
{
    PyObject_GC_UnTrack(self);
    tap_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int tap_init(Tap *self, PyObject *args, PyObject *kw)
{
    static char *kwlist[] = {"inner", "log", NULL};
    PyObject *inner, *log;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OO:TapLink", kwlist, &inner, &log))
        return -1;
    Py_INCREF(inner);
    Py_XSETREF(self->inner, inner);
    Py_INCREF(log);
    Py_XSETREF(self->log, log);
    return 0;
}

/* Tlog.add(data): log._write(stamp + data); log.count += 1 */
static int tap_add_to(PyObject *log, PyObject *data)
{
    if (!PyBytes_Check(data)) {      /* the reference's `bytes + data` takes any buffer */
        PyObject *r = PyObject_CallMethodOneArg(log, n_add, data);
        Py_XDECREF(r);
        return r == NULL ? -1 : 0;
    }
    PyObject *t = fast_getattr(log, n_t_us);
    if (t == NULL)
        return -1;
    unsigned long long t_us = PyLong_AsUnsignedLongLong(t);
    Py_DECREF(t);
    if (t_us == (unsigned long long)-1 && PyErr_Occurred())
        return -1;
    Py_ssize_t n = PyBytes_GET_SIZE(data);
    PyObject *rec = PyBytes_FromStringAndSize(NULL, 8 + n);
    if (rec == NULL)
        return -1;
    uint8_t *p = (uint8_t *)PyBytes_AS_STRING(rec);
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(t_us >> (56 - 8 * i));
    memcpy(p + 8, PyBytes_AS_STRING(data), (size_t)n);
    PyObject *r = PyObject_CallMethodOneArg(log, n_write, rec);
    Py_DECREF(rec);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    PyObject *c = fast_getattr(log, n_count);
    if (c == NULL)
        return -1;
    long long k = PyLong_AsLongLong(c);
    Py_DECREF(c);
    if (k == -1 && PyErr_Occurred())
        return -1;
    PyObject *c1 = PyLong_FromLongLong(k + 1);
    if (c1 == NULL)
        return -1;
    int rc = fast_setattr(log, n_count, c1);
    Py_DECREF(c1);
    return rc;
}

static int tap_add(Tap *self, PyObject *data)
{
    PyObject *log = Py_NewRef(self->log);    /* held: Python code below may replace it */
    int rc = tap_add_to(log, data);
    Py_DECREF(log);
    return rc;
}

/* inner or log deleted (`del tap.inner`) or never set (TapLink.__new__ alone) */
static int tap_ready(Tap *self)
{
    if (self->inner == NULL || self->log == NULL) {
        PyErr_SetString(PyExc_AttributeError, "TapLink: no inner link or no log");
        return -1;
    }
    return 0;
}

static PyTypeObject TapType;
static PyObject *tap_send(Tap *self, PyObject *data);
static PyObject *tap_recv(Tap *self, PyObject *unused);

/* link.recv() and link.send(data) from C: a compiled link (exactly MemoryLink or TapLink,
 * whose methods cannot be replaced) is called directly, any other link through its method */
static PyObject *link_recv(PyObject *link)
{
    if (Py_TYPE(link) == &MemLinkType)
        return ml_recv((MemLink *)link, NULL);
    if (Py_TYPE(link) == &TapType)
        return tap_recv((Tap *)link, NULL);
    return PyObject_CallMethodNoArgs(link, n_recv);
}

static PyObject *link_send(PyObject *link, PyObject *data)
{
    if (Py_TYPE(link) == &MemLinkType)
        return ml_send((MemLink *)link, data);
    if (Py_TYPE(link) == &TapType)
        return tap_send((Tap *)link, data);
    return PyObject_CallMethodOneArg(link, n_send, data);
}

static PyObject *tap_send(Tap *self, PyObject *data)
{
    if (tap_ready(self) < 0 || tap_add(self, data) < 0 || tap_ready(self) < 0)
        return NULL;
    if (Py_EnterRecursiveCall(" in TapLink.send"))   /* a loop of taps: RecursionError */
        return NULL;
    PyObject *inner = Py_NewRef(self->inner);     /* held: the log may have replaced it */
    PyObject *r = link_send(inner, data);
    Py_DECREF(inner);
    Py_LeaveRecursiveCall();
    return r;
}

static PyObject *tap_recv(Tap *self, PyObject *unused)
{
    if (tap_ready(self) < 0 || Py_EnterRecursiveCall(" in TapLink.recv"))
        return NULL;
    PyObject *inner = Py_NewRef(self->inner);
    PyObject *data = link_recv(inner);
    Py_DECREF(inner);
    Py_LeaveRecursiveCall();
    if (data == NULL || data == Py_None)
        return data;
    if (tap_ready(self) < 0 || tap_add(self, data) < 0) {
        Py_DECREF(data);
        return NULL;
    }
    return data;
}

static PyObject *tap_close(Tap *self, PyObject *unused)
{
    if (tap_ready(self) < 0)
        return NULL;
    return PyObject_CallMethodNoArgs(self->inner, n_close);
}

static PyMethodDef tap_methods[] = {
    {"send", (PyCFunction)tap_send, METH_O, "log, then send on the inner link"},
    {"recv", (PyCFunction)tap_recv, METH_NOARGS, "receive from the inner link, log it"},
    {"close", (PyCFunction)tap_close, METH_NOARGS, "close the inner link"},
    {NULL, NULL, 0, NULL}};

static PyMemberDef tap_members[] = {
    {"inner", T_OBJECT_EX, offsetof(Tap, inner), 0, "the wrapped link"},
    {"log", T_OBJECT_EX, offsetof(Tap, log), 0, "the Tlog"},
    {NULL, 0, 0, 0, NULL}};

static PyTypeObject TapType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "mav._fastpath.TapLink",
    .tp_basicsize = sizeof(Tap),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "A link wrapper logging every datagram to a Tlog (cosim.outputs.tlog.TapLink)",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)tap_init,
    .tp_dealloc = (destructor)tap_dealloc,
    .tp_traverse = (traverseproc)tap_traverse,
    .tp_clear = (inquiry)tap_clear,
    .tp_methods = tap_methods,
    .tp_members = tap_members,
};
