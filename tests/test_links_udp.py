"""UdpLink's compiled receive (mav/csrc/udp.c) against socket.recvfrom, the reference: the
same datagrams, senders and learned reply address on real sockets, None when nothing waits,
a refused earlier send and a closed socket handled as before. Ports: 0 (the kernel's pick)."""

from __future__ import annotations

import random
import socket

import pytest

from mav import fastpath, reference
from mav.links import UdpLink

LIB = fastpath.lib
needs_c = pytest.mark.skipif(LIB is None, reason="needs the compiled fast path")


def _traffic(compiled: bool, seed: int) -> list:
    rng = random.Random(seed)
    rx = UdpLink(("127.0.0.1", 0))
    senders = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3)]
    for s in senders:
        s.bind(("127.0.0.1", 0))
    names = {s.getsockname(): i for i, s in enumerate(senders)}
    log = []
    try:
        for _ in range(400):
            k = rng.randrange(3)
            n = rng.choice([0, 1, 12, 280, rng.randrange(0, 9000), 65507])
            payload = bytes(rng.randrange(256) for _ in range(min(n, 64))) + bytes(n - min(n, 64))
            if rng.random() < 0.7:
                senders[k].sendto(payload, rx.local_address)
            if compiled:
                got = rx.recv()
            else:
                with reference.python():
                    got = rx.recv()
            if got is None:
                log.append(None)
            else:                    # sockets differ per run: compare who sent, not the port
                log.append((got, names[rx.remote]))
        while True:                  # whatever is still queued
            got = rx.recv() if compiled else _py_recv(rx)
            if got is None:
                break
            log.append((got, names[rx.remote]))
    finally:
        for s in senders:
            s.close()
        rx.close()
    return log


def _py_recv(link: UdpLink):
    with reference.python():
        return link.recv()


@needs_c
@pytest.mark.parametrize("seed", [1, 2])
def test_compiled_udp_receive_answers_as_recvfrom(seed):
    got = _traffic(True, seed)
    assert got == _traffic(False, seed)
    assert sum(g is None for g in got) > 20 and sum(g is not None for g in got) > 200


@needs_c
def test_compiled_udp_receive_raw_and_errors():
    a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    a.bind(("127.0.0.1", 0))
    a.setblocking(False)
    b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    b.bind(("127.0.0.1", 0))
    assert LIB.udp_recv(a.fileno()) is None                    # nothing waiting
    b.sendto(b"hello", a.getsockname())
    data, addr = LIB.udp_recv(a.fileno())
    assert data == b"hello" and addr == b.getsockname()
    b.sendto(b"", a.getsockname())
    assert LIB.udp_recv(a.fileno()) == (b"", b.getsockname())  # an empty datagram
    # a send refused by a closed port: the next receive on that socket sees ECONNREFUSED
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.bind(("127.0.0.1", 0))
    dead = c.getsockname()
    c.close()
    a.connect(dead)
    a.send(b"x")
    with pytest.raises(ConnectionRefusedError):
        for _ in range(1000):            # the ICMP error arrives asynchronously
            LIB.udp_recv(a.fileno())
    fd = a.fileno()
    a.close()
    with pytest.raises(OSError):
        LIB.udp_recv(fd)                  # not a socket any more
    b.close()


@needs_c
def test_udp_link_swallows_a_refused_send_as_before():
    rx = UdpLink(("127.0.0.1", 0))
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.bind(("127.0.0.1", 0))
    dead = c.getsockname()
    c.close()
    rx.sock.connect(dead)
    rx.remote = dead
    rx.send(b"x")
    assert all(rx.recv() is None for _ in range(200))         # compiled: None, as recvfrom
    rx.send(b"x")
    assert rx.recv_spin(200_000, 0.0) is None                 # the spin: None at once
    rx.close()
