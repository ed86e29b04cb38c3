"""The numerics of a process: which CPU-specific code each library runs, and so whether a
flight gives the same bits on every x86-64 CPU.

Four places pick their code by the CPU they run on, once, when the process starts or the
library loads (ARCHITECTURE.md, "Numerics"):

- glibc's libm: ``exp``, ``log``, ``pow``, ``sin``, ``cos``, ``tan``, ``atan``, ``atan2``,
  ``asin``, ``acos`` have FMA/AVX2 variants that round differently in the last bit (measured
  here: about 1 argument in 2,000 differs). Python's ``math``, numpy's scalar loops and our
  compiled modules all call it. Chosen by ld.so at exec: ``GLIBC_TUNABLES`` only.
- numpy: SIMD loops per CPU (AVX-512 ``sin``/``cos``/``exp``/``log``... are other algorithms),
  at import: ``NPY_ENABLE_CPU_FEATURES`` / ``NPY_DISABLE_CPU_FEATURES``.
- OpenCV: dispatched SSE4/AVX/AVX2/AVX-512 code and Intel IPP's own per-CPU code, at load:
  ``OPENCV_CPU_DISABLE``, ``OPENCV_IPP``.
- OpenBLAS (numpy's, scipy's and OpenCV's copies): a kernel per CPU, and threads that change
  the order of sums, at load: ``OPENBLAS_CORETYPE``, ``OPENBLAS_NUM_THREADS``.

``native`` (the default) lets each pick the fastest code for this CPU. ``portable`` holds all
four to the x86-64-v2 level (SSE4.2), which every x86-64 CPU from 2009 on runs the same way:
the same scenario and seed then give the same bytes on any of them. All four are read when a
process starts, so a process cannot change its numerics: ``cosim`` starts itself again with
them (``enter``), ``python -m cosim.numerics portable -- CMD`` starts any command with them,
and a run checks the process it flies in (``check``). Child processes (the SIL vehicle, the
render process, a study's Dask workers) inherit them.

``emulate`` is the other direction, for tests: it makes this CPU look like an older one to the
same four libraries (``baseline``: SSE4.2 only; ``avx2``: no AVX-512).
"""

from __future__ import annotations

import os
import platform
import sys
from typing import Any

MODES = ("native", "portable")
MARK = "COSIM_NUMERICS"            # the mode a process was started with (set with the rest)
_REEXEC = "COSIM_NUMERICS_REEXEC"  # set by enter() on the process it starts: no second round

# glibc's CPU features whose libm variants round differently (the FMA ones) or that imply them
GLIBC_OFF = ("AVX", "AVX2", "FMA", "FMA4", "AVX512F")
# OpenCV's CPU features above SSE4.2: their ids (core/cvdef.h, CV_CPU_*) and the names
# OPENCV_CPU_DISABLE takes (core/src/system.cpp, g_hwFeatureNames)
OPENCV_ABOVE_SSE42 = {
    9: "FP16", 10: "AVX", 11: "AVX2", 12: "FMA3", 13: "AVX512F", 14: "AVX512BW",
    15: "AVX512CD", 16: "AVX512DQ", 17: "AVX512ER", 18: "AVX512IFMA", 19: "AVX512PF",
    20: "AVX512VBMI", 21: "AVX512VL", 22: "AVX512VBMI2", 23: "AVX512VNNI", 24: "AVX512BITALG",
    25: "AVX512VPOPCNTDQ", 26: "AVX5124VNNIW", 27: "AVX5124FMAPS", 256: "AVX512-SKX",
    257: "AVX512-COMMON", 258: "AVX512-KNL", 259: "AVX512-KNM", 260: "AVX512-CNL",
    261: "AVX512-CLX", 262: "AVX512-ICL"}
OPENBLAS_CORE = "Nehalem"          # OpenBLAS's SSE4.2-era kernels; every x86-64 CPU runs them
_CV_NAMES = {6: "SSE4.1", 7: "SSE4.2", 8: "POPCNT", **OPENCV_ABOVE_SSE42}

# emulated older CPUs (tests, and users checking their app): what each library is told
LEVELS = {
    "baseline": {"glibc": GLIBC_OFF, "opencv": "above SSE4.2", "ipp": "sse42",
                 "numpy": "baseline", "openblas": OPENBLAS_CORE},
    "avx2": {"glibc": ("AVX512F",), "opencv": "AVX-512", "ipp": "avx2", "numpy": "avx2",
             "openblas": "Haswell"},
}


class NumericsError(Exception):
    """The process does not run the numerics a run asks for."""


def initial_environ() -> dict[str, str]:
    """The environment this process was started with (what ld.so and the libraries read),
    not os.environ as changed since."""
    try:
        with open("/proc/self/environ", "rb") as f:
            raw = f.read()
    except OSError:
        return dict(os.environ)
    out = {}
    for item in raw.split(b"\0"):
        k, sep, v = item.partition(b"=")
        if sep:
            out[k.decode(errors="replace")] = v.decode(errors="replace")
    return out


def _hwcaps_off(tunables: str) -> set[str]:
    off: set[str] = set()
    for part in tunables.split(":"):
        key, _, val = part.partition("=")
        if key == "glibc.cpu.hwcaps":
            off |= {f[1:] for f in val.split(",") if f.startswith("-")}
    return off


def _with_hwcaps_off(tunables: str, features: tuple[str, ...]) -> str:
    """GLIBC_TUNABLES with `features` masked too (one glibc.cpu.hwcaps entry, others kept)."""
    parts = [p for p in tunables.split(":") if p and not p.startswith("glibc.cpu.hwcaps=")]
    caps = [c for p in tunables.split(":") if p.startswith("glibc.cpu.hwcaps=")
            for c in p.partition("=")[2].split(",") if c]
    caps += [f"-{f}" for f in features if f"-{f}" not in caps]
    return ":".join([*parts, "glibc.cpu.hwcaps=" + ",".join(caps)])


def _opencv_off(which: str = "above SSE4.2") -> list[str]:
    """The OPENCV_CPU_DISABLE names of this CPU's features above SSE4.2 (or its AVX-512 ones):
    only those it has (OpenCV warns about the others)."""
    import cv2

    masked = set(initial_environ().get("OPENCV_CPU_DISABLE", "").replace(";", ",").split(","))
    return [n for i, n in OPENCV_ABOVE_SSE42.items()      # this CPU's, even if masked here
            if (cv2.checkHardwareSupport(i) or n in masked)
            and (which == "above SSE4.2" or "512" in n)]


def _numpy_baseline() -> list[str]:
    from numpy._core._multiarray_umath import __cpu_baseline__

    return list(__cpu_baseline__)


def _numpy_avx2() -> list[str]:
    """numpy's dispatch targets that need AVX-512 (names differ between numpy versions)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__

    return [f for f in __cpu_dispatch__ if "512" in f or f in ("X86_V4",)]


def portable_env(environ: dict[str, str] | None = None) -> dict[str, str]:
    """`environ` (default os.environ) with the portable numerics set."""
    env = dict(os.environ if environ is None else environ)
    env[MARK] = "portable"
    env["GLIBC_TUNABLES"] = _with_hwcaps_off(env.get("GLIBC_TUNABLES", ""), GLIBC_OFF)
    env.pop("NPY_DISABLE_CPU_FEATURES", None)
    env["NPY_ENABLE_CPU_FEATURES"] = ",".join(_numpy_baseline())
    off = [f for f in env.get("OPENCV_CPU_DISABLE", "").replace(";", ",").split(",") if f]
    env["OPENCV_CPU_DISABLE"] = ",".join(off + [f for f in _opencv_off() if f not in off])
    if env.get("OPENCV_IPP") != "disabled":
        env["OPENCV_IPP"] = "sse42"
    env["OPENCV_OPENCL_RUNTIME"] = "disabled"
    env["OPENBLAS_CORETYPE"] = OPENBLAS_CORE
    env["OPENBLAS_NUM_THREADS"] = "1"
    return env


def native_env(environ: dict[str, str] | None = None) -> dict[str, str]:
    """`environ` without what portable_env set (an emulation's settings go too)."""
    env = dict(os.environ if environ is None else environ)
    for k in (MARK, "NPY_ENABLE_CPU_FEATURES", "NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE",
              "OPENCV_IPP", "OPENCV_OPENCL_RUNTIME", "OPENBLAS_CORETYPE",
              "OPENBLAS_NUM_THREADS"):
        env.pop(k, None)
    tun = env.pop("GLIBC_TUNABLES", "")
    rest = ":".join(p for p in tun.split(":") if p and not p.startswith("glibc.cpu.hwcaps="))
    if rest:
        env["GLIBC_TUNABLES"] = rest
    return env


def emulation_env(level: str, environ: dict[str, str] | None = None) -> dict[str, str]:
    """`environ` as this process's libraries would see a CPU of `level` (LEVELS; 'native':
    this CPU as it is), without any numerics the caller was started with. Only features this
    CPU has can be taken away."""
    if level != "native" and level not in LEVELS:
        raise ValueError(f"level {level!r}: one of native, {', '.join(LEVELS)}")
    env = native_env(environ)           # from this CPU as it is, whatever the caller runs
    if level == "native":
        return env
    lv = LEVELS[level]
    env["GLIBC_TUNABLES"] = _with_hwcaps_off(env.get("GLIBC_TUNABLES", ""), lv["glibc"])
    env["OPENCV_CPU_DISABLE"] = ",".join(_opencv_off(lv["opencv"]))
    env["OPENCV_IPP"] = lv["ipp"]
    if lv["numpy"] == "baseline":
        env["NPY_ENABLE_CPU_FEATURES"] = ",".join(_numpy_baseline())
    else:
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(_numpy_avx2())
    env["OPENBLAS_CORETYPE"] = lv["openblas"]
    return env


# --------------------------------------------------------------------------- what runs here
def _numpy() -> dict[str, Any]:
    import numpy as np
    from numpy._core._multiarray_umath import (
        __cpu_baseline__,
        __cpu_dispatch__,
        __cpu_features__,
    )

    return {"version": np.__version__, "baseline": list(__cpu_baseline__),
            "dispatched": [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]}


def _opencv() -> dict[str, Any]:
    import cv2

    ipp = cv2.ipp.getIppVersion() if cv2.ipp.useIPP() else "off"
    return {"version": cv2.__version__, "optimized": bool(cv2.useOptimized()),
            "features": [n for i, n in _CV_NAMES.items() if cv2.checkHardwareSupport(i)],
            "ipp": ipp, "opencl": bool(cv2.ocl.useOpenCL())}


def _blas() -> list[dict[str, Any]]:
    try:
        from threadpoolctl import threadpool_info
    except ImportError:      # a dependency; a broken install still runs
        return []
    return sorted(({"library": os.path.basename(i.get("filepath", "")),
                    "version": i.get("version"), "kernel": i.get("architecture"),
                    "threads": i.get("num_threads")}
                   for i in threadpool_info() if i.get("user_api") == "blas"),
                  key=lambda b: b["library"])


def _cpu() -> dict[str, Any]:
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name") and model in ("", platform.machine()):
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    return {"model": model,
            "features": [f for f in ("sse4_2", "avx", "fma", "avx2", "avx512f") if f in flags]}


def problems() -> list[str]:
    """What keeps this process from the portable numerics (empty: it runs them)."""
    init = initial_environ()
    out = []
    missing = [f for f in GLIBC_OFF if f not in _hwcaps_off(init.get("GLIBC_TUNABLES", ""))]
    if missing:
        out.append(f"libm: glibc may pick its {', '.join(missing)} code (GLIBC_TUNABLES was "
                   "not set when the process started)")
    np_ = _numpy()
    if np_["dispatched"]:
        out.append(f"numpy dispatches to {', '.join(np_['dispatched'])}")
    cv = _opencv()
    above = [f for f in cv["features"] if f in OPENCV_ABOVE_SSE42.values()]
    if above:
        out.append(f"OpenCV dispatches to {', '.join(above)}")
    if cv["ipp"] != "off" and "SSE4.2" not in cv["ipp"]:
        out.append(f"OpenCV's IPP runs {cv['ipp']}")
    if cv["opencl"]:
        out.append("OpenCV may use OpenCL")
    for b in _blas():
        if b["kernel"] != OPENBLAS_CORE or b["threads"] != 1:
            out.append(f"OpenBLAS {b['library']} runs {b['kernel']} on {b['threads']} threads")
    return out


def mode() -> str:
    """'portable' when every library here runs the portable numerics, else 'native'."""
    return "native" if problems() else "portable"


def describe() -> dict[str, Any]:
    """What this process's numerics are (summary.json `numerics`)."""
    init = initial_environ()
    probs = problems()
    return {"mode": "native" if probs else "portable", "not_portable": probs,
            "cpu": _cpu(), "numpy": _numpy(), "opencv": _opencv(), "blas": _blas(),
            "libm": {"glibc": "-".join(platform.libc_ver()),
                     "masked": sorted(_hwcaps_off(init.get("GLIBC_TUNABLES", "")))}}


def check(wanted: str) -> None:
    """Raise NumericsError when a run asks for portable numerics this process lacks."""
    if wanted not in MODES:
        raise NumericsError(f"numerics {wanted!r}: one of {', '.join(MODES)}")
    if wanted == "portable":
        probs = problems()
        if probs:
            raise NumericsError(
                "this process does not run the portable numerics (" + "; ".join(probs) +
                "). They are fixed when a process starts: run it with `cosim ... --numerics "
                "portable`, or start Python with `python -m cosim.numerics portable -- "
                "python ...`")


def enter(wanted: str, argv: list[str]) -> None:
    """Make this process run `wanted`: when it does not, start `python -m cosim.cli ARGV`
    in its place with the numerics set (os.execve: same pid, same terminal). Call it before
    anything is written. 'native' from a portable process starts it without them."""
    if wanted not in MODES:
        raise NumericsError(f"--numerics {wanted!r}: one of {', '.join(MODES)}")
    if mode() == wanted:
        return
    if os.environ.get(_REEXEC):       # started for this already and still not: say why
        check(wanted)
        return
    env = portable_env() if wanted == "portable" else native_env()
    env[_REEXEC] = "1"
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, "-m", "cosim.cli", *argv], env)


def main(argv: list[str] | None = None) -> int:
    """python -m cosim.numerics [describe | portable|native|emulate LEVEL [--] CMD ...]"""
    import json
    import shlex

    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] == "describe":
        print(json.dumps(describe(), indent=2))
        return 0
    what = args.pop(0)
    before = dict(os.environ)          # (importing cv2 changes os.environ)
    if what == "emulate":
        if not args:
            print("usage: python -m cosim.numerics emulate LEVEL -- CMD", file=sys.stderr)
            return 2
        level = args.pop(0)
        try:
            env = emulation_env(level)
        except ValueError as exc:
            print(f"cosim.numerics: {exc}", file=sys.stderr)
            return 2
    elif what in MODES:
        env = portable_env() if what == "portable" else native_env()
    else:
        print(f"cosim.numerics: {what!r}: describe, portable, native or emulate LEVEL",
              file=sys.stderr)
        return 2
    if args and args[0] == "--":
        args.pop(0)
    if not args:
        for k in sorted(set(env) | set(before)):
            if env.get(k) != before.get(k):
                print(f"export {k}={shlex.quote(env[k])}" if k in env else f"unset {k}")
        return 0
    try:
        os.execvpe(args[0], args, env)
    except OSError as exc:
        print(f"cosim.numerics: cannot start {args[0]!r}: {exc.strerror}", file=sys.stderr)
        return 127


if __name__ == "__main__":
    sys.exit(main())
