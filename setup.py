"""The build backend's one addition: a non-editable install (``pip install .``, a wheel) carries
the compiled build.

setuptools copies the sources (with every ``.pxd`` and the FMI binding's C, pyproject.toml's
package-data) into its build folder; this step then compiles there every module the packages
list (``mav.COMPILED``, ``cosim.COMPILED`` and ``cosim.BINDINGS``) with the project's own
builder (onesource/build.py: the same Cython directives, gcc flags and embedded source hash as
``make build``), so each extension lies beside the source it was built from and the loader's
stale-build check (onesource/switch.py) works in site-packages as in a checkout. The wheel is
tagged for this interpreter and platform. An editable install (``pip install -e .``, what
``make setup`` does) compiles nothing here: ``make build`` compiles in place.

Needs gcc and the Python headers (the README's prerequisites) and Cython (a build requirement
in pyproject.toml); a missing one stops the install with the builder's message.
"""

from __future__ import annotations

import sys
from pathlib import Path

from setuptools import Distribution, setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyCompiled(build_py):
    """build_py, then the compiled modules built beside their copies in build_lib."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return
        sys.path.insert(0, str(ROOT))
        try:
            import cosim  # noqa: F401  (lists its modules with the switch)
            import mav  # noqa: F401
            from onesource.build import BuildError, build_modules
            from onesource.switch import compiled_modules, extension_path
        finally:
            sys.path.remove(str(ROOT))
        lib = Path(self.build_lib).resolve()
        mods = {}
        for name, (src, so) in compiled_modules().items():
            copy = lib / src.relative_to(ROOT)
            built = (lib / so.relative_to(ROOT) if src.suffix == ".c"
                     else extension_path(copy))
            mods[name] = (copy, built)
        try:
            build_modules(mods, force=True,
                          build_dir=Path(self.get_finalized_command("build").build_temp)
                          / "cython", echo=lambda s: print(s, file=sys.stderr))
        except BuildError as exc:
            raise SystemExit(f"cosim: the compiled build failed: {exc}") from None


class BinaryDistribution(Distribution):
    """A wheel with extension modules: tagged for this interpreter and platform."""

    def has_ext_modules(self) -> bool:
        return True


setup(cmdclass={"build_py": BuildPyCompiled}, distclass=BinaryDistribution)
