"""Compile the modules the packages list (the model) into extension modules (the generated
code) with Cython: ``python -m onesource.build`` (``make build``; the install step runs it, and
setup.py for a wheel). See onesource/switch.py for how a run chooses between them.

Each module `pkg/mod.py` (with its `pkg/mod.pxd`, if any: types Cython reads beside the
source, which stays plain Python) is translated by Cython to C in `build/cython/`, the SHA-256
of its source is embedded in that C, and gcc compiles it against this interpreter's headers
into `pkg/mod<EXT_SUFFIX>` beside the source. Compiler flags keep every double operation
rounding as Python's does: -O2 without -ffast-math and with -ffp-contract=off (no fused
multiply-add), so a compiled run is bit-identical to the interpreted one. gcc's warnings are
shown; COSIM_WERROR=1 (CI) makes errors of gcc's warnings on the project's hand-written C (the
FMI binding) and of Cython's warnings on the sources (a clean build has none, so a new one
fails CI), never of gcc's warnings on the C Cython generates, which are Cython's.

A module is rebuilt when its source, the flags, Cython's or gcc's version or the interpreter's
ABI changed (a hash of all of them is embedded too); several processes may build at once (each
writes to a temporary file and moves it into place).

Examples::

    python -m onesource.build            # build what changed, print each module's path
    python -m onesource.build --force    # rebuild everything
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from onesource.switch import MARKER, build_root, compiled_modules, embedded_hash, source_hash

CFLAGS = ("-O2", "-shared", "-fPIC", "-Wall", "-Wextra", "-Wno-unused-parameter",
          "-Wno-unused-function", "-Wno-missing-field-initializers",
          "-ffp-contract=off", "-fno-fast-math")
LIBS = ("-lm",)
# Cython's compiler directives for every module: Python semantics everywhere (division and
# modulo as Python's, ZeroDivisionError, wraparound, bounds checks); annotations are the
# documentation they are in Python (a C type comes only from a .pxd or @cython.locals, so an
# argument annotated `float` still takes what Python would); a field typed as a compiled class
# that is still None (an object used before its __init__) raises instead of being followed
# (nonecheck); signatures kept for help()
DIRECTIVES = ("language_level=3", "binding=True", "embedsignature=True",
              "annotation_typing=False", "nonecheck=True")


class BuildError(RuntimeError):
    """A module could not be built (no compiler, no Python headers, no Cython, an error)."""


def _gcc() -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        raise BuildError("gcc not found: install it with `apt-get install gcc`")
    return gcc


def _include() -> str:
    include = sysconfig.get_paths()["include"]
    if not (Path(include) / "Python.h").is_file():
        raise BuildError(f"Python.h not found in {include} (install the Python headers: "
                         "`apt-get install python3-dev`)")
    return include


def toolchain_hash(extra: tuple[str, ...] = ()) -> str:
    """Of what, besides the source, shapes the generated code: flags, directives, Cython's and
    gcc's versions and the interpreter's ABI."""
    h = hashlib.sha256(" ".join(CFLAGS + LIBS + DIRECTIVES + extra).encode())
    h.update(SUFFIX_TAG.encode())
    try:
        import Cython
        h.update(Cython.__version__.encode())
    except ImportError:
        pass
    out = subprocess.run([_gcc(), "--version"], capture_output=True, text=True, check=False)
    h.update(out.stdout.encode())
    return h.hexdigest()[:16]


SUFFIX_TAG = sysconfig.get_config_var("EXT_SUFFIX") or ""


def _stamp(py: Path, tool: str) -> bytes:
    return MARKER + source_hash(py).encode() + b":" + tool.encode()


def up_to_date(py: Path, so: Path, tool: str) -> bool:
    if not so.is_file():
        return False
    with open(so, "rb") as f:
        return _stamp(py, tool) in f.read()


def _marker(src: Path, tool: str) -> bytes:
    """A C line that embeds the source hash the loader checks (onesource/switch.py)."""
    return (b'\n__attribute__((used)) static const char cosim_source_sha256[] = "'
            + _stamp(src, tool) + b'";\n')


def compile_module(name: str, src: Path, so: Path, build_dir: Path, tool: str,
                   werror: bool = False) -> tuple[Path, str]:
    """A `.py` source: Cython -> C (with the source hash embedded) -> gcc -> `so`. A `.c`
    source (a hand-written binding): gcc on it and the hash (with -Werror if `werror`).
    Returns the extension's path and what the compilers printed."""
    build_dir.mkdir(parents=True, exist_ok=True)
    c = build_dir / f"{name}.c"
    flags = CFLAGS
    log = ""
    if src.suffix == ".py":
        try:
            import Cython  # noqa: F401
        except ImportError:
            raise BuildError("Cython is not installed (pip install -e .)") from None
        cmd = [sys.executable, "-m", "cython", "-3", "--module-name", name, "-o", str(c)]
        for d in DIRECTIVES:
            cmd += ["-X", d]
        res = subprocess.run([*cmd, str(src)], capture_output=True, text=True, check=False)
        if res.returncode != 0:
            raise BuildError(f"cython failed on {src}:\n{res.stdout}{res.stderr}")
        log = res.stdout + res.stderr
        if werror and "warning:" in log:
            raise BuildError(f"cython warned on {src} (COSIM_WERROR=1):\n{log}")
        with open(c, "ab") as f:
            f.write(_marker(src, tool))
    else:
        c.write_bytes(b'#include "' + str(src).encode() + b'"\n' + _marker(src, tool))
        flags = (*CFLAGS, "-std=c99", "-fvisibility=hidden") + (("-Werror",) if werror else ())
    with tempfile.TemporaryDirectory(dir=build_dir, prefix=".so-") as tmp:
        out = Path(tmp) / so.name
        gcc = [_gcc(), *flags, f"-I{_include()}", str(c), "-o", str(out), *LIBS]
        res = subprocess.run(gcc, capture_output=True, text=True, check=False)
        if res.returncode != 0:
            raise BuildError(f"gcc failed on {c}:\n{' '.join(gcc)}\n{res.stderr}")
        log += res.stderr
        os.replace(out, so)
    if embedded_hash(so) != source_hash(src):
        raise BuildError(f"{so}: the embedded source hash does not match {src}")
    return so, log


def build_modules(modules: dict[str, tuple[Path, Path]], *, force: bool = False,
                  jobs: int | None = None, build_dir: Path | None = None, echo=print
                  ) -> list[Path]:
    """Compile every module of `modules` (name -> (source, extension)) that is not up to
    date, `jobs` at a time (default: the CPU count); returns the extensions' paths. Compiler
    output is echoed; COSIM_WERROR=1 (CI) turns warnings in hand-written C into errors."""
    tool = toolchain_hash()
    werror = os.environ.get("COSIM_WERROR") == "1"
    build_dir = build_dir or build_root() / "cython"
    todo = {n: v for n, v in modules.items() if force or not up_to_date(v[0], v[1], tool)}
    with ThreadPoolExecutor(max_workers=jobs or os.cpu_count() or 1) as pool:
        futures = {n: pool.submit(compile_module, n, src, so, build_dir, tool, werror)
                   for n, (src, so) in todo.items()}
        for n, fut in futures.items():
            _, log = fut.result()
            if log.strip():
                echo(f"{n}:\n{log.rstrip()}")
    return [so for _, so in modules.values()]


def main(argv: list[str] | None = None) -> int:
    """`python -m onesource.build`: every module the packages list (the flight software's and
    the simulator's, with the FMI binding), printing each extension's path; exit 1 with the
    reason when one cannot be built."""
    import cosim  # noqa: F401  (each package lists its modules when imported)
    import mav  # noqa: F401

    ap = argparse.ArgumentParser(prog="python -m onesource.build",
                                 description="Compile the listed modules with Cython.")
    ap.add_argument("--force", action="store_true", help="rebuild even if up to date")
    ap.add_argument("-j", "--jobs", type=int, default=None, help="modules compiled at once")
    args = ap.parse_args(argv)
    try:
        for so in build_modules(compiled_modules(), force=args.force, jobs=args.jobs):
            print(so)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
