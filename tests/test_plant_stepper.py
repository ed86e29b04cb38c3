"""The compiled FMI stepper (cosim/plant/csrc/fmi2step.c) against the ctypes path it replaces:
the same outputs bit for bit, the same tick counter, the same errors, states and a whole
mission the same."""

from __future__ import annotations

import math
import random

import pytest

from cosim.errors import ComponentError
from cosim.plant.fmu import Plant
from cosim.scenario.vehicles import BEBOP2, MAMBO


def test_the_stepper_is_built_and_builds_are_checked(tmp_path):
    """The install step built it (python -m onesource.build) from its current source; a build
    embeds the source's hash (what the switch checks), is skipped while the source is
    unchanged, redone when it changes, and a broken source fails with gcc's words."""
    from cosim import BINDINGS
    from onesource import switch as compiled
    from onesource.build import BuildError, build_modules

    src, so = BINDINGS["cosim.plant._fmi2step"]
    assert compiled.module_status(src, so) == "fresh"
    copy = tmp_path / "fmi2step.c"
    copy.write_text(src.read_text().replace("_fmi2step", "ext"))
    lib = tmp_path / ("ext" + compiled.SUFFIX)
    mods = {"ext": (copy, lib)}
    build_modules(mods, build_dir=tmp_path / "b")
    first = lib.stat().st_mtime_ns
    assert compiled.module_status(copy, lib) == "fresh"
    build_modules(mods, build_dir=tmp_path / "b")
    assert lib.stat().st_mtime_ns == first              # up to date: not rebuilt
    copy.write_text(copy.read_text() + "\n/* changed */\n")
    assert compiled.module_status(copy, lib) == "stale"
    build_modules(mods, build_dir=tmp_path / "b")
    assert lib.stat().st_mtime_ns != first and compiled.module_status(copy, lib) == "fresh"
    copy.write_text("this is not C;\n")
    with pytest.raises(BuildError, match="gcc failed"):
        build_modules(mods, build_dir=tmp_path / "b")


def random_inputs(seed: int, n: int) -> list[tuple[float, ...]]:
    rng = random.Random(seed)
    return [(rng.random(), rng.random(), rng.random(), rng.random(), rng.uniform(-3, 3),
             rng.uniform(-3, 3), rng.uniform(-1, 1)) for _ in range(n)]


def fly(vehicle, inputs, *, stepper: bool, fast: bool = True) -> tuple[list, int, float]:
    with Plant(vehicle, z0=-1.0, omega0=vehicle.omega_hover, stepper=stepper, fast=fast) as p:
        assert (p._stepper is not None) == stepper
        out = [tuple(p.step(*u)) for u in inputs]
        return out, p.k, p.t


@pytest.mark.parametrize("vehicle", [MAMBO, BEBOP2], ids=["mambo", "bebop2"])
@pytest.mark.parametrize("fast", [True, False], ids=["fused", "four-calls"])
def test_stepper_is_bit_identical_to_ctypes(vehicle, fast):
    inputs = random_inputs(3, 4000)
    ref = fly(vehicle, inputs, stepper=False, fast=fast)
    got = fly(vehicle, inputs, stepper=True, fast=fast)
    assert got == ref
    assert got[1] == 4000


def test_keywords_defaults_and_bad_arguments():
    with Plant(MAMBO, stepper=True) as a, Plant(MAMBO, stepper=False) as b:
        for _ in range(20):
            assert a.step(0.6, 0.6, 0.6, 0.6, wind_e=2.0) == b.step(0.6, 0.6, 0.6, 0.6,
                                                                      wind_e=2.0)
            assert a.step(0.6, 0.6, 0.6, 0.6) == b.step(0.6, 0.6, 0.6, 0.6)
        with pytest.raises(TypeError, match="unexpected keyword argument 'gust'"):
            a.step(0.5, 0.5, 0.5, 0.5, gust=1.0)
        with pytest.raises(TypeError, match="multiple values for 'u1'"):
            a.step(0.5, 0.5, 0.5, 0.5, u1=1.0)
        with pytest.raises(TypeError, match="at most 7"):
            a.step(*([0.5] * 8))
        with pytest.raises(TypeError):
            a.step(0.5, "x", 0.5, 0.5)
        assert a.k == b.k == 40


@pytest.mark.parametrize("stepper", [True, False], ids=["stepper", "ctypes"])
def test_errors_state_and_reset_as_the_ctypes_path(stepper):
    with Plant(MAMBO, stepper=stepper) as p:
        ref = [tuple(p.step(0.8, 0.8, 0.8, 0.8)) for _ in range(30)]
        snap = p.get_state()
        after = [tuple(p.step(0.7, 0.8, 0.8, 0.8)) for _ in range(30)]
        with pytest.raises(ComponentError, match=r"quadrotorSetStepGet .* returned Error "
                                                 r"at t = 0\.3 s: .*'u2' must be a number"):
            p.step(0.8, math.nan, 0.8, 0.8)
        assert p.k == 60                       # a failed tick does not advance the clock
        p.set_state(snap)
        assert p.k == 30
        assert [tuple(p.step(0.7, 0.8, 0.8, 0.8)) for _ in range(30)] == after
        p.reset()
        assert p.k == 0 and [tuple(p.step(0.8, 0.8, 0.8, 0.8)) for _ in range(30)] == ref
        p.k = 100               # the counter sets the next doStep's time: the FMU refuses
        with pytest.raises(ComponentError, match="currentCommunicationPoint 0.5 does not"):
            p.step(0.8, 0.8, 0.8, 0.8)


def test_closed_plant_no_longer_calls_the_stepper():
    p = Plant(MAMBO, stepper=True)
    p.step(0.5, 0.5, 0.5, 0.5)
    p.close()
    assert p._stepper is None and "step" not in p.__dict__ and p.k == 1


@pytest.mark.flight
def test_seed_mission_identical_with_and_without_the_stepper(monkeypatch):
    from cosim.bench.command import SEED
    from cosim.load import load_scenario
    from cosim.sim.master import RunOptions, run_scenario

    sc = load_scenario(SEED)
    runs = []
    use = Plant._use_stepper
    for want in (True, False):
        monkeypatch.setattr(Plant, "_use_stepper", lambda self, _w, want=want: use(self, want))
        res = run_scenario(sc, RunOptions(mode="mil"))
        runs.append((res.exit_reason, res.ticks, res.series.tobytes()))
    assert runs[0] == runs[1]
    assert runs[0][0].value == "mission_complete"
