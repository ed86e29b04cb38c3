/* mav._fastpath: the onboard stack's per-tick hot path compiled, as the generated code that runs
 * on a real drone is (`python -m mav.build` builds it; mav/fastpath.py loads it).
 *
 * One translation unit: this file is the module (its method table and init); the parts are
 * included below, each beside its Python reference and tested back to back with it
 * (mav/README.md lists them): slots.c attribute access by cached slot offset (used by the
 * others), cascade.c the controller, framing.c the MAVLink 2 framing and
 * checks, setpoint.c the offboard setpoint accept path, memlink.c the in-memory link and tlog
 * tap, telemetry.c the state telemetry, globalpos.c GLOBAL_POSITION_INT, decode.c the one-frame decoders, battery.c the battery
 * step, udp.c a UDP receive without an exception when nothing waits, tick.c, tick_tel.c and
 * tick_run.c the vehicle's tick (Onboard.poll) in one call, hilsim.c the simulator's ODOMETRY
 * and MIL exchange, client.c the offboard client's position setpoint. Compiled with -O2
 * -ffp-contract=off and no fast-math (mav/build.py) so every double operation rounds as
 * Python's does.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "slots.c"
#include "cascade.c"
#include "framing.c"
#include "setpoint.c"
#include "memlink.c"
#include "telemetry.c"
#include "globalpos.c"
#include "decode.c"
#include "battery.c"
#include "udp.c"
#include "hilsim.c"
#include "tick.c"
#include "tick_tel.c"
#include "tick_run.c"
#include "client.c"

static PyMethodDef module_methods[] = {
    {"frame", (PyCFunction)(void (*)(void))fp_frame, METH_FASTCALL,
     "frame(seq, sysid, compid, msgid, crc_extra, payload): an unsigned MAVLink 2 frame"},
    {"check", (PyCFunction)(void (*)(void))fp_check, METH_FASTCALL,
     "check(data, start, end, msgid, crc_extra): the payload length of a valid frame, or -1"},
    {"setpoint_local_ned", (PyCFunction)(void (*)(void))fp_setpoint_local_ned, METH_FASTCALL,
     "setpoint_local_ned(data, of, sysid, compid, max_pos, max_vel, max_yaw, max_rate): "
     "apply an accepted LOCAL_NED offboard setpoint datagram (see setpoint.c)"},
    {"frame_on", (PyCFunction)(void (*)(void))fp_frame_on, METH_FASTCALL,
     "frame_on(mav, msgid, crc_extra, payload): wire.frame on a link that does not sign "
     "(None if it signs)"},
    {"battery_step", (PyCFunction)(void (*)(void))fp_battery_step, METH_FASTCALL,
     "battery_step(battery, dt, u1, u2, u3, u4): Battery.step compiled (see battery.c)"},
    {"udp_recv", (PyCFunction)fp_udp_recv, METH_O,
     "udp_recv(fd): (data, (host, port)) of one waiting datagram, or None (see udp.c)"},
    {"unpack_one", (PyCFunction)(void (*)(void))fp_unpack_one, METH_FASTCALL,
     "unpack_one(fallback, unpack_from, unpack, used_len, msgid, crc_extra, data): "
     "the leading fields of a one-frame datagram, or None (see decode.c)"},
    {"odometry_frame", (PyCFunction)(void (*)(void))fp_odometry_frame, METH_FASTCALL,
     "odometry_frame(fallback, mav, msgid, crc_extra, tail, t_us, m): the simulator's "
     "ODOMETRY frame (see hilsim.c)"},
    {"mil_exchange", (PyCFunction)(void (*)(void))fp_mil_exchange, METH_FASTCALL,
     "mil_exchange(sim, poll, pending, data): one lockstep HIL exchange in memory "
     "(see hilsim.c)"},
    {"client_setpoint", (PyCFunction)(void (*)(void))fp_client_setpoint,
     METH_FASTCALL | METH_KEYWORDS,
     "client_setpoint(fallback, client, x, y, z, yaw, vx, vy, vz, yaw_rate): "
     "OffboardClient.set_position_target compiled (see client.c)"},
    {"client_poll", (PyCFunction)(void (*)(void))fp_client_poll, METH_FASTCALL,
     "client_poll(fallback, client, t): OffboardClient.poll compiled (see client.c)"},
    {"set_halves", (PyCFunction)(void (*)(void))fp_set_halves, METH_FASTCALL,
     "set_halves(obj, name_a, name_b, f, compid): obj.name_a = f[1:4], obj.name_b = f[4:7] "
     "(see client.c)"},
    {"emit_global", (PyCFunction)(void (*)(void))fp_emit_global, METH_FASTCALL,
     "emit_global(fallback, geo, vs, msgid, crc_extra, ch): GLOBAL_POSITION_INT's emit and "
     "send (see globalpos.c)"},
    {"emit_state", (PyCFunction)(void (*)(void))fp_emit_state, METH_FASTCALL,
     "emit_state(kind, msgid, crc_extra, fallback, vs, ch): a state stream's emit and send "
     "(see telemetry.c)"},
    {"state_msg", (PyCFunction)(void (*)(void))fp_state_msg, METH_FASTCALL,
     "state_msg(kind, msgid, crc_extra, mav, state, t_us): ATTITUDE (0) or "
     "LOCAL_POSITION_NED (1) of a VehicleState, framed on mav (see telemetry.c)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef fastpath_module = {
    PyModuleDef_HEAD_INIT, "_fastpath",
    "The onboard stack's per-tick hot path, compiled (see mav/fastpath.py)", -1,
    module_methods};

PyMODINIT_FUNC PyInit__fastpath(void)
{
    crc_init();
    for (int i = 0; i < S_N; i++)
        if ((s_names[i] = PyUnicode_InternFromString(S_NAMES[i])) == NULL)
            return NULL;
    for (int i = 0; i < P_N; i++)
        if ((p_names[i] = PyUnicode_InternFromString(P_NAMES[i])) == NULL)
            return NULL;
    if ((name_armed = PyUnicode_InternFromString("armed")) == NULL)
        return NULL;
    if (sp_init() < 0 || tm_init() < 0 || bat_init() < 0 || (py_ten = PyLong_FromLong(HDR_V2)) == NULL)
        return NULL;
    if (tick_init_names() < 0 || client_init() < 0 || gp_init() < 0 || tap_init_names() < 0)
        return NULL;
    /* the module's types: (name, type) */
    static struct { const char *name; PyTypeObject *type; } types[] = {
        {"MemoryLink", &MemLinkType}, {"TapLink", &TapType}, {"Tick", &TickType},
        {"Cascade", &CascadeType}};
    const int n_types = (int)(sizeof types / sizeof types[0]);
    for (int i = 0; i < n_types; i++)
        if (PyType_Ready(types[i].type) < 0)
            return NULL;
    PyObject *m = PyModule_Create(&fastpath_module);
    if (m == NULL)
        return NULL;
    for (int i = 0; i < n_types; i++) {
        Py_INCREF(types[i].type);
        if (PyModule_AddObject(m, types[i].name, (PyObject *)types[i].type) < 0) {
            Py_DECREF(types[i].type);
            Py_DECREF(m);
            return NULL;
        }
    }
    return m;
}
