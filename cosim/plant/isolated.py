"""A user's plant FMU in a process of its own, so that a crash or a hang in its code ends the
run with `component_error: plant ...` (everything recorded) instead of ending or freezing it.

A user's FMU is native code the project has not read: a segmentation fault in its doStep
killed the whole run (no message, no summary, no series), and a doStep that never returned
froze it. fmpy's own remoting runs 32-bit Windows binaries only, so `IsolatedPlant` starts a
worker of ours, `python -m cosim.plant.isolated`, which opens the FMU with `MappedPlant`
(cosim/plant/mapped.py), and talks to it over two pipes: per tick the 7 inputs go there and
the 21 outputs (`OUTPUT_NAMES` order) come back, as packed doubles, so the flight is the same
bit for bit as in this process. Every answer is awaited at most `timeout_s`
(`[vehicle] fmu_timeout_s`, default `TIMEOUT_S`):

- the worker dies (a crash in the FMU): ComponentError('plant', 'the FMU's process died of
  SIGSEGV during DoStep at t = ... s: <the last lines it wrote>'; the worker's faulthandler
  writes the Python stack, down to the FMU call);
- no answer in time (a hang): the worker is killed, ComponentError('plant', 'DoStep did not
  return within ... s ...');
- Ctrl-C or SIGTERM while the worker computes: the wait is interrupted like any other (the
  run ends 'interrupted', exit 130 / 143) and the worker is killed when the plant closes.

The worker sits in a session of its own (the terminal's Ctrl-C is the run's to answer) and is
killed by the kernel when the process that started it dies (PR_SET_PDEATHSIG), so a SIGKILL of
the run leaves no worker behind. The master owns the folder the FMU is extracted to.

The project's own FMUs stay in the master's process (`Plant`, and `MappedPlant` for its FMI
3.0 build): the default path pays nothing. A user's FMU pays one pipe round trip per tick
(measured: scenarios/README.md, "Your own plant FMU").
"""

from __future__ import annotations

import ctypes
import faulthandler
import os
import pickle
import re
import select
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cosim import tempdirs
from cosim.errors import ComponentError, clip
from cosim.plant.fmu import OUTPUT_NAMES, FmuPlant

TIMEOUT_S = 10.0          # s: the longest one call into a user's FMU may take (default)
START_S = 60.0            # s: at least this for the worker to start and open the FMU
CLOSE_S = 5.0             # s: for the worker to free the FMU and exit before it is killed
TAIL_BYTES = 4096         # of the worker's own output, for the error message

_STEP, _RESET, _CLOSE = 1, 2, 3                       # requests (one byte, then the inputs)
_Y, _ERROR = 1, 2                                     # answers
_REQ_STEP = struct.Struct("<B7d")
_REQ = struct.Struct("<B")
_HEAD = struct.Struct("<BI")                          # answer: kind, payload bytes
_LEN = struct.Struct("<I")
_N_Y = len(OUTPUT_NAMES)
_Y_BYTES = struct.Struct(f"<{_N_Y}d")
_FRAME = re.compile(r'\s*File "(.+)", line (\d+) in (.+)')     # faulthandler's frame lines


class IsolatedPlant(FmuPlant):
    """`MappedPlant(vehicle, spec, ...)` run in a worker process; the same interface (`y`,
    `step`, `k`, `t`, `reset`, `close`)."""

    def __init__(self, vehicle, spec, *, step_size: float = 0.005, x0: float = 0.0,
                 y0: float = 0.0, yaw0: float = 0.0, timeout_s: float = TIMEOUT_S) -> None:
        self.vehicle = vehicle
        self.step_size = float(step_size)
        self.timeout_s = float(timeout_s)
        self.k = 0
        self.y: list[float] = [float("nan")] * _N_Y
        self._proc: subprocess.Popen | None = None
        self._busy = False                       # a request without its answer yet
        self._unzipdir: str | None = None
        self._stderr = None
        try:
            self._unzipdir = tempdirs.make("fmu")
            self._stderr = tempfile.TemporaryFile()   # noqa: SIM115 (closed in close())
            self._proc = subprocess.Popen(
                [sys.executable, "-m", __name__, str(os.getpid())],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr,
                start_new_session=True, close_fds=True)
            self._out = self._proc.stdin.fileno()
            self._in = self._proc.stdout.fileno()
            self._poll = select.poll()
            self._poll.register(self._in, select.POLLIN)
            args = pickle.dumps((vehicle, spec, self.step_size, x0, y0, yaw0, self._unzipdir))
            self._send(_LEN.pack(len(args)) + args)
            self._answer("start", max(START_S, self.timeout_s))
        except BaseException:
            self.close()
            raise

    # ---- the tick --------------------------------------------------------------------------
    def step(self, u1: float, u2: float, u3: float, u4: float, wind_n: float = 0.0,
             wind_e: float = 0.0, wind_d: float = 0.0) -> list[float]:
        """Hold the inputs over one tick, advance t_k -> t_k+1; returns :attr:`y`."""
        if self._proc is None:
            self._used_closed()
        self._send(_REQ_STEP.pack(_STEP, u1, u2, u3, u4, wind_n, wind_e, wind_d))
        self._answer("DoStep", self.timeout_s)
        self.k += 1
        return self.y

    def reset(self) -> None:
        """Back to t = 0: a fresh instance of the FMU, in the same worker."""
        if self._proc is None:
            self._used_closed()
        self._send(_REQ.pack(_RESET))
        self._answer("reset", max(START_S, self.timeout_s))
        self.k = 0

    # ---- the pipe --------------------------------------------------------------------------
    def _send(self, data: bytes) -> None:
        try:
            os.write(self._out, data)        # a few dozen bytes: the pipe takes them at once
        except BrokenPipeError:
            raise self._died("a request") from None
        self._busy = True

    def _answer(self, what: str, timeout_s: float) -> None:
        kind, n = _HEAD.unpack(self._read(_HEAD.size, what, timeout_s))
        body = self._read(n, what, timeout_s)
        self._busy = False
        if kind == _Y:
            self.y[:] = _Y_BYTES.unpack(body)
            return
        raise ComponentError("plant", body.decode("utf-8", "replace"))

    def _read(self, n: int, what: str, timeout_s: float) -> bytes:
        buf = b""
        deadline = time.monotonic() + timeout_s
        while len(buf) < n:
            left = deadline - time.monotonic()
            if left <= 0.0 or not self._poll.poll(left * 1000.0):
                raise self._hung(what)
            chunk = os.read(self._in, n - len(buf))
            if not chunk:
                raise self._died(what)
            buf += chunk
        return buf

    def _hung(self, what: str) -> ComponentError:
        self._kill()
        return ComponentError("plant", f"{what} did not return within {self.timeout_s:g} s "
                                       f"at t = {self.t:.6g} s (the FMU hangs; its process was "
                                       f"stopped; [vehicle] fmu_timeout_s sets the limit)"
                                       f"{self._tail()}")

    def _died(self, what: str) -> ComponentError:
        proc = self._proc
        try:
            rc = proc.wait(timeout=CLOSE_S) if proc is not None else None
        except subprocess.TimeoutExpired:
            self._kill()
            rc = None
        if rc is not None and rc < 0:
            try:
                how = f"died of {signal.Signals(-rc).name}"
            except ValueError:
                how = f"died of signal {-rc}"
        else:
            how = f"exited (status {rc})"
        return ComponentError("plant", f"the FMU's process {how} during {what} at t = "
                                       f"{self.t:.6g} s (a crash in the FMU){self._tail()}")

    def _tail(self) -> str:
        """What the worker wrote last: the FMU's messages and, after a crash, where it was
        (the frames of faulthandler's report inside the FMU, innermost first)."""
        try:
            f = self._stderr
            f.seek(max(0, os.fstat(f.fileno()).st_size - TAIL_BYTES))
            lines = f.read().decode("utf-8", "replace").splitlines()
        except (OSError, ValueError, AttributeError):
            return ""
        crash = next((i for i, x in enumerate(lines) if x.startswith("Fatal Python error:")),
                     len(lines))
        said = [x.strip() for x in lines[:crash] if x.strip()][-3:]
        if crash < len(lines):
            frames = []
            for x in lines[crash + 1:]:
                m = _FRAME.match(x)
                if m is None:
                    continue
                if "fmpy" in Path(m[1]).parts:      # the binding that called the FMU: out
                    break
                frames.append(f"{m[3]} ({Path(m[1]).name}:{m[2]})")
            said.append(lines[crash][len("Fatal Python error:"):].strip() + (
                " in " + " < ".join(frames[:3]) if frames else " in the FMU's native code"))
        return f": {clip(' / '.join(said), 600)}" if said else ""

    # ---- life cycle ------------------------------------------------------------------------
    def _kill(self) -> None:
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()

    def close(self) -> None:
        """Stop the worker (it frees the FMU; killed if busy or slow), remove the extracted
        files (idempotent)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            try:
                if not self._busy and proc.poll() is None:
                    os.write(proc.stdin.fileno(), _REQ.pack(_CLOSE))
                    proc.wait(timeout=CLOSE_S)
            except (OSError, subprocess.TimeoutExpired):
                pass
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
                for f in (proc.stdin, proc.stdout):
                    if f is not None:
                        f.close()
        if self._stderr is not None:
            self._stderr.close()
        if self._unzipdir is not None:
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            self._unzipdir = None


# ---------------------------------------------------------------------- the worker
def _die_with_parent(parent: int) -> None:
    """The kernel kills this process when its parent dies (Linux; elsewhere the closed pipe
    ends it once the FMU returns)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)          # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:                          # it died before the call above
        os._exit(1)


def _read_exact(fd: int, n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        chunk = os.read(fd, n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return buf


def _serve(fin: int, fout: int) -> int:
    from cosim.plant.mapped import MappedPlant

    def answer(kind: int, body: bytes) -> None:
        os.write(fout, _HEAD.pack(kind, len(body)) + body)

    def failed(exc: BaseException) -> None:
        text = str(exc)[len("plant: "):] if isinstance(exc, ComponentError) else \
            f"{type(exc).__name__}: {exc}"
        answer(_ERROR, text.encode("utf-8", "replace"))

    head = _read_exact(fin, _LEN.size)
    if head is None:
        return 0
    vehicle, spec, h, x0, y0, yaw0, unzipdir = pickle.loads(_read_exact(fin, *_LEN.unpack(head)))
    try:
        plant = MappedPlant(vehicle, spec, step_size=h, x0=x0, y0=y0, yaw0=yaw0,
                            unzipdir=unzipdir)
    except Exception as exc:
        failed(exc)
        return 1
    answer(_Y, _Y_BYTES.pack(*plant.y))
    step = plant.step
    try:
        while True:
            op = _read_exact(fin, 1)
            if op is None or op[0] == _CLOSE:
                return 0
            try:
                if op[0] == _STEP:
                    y = step(*_REQ_STEP.unpack(op + _read_exact(fin, _REQ_STEP.size - 1))[1:])
                else:
                    plant.reset()
                    y = plant.y
            except Exception as exc:
                failed(exc)
                continue
            answer(_Y, _Y_BYTES.pack(*y))
    finally:
        plant.close()


def main() -> int:
    _die_with_parent(int(sys.argv[1]))
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # the run stops this process
    faulthandler.enable()                               # a crash: the Python stack, to stderr
    # the pipes move away from 0 and 1: what the FMU prints goes to stderr, not into them
    fin, fout = os.dup(0), os.dup(1)
    os.dup2(2, 1)
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    return _serve(fin, fout)


if __name__ == "__main__":
    sys.exit(main())
