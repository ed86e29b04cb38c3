"""Shared test setup: the tests run on what the switch chose for this process (onesource/switch.py:
compiled when built, the default); tests/test_compiled.py runs flights and the onboard
behaviour tests interpreted too, back to back."""

import signal

import pytest

# The Ctrl-C tests send SIGINT to the programs they start. A test run started as a background
# job (a shell's `cmd &`, some CI runners) has SIGINT ignored, and a program it starts inherits
# that and never sees the signal (Python then installs no KeyboardInterrupt handler): the tests
# would fail for the runner's reason. They restore the default, as a terminal's user has it.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_addoption(parser):
    parser.addoption("--fast", action="store_true",
                     help="the fast lane (make test-fast): unit tests of the parts; tests marked "
                          "flight or slow are left out, and a test that starts a whole flight "
                          "anyway fails, naming the marker it lacks")


def pytest_collection_modifyitems(config, items):
    if not config.getoption("--fast"):
        return
    keep, drop = [], []
    for item in items:
        (drop if item.get_closest_marker("flight") or item.get_closest_marker("slow")
         else keep).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


@pytest.fixture(autouse=True)
def _fast_lane_flies_nothing(request, monkeypatch):
    """In the fast lane, building a run's plant (every whole flight does) fails the test."""
    if request.config.getoption("--fast"):
        from cosim.sim import fleet, master

        def refuse(*args, **kwargs):
            raise AssertionError("a whole flight in the fast lane: mark the test "
                                 "`@pytest.mark.flight` (or its module: pytestmark)")
        monkeypatch.setattr(master, "build_plant", refuse)
        monkeypatch.setattr(fleet, "build_plant", refuse)
