/* The per-tick HIL decoders in one call (included by fastpath.c): wire._one_frame_decoder's
 * `decode_compiled` without its Python frame. Called through functools.partial with the
 * message's constants bound, so a tick's ODOMETRY and HIL_ACTUATOR_CONTROLS decode run no
 * Python code.
 *
 * unpack_one(fallback, unpack_from, unpack, used_len, msgid, crc_extra, data) -> tuple | None:
 * data not exactly bytes -> fallback(data) (the Python decoder); otherwise None unless data is
 * exactly one well-formed MAVLink 2 frame of msgid with a correct CRC (fp_check's verdict),
 * else the leading fields: unpack_from(data, 10) when the payload covers them, or
 * unpack(payload + zeros up to used_len) for a trimmed payload (MAVLink 2 zero-extends). */
static PyObject *py_ten;

static PyObject *fp_unpack_one(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "unpack_one(fallback, unpack_from, unpack, used_len, "
                                         "msgid, crc_extra, data)");
        return NULL;
    }
    PyObject *data = args[6];
    if (!PyBytes_CheckExact(data))
        return PyObject_CallOneArg(args[0], data);
    long used_len = PyLong_AsLong(args[3]);
    long msgid = PyLong_AsLong(args[4]);
    long extra = PyLong_AsLong(args[5]);
    if (PyErr_Occurred())
        return NULL;
    if (used_len < 0 || used_len > 255) {
        PyErr_SetString(PyExc_ValueError, "unpack_one: used_len must be 0..255");
        return NULL;
    }
    const uint8_t *d = (const uint8_t *)PyBytes_AS_STRING(data);
    Py_ssize_t n = PyBytes_GET_SIZE(data);
    if (n < 12 || d[0] != MAGIC_V2 || d[7] != (msgid & 0xFF) || d[8] != ((msgid >> 8) & 0xFF) ||
        d[9] != ((msgid >> 16) & 0xFF))
        Py_RETURN_NONE;
    uint8_t flags = d[2], plen = d[1];
    Py_ssize_t crc_at = HDR_V2 + plen;
    if ((flags & ~1) != 0 || crc_at + 2 + (flags ? SIG_LEN : 0) != n)
        Py_RETURN_NONE;
    uint16_t crc = crc_acc(0xFFFF, d + 1, HDR_V2 - 1 + plen);
    uint8_t ex = (uint8_t)extra;
    crc = crc_acc(crc, &ex, 1);
    if (crc != (uint16_t)(d[crc_at] | d[crc_at + 1] << 8))
        Py_RETURN_NONE;
    if (plen >= used_len) {
        PyObject *a[2] = {data, py_ten};
        return PyObject_Vectorcall(args[1], a, 2, NULL);
    }
    PyObject *padded = PyBytes_FromStringAndSize(NULL, used_len);
    if (padded == NULL)
        return NULL;
    uint8_t *p = (uint8_t *)PyBytes_AS_STRING(padded);
    memcpy(p, d + HDR_V2, plen);
    memset(p + plen, 0, (size_t)(used_len - plen));
    PyObject *r = PyObject_CallOneArg(args[2], padded);
    Py_DECREF(padded);
    return r;
}
