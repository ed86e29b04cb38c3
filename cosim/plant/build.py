"""Build the simulator's FMI stepper (`cosim/plant/csrc/fmi2step.c` -> `cosim/plant/_fmi2step*.so`):
``python -m cosim.plant.build`` (the install step runs it after the FMU and the onboard fast
path). Same compiler flags and up-to-date check as the onboard fast path (mav/build.py).
Without the library the plant is stepped through ctypes, with the same results.

Examples::

    python -m cosim.plant.build            # build if the source changed, print the path
    python -m cosim.plant.build --force    # always rebuild
"""

from __future__ import annotations

import pathlib
import sysconfig

from mav.build import build_extension, build_main

PACKAGE_DIR = pathlib.Path(__file__).resolve().parent
SOURCE = PACKAGE_DIR / "csrc" / "fmi2step.c"


def library_path() -> pathlib.Path:
    return PACKAGE_DIR / ("_fmi2step" + sysconfig.get_config_var("EXT_SUFFIX"))


def build(force: bool = False) -> pathlib.Path:
    return build_extension(SOURCE, library_path(), force=force)


def main(argv: list[str] | None = None) -> int:
    return build_main(argv, "python -m cosim.plant.build",
                      "Build the FMI stepper (cosim/plant/_fmi2step).", SOURCE, library_path())


if __name__ == "__main__":
    raise SystemExit(main())
