"""The temporary folders of a run, named with the process that owns them, and the folders
of runs that died cleaned when the next one starts (issue 43, item 15).

A run keeps its series spool, a user FMU's extraction and (without `--out`) its whole run
folder in TMPDIR while it flies, and removes them when it ends. A run killed with SIGKILL (or
the machine's OOM killer) cannot: its folders stayed for ever. Each folder is named
`cosim-<kind>-<pid>-<where>-<random>` (`where`: a tag of the host and the pid namespace, so
that a TMPDIR shared by machines or containers never mixes their pids); `sweep()`, called as a
run or a study starts, removes those of this host whose owner is gone: no process with that
pid, or one that started after the folder last changed (the pid was used again, or the machine
restarted). A folder of a live process is never touched, nor another user's.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import socket
import tempfile
import time
from pathlib import Path

PREFIX = "cosim-"
_OURS = re.compile(r"cosim-[a-z]+-(\d+)-([0-9a-f]{8})-[A-Za-z0-9_]+")
_MARGIN_S = 2.0          # s: a folder changed this long before its pid's process started


@functools.cache
def _where() -> str:
    """8 hex digits naming this host and pid namespace."""
    try:
        ns = os.readlink("/proc/self/ns/pid")
    except OSError:
        ns = ""
    return hashlib.sha256(f"{socket.gethostname()}|{ns}".encode()).hexdigest()[:8]


def prefix(kind: str) -> str:
    """`cosim-<kind>-<pid>-<where>-`: the name of a folder this process owns starts so."""
    return f"{PREFIX}{kind}-{os.getpid()}-{_where()}-"


def make(kind: str) -> str:
    """A new temporary folder of this process (the caller removes it)."""
    return tempfile.mkdtemp(prefix=prefix(kind))


def folder(kind: str) -> tempfile.TemporaryDirectory:
    """A temporary folder of this process, removed when the object is closed or collected."""
    return tempfile.TemporaryDirectory(prefix=prefix(kind))


def _boot_time() -> float | None:
    try:
        for line in Path("/proc/stat").read_text().splitlines():
            if line.startswith("btime "):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def owner_alive(pid: int, changed_s: float) -> bool:
    """Is the process that owns a folder last changed at `changed_s` (epoch s) still running?
    A pid nobody has is dead; one whose process started after that is another process."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:         # another user's live process
        pass
    boot = _boot_time()
    if boot is None:
        return True
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        started = boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return True                  # cannot tell: keep it
    return started <= changed_s + _MARGIN_S


def sweep(root: str | os.PathLike | None = None) -> list[Path]:
    """Remove this host's `cosim-<kind>-<pid>-<where>-*` folders in `root` (default TMPDIR)
    whose owner is gone; the folders removed. Never raises: a folder that cannot be removed
    stays."""
    root = Path(root if root is not None else tempfile.gettempdir())
    removed = []
    try:
        entries = list(os.scandir(root))
    except OSError:
        return removed
    for e in entries:
        m = _OURS.fullmatch(e.name)
        if m is None or m[2] != _where() or int(m[1]) == os.getpid():
            continue
        try:
            if not e.is_dir(follow_symlinks=False) or e.stat(follow_symlinks=False).st_uid \
                    != os.getuid():
                continue
            changed = e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if owner_alive(int(m[1]), min(changed, time.time())):
            continue
        shutil.rmtree(e.path, ignore_errors=True)
        if not os.path.lexists(e.path):
            removed.append(Path(e.path))
    return removed
