"""Shared test setup: the onboard behaviour tests run against both implementations of the
vehicle's tick, the compiled one (mav/csrc/tick.c, the default) and its Python reference
(`Onboard.poll`), so each is held to the behaviour, not only to the other (tests/test_tick.py
compares them byte for byte)."""

from __future__ import annotations

import pytest

# the modules whose tests drive an in-process vehicle tick by tick through its rare branches
BOTH_TICKS = {"test_onboard_protocol", "test_onboard_failsafes", "test_onboard_auto",
              "test_onboard_signing", "test_onboard_battery_faults", "test_fuzz",
              "test_mission_protocol", "test_onboard_reboot", "test_onboard_setpoints_global",
              "test_onboard_telemetry"}


def pytest_generate_tests(metafunc):
    if metafunc.module.__name__.rpartition(".")[2] in BOTH_TICKS:
        from mav import fastpath

        if fastpath.lib is not None:
            metafunc.parametrize("_onboard_tick", ["c_tick", "py_tick"], indirect=True)


@pytest.fixture(autouse=True)
def _onboard_tick(request, monkeypatch):
    """`py_tick`: vehicles built in the test run `Onboard.poll` in Python."""
    if getattr(request, "param", "c_tick") == "py_tick":
        from mav.onboard.vehicle import Onboard

        monkeypatch.setattr(Onboard, "compiled_tick", False)
