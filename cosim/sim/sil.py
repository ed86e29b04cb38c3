"""SIL: the onboard flight stack as its own OS process, on free loopback ports."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from pathlib import Path

from cosim.errors import ComponentError
from onesource import switch as compiled


class OnboardProcess:
    """Starts `python -m mav.onboard` with port 0 everywhere and reads the ports it bound.

    Always call `close()` (or use `with`): it terminates the process and waits for it.
    stderr goes to `log_path` so a crash can be reported with its last lines.
    """

    def __init__(
        self,
        vehicle: str,
        api_remote: tuple[str, int],
        gcs_remote: tuple[str, int],
        log_path: Path,
        *,
        hil_timeout_s: float = 10.0,
        extra_args: tuple[str, ...] = (),
        start_timeout_s: float = 30.0,
    ) -> None:
        self.log_path = Path(log_path)
        self.stats: dict = {}                   # the process's counters, after close()
        self._log = open(self.log_path, "w")  # noqa: SIM115 (closed in close())
        cmd = [
            sys.executable, "-m", "mav.onboard",
            "--vehicle", vehicle,
            "--hil-bind", "127.0.0.1:0", "--api-bind", "127.0.0.1:0", "--gcs-bind", "127.0.0.1:0",
            "--api-remote", f"{api_remote[0]}:{api_remote[1]}",
            "--gcs-remote", f"{gcs_remote[0]}:{gcs_remote[1]}",
            "--hil-timeout", str(hil_timeout_s),
            *extra_args,
        ]
        # the flight stack runs compiled or interpreted as this process does (onesource/switch.py)
        env = dict(os.environ, PYTHONUNBUFFERED="1", **compiled.environment())
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=self._log, stdin=subprocess.DEVNULL, env=env,
        )
        self.ports = self._read_ports(start_timeout_s)

    def _read_ports(self, timeout: float) -> dict[str, int]:
        deadline = time.monotonic() + timeout
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        buf = b""
        while b"\n" not in buf:
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                self.close()
                raise ComponentError("onboard", f"process did not start: {self.failure_text()}")
            r, _, _ = select.select([fd], [], [], min(left, 0.2))
            if r:
                chunk = os.read(fd, 4096)
                if not chunk:
                    continue
                buf += chunk
        line = buf.split(b"\n", 1)[0].decode(errors="replace").split()
        if not line or line[0] != "PORTS":
            self.close()
            raise ComponentError("onboard", f"unexpected first line {line!r}")
        return {k: int(v) for k, v in (item.split("=") for item in line[1:])}

    def alive(self) -> bool:
        return self.proc.poll() is None

    def failure_text(self) -> str:
        code = self.proc.poll()
        try:
            tail = self.log_path.read_text().strip().splitlines()[-5:]
        except OSError:
            tail = []
        state = "still running" if code is None else f"exited with code {code}"
        return state + (": " + " | ".join(tail) if tail else "")

    def _read_stats(self) -> dict:
        """The counters the process prints as it exits (`onboard: exit N; stats {...}`)."""
        import ast

        try:
            for line in reversed(self.log_path.read_text().splitlines()):
                if line.startswith("onboard: exit") and "stats " in line:
                    return dict(ast.literal_eval(line.split("stats ", 1)[1]))
        except (OSError, ValueError, SyntaxError):
            pass
        return {}

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=3.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()
        if not self._log.closed:
            self._log.close()
            self.stats = self._read_stats()

    def __enter__(self) -> OnboardProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
