/* The simulator's side of the HIL link, compiled (included by fastpath.c): its ODOMETRY and
 * MIL's lockstep exchange (below).
 *
 * The ODOMETRY's reference is
 * mav.hil.HilSimulatorCodec.encode_odometry: the payload is struct "<Q13f" of (t_us, *m) and
 * the constant tail, framed on the simulator's MAVLink object as wire.frame does.
 *
 * odometry_frame(fallback, mav, msgid, crc_extra, tail, t_us, m) -> bytes
 *
 * Anything but the per-tick case (m not a tuple of 13 floats, t_us not an int in 0..2^64-1, a
 * signing `mav`, a tail that does not fill the payload) returns fallback(t_us, m): the
 * reference, which then packs or raises as struct does. The floats are packed by
 * PyFloat_Pack4 as struct's "<f" is (too large for a float: OverflowError, as struct raises).
 * Tested byte for byte against the reference (tests/test_fastpath_encoders.py).
 */
#define ODO_HEAD 60      /* "<Q13f" */

static PyObject *fp_odometry_frame(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 7 || !PyBytes_Check(args[4])) {
        PyErr_SetString(PyExc_TypeError, "odometry_frame(fallback, mav, msgid, crc_extra, "
                                         "tail: bytes, t_us, m)");
        return NULL;
    }
    PyObject *m = args[6], *t_us = args[5];
    Py_ssize_t tail = PyBytes_GET_SIZE(args[4]);
    if (!PyTuple_CheckExact(m) || PyTuple_GET_SIZE(m) != 13 || !PyLong_CheckExact(t_us) ||
        tail < 1 || ODO_HEAD + tail > 255)
        return PyObject_CallFunctionObjArgs(args[0], t_us, m, NULL);
    for (int i = 0; i < 13; i++)
        if (!PyFloat_CheckExact(PyTuple_GET_ITEM(m, i)))
            return PyObject_CallFunctionObjArgs(args[0], t_us, m, NULL);
    unsigned long long t = PyLong_AsUnsignedLongLong(t_us);
    if (t == (unsigned long long)-1 && PyErr_Occurred()) {
        PyErr_Clear();     /* negative or too large: the reference raises struct.error */
        return PyObject_CallFunctionObjArgs(args[0], t_us, m, NULL);
    }
    int signing = signs_outgoing(args[1]);
    if (signing < 0)
        return NULL;
    if (signing)
        return PyObject_CallFunctionObjArgs(args[0], t_us, m, NULL);
    long msgid = PyLong_AsLong(args[2]), extra = PyLong_AsLong(args[3]);
    if (PyErr_Occurred())
        return NULL;
    uint8_t pl[255];
    for (int i = 0; i < 8; i++)
        pl[i] = (uint8_t)(t >> (8 * i));
    for (int i = 0; i < 13; i++)
        if (PyFloat_Pack4(PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(m, i)), (char *)pl + 8 + 4 * i, 1) < 0)
            return NULL;
    memcpy(pl + ODO_HEAD, PyBytes_AS_STRING(args[4]), (size_t)tail);
    return frame_on(args[1], msgid, (uint8_t)extra, pl, ODO_HEAD + tail);
}

/* mil_exchange(sim, poll, pending, data) -> bytes | None: one lockstep HIL exchange over an
 * in-memory pair, as cosim's OnboardHandle.exchange does it in MIL (the reference):
 * sim.send(data), then poll() until it handles a tick or nothing is queued at the vehicle's
 * end (`pending()`), then the answer, sim.recv() (None if there was none). Exceptions are the
 * reference's, unwrapped: its caller names them. */
static PyObject *fp_mil_exchange(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "mil_exchange(sim, poll, pending, data)");
        return NULL;
    }
    PyObject *r = link_send(args[0], args[3]);
    if (r == NULL)
        return NULL;
    Py_DECREF(r);
    for (;;) {
        r = PyObject_CallNoArgs(args[1]);
        int done = r ? PyObject_IsTrue(r) : -1;
        Py_XDECREF(r);
        if (done < 0)
            return NULL;
        if (done)
            break;
        r = PyObject_CallNoArgs(args[2]);
        int more = r ? PyObject_IsTrue(r) : -1;
        Py_XDECREF(r);
        if (more < 0)
            return NULL;
        if (!more)
            break;
    }
    return link_recv(args[0]);
}
