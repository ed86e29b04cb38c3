/* Attribute reads and writes from C at the cost of a slot access (included by fastpath.c
 * first: the other parts use it).
 *
 * The records the tick reads and writes (VehicleStatus, VehicleState, Setpoint, Chan, Stream,
 * Battery) are classes with __slots__. `PyObject_GetAttr` on them looks the name up in the
 * type (the method cache, then the member descriptor) before reading the slot; here the slot's
 * offset is cached, guarded by the exact type and its version tag (CPython
 * changes the tag whenever the type or a base is modified), which is how CPython's own
 * specialised LOAD_ATTR_SLOT guards. Only a plain object slot (a T_OBJECT_EX member that is
 * not read-only, on a type with the generic getattr and setattr) is cached; for anything else
 * (an instance-dict attribute, a property, a type that customises attribute access) the cache
 * remembers that and the generic PyObject_GetAttr / PyObject_SetAttr run, so the answer is
 * always the one Python gives. An unset slot goes to the generic path too, which raises the
 * AttributeError Python raises. The cache is direct-mapped on (interned name, type); names
 * that are not interned strings always take the generic path. The sites that read the same
 * names every tick (the tick's names, the controller's and telemetry's field lists) keep
 * their own one-entry cache per name in front of it (`slot_at`), which skips the hashing.
 */

typedef struct {
    PyObject *name;          /* interned attribute name (not owned: names are kept alive) */
    PyTypeObject *type;      /* not owned: the version tag check makes a stale entry miss */
    unsigned int version;
    Py_ssize_t offset;       /* -1: not a plain slot, use the generic path */
} SlotEntry;

#define SLOT_CACHE 4096      /* direct-mapped on (name, type) */
static SlotEntry slot_cache[SLOT_CACHE];

/* the offset of `name` as a plain object slot of tp, or -1 */
static Py_ssize_t slot_offset(PyTypeObject *tp, PyObject *name)
{
    if (tp->tp_getattro != PyObject_GenericGetAttr || tp->tp_setattro != PyObject_GenericSetAttr)
        return -1;
    PyObject *d = _PyType_Lookup(tp, name);     /* borrowed; assigns the version tag */
    if (d == NULL || Py_TYPE(d) != &PyMemberDescr_Type ||
        !PyType_IsSubtype(tp, PyDescr_TYPE(d)))   /* another class's slot: Python refuses */
        return -1;
    PyMemberDef *m = ((PyMemberDescrObject *)d)->d_member;
    if (m->type != T_OBJECT_EX || (m->flags & READONLY))
        return -1;
    return m->offset;
}

/* off, noted in the cache entry e for (name, tp) when tp's version tag is valid */
static Py_ssize_t remember(SlotEntry *e, PyTypeObject *tp, PyObject *name, Py_ssize_t off)
{
    if (PyType_HasFeature(tp, Py_TPFLAGS_VALID_VERSION_TAG)) {
        e->name = name;
        e->type = tp;
        e->version = tp->tp_version_tag;
        e->offset = off;
    }
    return off;
}

/* the slot offset of name on o's type, or -1 (then the generic path applies) */
static Py_ssize_t slot_of(PyObject *o, PyObject *name)
{
    PyTypeObject *tp = Py_TYPE(o);
    if (!PyUnicode_CheckExact(name) || !PyUnicode_CHECK_INTERNED(name))
        return -1;
    uintptr_t h = ((uintptr_t)name ^ ((uintptr_t)tp << 7)) * (uintptr_t)0x9E3779B97F4A7C15ULL;
    SlotEntry *e = &slot_cache[(h >> 40) & (SLOT_CACHE - 1)];
    if (e->name == name && e->type == tp && e->version == tp->tp_version_tag &&
        PyType_HasFeature(tp, Py_TPFLAGS_VALID_VERSION_TAG))
        return e->offset;
    Py_ssize_t off = slot_offset(tp, name);
    return remember(e, tp, name, off);
}

/* a call site's own one-entry cache `e` for one name: no hashing while the site sees the same
 * type (with the same guard); anything else asks slot_of */
static Py_ssize_t slot_at(SlotEntry *e, PyObject *o, PyObject *name)
{
    PyTypeObject *tp = Py_TYPE(o);
    if (e->type == tp && e->version == tp->tp_version_tag &&
        PyType_HasFeature(tp, Py_TPFLAGS_VALID_VERSION_TAG))
        return e->offset;
    Py_ssize_t off = slot_of(o, name);
    return remember(e, tp, name, off);
}

/* o.name, read from the slot at `off` (-1: the generic path) */
static PyObject *getattr_off(PyObject *o, Py_ssize_t off, PyObject *name)
{
    if (off >= 0) {
        PyObject *v = *(PyObject **)((char *)o + off);
        if (v != NULL) {
            Py_INCREF(v);
            return v;
        }
    }
    return PyObject_GetAttr(o, name);
}

/* o.name = v, into the slot at `off` (-1: the generic path) */
static int setattr_off(PyObject *o, Py_ssize_t off, PyObject *name, PyObject *v)
{
    if (off < 0)
        return PyObject_SetAttr(o, name, v);
    PyObject **p = (PyObject **)((char *)o + off);
    PyObject *old = *p;
    Py_INCREF(v);
    *p = v;
    Py_XDECREF(old);
    return 0;
}

/* getattr(o, name) -> new reference, or NULL with the error set */
static PyObject *fast_getattr(PyObject *o, PyObject *name)
{
    return getattr_off(o, slot_of(o, name), name);
}

/* setattr(o, name, v) -> 0, or -1 with the error set */
static int fast_setattr(PyObject *o, PyObject *name, PyObject *v)
{
    return setattr_off(o, slot_of(o, name), name, v);
}

/* the same through a call site's cache (slot_at) */
static PyObject *getattr_at(SlotEntry *e, PyObject *o, PyObject *name)
{
    return getattr_off(o, slot_at(e, o, name), name);
}

static int setattr_at(SlotEntry *e, PyObject *o, PyObject *name, PyObject *v)
{
    return setattr_off(o, slot_at(e, o, name), name, v);
}
