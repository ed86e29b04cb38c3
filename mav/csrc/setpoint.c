/* The offboard setpoint stream, compiled (included by fastpath.c: one translation unit).
 *
 * setpoint_local_ned(data, of, sysid, compid, max_pos, max_vel, max_yaw, max_rate) -> bool
 *
 * The 200 Hz case of mav/onboard/offboard.py `Offboard.on_setpoint` for a datagram that is one
 * MAVLink 2 SET_POSITION_TARGET_LOCAL_NED frame (LinkInput's fast case: what wire.decode_fast
 * accepts, unsigned link): when the setpoint is one the Python code ACCEPTS in MAV_FRAME_LOCAL_NED
 * (addressed to sysid and compid or component 0, a supported type_mask, values in range), writes
 * the Setpoint `of` exactly as that code does (x..yaw_rate, NaN where not commanded, yaw wrapped
 * to [-pi, pi)) and returns True. Anything else (not such a frame, another frame of reference,
 * a setpoint to reject) returns False and leaves `of` alone: the caller then runs the Python
 * path, which counts and reports it. Tested back to back with the Python path on random and
 * hostile setpoints (tests/test_fastpath.py).
 */
#define SP_MSGID 84
#define SP_CRC_EXTRA 143
#define SP_PAYLOAD 53          /* time_boot_ms, 11 floats, type_mask, target sys/comp, frame */
#define FRAME_LOCAL_NED 1
enum { IGN_X = 1, IGN_Y = 2, IGN_Z = 4, IGN_VX = 8, IGN_VY = 16, IGN_VZ = 32,
       IGN_YAW = 1024, IGN_YAW_RATE = 2048 };
enum { O_X, O_Y, O_Z, O_VX, O_VY, O_VZ, O_YAW, O_YAW_RATE, O_N };
static const char *O_NAMES[O_N] = {"x", "y", "z", "vx", "vy", "vz", "yaw", "yaw_rate"};
static PyObject *o_names[O_N];

static int sp_init(void)
{
    for (int i = 0; i < O_N; i++)
        if ((o_names[i] = PyUnicode_InternFromString(O_NAMES[i])) == NULL)
            return -1;
    return 0;
}

static double f32_at(const uint8_t *p)
{
    float f;
    memcpy(&f, p, sizeof f);   /* little-endian hosts only, as the struct '<f' it matches */
    return (double)f;
}

static PyObject *fp_setpoint_local_ned(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 8 || !PyBytes_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "setpoint_local_ned(data: bytes, of, sysid, compid, "
                                         "max_pos, max_vel, max_yaw, max_rate)");
        return NULL;
    }
    long sysid = PyLong_AsLong(args[2]), compid = PyLong_AsLong(args[3]);
    double lim[4];
    for (int i = 0; i < 4; i++)
        lim[i] = PyFloat_AsDouble(args[4 + i]);
    if (PyErr_Occurred())
        return NULL;
    const uint8_t *d = (const uint8_t *)PyBytes_AS_STRING(args[0]);
    Py_ssize_t n = PyBytes_GET_SIZE(args[0]);
    /* one frame of this id filling the datagram, CRC right (wire.decode_fast's verdict) */
    if (n < 12 || d[0] != MAGIC_V2 || d[7] != SP_MSGID || d[8] != 0 || d[9] != 0)
        Py_RETURN_FALSE;
    uint8_t flags = d[2], plen = d[1];
    if ((flags & ~1) != 0 || HDR_V2 + plen + 2 + (flags ? SIG_LEN : 0) != n)
        Py_RETURN_FALSE;
    uint16_t crc = crc_acc(0xFFFF, d + 1, HDR_V2 - 1 + plen);
    uint8_t extra = SP_CRC_EXTRA;
    crc = crc_acc(crc, &extra, 1);
    if (crc != (uint16_t)(d[HDR_V2 + plen] | d[HDR_V2 + plen + 1] << 8))
        Py_RETURN_FALSE;
    uint8_t p[SP_PAYLOAD];                 /* trimmed payloads are zero-extended */
    memset(p, 0, sizeof p);
    memcpy(p, d + HDR_V2, plen < SP_PAYLOAD ? plen : SP_PAYLOAD);
    double x = f32_at(p + 4), y = f32_at(p + 8), z = f32_at(p + 12);
    double vx = f32_at(p + 16), vy = f32_at(p + 20), vz = f32_at(p + 24);
    double yaw = f32_at(p + 40), yaw_rate = f32_at(p + 44);
    unsigned mask = (unsigned)(p[48] | p[49] << 8);
    long tsys = p[50], tcomp = p[51], frame = p[52];
    /* offboard.py on_setpoint, its accepting path for MAV_FRAME_LOCAL_NED */
    if (tsys != sysid || !(tcomp == 0 || tcomp == compid) || frame != FRAME_LOCAL_NED)
        Py_RETURN_FALSE;
    unsigned pxy = mask & (IGN_X | IGN_Y), vxy = mask & (IGN_VX | IGN_VY);
    int use_pxy = pxy == 0, use_vxy = vxy == 0;
    int use_pz = !(mask & IGN_Z), use_vz = !(mask & IGN_VZ);
    int use_yaw = !(mask & IGN_YAW), use_rate = !(mask & IGN_YAW_RATE);
    if ((pxy != 0 && pxy != (IGN_X | IGN_Y)) || (vxy != 0 && vxy != (IGN_VX | IGN_VY)) ||
        !(use_pxy || use_vxy) || !(use_pz || use_vz))
        Py_RETURN_FALSE;
    if ((use_pxy && !(fabs(x) <= lim[0] && fabs(y) <= lim[0])) || (use_pz && !(fabs(z) <= lim[0])))
        Py_RETURN_FALSE;
    if ((use_vxy && !(fabs(vx) <= lim[1] && fabs(vy) <= lim[1])) ||
        (use_vz && !(fabs(vz) <= lim[1])))
        Py_RETURN_FALSE;
    if ((use_yaw && !(fabs(yaw) <= lim[2])) || (use_rate && !(fabs(yaw_rate) <= lim[3])))
        Py_RETURN_FALSE;
    double nan = Py_NAN;
    double v[O_N] = {use_pxy ? x : nan, use_pxy ? y : nan, use_pz ? z : nan,
                     use_vxy ? vx : nan, use_vxy ? vy : nan, use_vz ? vz : nan,
                     use_yaw ? py_mod(yaw + PI_, TWO_PI_) - PI_ : nan,
                     use_rate ? yaw_rate : nan};
    PyObject *of = args[1];
    for (int i = 0; i < O_N; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (f == NULL)
            return NULL;
        int r = fast_setattr(of, o_names[i], f);
        Py_DECREF(f);
        if (r < 0)
            return NULL;
    }
    Py_RETURN_TRUE;
}
