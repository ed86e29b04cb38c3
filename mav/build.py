"""Build the onboard fast path (`mav/csrc/fastpath.c`, which includes the other `csrc/*.c`,
-> `mav/_fastpath*.so`):
``python -m mav.build`` (the install step runs it, as it builds the FMU).

A CPython extension compiled with gcc against this interpreter's headers, with the flags that
keep it bit-identical to the Python reference (mav/cascade.py): -O2 without -ffast-math and
with -ffp-contract=off (no fused multiply-add), so every double operation rounds as Python's
does. A build is skipped when a hash of the source, the flags, the interpreter's ABI tag and
gcc's version matches the one recorded beside the library. Without the library (no compiler,
another platform) the onboard stack runs its Python implementation, with the same results.

Examples::

    python -m mav.build            # build if the source changed, print the path
    python -m mav.build --force    # always rebuild
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import tempfile

PACKAGE_DIR = pathlib.Path(__file__).resolve().parent
SOURCE = PACKAGE_DIR / "csrc" / "fastpath.c"
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-Wall", "-Wextra", "-Wno-unused-parameter",
          "-ffp-contract=off", "-fno-fast-math", "-fvisibility=hidden")
LIBS = ("-lm",)


class BuildError(RuntimeError):
    """The fast path could not be built (no compiler, no Python headers, compile error)."""


def library_path() -> pathlib.Path:
    """Where the extension goes: beside this file, named for this interpreter's ABI."""
    return PACKAGE_DIR / ("_fastpath" + sysconfig.get_config_var("EXT_SUFFIX"))


def _gcc() -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        raise BuildError("gcc not found: install it with `apt-get install gcc`")
    return gcc


def source_hash(source: pathlib.Path = SOURCE) -> str:
    """Of the source and the C files beside it (the ones it includes), flags, ABI and gcc."""
    h = hashlib.sha256(source.read_bytes())
    for other in sorted(source.parent.glob("*.c")):
        if other != source:
            h.update(other.name.encode() + b"\0" + other.read_bytes())
    h.update(" ".join(CFLAGS + LIBS).encode())
    h.update((sysconfig.get_config_var("EXT_SUFFIX") or "").encode())
    out = subprocess.run([_gcc(), "--version"], capture_output=True, text=True, check=False)
    h.update(out.stdout.encode())
    return h.hexdigest()


def build(force: bool = False) -> pathlib.Path:
    """Compile the fast path if needed; returns its path."""
    return build_extension(SOURCE, library_path(), force=force)


def build_extension(source: pathlib.Path, lib: pathlib.Path, force: bool = False
                    ) -> pathlib.Path:
    """Compile one C source into the CPython extension `lib` if needed (the hash of the source,
    flags, ABI tag and gcc recorded beside it differs); returns `lib`. Safe from several
    processes at once (written to a temporary file and moved into place). Also used for the
    simulator's own extension (cosim/plant/build.py)."""
    stamp = lib.with_name(lib.name + ".sha256")
    digest = source_hash(source)
    if not force and lib.is_file() and stamp.is_file() and stamp.read_text().strip() == digest:
        return lib
    include = sysconfig.get_paths()["include"]
    if not (pathlib.Path(include) / "Python.h").is_file():
        raise BuildError(f"Python.h not found in {include} (install the Python headers)")
    with tempfile.TemporaryDirectory(dir=lib.parent, prefix=".build-") as tmp:
        out = pathlib.Path(tmp) / lib.name
        cmd = [_gcc(), *CFLAGS, f"-I{include}", source.name, "-o", str(out), *LIBS]
        res = subprocess.run(cmd, capture_output=True, text=True, cwd=source.parent,
                             check=False)
        if res.returncode != 0:
            raise BuildError(f"gcc failed ({res.returncode}):\n{' '.join(cmd)}\n{res.stderr}")
        os.replace(out, lib)
        tmp_stamp = pathlib.Path(tmp) / "stamp"
        tmp_stamp.write_text(digest + "\n")
        os.replace(tmp_stamp, stamp)
    return lib


def build_main(argv: list[str] | None, prog: str, description: str, source: pathlib.Path,
               lib: pathlib.Path) -> int:
    """The command line of a builder (`--force`): prints the library's path; exit 1 with the
    reason when it cannot be built."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("--force", action="store_true", help="rebuild even if up to date")
    args = ap.parse_args(argv)
    try:
        print(build_extension(source, lib, force=args.force))
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    return build_main(argv, "python -m mav.build",
                      "Build the onboard fast path (mav/_fastpath).", SOURCE, library_path())


if __name__ == "__main__":
    raise SystemExit(main())
