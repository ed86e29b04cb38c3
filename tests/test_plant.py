"""cosim.plant.Plant: the stepping contract, physics sanity, states, errors."""

from __future__ import annotations

import math

import pytest

import cosim.plant.fmu as cp
from cosim.errors import ComponentError
from cosim.plant.fmu import OUTPUT_NAMES, Plant, PlantState
from cosim.scenario.vehicles import BEBOP2, MAMBO, PRESETS

VEHICLES = list(PRESETS.values())


def run(plant: Plant, cmd, n: int, **wind) -> list[list[float]]:
    return [list(plant.step(*cmd, **wind)) for _ in range(n)]


def test_output_index_constants_follow_output_names():
    assert len(OUTPUT_NAMES) == 21
    for i, name in enumerate(OUTPUT_NAMES):
        assert getattr(cp, f"Y_{name.upper()}") == i


def test_initial_outputs_and_time_counter():
    with Plant(MAMBO, x0=1.0, y0=-2.0, z0=-0.5, yaw0=math.pi / 2) as p:
        assert p.k == 0 and p.t == 0.0
        y = p.y
        assert (y[cp.Y_X], y[cp.Y_Y], y[cp.Y_Z]) == (1.0, -2.0, -0.5)
        assert y[cp.Y_QW] == pytest.approx(math.cos(math.pi / 4))
        assert y[cp.Y_QZ] == pytest.approx(math.sin(math.pi / 4))
        assert y[cp.Y_ON_GROUND] == 0.0
        out = p.step(0, 0, 0, 0)
        assert out is p.y
        for _ in range(9):
            p.step(0, 0, 0, 0)
        assert p.k == 10 and p.t == 10 * 0.005


@pytest.mark.parametrize("vehicle", VEHICLES, ids=lambda v: v.name)
def test_rests_on_the_floor_at_zero_command(vehicle):
    """Motors off on the floor: z = 0 +- 1 mm, accelerometer reads -g, on_ground, no drift."""
    with Plant(vehicle) as p:
        rows = run(p, (0, 0, 0, 0), 400)
    for y in rows:
        assert abs(y[cp.Y_Z]) < 1e-3
        assert y[cp.Y_AZ] == pytest.approx(-vehicle.g, abs=1e-9)
        assert y[cp.Y_ON_GROUND] == 1.0
        assert y[cp.Y_X] == 0.0 and y[cp.Y_Y] == 0.0


@pytest.mark.parametrize("vehicle", VEHICLES, ids=lambda v: v.name)
def test_hover_command_holds_position_in_the_air(vehicle):
    """In the air at 1 m with the rotors at hover speed and u = u_hover: < 1 mm in 5 s,
    and the accelerometer reads -g (thrust/m)."""
    u = vehicle.u_hover
    with Plant(vehicle, z0=-1.0, omega0=vehicle.omega_hover) as p:
        rows = run(p, (u, u, u, u), 1000)
    last = rows[-1]
    drift = math.dist((last[cp.Y_X], last[cp.Y_Y], last[cp.Y_Z]), (0.0, 0.0, -1.0))
    assert drift < 1e-3
    assert last[cp.Y_AZ] == pytest.approx(-vehicle.g, rel=1e-9)
    assert last[cp.Y_ON_GROUND] == 0.0


@pytest.mark.parametrize("vehicle", VEHICLES, ids=lambda v: v.name)
def test_hover_command_spins_up_on_the_floor_without_lifting_off(vehicle):
    """From standstill on the floor, u_hover spins the rotors up to exactly carry the weight:
    the vehicle neither sinks nor climbs (|z| < 1 mm over 5 s), then a little more lifts it."""
    u = vehicle.u_hover
    with Plant(vehicle) as p:
        rows = run(p, (u, u, u, u), 1000)
        assert all(abs(y[cp.Y_Z]) < 1e-3 for y in rows)
        assert rows[-1][cp.Y_OMEGA1] == pytest.approx(vehicle.omega_hover, rel=1e-9)
        up = run(p, (1.05 * u,) * 4, 200)
    assert up[-1][cp.Y_Z] < -0.05 and up[-1][cp.Y_ON_GROUND] == 0.0


@pytest.mark.parametrize("vehicle", VEHICLES, ids=lambda v: v.name)
def test_rotor_numbering_and_spin_directions(vehicle):
    """PX4 quad-X: right rotors (1, 4) faster roll left (p < 0); front rotors (1, 3) faster
    pitch nose up (q > 0); CCW rotors (1, 2) faster yaw right (r > 0)."""
    u, d = vehicle.u_hover, 0.02

    def rates(cmd):
        with Plant(vehicle, z0=-1.0, omega0=vehicle.omega_hover) as p:
            y = run(p, cmd, 20)[-1]
        return y[cp.Y_P], y[cp.Y_Q], y[cp.Y_R]

    p_, q_, r_ = rates((u + d, u - d, u - d, u + d))
    assert p_ < -0.1 and abs(q_) < 1e-9 and abs(r_) < 1e-9
    p_, q_, r_ = rates((u + d, u - d, u + d, u - d))
    assert q_ > 0.1 and abs(p_) < 1e-9 and abs(r_) < 1e-9
    p_, q_, r_ = rates((u + d, u + d, u - d, u - d))
    assert r_ > 0.01 and abs(p_) < 1e-9 and abs(q_) < 1e-9


def test_commands_outside_0_1_are_clamped():
    """u > 1 acts like 1, u < 0 like 0 (bit for bit), including +-inf."""
    def final(cmd):
        with Plant(MAMBO) as p:
            return run(p, cmd, 100)[-1]

    assert final((1.7, 1.0, math.inf, 1.0)) == final((1.0, 1.0, 1.0, 1.0))
    assert final((-0.5, -math.inf, 0.0, 0.0)) == final((0.0, 0.0, 0.0, 0.0))
    top = final((1.0, 1.0, 1.0, 1.0))
    assert top[cp.Y_OMEGA1] <= MAMBO.omega_max


def test_nan_command_raises_and_reset_recovers():
    with Plant(MAMBO) as p:
        ref = run(p, (0.8, 0.8, 0.8, 0.8), 50)
        with pytest.raises(ComponentError, match=r"input 'u2' must be a number, got NaN") as e:
            p.step(0.8, math.nan, 0.8, 0.8)
        assert e.value.part == "plant"
        p.reset()
        assert run(p, (0.8, 0.8, 0.8, 0.8), 50) == ref


def test_bad_vehicle_parameters_raise_component_error():
    with pytest.raises(ComponentError, match=r"parameter 'mass' must be > 0, got -1"):
        Plant(MAMBO.with_overrides(mass=-1.0))
    with pytest.raises(ComponentError, match=r"parameter 'Iyy' must be > 0, got 0"):
        Plant(MAMBO.with_overrides(Iyy=0.0))
    with pytest.raises(ValueError, match="step_size"):
        Plant(MAMBO, step_size=0.0)


def _flight(plant: Plant, n: int, k0: int = 0) -> list[list[float]]:
    """A deterministic, input-rich command sequence (depends on the tick only)."""
    out = []
    for k in range(k0, k0 + n):
        a = 0.72 + 0.03 * math.sin(0.05 * k)
        out.append(list(plant.step(a, a + 0.01 * math.sin(0.3 * k), a, a - 0.005,
                                   wind_n=0.5 * math.cos(0.01 * k))))
    return out


def test_save_restore_continue_is_bit_identical():
    with Plant(MAMBO) as p:
        _flight(p, 300)
        s = p.get_state()
        assert isinstance(s, PlantState) and s.k == 300
        ref = _flight(p, 400, 300)
        _flight(p, 50, 700)  # wander off, then come back
        p.set_state(s)
        assert p.k == 300 and p.t == 300 * 0.005
        assert _flight(p, 400, 300) == ref


def test_reset_and_a_second_instance_reproduce_a_run_bit_identically():
    with Plant(MAMBO) as p:
        y0 = list(p.y)
        ref = _flight(p, 600)
        p.reset()
        assert p.k == 0 and p.y == y0
        assert _flight(p, 600) == ref
    with Plant(MAMBO) as q:
        assert _flight(q, 600) == ref


def test_state_from_one_instance_restores_into_another():
    with Plant(MAMBO) as a, Plant(MAMBO) as b:
        _flight(a, 200)
        b.set_state(a.get_state())
        assert b.y == a.y
        assert _flight(a, 100, 200) == _flight(b, 100, 200)
        with pytest.raises(TypeError):
            b.set_state("not a state")


@pytest.mark.parametrize("vehicle", VEHICLES, ids=lambda v: v.name)
def test_lands_without_bouncing_sliding_or_sinking(vehicle):
    """Dropped from 1 m with the motors off (4.4 m/s at impact): after touch-down it stays on
    the floor (never more than 1 mm above it), penetrates < 1 cm and comes to rest at
    z = 0 +- 1 mm."""
    with Plant(vehicle, z0=-1.0) as p:
        rows = run(p, (0, 0, 0, 0), 80)
        assert rows[-1][cp.Y_ON_GROUND] == 0.0
        rows += run(p, (0, 0, 0, 0), 600)
    zs = [y[cp.Y_Z] for y in rows]
    k_touch = next(i for i, y in enumerate(rows) if y[cp.Y_ON_GROUND])
    after = rows[k_touch:]
    assert min(y[cp.Y_Z] for y in after) > -1e-3
    assert max(zs) < 1e-2
    last = after[-1]
    assert abs(last[cp.Y_Z]) < 1e-3 and last[cp.Y_ON_GROUND] == 1.0
    assert abs(last[cp.Y_VZ]) < 1e-6


def test_landing_with_horizontal_speed_stops_quickly():
    """Touch down at about 1 m/s sideways: friction stops it within 5 cm, level."""
    v = MAMBO
    with Plant(v, z0=-0.3, omega0=v.omega_hover) as p:
        # drift east in a 2 m/s wind at hover thrust for 1 s, then motors off and fall
        u = v.u_hover
        run(p, (u, u, u, u), 200, wind_e=2.0)
        vy_before = p.y[cp.Y_VY]
        assert vy_before > 0.3
        rows = run(p, (0, 0, 0, 0), 400)
    k_touch = next(i for i, y in enumerate(rows) if y[cp.Y_ON_GROUND])
    y_touch = rows[k_touch][cp.Y_Y]
    assert rows[-1][cp.Y_Y] - y_touch < 0.05
    assert abs(rows[-1][cp.Y_VY]) < 1e-3
    assert abs(rows[-1][cp.Y_QX]) < 1e-3 and abs(rows[-1][cp.Y_QY]) < 1e-3


def test_wind_pushes_the_vehicle_downwind():
    u = MAMBO.u_hover
    with Plant(MAMBO, z0=-1.0, omega0=MAMBO.omega_hover) as p:
        y = run(p, (u, u, u, u), 200, wind_n=1.0, wind_e=-2.0)[-1]
    assert y[cp.Y_VX] > 0.0 and y[cp.Y_VY] < 0.0
    # drag acceleration is in the body x/y axes of the accelerometer
    assert y[cp.Y_AX] > 0.0 and y[cp.Y_AY] < 0.0


def test_close_is_idempotent():
    p = Plant(MAMBO)
    p.close()
    p.close()
    with Plant(BEBOP2) as q:
        q.step(0, 0, 0, 0)
    q.close()


def test_bench_step_reports_microseconds():
    from cosim.bench.plant import bench_step

    r = bench_step(n=2000)
    assert set(r) >= {"step_us", "do_step_us", "step_us_min", "do_step_us_min"}
    assert all(v > 0 for v in r.values())


def test_fused_step_is_bit_identical_to_the_standard_fmi_calls():
    """quadrotorSetStepGet (one ctypes call) gives the same bits as fmi2SetReal + fmi2DoStep +
    fmi2GetReal + fmi2GetBoolean, through take-off, flight with wind, touchdown and rest."""
    u = MAMBO.u_hover
    with Plant(MAMBO) as fast, Plant(MAMBO, fast=False) as std:
        assert fast._raw_set_step_get is not None and std._raw_set_step_get is None
        assert fast.y == std.y
        for k in range(1500):
            c = 1.15 * u if k < 300 else (0.95 * u if k < 900 else 0.0)
            cmd = (c * (1.0 + 0.01 * math.sin(0.01 * k)), c, c * 0.999, c, 0.3, -0.2, 0.05)
            assert fast.step(*cmd) == std.step(*cmd), k
        assert fast.y[cp.Y_ON_GROUND] == 1.0
    # errors: the FMU's message, and the run recovers after a reset (one instance at a time:
    # fmpy's logger proxy delivers the FMU's messages to the last instance created)
    with Plant(MAMBO) as fast:
        with pytest.raises(ComponentError, match=r"input 'u2' must be a number, got NaN"):
            fast.step(u, math.nan, u, u)
        fast.reset()
        y1 = list(fast.step(u, u, u, u))
    with Plant(MAMBO, fast=False) as std:
        assert std.step(u, u, u, u) == y1
