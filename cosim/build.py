"""Compile the simulator's listed modules with Cython, and its one hand-written C binding (the
FMI 2.0 stepper, cosim/plant/csrc/fmi2step.c): ``python -m cosim.build`` (the install step
runs it after ``python -m mav.build``; ``make build`` runs both). The rules are mav/build.py's.

Examples::

    python -m cosim.build            # build what changed, print each module's path
    python -m cosim.build --force    # rebuild everything
"""

from __future__ import annotations

from mav.build import build_main


def main(argv: list[str] | None = None) -> int:
    return build_main(argv, "python -m cosim.build",
                      "Compile the simulator's modules with Cython and its FMI binding.",
                      ["cosim"])


if __name__ == "__main__":
    raise SystemExit(main())
