"""A camera stream's renders in a child process, so that a single run uses a second core
(issue 29).

With a camera latency, the frame captured at tick k reaches the app at k + latency; its render
(and the app's per-frame image work, `FrameStage`) is a pure function of the pose at capture
and of the camera's own seeded noise, drawn in capture order. A worker *thread* can do it, but
the render is partly Python and both threads then take turns on the interpreter lock: measured
on E2, the thread pipeline was 1.1x the sequential run. A forked child process has its own
interpreter: it gets the parent's camera as it is at the first capture (its textures, tiles
and noise generator, copied on write), renders the frames in the order they were captured and
writes each (with the arrays of its `FrameStage` result) into a slot of a shared memory map;
the parent copies a frame out when it is delivered. The frames are the bytes the sequential
run makes, so the flight is the same bit for bit (tests/test_paper2_speed.py).

The child is forked only from a process with one thread (`fork_is_safe`: a thread holding a
lock at the fork would leave it held in the child) and after OpenCV was set to one thread
(cosim/cvthreads.py: its worker pool is not copied by a fork); otherwise the stream keeps its
worker thread. An error in the child is raised in the parent when that frame is delivered;
the child ends with the run (or with the parent: its pipe closes). A child that does not
answer within `timeout_s` (stopped by SIGSTOP, stuck) is killed and the wait raises: the run
ends `component_error: camera` instead of waiting for ever.
"""

from __future__ import annotations

import atexit
import mmap
import multiprocessing as mp
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

ALIGN = 64
TIMEOUT_S = 30.0      # s: the longest the run waits for the child's answer (default of
                      # [camera] render_timeout_s, cosim/sensors/stream.py)


def _aligned(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def fork_is_safe() -> bool:
    """A fork now copies no other thread's held locks: Linux (macOS's system libraries are
    not fork-safe), one Python thread."""
    return sys.platform.startswith("linux") and threading.active_count() == 1


def _pack(values: list, buf: memoryview) -> list:
    """Write the C-contiguous arrays of `values` that fit into `buf`; a description of each
    value: ("a", shape, dtype, offset) for an array written, ("v", value) otherwise."""
    out, off = [], 0
    for v in values:
        if (isinstance(v, np.ndarray) and v.flags.c_contiguous and v.dtype.hasobject is False
                and off + v.nbytes <= len(buf)):
            buf[off:off + v.nbytes] = v.reshape(-1).view(np.uint8)
            out.append(("a", v.shape, v.dtype.str, off))
            off += _aligned(v.nbytes)
        else:
            out.append(("v", v))
    return out


def _unpack(desc: list, buf: mmap.mmap, base: int) -> list:
    out = []
    for d in desc:
        if d[0] == "a":
            _, shape, dtype, off = d
            n = int(np.prod(shape, dtype=np.int64))
            out.append(np.frombuffer(buf, dtype, n, base + off).reshape(shape).copy())
        else:
            out.append(d[1])
    return out


def _serve(conn, parent_end, job: Callable[..., tuple], buf: mmap.mmap, slot_bytes: int,
           n_slots: int) -> None:
    """The child: render each requested frame in order into its slot, answer with its
    description; None (or the parent gone) ends it."""
    parent_end.close()           # else the pipe never reads as closed when the parent dies
    # Ctrl-C or a TERM to the process group is the parent's to handle: it ends the run,
    # closes the stream, and this child reports its CPU time and exits (or sees the pipe
    # closed if the parent died)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    view = memoryview(buf)
    try:
        while True:
            msg = conn.recv()
            if msg is None:
                conn.send((-1, time.process_time(), None, None))      # its CPU time, s
                return
            i, args = msg
            try:
                img, blur_px, pre = job(*args)
                tup = isinstance(pre, tuple)
                values = [img, *pre] if tup else [img, pre]
                base = (i % n_slots) * slot_bytes
                conn.send((i, blur_px, tup, _pack(values, view[base:base + slot_bytes])))
            except Exception:                      # raised in the parent at delivery
                conn.send((i, None, None, traceback.format_exc()))
    except (EOFError, OSError, KeyboardInterrupt):
        return
    finally:
        view.release()


class RenderProcess:
    """`job(*args) -> (image, blur px, FrameStage result)` run in a forked child, one request
    at a time in order; `submit(*args)` returns a ticket, `result(ticket)` the job's value
    (its arrays copied out of the shared slot)."""

    def __init__(self, job: Callable[..., tuple], frame_bytes: int, n_slots: int = 8,
                 timeout_s: float = TIMEOUT_S) -> None:
        self.n_slots = int(n_slots)
        self.timeout_s = float(timeout_s)
        self.slot_bytes = _aligned(2 * int(frame_bytes) + 4 * ALIGN)
        self.buf = mmap.mmap(-1, self.slot_bytes * self.n_slots)
        ctx = mp.get_context("fork")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_serve, name="cosim-render", daemon=True,
                                args=(child, self.conn, job, self.buf, self.slot_bytes,
                                      self.n_slots))
        self.proc.start()
        child.close()
        # before multiprocessing's own exit handler, which would SIGTERM the child (ignored)
        # and wait for it without end
        atexit.register(self.close)
        self.sent = 0
        self.received = 0
        self.done: dict[int, Any] = {}
        self.cpu_s: float | None = None   # the child's CPU time, once it has ended

    def submit(self, *args: Any) -> int:
        i = self.sent
        while i - self.received >= self.n_slots:    # its slot holds a frame not copied yet
            self._receive()
        try:
            self.conn.send((i, args))
        except OSError as exc:
            raise self._ended() from exc
        self.sent += 1
        return i

    def _ended(self) -> RuntimeError:
        self.proc.join(1.0)
        return RuntimeError(f"the camera's render process ended (exit code "
                            f"{self.proc.exitcode})")

    def _hung(self) -> RuntimeError:
        """No answer in time: the child is killed (a stopped one too) and the run told."""
        pid = self.proc.pid
        try:
            state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            state = "?"
        how = {"T": "stopped (SIGSTOP)", "t": "stopped by a debugger", "D": "waiting on a disk",
               "Z": "ended"}.get(state, "stuck")
        self.proc.kill()
        self.proc.join(5.0)
        return RuntimeError(f"the render process (pid {pid}) did not answer within "
                            f"{self.timeout_s:g} s for frame {self.received}: it was {how}, "
                            f"and is ended ([camera] render_timeout_s sets the limit)")

    def _receive(self) -> None:
        try:
            if not self.conn.poll(self.timeout_s):
                raise self._hung()
            i, blur_px, tup, desc = self.conn.recv()
        except (EOFError, OSError) as exc:
            raise self._ended() from exc
        if tup is None:
            self.done[i] = RuntimeError(f"camera render (in its process) failed:\n{desc}")
        else:
            base = (i % self.n_slots) * self.slot_bytes
            values = _unpack(desc, self.buf, base)
            self.done[i] = (values[0], blur_px, tuple(values[1:]) if tup else values[1])
        self.received += 1

    def result(self, i: int) -> tuple:
        while i not in self.done:
            self._receive()
        r = self.done.pop(i)
        if isinstance(r, BaseException):
            raise r
        return r

    def close(self) -> None:
        """End the child (frames not yet delivered are dropped) and free the slots."""
        if self.proc is None:
            return
        try:
            if not self.proc.is_alive():     # killed (no answer in time) or ended
                raise EOFError
            self.conn.send(None)
            while self.conn.poll(5.0):           # frames not delivered, then its CPU time
                i, cpu_s, _, _ = self.conn.recv()
                if i < 0:
                    self.cpu_s = cpu_s
                    break
        except (OSError, EOFError, ValueError):
            pass
        self.proc.join(5.0)
        if self.proc.is_alive():      # it ignores SIGTERM (its run's to handle): kill it
            self.proc.kill()
            self.proc.join(5.0)
        atexit.unregister(self.close)
        self.conn.close()
        self.proc = None
        self.buf.close()
