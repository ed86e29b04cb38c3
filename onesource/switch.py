"""Compiled or interpreted: the one switch, for the whole run.

The flight software and the master's tick are written once, in typed Python (the model); the
install step compiles the modules each package lists (`register`) with Cython into extension
modules beside their sources (`python -m onesource.build`, `make build`), and runs use them. The
same `.py` files run interpreted when they are not compiled, with the same results bit for bit
(tests/test_compiled.py flies both), as Simulink tests a model against its generated code.

The environment variable ``COSIM_COMPILED`` decides, once per process, at the first import of
a listed module:

- ``0``: interpreted, every listed module from its `.py`;
- ``1``: compiled, and an error (`CompiledError`, one line naming the rebuild command) if a
  listed module is not built or was built from another source;
- unset: compiled when every listed module is built from its current source; interpreted
  when none is built (no compiler); interpreted with one line on stderr naming the module and
  the rebuild command when one is missing or out of date. A compiled module whose source
  changed is never used: each carries the SHA-256 of its source (`.py` and `.pxd`),
  embedded when it was built, and is checked against the source before it is loaded.

`describe()` says which ran (summary.json, `cosim bench`); `environment()` is what a child
process (the SIL flight stack) needs to decide the same way.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import mmap
import os
import re
import sys
from pathlib import Path

ENV = "COSIM_COMPILED"
ROOT = Path(__file__).resolve().parent.parent    # the folder that holds the packages
# a source checkout (pyproject.toml beside the packages), or an installed package
CHECKOUT = (ROOT / "pyproject.toml").is_file()
REBUILD = "make build" if CHECKOUT else "python -m onesource.build"


def build_root() -> Path:
    """Where builds (the FMU, Cython's C) are made: ``COSIM_BUILD_DIR`` if set, else
    ``<checkout>/build``, else (an installed package, whose site-packages is no work folder)
    the user's cache, ``$XDG_CACHE_HOME/cosim`` or ``~/.cache/cosim``."""
    if os.environ.get("COSIM_BUILD_DIR"):
        return Path(os.environ["COSIM_BUILD_DIR"])
    if CHECKOUT:
        return ROOT / "build"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "cosim"
MARKER = b"COSIM-SOURCE-SHA256:"
SUFFIX = importlib.machinery.EXTENSION_SUFFIXES[0]   # e.g. .cpython-311-x86_64-linux-gnu.so


class CompiledError(ImportError):
    """COSIM_COMPILED=1 and a listed module is not built from its current source."""


# `from pkg.mod cimport Name`, `from pkg cimport mod [as m], ...`, `cimport pkg.mod`
_CIMPORT = re.compile(r"^\s*(?:from\s+([\w.]+)\s+cimport\s+([\w, ]+)|cimport\s+([\w.]+))",
                      re.M)


def _pxd_closure(pxd: Path) -> list[Path]:
    """`pxd` and every project .pxd it cimports, directly or not: the C layouts compiled into
    a module (a field added to a record's .pxd changes the code of every module that cimports
    it, so it is part of their source)."""
    seen: dict[Path, None] = {}
    todo = [pxd]
    while todo:
        f = todo.pop()
        if f in seen or not f.is_file():
            continue
        seen[f] = None
        root = f.parent
        while (root / "__init__.py").is_file():
            root = root.parent
        for frm, names, mod in _CIMPORT.findall(f.read_text(encoding="utf-8")):
            # the module cimported from, or the modules a package's cimport names
            mods = [mod] if mod else [frm] + [f"{frm}.{n.split()[0]}" for n in names.split(",")
                                              if n.strip()]
            for m in mods:
                dep = root.joinpath(*m.split(".")).with_suffix(".pxd")
                if dep.is_file():
                    todo.append(dep)
    return sorted(seen)


def source_hash(src: Path) -> str:
    """SHA-256 of a module's source: the `.py` (or a binding's `.c`) and, when there is one,
    its `.pxd` with every project `.pxd` that one cimports."""
    h = hashlib.sha256(src.read_bytes())
    for pxd in _pxd_closure(src.with_suffix(".pxd")):
        h.update(b"\0pxd\0" + pxd.name.encode() + b"\0" + pxd.read_bytes())
    return h.hexdigest()


def extension_path(py: Path) -> Path:
    """Where a module's compiled form lives: beside its source, with this interpreter's suffix."""
    return py.with_name(py.stem + SUFFIX)


def embedded_hash(so: Path) -> str | None:
    """The source hash a compiled module was built from (the build embeds it), or None."""
    try:
        with open(so, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as m:
            i = m.find(MARKER)
            if i < 0:
                return None
            j = i + len(MARKER)
            return m[j:j + 64].decode("ascii", "replace")
    except (OSError, ValueError):
        return None


def module_status(src: Path, so: Path | None = None) -> str:
    """'fresh' (built from this source), 'stale' (built from another) or 'missing'."""
    so = so or extension_path(src)
    if not so.is_file():
        return "missing"
    return "fresh" if embedded_hash(so) == source_hash(src) else "stale"


class _State:
    def __init__(self) -> None:
        self.modules: dict[str, Path] = {}     # module name -> its source (.py, or .c)
        self.extensions: dict[str, Path] = {}  # module name -> its compiled form
        self.mode: str | None = None           # 'compiled' | 'interpreted', once decided
        self.why = ""
        self.interpreted: set[str] = set()     # listed modules that run from source anyway


_state = _State()


def _problem(names: list[str], status: dict[str, str]) -> str:
    bad = [n for n in names if status[n] != "fresh"]
    what = {"missing": "is not built", "stale": "changed since it was compiled"}
    first = bad[0]
    more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
    return (f"{_state.modules[first].name} ({first}) {what[status[first]]}{more}: "
            f"rebuild with `{REBUILD}`")


def _status(names: list[str]) -> dict[str, str]:
    return {n: module_status(_state.modules[n], _state.extensions[n]) for n in names}


def _decide(names: list[str]) -> None:
    env = os.environ.get(ENV)
    if env not in (None, "", "0", "1"):
        raise CompiledError(f"{ENV}={env!r}: allowed values are 0 (interpreted), 1 (compiled), "
                            f"or unset (compiled when built)")
    if env == "0":
        _state.mode, _state.why = "interpreted", f"{ENV}=0"
        return
    status = _status(names)
    if all(s == "fresh" for s in status.values()):
        _state.mode, _state.why = "compiled", f"{len(names)} modules"
        return
    problem = _problem(names, status)
    if env == "1":
        raise CompiledError(f"{ENV}=1 but {problem}")
    _state.mode = "interpreted"
    if all(s == "missing" for s in status.values()):
        _state.why = f"not built ({REBUILD})"
    else:
        _state.why = problem
        print(f"cosim: running interpreted: {problem}", file=sys.stderr)


def mode() -> str:
    """'compiled' or 'interpreted' for this process (decided on the first call)."""
    if _state.mode is None:
        _decide(sorted(_state.modules))
    return _state.mode  # type: ignore[return-value]


def describe() -> str:
    """One line for reports: which ran, and why."""
    m = mode()
    if m == "compiled" and _state.interpreted:
        return f"compiled, but interpreted: {', '.join(sorted(_state.interpreted))}"
    return f"{m} ({_state.why})"


def environment() -> dict[str, str]:
    """The environment a child process needs to run the way this one does."""
    return {ENV: "1" if mode() == "compiled" else "0"}


def register(package_dir: Path, names: list[str],
             bindings: dict[str, tuple[Path, Path]] | None = None) -> None:
    """List a package's compiled modules (dotted names; their sources lie under the folder
    that holds `package_dir`) and its hand-written C bindings (name -> (C source, extension);
    used only in compiled mode, by their callers). Called by each package's `__init__`,
    before any of them is imported. Registered after the decision (a package imported late),
    the same rules apply to the new modules alone."""
    root = Path(package_dir).resolve().parent
    found = {n: (root.joinpath(*n.split(".")).with_suffix(".py"), None) for n in names}
    found.update(bindings or {})
    new = [n for n in found if n not in _state.modules]
    for n in new:
        src, so = found[n]
        _state.modules[n] = src
        _state.extensions[n] = so or extension_path(src)
    if _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)
    if _state.mode == "compiled" and new:
        status = _status(new)
        if any(s != "fresh" for s in status.values()):
            problem = _problem(new, status)
            if os.environ.get(ENV) == "1":
                raise CompiledError(f"{ENV}=1 but {problem}")
            print(f"cosim: running these modules interpreted: {problem}", file=sys.stderr)
            _state.interpreted.update(n for n in new if status[n] != "fresh")


def compiled_modules() -> dict[str, tuple[Path, Path]]:
    """Every listed module: (its source, its compiled form)."""
    return {n: (src, _state.extensions[n]) for n, src in _state.modules.items()}


def uses(name: str) -> bool:
    """Whether this run uses the compiled form of the listed module `name`."""
    return mode() == "compiled" and name not in _state.interpreted


class _Finder:
    """Loads a listed module from its extension or from its source, as `mode()` says."""

    @staticmethod
    def find_spec(fullname, path=None, target=None):
        py = _state.modules.get(fullname)
        if py is None:
            return None
        if py.suffix == ".c" and not uses(fullname):   # a binding: compiled mode only
            raise ModuleNotFoundError(f"{fullname} is used only when running compiled "
                                      f"({describe()})", name=fullname)
        if uses(fullname):
            so = _state.extensions[fullname]
            loader = importlib.machinery.ExtensionFileLoader(fullname, str(so))
            return importlib.util.spec_from_file_location(fullname, so, loader=loader)
        loader = importlib.machinery.SourceFileLoader(fullname, str(py))
        return importlib.util.spec_from_file_location(fullname, py, loader=loader)

    @staticmethod
    def invalidate_caches() -> None:
        pass


_FINDER = _Finder()
