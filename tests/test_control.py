"""Onboard low-level controllers (mav.control): mixer, signs, limits, parameters, and closed
loops with the plant FMU (take-off, hold, go-to, velocity, yaw, land) for both vehicles."""

from __future__ import annotations

import math

import pytest

from cosim.scenario.vehicles import PRESETS
from mav.airframe import BEBOP2, MAMBO, Airframe
from mav.control import Bebop2Controller, MamboController, ParamSpec, make_controller
from mav.mixer import inverse4, mixer_matrix
from mav.types import Setpoint, VehicleState

VEHICLES = [MAMBO, BEBOP2]
IDS = [v.name for v in VEHICLES]


def tilt(v: Airframe) -> str:
    """The tilt limit's name (the Mambo's template limit, the Bebop 2's Parrot MaxTilt)."""
    return "TPL_TILTMAX_AIR" if v is MAMBO else "CAS_TILTMAX_AIR"


def vz_limit(v: Airframe) -> str:
    return "TPL_Z_VEL_MAX" if v is MAMBO else "CAS_Z_VEL_MAX"


# ----------------------------------------------------------------------------- helpers
def hover_state(z: float = -1.0, yaw: float = 0.0) -> VehicleState:
    s = VehicleState()
    s.z = z
    s.qw, s.qz = math.cos(yaw / 2), math.sin(yaw / 2)
    return s


def hold_setpoint(s: VehicleState, yaw: float = 0.0) -> Setpoint:
    sp = Setpoint()
    sp.armed = True
    sp.x, sp.y, sp.z, sp.yaw = s.x, s.y, s.z, yaw
    return sp


def wrench(v: Airframe, u: list[float]) -> list[float]:
    """[T, N, M, L] (N, N m) the rotors produce at steady state for commands u."""
    t = [v.k_thrust * (ui * v.omega_max) ** 2 for ui in u]
    return [sum(a * b for a, b in zip(row, t, strict=True)) for row in mixer_matrix(v)]


def one_tick(ctrl, s: VehicleState, sp: Setpoint) -> list[float]:
    out = [math.nan] * 4
    ctrl.update(s, sp, out)
    return out


# ----------------------------------------------------------------------------- mixer
@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_mixer_inverse_round_trip(v):
    A = mixer_matrix(v)
    Ai = inverse4(A)
    for i in range(4):
        for j in range(4):
            prod = sum(A[i][k] * Ai[k][j] for k in range(4))
            assert prod == pytest.approx(1.0 if i == j else 0.0, abs=1e-9)
    # a wrench inside the envelope comes back unchanged through the controller's mixer:
    # level hover at the setpoint commands exactly the weight and no torque
    ctrl = make_controller(v)
    u = one_tick(ctrl, hover_state(), hold_setpoint(hover_state()))
    assert u == pytest.approx([v.u_hover] * 4, rel=1e-12)
    T, N, M, L = wrench(v, u)
    assert T == pytest.approx(v.weight, rel=1e-9)
    assert (N, M, L) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_mixer_geometry_matches_the_motor_contract():
    A = mixer_matrix(MAMBO)
    a = MAMBO.arm_length * math.sqrt(2) / 2
    c = MAMBO.k_torque / MAMBO.k_thrust
    assert A[1] == pytest.approx([c, c, -c, -c])      # 1, 2 CCW: +yaw
    assert A[2] == pytest.approx([a, -a, a, -a])      # front 1, 3: pitch up
    assert A[3] == pytest.approx([-a, a, a, -a])      # left 2, 3: roll right


# ----------------------------------------------------------------------------- signs
@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_forward_error_pitches_nose_down(v):
    s = hover_state()
    sp = hold_setpoint(s)
    sp.x = 0.5  # target ahead (north, heading north)
    u = one_tick(make_controller(v), s, sp)
    _, _, M, L = wrench(v, u)
    assert M < 0 and abs(L) < 1e-12
    assert u[0] < u[1] and u[2] < u[3]  # front rotors (1, 3) slower than rear (2, 4)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_right_error_rolls_right_and_errors_rotate_with_yaw(v):
    s = hover_state()
    sp = hold_setpoint(s)
    sp.y = 0.5  # target east = to the right when heading north
    u = one_tick(make_controller(v), s, sp)
    assert wrench(v, u)[3] > 0 and u[1] > u[0] and u[2] > u[3]  # left rotors (2, 3) faster
    # heading east (yaw +90 deg): a target to the north is to the LEFT -> roll left
    s = hover_state(yaw=math.pi / 2)
    sp = hold_setpoint(s, yaw=math.pi / 2)
    sp.x = 0.5
    _, _, M, L = wrench(v, one_tick(make_controller(v), s, sp))
    assert L < 0 and abs(M) < 1e-9 * abs(L)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_velocity_damping_brakes(v):
    s = hover_state()
    s.vx = 1.0  # moving forward at the position setpoint -> pitch up to brake
    u = one_tick(make_controller(v), s, hold_setpoint(s))
    assert wrench(v, u)[2] > 0 and u[0] > u[1]


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_yaw_and_rate_damping_signs(v):
    s = hover_state()
    sp = hold_setpoint(s, yaw=0.3)
    u = one_tick(make_controller(v), s, sp)
    assert wrench(v, u)[1] > 0 and u[0] > u[2] and u[1] > u[3]  # yaw right: 1, 2 faster
    # wrap: +179 deg wanted, -179 deg now -> turn left by 2 deg, not right by 358
    s = hover_state(yaw=math.radians(-179))
    sp = hold_setpoint(s, yaw=math.radians(179))
    assert wrench(v, one_tick(make_controller(v), s, sp))[1] < 0
    # rolling right (p > 0) at the attitude setpoint -> damping torque to the left
    s = hover_state()
    s.p = 1.0
    assert wrench(v, one_tick(make_controller(v), s, hold_setpoint(s)))[3] < 0


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_climb_command_adds_thrust_equally(v):
    s = hover_state(z=0.0)
    sp = hold_setpoint(s)
    sp.z = -1.0
    u = one_tick(make_controller(v), s, sp)
    assert all(ui > v.u_hover for ui in u) and max(u) == pytest.approx(min(u), rel=1e-12)


# ----------------------------------------------------------------------------- limits
def _pitch_ref(v: Airframe, ctrl, s: VehicleState, sp: Setpoint) -> float:
    """The pitch reference of a first tick at rest and level: torque = kp * pitch_ref."""
    M = wrench(v, one_tick(ctrl, s, sp))[2]
    return M / ctrl.linear_gains()["pitch_kp"]


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_tilt_limit(v):
    ctrl = make_controller(v)
    ctrl.set_param("MPC_XY_VEL_MAX", 7.0)  # so that the tilt limit, not the speed, binds
    s = hover_state()
    sp = hold_setpoint(s)
    sp.x = 100.0
    lim = math.radians(ctrl.get_param(tilt(v)))
    assert _pitch_ref(v, ctrl, s, sp) == pytest.approx(-lim, rel=1e-9)
    ctrl.set_param(tilt(v), 10.0)
    ctrl.reset()
    assert _pitch_ref(v, ctrl, s, sp) == pytest.approx(-math.radians(10.0), rel=1e-9)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_horizontal_speed_limit(v):
    ctrl = make_controller(v)
    ctrl.set_param(tilt(v), 45.0 if v is MAMBO else 35.0)
    ctrl.set_param("MPC_XY_VEL_MAX", 1.0)
    g = ctrl.linear_gains()
    s = hover_state()
    sp = hold_setpoint(s)
    sp.x = sp.y = math.nan
    sp.vx = 50.0  # velocity mode, far above the limit: commanded speed = the limit
    expected = -(g["k_vxy"] * 1.0 + g["c_drag"] * 1.0)
    assert _pitch_ref(v, ctrl, s, sp) == pytest.approx(expected, rel=1e-9)
    # position mode: the error saturation and the speed limit both hold
    sp.x, sp.y, sp.vx = 3.0, 0.0, math.nan
    ctrl.reset()
    assert _pitch_ref(v, ctrl, s, sp) == pytest.approx(-g["k_vxy"] * 1.0, rel=1e-9)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_climb_rate_and_thrust_limits(v):
    ctrl = make_controller(v)
    g = ctrl.linear_gains()
    s = hover_state(z=0.0)
    sp = hold_setpoint(s)
    sp.z = -100.0
    ctrl.set_param(vz_limit(v), 0.5)  # small enough not to hit the thrust limit
    vz_max = 0.5
    T = wrench(v, one_tick(ctrl, s, sp))[0]
    assert T == pytest.approx(v.weight + g["k_vz"] * vz_max, rel=1e-9)
    ctrl.set_param("MPC_THR_MAX", 0.2)  # below the weight + climb demand: saturates
    ctrl.reset()
    T = wrench(v, one_tick(ctrl, s, sp))[0]
    assert T == pytest.approx(0.2 * 4 * v.thrust_max, rel=1e-9)
    # descent: commanded down at the limit, never a negative rotor command
    sp.z = 100.0
    ctrl.set_param("MPC_THR_MAX", 1.0)
    ctrl.reset()
    u = one_tick(ctrl, s, sp)
    assert wrench(v, u)[0] == pytest.approx(v.weight - g["k_vz"] * vz_max, rel=1e-9)
    assert all(0.0 <= ui <= 1.0 for ui in u)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_outputs_stay_in_unit_range_under_absurd_inputs(v):
    ctrl = make_controller(v)
    s = hover_state(z=0.0)
    s.p, s.q, s.r, s.vx, s.vz = 50.0, -50.0, 30.0, 20.0, -9.0
    s.qw, s.qx = math.cos(0.6), math.sin(0.6)  # 69 deg roll
    sp = hold_setpoint(hover_state())
    sp.x, sp.yaw = 50.0, 3.0
    for _ in range(50):
        u = one_tick(ctrl, s, sp)
        assert all(0.0 <= ui <= 1.0 and math.isfinite(ui) for ui in u)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_nan_state_never_reaches_the_motors(v):
    ctrl = make_controller(v)
    s = hover_state()
    s.q = math.nan
    u = one_tick(ctrl, s, hold_setpoint(hover_state()))
    assert all(0.0 <= ui <= 1.0 for ui in u)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_yaw_rate_setpoint_is_limited(v):
    """An excessive yaw-rate setpoint is cut to MC_YAWRATE_MAX (the heading reference of the
    Mambo integrates the limited rate, so it cannot run away)."""
    ctrl = make_controller(v)
    ctrl.set_param("MC_YAWRATE_MAX", 30.0)
    g = ctrl.linear_gains()
    s = hover_state()
    sp = hold_setpoint(s, yaw=math.nan)
    sp.yaw_rate = 100.0
    N = wrench(v, one_tick(ctrl, s, sp))[1]
    assert N == pytest.approx(g["k_r"] * math.radians(30.0), rel=1e-9)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_yaw_rate_limit(v):
    ctrl = make_controller(v)
    ctrl.set_param("MC_YAWRATE_MAX", 30.0)
    g = ctrl.linear_gains()
    s = hover_state()
    sp = hold_setpoint(s, yaw=3.0)  # big heading error: rate command saturates
    N = wrench(v, one_tick(ctrl, s, sp))[1]
    assert N == pytest.approx(g["k_r"] * math.radians(30.0), rel=1e-9)


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_yaw_gets_only_the_headroom_left(v):
    """A yaw demand beyond the rotors' authority is cut; thrust, roll, pitch are kept."""
    ctrl = make_controller(v)
    ctrl.set_param("MC_YAWRATE_MAX", 200.0)
    ctrl.set_param("CAS_YAWRATE_P" if v is BEBOP2 else "TPL_YAW_D", 0.02 if v is MAMBO else 50)
    s = hover_state()
    u = one_tick(ctrl, s, hold_setpoint(s, yaw=3.0))
    T, N, M, L = wrench(v, u)
    assert T == pytest.approx(v.weight, rel=1e-9) and abs(M) + abs(L) < 1e-12
    # one rotor pair at a bound: 1, 2 at full speed or 3, 4 stopped
    assert max(u) == pytest.approx(1.0, rel=1e-12) or min(u) == pytest.approx(0.0, abs=1e-6)
    c = v.k_torque / v.k_thrust
    t_h = v.weight / 4
    assert N == pytest.approx(4 * c * min(v.thrust_max - t_h, t_h), rel=1e-9)


# ----------------------------------------------------------------------------- parameters
@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_param_table_is_well_formed(v):
    ctrl = make_controller(v)
    table = ctrl.param_table()
    names = [p.name for p in table]
    assert len(names) == len(set(names))
    for p in table:
        assert isinstance(p, ParamSpec)
        assert 0 < len(p.name) <= 16 and p.name == p.name.upper()
        assert p.min <= p.default <= p.max, p.name
        # a PX4 name whose PX4 metadata gives no unit has none here; its doc says it
        assert p.doc and (p.unit or "1/s" in p.doc), p.name
        assert ctrl.get_param(p.name) == p.default


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_set_param_validates(v):
    ctrl = make_controller(v)
    with pytest.raises(ValueError, match="unknown parameter 'NOPE'"):
        ctrl.set_param("NOPE", 1.0)
    with pytest.raises(ValueError, match="unknown parameter"):
        ctrl.get_param("NOPE")
    with pytest.raises(ValueError, match=rf"{tilt(v)} = 90 deg is outside"):
        ctrl.set_param(tilt(v), 90.0)
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="finite"):
            ctrl.set_param(tilt(v), bad)
    with pytest.raises(ValueError, match="number"):
        ctrl.set_param(tilt(v), "steep")
    before = ctrl.get_param(tilt(v))
    assert before != 12.5
    ctrl.set_param(tilt(v), 12.5)
    assert ctrl.get_param(tilt(v)) == 12.5


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_set_param_takes_effect_on_next_update(v):
    ctrl = make_controller(v)
    name = "TPL_PITCH_P" if v is MAMBO else "CAS_RP_P"
    s = hover_state()
    s.qw, s.qy = math.cos(0.05), math.sin(0.05)  # pitched up 0.1 rad
    sp = hold_setpoint(hover_state())
    M1 = wrench(v, one_tick(ctrl, s, sp))[2]
    ctrl.reset()
    ctrl.set_param(name, ctrl.get_param(name) / 2)
    M2 = wrench(v, one_tick(ctrl, s, sp))[2]
    assert M1 < 0 and M2 == pytest.approx(M1 / 2, rel=1e-6)


def test_presets():
    ctrl = MamboController(MAMBO, preset="template")
    assert ctrl.get_param("TPL_XY_P") == 0.24 and ctrl.get_param("TPL_XY_D") == 0.1
    ctrl.apply_preset("default")
    assert ctrl.get_param("TPL_XY_D") == MamboController.PARAMS[1].default
    with pytest.raises(ValueError, match="unknown preset 'fast'; choose one of default"):
        ctrl.apply_preset("fast")


def test_make_controller():
    assert type(make_controller(MAMBO)) is MamboController
    assert type(make_controller(BEBOP2)) is Bebop2Controller
    assert make_controller(MAMBO, dt=0.01).dt == 0.01
    with pytest.raises(ValueError, match="no controller for vehicle 'x'"):
        make_controller(MAMBO.with_overrides(name="x"))
    with pytest.raises(ValueError, match="dt"):
        make_controller(MAMBO, dt=0.0)


# ----------------------------------------------------------------------------- state
def _scripted(ctrl, n: int = 300) -> list[list[float]]:
    """A fixed input sequence with errors that charge every integrator."""
    s = hover_state(z=-0.8)
    sp = hold_setpoint(hover_state(), yaw=0.2)
    sp.x, sp.vy = 0.3, 0.1
    res = []
    for k in range(n):
        s.t = k * ctrl.dt
        s.qw, s.qx, s.qy = math.cos(0.02), math.sin(0.02) * 0.6, math.sin(0.02) * 0.8
        s.p = 0.1 * math.sin(k * 0.05)
        res.append(one_tick(ctrl, s, sp))
    return res


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_deterministic(v):
    assert _scripted(make_controller(v)) == _scripted(make_controller(v))


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_disarmed_outputs_zero_and_resets(v):
    ctrl = make_controller(v)
    _scripted(ctrl)
    sp = hold_setpoint(hover_state())
    sp.armed = False
    assert one_tick(ctrl, hover_state(), sp) == [0.0, 0.0, 0.0, 0.0]
    # after re-arming it behaves exactly like a new controller (integrators, counter cleared)
    assert _scripted(ctrl) == _scripted(make_controller(v))
    _scripted(ctrl)
    ctrl.reset()
    assert _scripted(ctrl) == _scripted(make_controller(v))


# ----------------------------------------------------------------------------- closed loop
plant_mod = pytest.importorskip("cosim.plant.fmu")


def state_from_plant_outputs(y: list[float], t: float, out: VehicleState) -> VehicleState:
    """Ground truth plant outputs -> the controller's state record (in place)."""
    P = plant_mod
    out.t = t
    out.x, out.y, out.z = y[P.Y_X], y[P.Y_Y], y[P.Y_Z]
    out.vx, out.vy, out.vz = y[P.Y_VX], y[P.Y_VY], y[P.Y_VZ]
    out.qw, out.qx, out.qy, out.qz = y[P.Y_QW], y[P.Y_QX], y[P.Y_QY], y[P.Y_QZ]
    out.p, out.q, out.r = y[P.Y_P], y[P.Y_Q], y[P.Y_R]
    return out


class Flight:
    """Plant + controller in the master's order: read y(t_k), control, step to t_k+1."""

    def __init__(self, v: Airframe, preset: str = "default"):
        self.v = v
        self.plant = plant_mod.Plant(PRESETS[v.name])   # the plant's preset of this airframe
        self.ctrl = make_controller(v)
        if preset != "default":
            self.ctrl.apply_preset(preset)
        self.s, self.sp, self.u = VehicleState(), Setpoint(), [0.0] * 4
        self.sp.armed = True
        self.log: list[list[float]] = []

    def fly(self, seconds: float) -> list[list[float]]:
        """Fly `seconds`; returns the plant outputs of every tick of this leg."""
        P = self.plant
        leg = []
        y = P.y
        for _ in range(int(round(seconds / P.step_size))):
            state_from_plant_outputs(y, P.t, self.s)
            self.ctrl.update(self.s, self.sp, self.u)
            y = list(P.step(*self.u))
            leg.append(y)
        self.log += leg
        return leg

    def close(self):
        self.plant.close()


def _yaw(y) -> float:
    P = plant_mod
    qw, qx, qy, qz = y[P.Y_QW], y[P.Y_QX], y[P.Y_QY], y[P.Y_QZ]
    return math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_closed_loop_mission(v):
    """Take off from the floor to 1 m, hold, go 1 m north-east, fly a velocity, turn, land."""
    P = plant_mod
    f = Flight(v)
    sp = f.sp
    try:
        assert f.plant.y[P.Y_ON_GROUND] == 1.0
        # take off by a step of the altitude setpoint (no boost: 6 s to settle) and hold
        sp.x, sp.y, sp.z, sp.yaw = 0.0, 0.0, -1.0, 0.0
        leg = f.fly(6.0)
        assert min(y[P.Y_Z] for y in leg) > -1.15  # overshoot < 15 cm
        hold = f.fly(4.0)
        assert max(abs(y[P.Y_Z] + 1.0) for y in hold) < 0.06
        assert max(abs(y[P.Y_Z] + 1.0) for y in hold[-200:]) < 0.03
        assert max(math.hypot(y[P.Y_X], y[P.Y_Y]) for y in hold) < 0.005
        # go to a position 1 m away (diagonal, so both axes work)
        d = math.sqrt(0.5)
        sp.x, sp.y = d, d
        leg = f.fly(5.0)
        along = [(y[P.Y_X] + y[P.Y_Y]) * d for y in leg]
        assert max(along) < 1.05  # overshoot < 5 cm
        end = leg[-1]
        assert math.hypot(end[P.Y_X] - d, end[P.Y_Y] - d) < 0.03
        assert max(abs(y[P.Y_Z] + 1.0) for y in leg) < 0.05
        # velocity setpoint: 0.5 m/s east, altitude held
        sp.x = sp.y = math.nan
        sp.vx, sp.vy = 0.0, 0.5
        leg = f.fly(4.0)
        assert all(abs(y[P.Y_VY] - 0.5) < 0.03 and abs(y[P.Y_VX]) < 0.03 for y in leg[-200:])
        # heading: turn to +90 deg while hovering in place
        sp.vx = sp.vy = math.nan
        end = leg[-1]
        sp.x, sp.y, sp.yaw = end[P.Y_X], end[P.Y_Y], math.pi / 2
        leg = f.fly(4.0)
        assert abs(_yaw(leg[-1]) - math.pi / 2) < math.radians(2)
        assert max(abs(y[P.Y_Z] + 1.0) for y in leg) < 0.05
        # land: descend at 0.5 m/s until on the ground
        sp.x = sp.y = math.nan
        sp.z, sp.vz = math.nan, 0.5
        leg = f.fly(3.0)
        touch = next(i for i, y in enumerate(leg) if y[P.Y_ON_GROUND] == 1.0)
        assert 0.3 < leg[touch - 1][P.Y_VZ] < 0.6
        sp.armed = False
        leg = f.fly(0.5)
        assert f.u == [0.0] * 4 and leg[-1][P.Y_ON_GROUND] == 1.0
    finally:
        f.close()


@pytest.mark.parametrize("v", VEHICLES, ids=IDS)
def test_closed_loop_yaw_rate(v):
    """A yaw-rate setpoint turns at that rate (Bebop 2: limited to MaxRotationSpeed)."""
    P = plant_mod
    f = Flight(v)
    sp = f.sp
    try:
        sp.x, sp.y, sp.z, sp.yaw = 0.0, 0.0, -1.0, 0.0
        f.fly(3.0)
        sp.yaw = math.nan
        sp.yaw_rate = 0.5
        leg = f.fly(2.0)
        assert all(abs(y[P.Y_R] - 0.5) < 0.03 for y in leg[-100:])
        sp.yaw_rate = math.nan  # hold the heading reached
        leg = f.fly(2.0)
        assert abs(leg[-1][P.Y_R]) < 0.02
        assert abs(_yaw(leg[-1]) - _yaw(leg[-100])) < math.radians(1)
    finally:
        f.close()


def test_closed_loop_mambo_template_preset_flies():
    """The template's own gains also hold position on our plant (less damped, see
    docs/papers/line-follower.md)."""
    P = plant_mod
    f = Flight(MAMBO, preset="template")
    sp = f.sp
    try:
        sp.x, sp.y, sp.z, sp.yaw = 0.0, 0.0, -1.0, 0.0
        f.fly(5.0)
        sp.x = 0.5
        leg = f.fly(8.0)
        assert max(y[P.Y_X] for y in leg) > 0.55  # overshoots (> 10 %) ...
        assert abs(leg[-1][P.Y_X] - 0.5) < 0.03   # ... but settles
    finally:
        f.close()
