/* MAVLink 2 framing, compiled (included by fastpath.c).
 * The per-tick codec's framing and checks (mav/wire.py `frame`, `decode_fast` and the
 * one-frame decoders), same bytes and same verdicts; the payload packing and unpacking stay
 * with Python's struct (already compiled). CRC-16/MCRF4XX (X.25) with the message's CRC_EXTRA.
 */
#define MAGIC_V2 0xFD
#define HDR_V2 10
#define SIG_LEN 13

static uint16_t crc_t[8][256];   /* X.25 (reflected 0x1021 = 0x8408), slice-by-8, at import */

static void crc_init(void)
{
    for (int i = 0; i < 256; i++) {
        uint16_t c = (uint16_t)i;
        for (int k = 0; k < 8; k++)
            c = (c & 1) ? (uint16_t)((c >> 1) ^ 0x8408) : (uint16_t)(c >> 1);
        crc_t[0][i] = c;
    }
    for (int k = 1; k < 8; k++)
        for (int i = 0; i < 256; i++)
            crc_t[k][i] = (uint16_t)((crc_t[k - 1][i] >> 8) ^ crc_t[0][crc_t[k - 1][i] & 0xFF]);
}

static inline uint16_t crc_acc(uint16_t crc, const uint8_t *p, Py_ssize_t n)
{
    while (n >= 8) {
        crc ^= (uint16_t)(p[0] | p[1] << 8);
        crc = (uint16_t)(crc_t[7][crc & 0xFF] ^ crc_t[6][crc >> 8] ^ crc_t[5][p[2]] ^
                         crc_t[4][p[3]] ^ crc_t[3][p[4]] ^ crc_t[2][p[5]] ^ crc_t[1][p[6]] ^
                         crc_t[0][p[7]]);
        p += 8;
        n -= 8;
    }
    while (n-- > 0)
        crc = (uint16_t)((crc >> 8) ^ crc_t[0][(crc ^ *p++) & 0xFF]);
    return crc;
}

/* an unsigned MAVLink 2 frame of payload pl[0:n], trailing zero bytes trimmed (one kept) */
static PyObject *frame_bytes(long seq, long sys, long comp, long msgid, uint8_t extra,
                             const uint8_t *pl, Py_ssize_t n)
{
    Py_ssize_t plen = n;
    while (plen > 1 && pl[plen - 1] == 0)
        plen--;
    PyObject *out = PyBytes_FromStringAndSize(NULL, HDR_V2 + plen + 2);
    if (out == NULL)
        return NULL;
    uint8_t *b = (uint8_t *)PyBytes_AS_STRING(out);
    b[0] = MAGIC_V2;
    b[1] = (uint8_t)plen;
    b[2] = 0;
    b[3] = 0;
    b[4] = (uint8_t)seq;
    b[5] = (uint8_t)sys;
    b[6] = (uint8_t)comp;
    b[7] = (uint8_t)(msgid & 0xFF);
    b[8] = (uint8_t)((msgid >> 8) & 0xFF);
    b[9] = (uint8_t)((msgid >> 16) & 0xFF);
    memcpy(b + HDR_V2, pl, (size_t)plen);
    uint16_t crc = crc_acc(0xFFFF, b + 1, HDR_V2 - 1 + plen);
    crc = crc_acc(crc, &extra, 1);
    b[HDR_V2 + plen] = (uint8_t)(crc & 0xFF);
    b[HDR_V2 + plen + 1] = (uint8_t)(crc >> 8);
    return out;
}

/* frame(seq, sysid, compid, msgid, crc_extra, payload) -> bytes: an unsigned MAVLink 2 frame,
 * trailing zero bytes of the payload trimmed (at least one kept) */
static PyObject *fp_frame(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 6 || !PyBytes_Check(args[5])) {
        PyErr_SetString(PyExc_TypeError,
                        "frame(seq, sysid, compid, msgid, crc_extra, payload: bytes)");
        return NULL;
    }
    long v[5];
    for (int i = 0; i < 5; i++) {
        v[i] = PyLong_AsLong(args[i]);
        if (v[i] == -1 && PyErr_Occurred())
            return NULL;
    }
    const uint8_t *pl = (const uint8_t *)PyBytes_AS_STRING(args[5]);
    Py_ssize_t n = PyBytes_GET_SIZE(args[5]);
    if (n < 1 || n > 255) {
        PyErr_SetString(PyExc_ValueError, "payload must be 1..255 bytes");
        return NULL;
    }
    return frame_bytes(v[0], v[1], v[2], v[3], (uint8_t)v[4], pl, n);
}

/* check(data, start, end, msgid, crc_extra) -> payload length, or -1 unless data[start:end] is
 * exactly one well-formed MAVLink 2 frame of that id (unsigned or signed: the signature is not
 * checked here) with a correct CRC (wire.decode_fast's verdict). end -1: the end of data. */
static PyObject *fp_check(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5 || !PyBytes_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "check(data: bytes, start, end, msgid, crc_extra)");
        return NULL;
    }
    Py_ssize_t n = PyBytes_GET_SIZE(args[0]);
    long v[4];
    for (int i = 0; i < 4; i++) {
        v[i] = PyLong_AsLong(args[i + 1]);
        if (v[i] == -1 && PyErr_Occurred())
            return NULL;
    }
    const uint8_t *d = (const uint8_t *)PyBytes_AS_STRING(args[0]);
    Py_ssize_t i = v[0], end = v[1] < 0 ? n : v[1];
    long r = -1;
    if (i >= 0 && end <= n && i + 12 <= end && d[i] == MAGIC_V2 &&
        d[i + 7] == (v[2] & 0xFF) && d[i + 8] == ((v[2] >> 8) & 0xFF) &&
        d[i + 9] == ((v[2] >> 16) & 0xFF)) {
        uint8_t flags = d[i + 2], plen = d[i + 1];
        Py_ssize_t crc_at = i + HDR_V2 + plen;
        if ((flags & ~1) == 0 && crc_at + 2 + (flags ? SIG_LEN : 0) == end) {
            uint16_t crc = crc_acc(0xFFFF, d + i + 1, HDR_V2 - 1 + plen);
            uint8_t extra = (uint8_t)v[3];
            crc = crc_acc(crc, &extra, 1);
            if (crc == (uint16_t)(d[crc_at] | d[crc_at + 1] << 8))
                r = plen;
        }
    }
    return PyLong_FromLong(r);
}
