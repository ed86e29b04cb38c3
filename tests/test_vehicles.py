"""Vehicle presets: values traceable to their sources, derived quantities, API."""

from __future__ import annotations

import dataclasses
import math

import pytest

from cosim.scenario.vehicles import BEBOP2, MAMBO, PRESETS, VehicleParams, get_vehicle


def test_presets_and_lookup():
    assert set(PRESETS) == {"mambo", "bebop2"}
    assert get_vehicle("mambo") is MAMBO and get_vehicle("bebop2") is BEBOP2
    with pytest.raises(ValueError, match="unknown vehicle 'x'; choose one of bebop2, mambo"):
        get_vehicle("x")


def test_fmu_parameters_are_all_fields_but_the_name_and_the_body_sphere():
    names = [f.name for f in dataclasses.fields(VehicleParams)]
    for v in PRESETS.values():
        params = v.fmu_parameters()
        assert list(params) == [n for n in names if n not in ("name", "body_radius")]
        assert all(isinstance(x, float) for x in params.values())


def test_with_overrides_rejects_unknown_fields():
    assert MAMBO.with_overrides(mass=0.07).mass == 0.07
    with pytest.raises(TypeError):
        MAMBO.with_overrides(massa=0.07)


def test_mambo_matches_the_minidrone_template():
    """reference/minidrone.md §1: vehicleVars.m numbers and the derived rotor constants."""
    assert MAMBO.mass == 0.063
    assert (MAMBO.Ixx, MAMBO.Iyy, MAMBO.Izz) == (5.82857e-5, 7.16914e-5, 1.0e-4)
    assert MAMBO.arm_length == 0.0624
    rho, r, ct = 1.184, 0.033, 0.0107
    cq = ct * math.sqrt(ct / 2)
    area = math.pi * r**2
    assert MAMBO.k_thrust == pytest.approx(ct * rho * area * r**2, rel=5e-3)
    assert MAMBO.k_torque == pytest.approx(cq * rho * area * r**3, rel=5e-3)
    assert MAMBO.omega_max == pytest.approx(math.sqrt(13840.8 * 500), rel=1e-3)


def test_bebop2_matches_its_cited_sources():
    """BebopS (mass, arm, lag, max speed, moment constant), LADAC (inertia), k_thrust from a
    6x3 propeller with Ct = 0.10."""
    assert BEBOP2.mass == 0.5
    assert (BEBOP2.Ixx, BEBOP2.Iyy, BEBOP2.Izz) == (1.92e-3, 1.85e-3, 3.34e-3)
    assert BEBOP2.arm_length == pytest.approx(0.12905, abs=1e-4)
    assert BEBOP2.motor_tau == 0.0125 and BEBOP2.omega_max == 1475.0
    d = 6 * 0.0254
    assert BEBOP2.k_thrust == pytest.approx(0.10 * 1.225 * d**4 / (4 * math.pi**2), rel=1e-3)
    assert BEBOP2.k_torque == pytest.approx(0.016 * BEBOP2.k_thrust, rel=1e-3)


@pytest.mark.parametrize("v", list(PRESETS.values()), ids=lambda v: v.name)
def test_presets_can_hover_with_margin(v):
    """Hover needs less than full command and leaves control authority: T/W in [1.8, 3.5]."""
    assert 0.4 < v.u_hover < 0.8
    assert 1.8 < 4 * v.thrust_max / v.weight < 3.5
    assert 4 * v.k_thrust * v.omega_hover**2 == pytest.approx(v.weight, rel=1e-12)


def test_drag_is_the_same_per_unit_mass_for_both_presets():
    """Both presets use Förster's Crazyflie drag scaled by mass (0.206 and 0.232 N/(m/s)/kg)."""
    for v in PRESETS.values():
        assert v.drag_xy / v.mass == pytest.approx(0.206, rel=0.01)
        assert v.drag_z / v.mass == pytest.approx(0.232, rel=0.01)
        assert v.Ixx / v.drag_rot == pytest.approx(58, rel=0.02)


@pytest.mark.parametrize("v", list(PRESETS.values()), ids=lambda v: v.name)
def test_rk4_substep_is_well_inside_stability(v):
    """The fastest non-contact mode (motor lag) must be slow against the 1 ms substep."""
    assert 0.001 / v.motor_tau < 0.1
