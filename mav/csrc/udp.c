/* A non-blocking UDP receive without an exception when nothing is waiting (included by
 * fastpath.c). The reference is mav.links.UdpLink.recv: `sock.recvfrom(65535)`, None on
 * BlockingIOError, ConnectionRefusedError or InterruptedError. In Python the empty case
 * raises and catches an OSError, ~1-2 us; a SIL tick meets it several times (the api and gcs
 * links polled when nothing came, the HIL wait's spin).
 *
 * udp_recv(fd) -> (data, (host, port)) | None: one datagram of an AF_INET socket and its
 * sender as socket.recvfrom gives them; None when none is waiting (EAGAIN); EINTR retried
 * after running the signal handlers, as CPython does (PEP 475); any other error raised as the
 * OSError CPython raises (ECONNREFUSED, an earlier send refused: ConnectionRefusedError,
 * which the caller handles as the reference does).
 * tests/test_links_udp.py runs both on the same sockets. */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <sys/socket.h>

static char udp_buf[65535];      /* the GIL is held throughout: one buffer serves */

static PyObject *fp_udp_recv(PyObject *mod, PyObject *arg)
{
    long fd = PyLong_AsLong(arg);
    if (fd == -1 && PyErr_Occurred())
        return NULL;
    struct sockaddr_storage sa;
    socklen_t sl;
    ssize_t n;
    for (;;) {
        sl = sizeof sa;
        n = recvfrom((int)fd, udp_buf, sizeof udp_buf, MSG_DONTWAIT, (struct sockaddr *)&sa,
                     &sl);
        if (n >= 0)
            break;
        if (errno == EINTR) {
            if (PyErr_CheckSignals() < 0)
                return NULL;
            continue;
        }
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            Py_RETURN_NONE;
        return PyErr_SetFromErrno(PyExc_OSError);   /* ECONNREFUSED: ConnectionRefusedError */
    }
    PyObject *addr;
    if (sl == 0) {
        Py_INCREF(Py_None);
        addr = Py_None;
    } else if (sa.ss_family == AF_INET) {
        const struct sockaddr_in *in = (const struct sockaddr_in *)&sa;
        char host[INET_ADDRSTRLEN];
        if (inet_ntop(AF_INET, &in->sin_addr, host, sizeof host) == NULL)
            return PyErr_SetFromErrno(PyExc_OSError);
        addr = Py_BuildValue("(si)", host, (int)ntohs(in->sin_port));
        if (addr == NULL)
            return NULL;
    } else {
        PyErr_SetString(PyExc_ValueError, "udp_recv: not an AF_INET socket");
        return NULL;
    }
    PyObject *data = PyBytes_FromStringAndSize(udp_buf, n);
    if (data == NULL) {
        Py_DECREF(addr);
        return NULL;
    }
    PyObject *t = PyTuple_Pack(2, data, addr);
    Py_DECREF(data);
    Py_DECREF(addr);
    return t;
}
