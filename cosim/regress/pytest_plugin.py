"""The pytest plugin (entry point `pytest11`: on as soon as cosim is installed).

pytest collects, as one test item per case, with the checks of `cosim test`:
- files named `test_*.toml` (a scenario or a suite file), wherever pytest looks;
- with `--cosim`, every scenario and suite file under the paths given to pytest
  (`pytest --cosim scenarios/`).
`--cosim-update` writes the baselines (as `cosim test --update`; pytest-regressions'
`--force-regen`), `--cosim-out DIR` keeps the runs there (default: pytest's temporary folder).
A failing case fails its item with the lines `cosim test` prints for it.
"""

from __future__ import annotations

from pathlib import Path

import pytest


def pytest_addoption(parser) -> None:
    g = parser.getgroup("cosim", "cosim flights as tests (cosim test)")
    g.addoption("--cosim", action="store_true",
                help="collect every scenario and suite file (*.toml) under the given paths")
    g.addoption("--cosim-update", action="store_true",
                help="write the baselines of the collected cases from this run")
    g.addoption("--cosim-out", default=None, metavar="DIR",
                help="the runs' folders (default: pytest's temporary folder)")


def pytest_configure(config) -> None:
    config.addinivalue_line("markers", "flight: a whole flight (a cosim case)")


def _tmp(config) -> Path:
    """pytest's temporary folder for this session (it keeps the last three sessions')."""
    factory = getattr(config, "_tmp_path_factory", None)
    if factory is not None:
        return factory.getbasetemp() / "cosim"
    import tempfile

    return Path(tempfile.mkdtemp(prefix="pytest-cosim-"))


def pytest_collect_file(file_path: Path, parent):
    if file_path.suffix != ".toml":
        return None
    if not (file_path.name.startswith("test_") or parent.config.getoption("cosim")):
        return None
    if {"baselines", "worlds"} & set(file_path.parts[:-1]):
        return None
    from cosim.regress.cases import kind_of, read_toml

    try:
        kind = kind_of(read_toml(file_path, "path"))
    except ValueError:
        kind = "scenario" if file_path.name.startswith("test_") else None  # its error shows
    return CosimFile.from_parent(parent, path=file_path) if kind else None


class CosimFile(pytest.File):
    def collect(self):
        from cosim.regress.cases import collect

        for case in collect([self.path]):
            yield CosimItem.from_parent(self, name=case.id, case=case)


class CosimCaseFailed(Exception):
    pass


class CosimItem(pytest.Item):
    def __init__(self, *, case, **kw) -> None:
        super().__init__(**kw)
        self.case = case
        self.add_marker(pytest.mark.flight)          # a whole flight (tests/conftest.py)

    def runtest(self) -> None:
        from cosim.regress.report import case_text
        from cosim.regress.runner import CaseJob, run_case, update

        cfg = self.config
        out = cfg.getoption("cosim_out")
        base = Path(out) if out else _tmp(cfg)
        job = CaseJob(0, self.case, base / self.case.suite / self.case.id)
        v = run_case(job)
        if cfg.getoption("cosim_update"):
            v["update"] = update(job, v)
        self.user_properties.append(("cosim_verdict", v["status"]))
        if v["status"] in ("failed", "error"):
            raise CosimCaseFailed(case_text(v, most=50))

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, CosimCaseFailed):
            return f"{self.case.suite}/{self.case.id} failed:\n{excinfo.value}"
        return super().repr_failure(excinfo, style)

    def reportinfo(self):
        return self.path, None, f"cosim: {self.case.suite}/{self.case.id}"
