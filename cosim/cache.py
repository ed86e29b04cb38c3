"""Results that depend only on what makes them, kept per process and, in a study, on disk.

Paper 2's runs rebuild the same things every run: the procedural textures of a world, the
renderer's tiles, and the taught key images with their features. Each is a pure function of
a few inputs, so it is kept under a SHA-256 of those inputs (``key``):

- in this process (``memo``): a small LRU of the last ``MEMO_MAX`` entries per kind, so a
  study worker's memory stays flat whatever the number of runs (one world per study, or a
  few when a study varies the world);
- on disk, when a folder is set (``set_dir``; a study sets ``<out>/cache`` in each worker):
  ``<dir>/<kind>/<key>.npz``, written to a temporary file and moved into place (several
  worker processes may write the same entry at once; they write the same bytes).

Nothing here changes a result: an entry holds the exact arrays the function returns.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

MEMO_MAX = 4          # entries per kind kept in memory
VERSION = "1"         # bump when a cached function changes its output

_memo: dict[str, OrderedDict[str, Any]] = {}
_dir: Path | None = Path(os.environ["COSIM_CACHE_DIR"]) if os.environ.get(
    "COSIM_CACHE_DIR") else None


def key(*parts: Any) -> str:
    """A SHA-256 of the parts' reprs (dataclasses, tuples, floats: repr is exact). A repr
    that does not say everything (a numpy array's, cut with '...'; an object's address) is
    refused: two different inputs could share it."""
    h = hashlib.sha256(VERSION.encode())
    for p in parts:
        r = repr(p)
        if "..." in r or " at 0x" in r:
            raise ValueError(f"cache.key: the repr of a {type(p).__name__} does not say all "
                             "of it")
        h.update(b"\x1f")
        h.update(r.encode())
    return h.hexdigest()


def set_dir(folder: str | Path | None) -> None:
    """The on-disk cache folder of this process (None: memory only)."""
    global _dir
    _dir = Path(folder) if folder else None


def get_dir() -> Path | None:
    return _dir


def memo(kind: str, k: str, make: Callable[[], Any]) -> Any:
    """The value of ``make()`` kept in this process under (kind, k)."""
    table = _memo.setdefault(kind, OrderedDict())
    if k in table:
        table.move_to_end(k)
        return table[k]
    value = table[k] = make()
    while len(table) > MEMO_MAX:
        table.popitem(last=False)
    return value


def arrays(kind: str, k: str, make: Callable[[], dict[str, np.ndarray]]
           ) -> dict[str, np.ndarray]:
    """Named arrays from ``make()``, kept in this process and on disk (when a folder is
    set). A missing or unreadable file is made again."""
    def load_or_make() -> dict[str, np.ndarray]:
        if _dir is None:
            return make()
        path = _dir / kind / f"{k}.npz"
        try:
            with np.load(path, allow_pickle=False) as z:
                return {n: z[n] for n in z.files}
        except (OSError, ValueError, EOFError):
            pass
        out = make()
        _save(path, out)
        return out
    return memo(kind, k, load_or_make)


def _save(path: Path, data: dict[str, np.ndarray]) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **data)
        os.replace(tmp, path)
    except OSError:     # a read-only or full disk: the cache is an optimisation only
        pass


def clear_memory() -> None:
    _memo.clear()
