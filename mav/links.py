"""Byte links between the parts: the same MAVLink bytes over UDP (SIL) or memory (MIL).

A link moves whole datagrams. `send` never blocks; `recv` returns one datagram or None.
MIL uses `MemoryLink.pair()`; SIL uses `UdpLink`. Both carry identical bytes, which is
what makes MIL and SIL runs bit-identical.
"""

from __future__ import annotations

import os
import select
import socket
import time
from collections import deque
from typing import Protocol


def kernel_drops(links: dict) -> dict[str, int]:
    """{'dropped_kernel_<name>': count} for each named link that is a UDP socket (or a tap or
    fault wrapper around one, followed through `inner`) whose kernel drop count can be read
    (`UdpLink.kernel_drops`); links without it (in memory, other OSes) are left out."""
    got = {}
    for name, link in links.items():
        while not hasattr(link, "kernel_drops") and hasattr(link, "inner"):
            link = link.inner
        n = link.kernel_drops() if hasattr(link, "kernel_drops") else None
        if n is not None:
            got["dropped_kernel_" + name] = n
    return got


class Link(Protocol):
    def send(self, data: bytes) -> None: ...

    def recv(self) -> bytes | None: ...

    def close(self) -> None: ...


class MemoryLink:
    """One end of an in-memory datagram pipe. Create both ends with `MemoryLink.pair()` (or
    `memory_pair()`)."""

    __slots__ = ("_inbox", "_peer", "sent_bytes")

    def __init__(self) -> None:
        self._inbox: deque[bytes] = deque()
        self._peer: MemoryLink | None = None
        self.sent_bytes = 0

    @classmethod
    def pair(cls) -> tuple[MemoryLink, MemoryLink]:
        a, b = cls(), cls()
        a._peer, b._peer = b, a
        return a, b

    def send(self, data: bytes) -> None:
        self.sent_bytes += len(data)
        self._peer._inbox.append(bytes(data))  # type: ignore[union-attr]

    def recv(self) -> bytes | None:
        inbox = self._inbox
        return inbox.popleft() if inbox else None

    def pending(self) -> int:
        """Datagrams waiting to be received at this end."""
        return len(self._inbox)

    def close(self) -> None:
        self._inbox.clear()


def memory_pair() -> tuple:
    """Two connected in-memory link ends."""
    return MemoryLink.pair()


def memory_link():
    """One unconnected end (nothing can be sent from it)."""
    return MemoryLink()


class SpinPolicy:
    """Spin-wait only while it pays (lockstep HIL between two processes, wall time only).

    Spinning for the other process's answer saves a sleep and a wake-up per tick when both
    run on CPUs of their own; when the CPUs are shared (other jobs, a small machine) the spin
    takes time from the very process it waits for. After each wait, `record(hit)` says whether
    the answer came within the spin; over each window of `window` waits, if fewer than half
    were hits, spinning stops for `backoff` waits and is then tried again. `ns` is the spin to
    use now (0: do not spin)."""

    __slots__ = ("spin_ns", "ns", "window", "backoff", "_n", "_hits", "_off")

    def __init__(self, spin_ns: int, window: int = 200, backoff: int = 4000) -> None:
        self.spin_ns = self.ns = max(0, int(spin_ns))
        self.window, self.backoff = window, backoff
        self._n = self._hits = self._off = 0

    def record(self, hit: bool) -> None:
        if self._off:                      # not spinning: count down to the next try
            self._off -= 1
            if not self._off:
                self.ns = self.spin_ns
            return
        self._n += 1
        self._hits += hit
        if self._n >= self.window:
            if 2 * self._hits < self._n and self.spin_ns:
                self.ns, self._off = 0, self.backoff
            self._n = self._hits = 0


class UdpLink:
    """A non-blocking UDP endpoint.

    bind: local (host, port); port 0 picks a free one (see `local_address`).
    remote: where to send. If None, replies go to whoever sent last (like mavutil `udpin:`);
    sending before anyone has sent is a silent drop, counted in `dropped_sends`.
    """

    def __init__(
        self, bind: tuple[str, int] = ("127.0.0.1", 0), remote: tuple[str, int] | None = None
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.remote = remote
        self._fixed_remote = remote is not None
        self.dropped_sends = 0
        self._poller: select.poll | None = None

    @property
    def local_address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def fileno(self) -> int:
        return self.sock.fileno()

    def send(self, data: bytes) -> None:
        if self.remote is None:
            self.dropped_sends += 1
            return
        try:
            self.sock.sendto(data, self.remote)
        except (BlockingIOError, ConnectionRefusedError, OSError):
            self.dropped_sends += 1

    def recv(self) -> bytes | None:
        try:
            data, addr = self.sock.recvfrom(65535)
        except (BlockingIOError, ConnectionRefusedError, InterruptedError):
            return None
        if not self._fixed_remote and addr:
            self.remote = addr
        return data

    def recv_spin(self, spin_ns: int, timeout: float) -> bytes | None:
        """One datagram: polled for up to `spin_ns` ns (wall clock), then waited for up to
        `timeout` s in the kernel; None if none came. The socket stays non-blocking.

        Spinning first saves the sleep and wake-up of a lockstep exchange when the answer
        comes within the spin (two processes on two CPUs); it costs CPU while it waits."""
        recv = self.sock.recvfrom
        if spin_ns > 0:
            clock = time.perf_counter_ns
            deadline = clock() + spin_ns
            while True:
                try:
                    data, addr = recv(65535)
                    break
                except (BlockingIOError, InterruptedError):
                    if clock() > deadline:
                        data = None
                        break
                except ConnectionRefusedError:
                    return None
            if data is not None:
                if not self._fixed_remote and addr:
                    self.remote = addr
                return data
        if self._poller is None:
            self._poller = select.poll()
            self._poller.register(self.sock.fileno(), select.POLLIN)
        if not self._poller.poll(max(0, round(timeout * 1000))):
            return None
        try:
            return self.recv()
        except ConnectionRefusedError:
            return None

    def recv_blocking(self, timeout: float) -> bytes | None:
        """Wait up to `timeout` seconds (wall clock) for one datagram."""
        self.sock.settimeout(timeout)
        try:
            data, addr = self.sock.recvfrom(65535)
        except (TimeoutError, ConnectionRefusedError):
            return None
        finally:
            self.sock.setblocking(False)
        if not self._fixed_remote and addr:
            self.remote = addr
        return data

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped for this socket since it was opened, mostly because
        its receive buffer was full (a flood faster than the reader): the `drops` column of
        Linux's /proc/net/udp, found by the socket's inode. None where that is not available
        (another OS, a closed socket). Reads a /proc file: call it now and then (at exit),
        not per tick."""
        try:
            inode = os.fstat(self.sock.fileno()).st_ino
            with open("/proc/net/udp") as f:
                next(f)                                  # the column names
                for line in f:
                    cols = line.split()
                    if len(cols) > 12 and int(cols[9]) == inode:
                        return int(cols[12])
        except (OSError, ValueError, StopIteration):
            pass
        return None

    def close(self) -> None:
        self.sock.close()


class UnixLink(UdpLink):
    """A non-blocking Unix-domain datagram endpoint bound to the file `path`: the same
    interface and semantics as `UdpLink` (`remote` a path; None: reply to the last sender),
    for the simulator link between two processes of one machine (no IP/UDP layers in the
    kernel; in the seed mission it measured no faster than loopback UDP: docs/performance.md).
    The file is removed on `close`. Linux and macOS; `path` must be short (108 bytes on
    Linux)."""

    def __init__(self, path: str, remote: str | None = None) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            self.sock.bind(path)
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self.path = path
        self.remote = remote
        self._fixed_remote = remote is not None
        self.dropped_sends = 0
        self._poller = None

    @property
    def local_address(self) -> str:
        return self.path

    def close(self) -> None:
        if self.sock.fileno() >= 0:
            self.sock.close()
            try:
                os.unlink(self.path)
            except OSError:
                pass

