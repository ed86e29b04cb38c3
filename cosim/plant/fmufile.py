"""An FMU file before it is opened: what it must hold for this machine, and what of it is
extracted, where (issue 43, item 14).

An FMU is a zip archive. `check` runs when a scenario loads (`cosim validate` too), so a bad
file is exit 2 naming `vehicle.fmu` before anything flies:

- its binary for this platform must be there (`binaries/linux64/<modelIdentifier>.so` for
  FMI 2.0, `binaries/x86_64-linux/...` for FMI 3.0): an FMU built for Windows only passed
  validation and failed when the run started;
- what a run extracts of it, the model description, that binary's folder and `resources/`
  (not its sources, documentation or other platforms' binaries), is at most `UNPACKED_MAX`
  bytes in at most `MEMBERS_MAX` files, as the archive declares them (zipfile never writes
  more than a member declares): a 3 GB file inside was extracted on every run.

`extract` unpacks that part into a temporary folder of this process (cosim/tempdirs.py); a
TMPDIR too full for it says so. `model_description` is fmpy's parse of its
modelDescription.xml, once per version of the file in a process (a study's worker flies the
same FMU run after run: the parse with its schema check was ~3.5 ms of each run's setup).
"""

from __future__ import annotations

import errno
import shutil
import tempfile
import zipfile
from pathlib import Path

UNPACKED_MAX = 1 << 30       # bytes: the most of an FMU a run extracts
MEMBERS_MAX = 10_000         # files


_MD_KEEP = 4                 # model descriptions kept per process (the newest)
_MD: dict[tuple, object] = {}


def model_description(path: str | Path, validate: bool = True):
    """fmpy's `read_model_description(path, validate)`, parsed once per version of the file
    in this process: kept under the file's resolved path, inode, size and modification time,
    so a file rebuilt or replaced is parsed again. (Callers read it, never change it.)"""
    from fmpy import read_model_description

    real = Path(path).resolve()
    st = real.stat()
    key = (str(real), st.st_ino, st.st_size, st.st_mtime_ns, validate)
    md = _MD.pop(key, None)
    if md is None:
        md = read_model_description(str(real), validate=validate)
    _MD[key] = md                                 # newest last
    while len(_MD) > _MD_KEEP:
        del _MD[next(iter(_MD))]
    return md


class FmuFileError(ValueError):
    """The FMU cannot be flown on this machine, or is too large to extract; says why."""


def platform_dir(fmi: int) -> str:
    """The folder of `binaries/` with this machine's binary (FMI 2.0 and 3.0 names)."""
    import fmpy

    return fmpy.platform if fmi == 2 else fmpy.platform_tuple


def _wanted(fmi: int):
    binaries = f"binaries/{platform_dir(fmi)}/"
    return lambda name: (name == "modelDescription.xml" or name.startswith(binaries)
                         or name.startswith("resources/"))


def check(path: str | Path, fmi: int, model_identifier: str) -> None:
    """FmuFileError unless the FMU at `path` has its binary for this platform and what a run
    extracts of it fits the limits."""
    import fmpy

    plat = platform_dir(fmi)
    binary = f"binaries/{plat}/{model_identifier}{fmpy.sharedLibraryExtension}"
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
    except (OSError, zipfile.BadZipFile) as exc:
        raise FmuFileError(f"a readable FMU (zip) file ({type(exc).__name__}: {exc})") \
            from None
    names = {i.filename for i in infos}
    if binary not in names:
        has = sorted({n.split("/")[1] for n in names
                      if n.startswith("binaries/") and n.count("/") >= 2 and n.split("/")[1]})
        raise FmuFileError(f"an FMU with a binary for this platform ({binary}; it has "
                           + (f"binaries for {', '.join(has)}" if has else "no binaries")
                           + ": export the FMU for this platform, or fly it where it runs)")
    wanted = _wanted(fmi)
    take = [i for i in infos if wanted(i.filename)]
    size = sum(i.file_size for i in take)
    if len(take) > MEMBERS_MAX or size > UNPACKED_MAX:
        big = max(take, key=lambda i: i.file_size)
        raise FmuFileError(f"an FMU whose description, binary and resources are at most "
                           f"{UNPACKED_MAX >> 20} MB in {MEMBERS_MAX} files (a run extracts "
                           f"them: this one's are {size / 2**20:.0f} MB in {len(take)} files, "
                           f"the largest {big.filename}, {big.file_size / 2**20:.0f} MB)")


def extract(path: str | Path, fmi: int, model_identifier: str,
            unzipdir: str | None = None) -> str:
    """Check the FMU (`check`), extract what a run needs of it into `unzipdir` (default: a
    new temporary folder of this process; the caller removes it); the folder."""
    from fmpy import extract as unzip

    from cosim import tempdirs

    check(path, fmi, model_identifier)
    folder = unzipdir or tempdirs.make("fmu")
    try:
        return str(unzip(str(path), unzipdir=folder, include=_wanted(fmi)))
    except BaseException as exc:
        if unzipdir is None:
            shutil.rmtree(folder, ignore_errors=True)
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise OSError(exc.errno, f"{exc.strerror}: no room to extract {Path(path).name} "
                                     f"(TMPDIR {tempfile.gettempdir()})") from None
        raise
