"""Build the Quadrotor FMU from source: ``python -m fmus.build``.

Compiles ``fmus/quadrotor/*.c`` with gcc against the FMI 2.0 headers shipped in the fmpy wheel
and packs ``build/Quadrotor.fmu`` (modelDescription.xml, binaries/linux64/Quadrotor.so,
sources/). ``--fmi 3`` builds the same model as FMI 3.0 Co-Simulation, ``build/Quadrotor3.fmu``:
model.c and fmi2.c with the FMI 2.0 names made internal (FMI2_FUNCTION_PREFIX) plus the FMI 3.0
glue fmi3.c, binaries/x86_64-linux/Quadrotor.so and the description `fmus/fmi3md.py` writes
from the FMI 2.0 one. The archive is deterministic (sorted entries, fixed timestamps and
permissions), so two builds of the same sources give the same bytes. A build is skipped when a
hash of the sources, the headers and the compiler flags matches the one recorded next to the
FMU (`<fmu>.sha256`, first line) and the FMU file is the one built (its own SHA-256, second
line): a truncated or altered FMU in the build folder is built again, not taken for a user's
bad file.

Examples::

    python -m fmus.build            # build if the sources changed, print the path
    python -m fmus.build --force    # always rebuild
    python -m fmus.build --fmi 3    # the FMI 3.0 Co-Simulation build
    python -m fmus.build --golden   # regenerate fmus/quadrotor/Quadrotor_out.csv
"""

from __future__ import annotations

import argparse
import csv
import functools
import hashlib
import io
import os
import pathlib
import platform
import shutil
import subprocess
import sys
import tempfile
import zipfile

from onesource.switch import build_root

PACKAGE_DIR = pathlib.Path(__file__).resolve().parent
SOURCE_DIR = PACKAGE_DIR / "quadrotor"
REPO_ROOT = PACKAGE_DIR.parent
BUILD_DIR = build_root()      # <checkout>/build, or the user's cache for an installed package
MODEL_IDENTIFIER = "Quadrotor"
C_SOURCES = ("model.c", "fmi2.c")
HEADERS = ("config.h",)
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-Wall", "-Wextra", "-fvisibility=hidden",
          "-ffp-contract=off", "-fno-fast-math")   # doubles round as written, on any CPU
LIBS = ("-lm",)
GOLDEN_CSV = SOURCE_DIR / "Quadrotor_out.csv"
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
FMI_VERSIONS = (2, 3)
# the FMI 3.0 build: extra sources and flags (the FMI 2.0 functions become internal names)
FMI3_SOURCES = ("fmi3.c",)
FMI3_CFLAGS = ("-DFMI2_FUNCTION_PREFIX=Quadrotor2_",)


class BuildError(RuntimeError):
    """The FMU could not be built (missing compiler, compile error, unsupported platform)."""


def _fmi_headers_dir() -> pathlib.Path:
    import fmpy

    d = pathlib.Path(os.path.dirname(fmpy.__file__)) / "c-code"
    if not (d / "fmi2Functions.h").is_file():
        raise BuildError(f"FMI 2.0 headers not found in {d} (is fmpy installed?)")
    return d


def _platform_dir(fmi: int = 2) -> str:
    if sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64"):
        return "linux64" if fmi == 2 else "x86_64-linux"
    raise BuildError(
        f"building the FMU is supported on linux x86_64 only, not {sys.platform}/"
        f"{platform.machine()}"
    )


def source_hash(fmi: int = 2) -> str:
    """SHA-256 over the FMU sources, the FMI headers, the compiler flags and gcc's version."""
    h = hashlib.sha256()
    for name in (*_sources(fmi), *HEADERS, "modelDescription.xml"):
        h.update(name.encode() + b"\0" + (SOURCE_DIR / name).read_bytes() + b"\0")
    hdr = _fmi_headers_dir()
    headers = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
    if fmi == 3:
        headers += ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
        h.update((PACKAGE_DIR / "fmi3md.py").read_bytes())
    for name in headers:
        h.update((hdr / name).read_bytes())
    h.update(" ".join(_cflags(fmi) + LIBS).encode())
    h.update(_gcc_version().encode())
    return h.hexdigest()


def _check_fmi(fmi: int) -> None:
    if fmi not in FMI_VERSIONS:
        raise BuildError(f"FMI version {fmi!r}: this FMU is built as FMI 2 or 3")


def _sources(fmi: int) -> tuple[str, ...]:
    return C_SOURCES if fmi == 2 else C_SOURCES + FMI3_SOURCES


def _cflags(fmi: int) -> tuple[str, ...]:
    return CFLAGS if fmi == 2 else CFLAGS + FMI3_CFLAGS


def _fmu_name(fmi: int) -> str:
    return f"{MODEL_IDENTIFIER}.fmu" if fmi == 2 else f"{MODEL_IDENTIFIER}{fmi}.fmu"


def _model_description(fmi: int) -> bytes:
    if fmi == 2:
        return (SOURCE_DIR / "modelDescription.xml").read_bytes()
    from fmus.fmi3md import fmi3_model_description

    return fmi3_model_description()


def _gcc() -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        raise BuildError("gcc not found: install it with `apt-get install gcc`")
    return gcc


@functools.cache
def _gcc_version() -> str:
    """gcc's version line, asked once per process (every Plant checks the build: a study's
    worker would otherwise start `gcc --version` for each run)."""
    out = subprocess.run([_gcc(), "--version"], capture_output=True, text=True, check=False)
    return out.stdout.splitlines()[0] if out.stdout else ""


def _zip_bytes(files: dict[str, bytes]) -> bytes:
    """A zip archive of `files` (archive name -> content) that depends on nothing else."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name in sorted(files):
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3  # unix
            mode = 0o755 if name.endswith(".so") else 0o644
            info.external_attr = (0o100000 | mode) << 16
            zf.writestr(info, files[name], compresslevel=9)
    return buf.getvalue()


def build(force: bool = False, out_dir: pathlib.Path | None = None,
          fmi: int = 2) -> pathlib.Path:
    """Compile and pack the FMU; returns the path of ``Quadrotor.fmu`` (`fmi` 3:
    ``Quadrotor3.fmu``, the FMI 3.0 Co-Simulation build of the same model).

    Skips the work when the recorded source hash matches (unless `force`). Safe to run from
    several processes at once: everything is written to temporary files and moved into place
    with ``os.replace``.
    """
    _check_fmi(fmi)
    out_dir = BUILD_DIR if out_dir is None else pathlib.Path(out_dir)
    fmu = out_dir / _fmu_name(fmi)
    stamp = out_dir / f"{_fmu_name(fmi)}.sha256"
    digest = source_hash(fmi)
    if not force and _built(fmu, stamp, digest):
        return fmu

    plat = _platform_dir(fmi)
    gcc = _gcc()
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=".build-") as tmp:
        so = pathlib.Path(tmp) / f"{MODEL_IDENTIFIER}.so"
        cmd = [
            gcc, *_cflags(fmi), f"-I{_fmi_headers_dir()}", f"-I{SOURCE_DIR}",
            *(str(SOURCE_DIR / c) for c in _sources(fmi)), "-o", str(so), *LIBS,
        ]
        # compile from a fixed directory so no path of the temp dir ends up in the binary
        res = subprocess.run(cmd, capture_output=True, text=True, cwd=SOURCE_DIR, check=False)
        if res.returncode != 0:
            raise BuildError(f"gcc failed ({res.returncode}):\n{' '.join(cmd)}\n{res.stderr}")
        files = {
            "modelDescription.xml": _model_description(fmi),
            f"binaries/{plat}/{MODEL_IDENTIFIER}.so": so.read_bytes(),
        }
        for name in (*_sources(fmi), *HEADERS):
            files[f"sources/{name}"] = (SOURCE_DIR / name).read_bytes()
        data = _zip_bytes(files)
        tmp_fmu = pathlib.Path(tmp) / "out.fmu"
        tmp_fmu.write_bytes(data)
        os.replace(tmp_fmu, fmu)
        tmp_stamp = pathlib.Path(tmp) / "out.sha256"
        tmp_stamp.write_text(f"{digest}\n{hashlib.sha256(data).hexdigest()}\n")
        os.replace(tmp_stamp, stamp)
    return fmu


def _built(fmu: pathlib.Path, stamp: pathlib.Path, digest: str) -> bool:
    """`fmu` is the build of these sources (`digest`), and its bytes are the ones built."""
    try:
        lines = stamp.read_text().split()
        return (len(lines) == 2 and lines[0] == digest
                and hashlib.sha256(fmu.read_bytes()).hexdigest() == lines[1])
    except (OSError, UnicodeDecodeError):
        return False


def fmu_path(build_if_needed: bool = True, fmi: int = 2) -> pathlib.Path:
    """Path of ``<build>/Quadrotor.fmu`` (`fmi` 3: ``Quadrotor3.fmu``; ``<build>``:
    onesource.switch.build_root), built (or rebuilt) first if `build_if_needed`."""
    if build_if_needed:
        return build(fmi=fmi)
    _check_fmi(fmi)
    return BUILD_DIR / _fmu_name(fmi)


# ---- golden output ------------------------------------------------------------------------

GOLDEN_STEP = 0.005  # s, communication step (the co-simulation base tick)
GOLDEN_EVERY = 4  # record every 4th step: 50 Hz
GOLDEN_STOP = 5.0  # s
GOLDEN_OUTPUTS = (
    "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r",
    "ax", "ay", "az", "omega1", "omega2", "omega3", "omega4", "on_ground",
)


def golden_inputs(t: float, u_hover: float) -> tuple[float, ...]:
    """Input sequence of the golden run (Mambo defaults), held over each 5 ms step.

    Returns (u1, u2, u3, u4, wind_n, wind_e, wind_d); see readme.md "Golden output".
    """
    d = 0.01
    h = u_hover
    wind = (1.0, 0.5, 0.0) if 1.0 <= t < 3.0 else (0.0, 0.0, 0.0)
    if t < 0.3:  # on the floor, motors off
        u = (0.0, 0.0, 0.0, 0.0)
    elif t < 1.0:  # take off and climb
        u = (0.75, 0.75, 0.75, 0.75)
    elif t < 1.5:  # hover thrust, in wind
        u = (h, h, h, h)
    elif t < 1.55:  # left rotors (2, 3) faster: roll right, then back
        u = (h - d, h + d, h + d, h - d)
    elif t < 1.6:
        u = (h + d, h - d, h - d, h + d)
    elif t < 1.65:  # front rotors (1, 3) faster: pitch up, then back
        u = (h + d, h - d, h + d, h - d)
    elif t < 1.7:
        u = (h - d, h + d, h - d, h + d)
    elif t < 2.2:  # CCW rotors (1, 2) faster: yaw right
        u = (h + d, h + d, h - d, h - d)
    elif t < 3.0:  # hover thrust
        u = (h, h, h, h)
    elif t < 4.2:  # descend onto the floor
        u = (0.6, 0.6, 0.6, 0.6)
    else:  # motors off, resting on the floor
        u = (0.0, 0.0, 0.0, 0.0)
    return (*u, *wind)


def golden_run(fmu: pathlib.Path | None = None) -> list[list[float]]:
    """Run the golden input sequence through the FMU (Co-Simulation); rows of time + outputs."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    fmu = fmu_path() if fmu is None else fmu
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipdir = extract(str(fmu))
    slave = FMU2Slave(
        guid=md.guid, unzipDirectory=unzipdir,
        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="golden",
    )
    try:
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        mass, k_thrust, omega_max, g = slave.getReal(
            [vr["mass"], vr["k_thrust"], vr["omega_max"], vr["g"]]
        )
        u_hover = (mass * g / (4.0 * k_thrust)) ** 0.5 / omega_max
        in_vr = [vr[n] for n in ("u1", "u2", "u3", "u4", "wind_n", "wind_e", "wind_d")]
        real_vr = [vr[n] for n in GOLDEN_OUTPUTS[:-1]]
        rows = []
        n_steps = round(GOLDEN_STOP / GOLDEN_STEP)
        for k in range(n_steps + 1):
            t = k * GOLDEN_STEP
            if k % GOLDEN_EVERY == 0:
                y = slave.getReal(real_vr)
                on = slave.getBoolean([vr["on_ground"]])[0]
                rows.append([t, *y, 1.0 if on else 0.0])
            if k == n_steps:
                break
            slave.setReal(in_vr, list(golden_inputs(t, u_hover)))
            slave.doStep(currentCommunicationPoint=t, communicationStepSize=GOLDEN_STEP)
        slave.terminate()
    finally:
        slave.freeInstance()
        shutil.rmtree(unzipdir, ignore_errors=True)
    return rows


def write_golden(path: pathlib.Path = GOLDEN_CSV) -> pathlib.Path:
    rows = golden_run()
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["time", *GOLDEN_OUTPUTS])
        for row in rows:
            w.writerow([f"{row[0]:.3f}"] + [repr(float(v)) for v in row[1:]])
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m fmus.build",
        description="Build build/Quadrotor.fmu (FMI 2.0) and build/Quadrotor3.fmu (FMI 3.0 "
        "Co-Simulation) from fmus/quadrotor (gcc, FMI headers from fmpy).",
        epilog="examples:\n  python -m fmus.build\n  python -m fmus.build --force\n"
        "  python -m fmus.build --fmi 3\n"
        "  python -m fmus.build --golden   # rewrite fmus/quadrotor/Quadrotor_out.csv",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--force", action="store_true", help="rebuild even if nothing changed")
    ap.add_argument("--golden", action="store_true", help="regenerate the golden output CSV")
    ap.add_argument("--fmi", type=int, choices=FMI_VERSIONS, default=None,
                    help="build only this FMI version (default: both)")
    args = ap.parse_args(argv)
    try:
        for fmi in (FMI_VERSIONS if args.fmi is None else (args.fmi,)):
            print(build(force=args.force, fmi=fmi))
    except BuildError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    if args.golden:
        print(write_golden())
    return 0


if __name__ == "__main__":
    sys.exit(main())
