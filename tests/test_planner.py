"""Path planner and mission state machine: gains, derivative term, hover band, landing rule,
lost-line hold and search, timeouts, yaw rotation; and a closed loop (renderer + IPS +
planner + a kinematic stand-in for the Mambo's position loop) over every built-in world."""

import math

import numpy as np
import pytest

from cosim.apps.ips import ImageProcessor, IPSResult
from cosim.apps.planner import Action, MissionLogic, MissionState, PlannerParams
from cosim.sensors.down import DownwardCamera
from cosim.world.floor import load_world
from mav.rotations import quat_from_euler

S = MissionState
Z = -1.1           # hover height (NED) of the released preset


def res(track=False, ex=0.0, ey=0.0, marker=False, mx=0.0, my=0.0) -> IPSResult:
    if not track and marker:
        ex, ey = mx, my
    return IPSResult(flag_track=track, flag_marker=marker, e_x=ex if track or marker else 0.0,
                     e_y=ey if track or marker else 0.0, vtp_rc=None, marker_rc=None,
                     marker_e_x=mx if marker else 0.0, marker_e_y=my if marker else 0.0,
                     direction=0.0, n_ring_px=1 if track else 0, marker_evaluated=True)


def following(params=None, t=1.0, ex=-27.0, ey=0.0, xy=(57.0, 95.0)) -> MissionLogic:
    m = MissionLogic(params)
    m.setpoint(0.0, (xy[0], xy[1], -0.05))
    m.on_ips(t, res(True, ex, ey), xy, m.params.z_hover)
    assert m.state is S.FOLLOWING
    return m


def test_takeoff_waits_for_hover_band_and_track():
    m = MissionLogic()
    assert m.setpoint(0.0, (57.0, 95.0, -0.05)) == (57.0, 95.0, Z, Action.TAKEOFF)
    m.on_ips(0.2, res(True, -27, 0), (57.0, 95.0), -0.6)          # too low
    assert m.state is S.TAKEOFF
    m.on_ips(0.4, res(False), (57.01, 95.0), Z)                   # in band, no track
    assert m.state is S.TAKEOFF
    # the take-off point is held even if the estimate drifts
    assert m.setpoint(0.5, (57.1, 95.1, -1.0))[:2] == (57.0, 95.0)
    m.on_ips(0.6, res(True, -27, 0), (57.02, 95.0), -1.15)
    assert m.state is S.FOLLOWING
    assert m.transitions[0][:3] == (0.6, "takeoff", "following")


def test_gain_and_estimate_base():
    m = following(ex=-27.0, ey=10.0)
    x, y, z, a = m.setpoint(1.005, (56.9, 95.05, Z))
    assert a is Action.FOLLOW and z == Z
    assert x == pytest.approx(56.9 - 0.0038 * 27.0)
    assert y == pytest.approx(95.05 + 0.0038 * 10.0)
    # the base is the estimate at every tick, the offset the last frame's error
    x2, y2, _, _ = m.setpoint(1.1, (56.5, 95.0, Z))
    assert (x2, y2) == pytest.approx((56.5 - 0.0038 * 27.0, 95.0 + 0.0038 * 10.0))
    assert type(x2) is float and type(y2) is float


def test_setpoint_returns_plain_floats_for_numpy_input():
    m = following()
    out = m.setpoint(1.2, np.array([56.9, 95.0, Z]))
    assert all(type(v) is float for v in out[:3])


def test_yaw_rotates_errors_into_ned():
    m = MissionLogic()
    m.setpoint(0.0, (57.0, 95.0, -0.05))
    m.on_ips(1.0, res(True, 20.0, 5.0), (57.0, 95.0), Z, yaw=math.pi / 2)  # facing East
    x, y, _, _ = m.setpoint(1.005, (57.0, 95.0, Z))
    # forward (e_x) is East, right (e_y) is South
    assert (x - 57.0, y - 95.0) == pytest.approx((-0.0038 * 5.0, 0.0038 * 20.0))


def test_derivative_term_and_hold():
    m = following(t=1.0, ex=-27.0)
    m.on_ips(1.2, res(True, -20.0, 1.0), (57.0, 95.0), Z)   # de_x = +7 (>= 2), de_y = +1 (< 2)
    x, y, _, _ = m.setpoint(1.205, (57.0, 95.0, Z))
    assert x == pytest.approx(57.0 + 0.0038 * -20.0 + 0.002 * 7.0)
    assert y == pytest.approx(95.0 + 0.0038 * 1.0)          # no derivative on y
    x, _, _, _ = m.setpoint(1.395, (57.0, 95.0, Z))         # still held at 0.195 s
    assert x == pytest.approx(57.0 + 0.0038 * -20.0 + 0.002 * 7.0)
    x, _, _, _ = m.setpoint(1.4001, (57.0, 95.0, Z))        # expired after 0.2 s
    assert x == pytest.approx(57.0 + 0.0038 * -20.0)
    # a change below the threshold adds nothing
    m.on_ips(1.4, res(True, -21.5, 1.0), (57.0, 95.0), Z)
    assert m.setpoint(1.405, (57.0, 95.0, Z))[0] == pytest.approx(57.0 + 0.0038 * -21.5)
    # paper preset: no derivative term
    p = following(PlannerParams.paper(), t=1.0, ex=-27.0)
    p.on_ips(1.2, res(True, -20.0, 0.0), (57.0, 95.0), -1.0)
    assert p.setpoint(1.205, (57.0, 95.0, -1.0))[0] == pytest.approx(57.0 + 0.0038 * -20.0)


def test_hover_band_gates_the_errors():
    m = following(ex=-27.0)
    for z, gated in [(-1.25, True), (-1.19, False), (-1.01, False), (-0.95, True)]:
        x, _, zr, _ = m.setpoint(1.05, (57.0, 95.0, z))
        assert zr == Z
        assert (x == 57.0) is gated
    # paper preset: band around z_H = -1.0
    p = following(PlannerParams.paper(), ex=-27.0)
    assert p.setpoint(1.05, (57.0, 95.0, -1.05))[0] != 57.0
    assert p.setpoint(1.05, (57.0, 95.0, -1.15))[0] == 57.0
    assert p.setpoint(1.05, (57.0, 95.0, -1.05))[2] == -1.0


def test_track_end_marker_and_landing_rule():
    m = following()
    m.on_ips(2.0, res(False, marker=True, mx=-12.0, my=3.0), (56.0, 95.0), Z)
    assert m.state is S.END_MARKER and m.ips_detect_marker is True
    x, y, _, a = m.setpoint(2.005, (56.0, 95.0, Z))
    assert a is Action.FOLLOW
    assert (x, y) == pytest.approx((56.0 - 0.0022 * 12.0, 95.0 + 0.0022 * 3.0))
    # |e(k)| + |e(k-4)| <= 5 px: needs the error small now and 4 frames ago
    errs = [2.0, 2.0, 1.0, 1.0, 2.0]
    for k, e in enumerate(errs):
        assert m.state is S.END_MARKER
        m.on_ips(2.2 + 0.2 * k, res(False, marker=True, mx=e, my=0.0), (56.0, 95.0), Z)
    assert m.state is S.LANDING and m.reason == "marker"
    x, y, z, a = m.setpoint(3.3, (56.01, 95.0, -1.0))
    assert (x, y, z, a) == (56.0, 95.0, 0.0, Action.LAND)


def test_landing_rule_needs_both_frames_small():
    m = following()
    # k:      0   1   2   3   4     5  6  7  8  9
    seq = [12, 12, 12, 12, None, 1, 1, 1, 1, 1]
    for k, e in enumerate(seq):
        r = res(False, marker=True, mx=e) if e is not None else res(False)
        m.on_ips(2.0 + 0.2 * k, r, (56.0, 95.0), Z)
        if k < 9:
            # k = 5..7: frame k-4 had 12 px; k = 8: frame 4 had no marker
            assert m.state is S.END_MARKER, k
    assert m.state is S.LANDING and m.transitions[-1][0] == pytest.approx(3.8)


def test_end_marker_is_latched_and_holds_without_marker():
    m = following()
    m.on_ips(2.0, res(False, marker=True, mx=-12.0), (56.0, 95.0), Z)
    m.on_ips(2.2, res(True, -27.0, 0.0), (55.9, 95.0), Z)   # the track behind: ignored
    assert m.state is S.END_MARKER
    assert m.setpoint(2.25, (55.8, 95.0, Z))[:2] == (55.9, 95.0)   # held where lost
    assert m.setpoint(2.35, (55.7, 95.1, Z))[:2] == (55.9, 95.0)


def test_lost_line_holds_then_recovers():
    m = following(xy=(56.5, 95.0))
    m.on_ips(2.0, res(False), (56.4, 95.02), Z)
    assert m.state is S.LOST and m.ips_detect_marker is True
    # hold where the line was lost, whatever the estimate does (no drift)
    for t, est in [(2.005, (56.38, 95.03)), (2.5, (56.3, 95.1))]:
        assert m.setpoint(t, (*est, Z)) == (56.4, 95.02, Z, Action.HOLD)
    m.on_ips(2.2, res(True, -20.0, -18.0), (56.39, 95.02), Z)
    assert m.state is S.FOLLOWING
    assert m.setpoint(2.205, (56.39, 95.02, Z))[0] == pytest.approx(56.39 - 0.0038 * 20.0)
    # lost again, and then the marker: End-Marker
    m.on_ips(2.4, res(False), (56.3, 95.0), Z)
    m.on_ips(2.6, res(False, marker=True, mx=10.0), (56.3, 95.0), Z)
    assert m.state is S.END_MARKER


def test_lost_timeout_lands():
    m = following(PlannerParams(lost_timeout=1.0))
    m.on_ips(2.0, res(False), (56.4, 95.0), Z)
    for k in range(1, 5):
        m.on_ips(2.0 + 0.2 * k, res(False), (56.4, 95.0), Z)
    assert m.state is S.LOST
    m.on_ips(3.0, res(False), (56.41, 95.0), Z)
    assert m.state is S.LANDING and m.reason == "lost"
    assert m.setpoint(3.005, (56.41, 95.0, Z))[3] is Action.LAND


def test_released_latch_on_first_loss():
    m = following(PlannerParams.released(), xy=(56.5, 95.0))
    m.on_ips(2.0, res(False), (56.4, 95.0), Z)
    assert m.state is S.END_MARKER
    assert m.setpoint(2.005, (56.3, 95.0, Z))[:2] == (56.4, 95.0)
    m.on_ips(2.2, res(True, -27.0, 0.0), (56.4, 95.0), Z)
    assert m.state is S.END_MARKER


def test_mission_timeout_and_done():
    m = MissionLogic(PlannerParams(mission_timeout=10.0))
    m.setpoint(5.0, (57.0, 95.0, -0.05))                 # the clock starts at the first call
    assert m.setpoint(14.995, (57.0, 95.0, -1.1))[3] is Action.TAKEOFF
    x, y, z, a = m.setpoint(15.0, (57.1, 95.0, -1.1))
    assert (x, y, z, a) == (57.1, 95.0, 0.0, Action.LAND) and m.reason == "timeout"
    assert m.setpoint(16.0, (57.1, 95.0, -0.5))[3] is Action.LAND
    assert m.setpoint(17.0, (57.1, 95.0, -0.05))[3] is Action.DONE
    assert m.state is S.DONE
    m.on_ips(17.2, res(True, -27.0), (57.1, 95.0), -0.05)
    assert m.state is S.DONE and m.setpoint(17.3, (57.1, 95.0, -0.05))[3] is Action.DONE


def test_params_presets_and_validation():
    d, r, p = PlannerParams(), PlannerParams.released(), PlannerParams.paper()
    assert d.search_on_loss and not r.search_on_loss and not p.search_on_loss
    assert (d.gain_track, d.gain_marker, d.deriv_gain, d.z_hover) == (0.0038, 0.0022, 0.002, -1.1)
    assert (p.gain_marker, p.deriv_gain, p.z_hover) == (18e-3, 0.0, -1.0)
    assert (d.land_max_error, d.land_delay, d.deriv_threshold, d.deriv_hold) == (5.0, 4, 2.0, 0.2)
    assert PlannerParams.released(search_on_loss=True).search_on_loss
    for bad in ({"z_hover": 1.0}, {"hover_band": 0.0}, {"land_delay": 0},
                {"gain_track": -1.0}, {"lost_timeout": math.nan}):
        with pytest.raises(ValueError):
            PlannerParams(**bad)


def test_ips_detect_marker_policy():
    m = MissionLogic()
    assert m.ips_detect_marker is None
    m = following()
    assert m.ips_detect_marker is None


# ---------------------------------------------------------------------- closed loop
G = 9.81


def fly(world_name: str, t_final: float = 110.0, params: PlannerParams | None = None):
    """Renderer + IPS + MissionLogic over a kinematic stand-in for the Mambo position loop:
    tilt_ref = 0.24 e - 0.1 v (template XY loop, e saturated at 3 m), tilt lag 80 ms,
    acceleration g tan(tilt); altitude a second-order approach to z_ref. Camera tilts with
    the body. Returns (logic, NE track (K, 2), states (K,))."""
    world = load_world(world_name)
    cam = DownwardCamera(world)
    ips = ImageProcessor()
    logic = MissionLogic(params)
    h = 0.005
    n, e, vn, ve, tn, te = 57.0, 95.0, 0.0, 0.0, 0.0, 0.0
    z, vz = -0.046, 0.0
    xy, states = [], []
    for k in range(int(t_final / h)):
        t = k * h
        if k % 40 == 0:
            img = cam.render(np.array([n, e, z]), quat_from_euler(te, -tn, 0.0))
            r = ips.process(img, detect_marker=logic.ips_detect_marker)
            logic.on_ips(t, r, (n, e), z, 0.0)
        xr, yr, zr, _ = logic.setpoint(t, (n, e, z))
        en, ee = max(-3.0, min(3.0, xr - n)), max(-3.0, min(3.0, yr - e))
        tn += h * (max(-0.5, min(0.5, 0.24 * en - 0.1 * vn)) - tn) / 0.08
        te += h * (max(-0.5, min(0.5, 0.24 * ee - 0.1 * ve)) - te) / 0.08
        vn += h * G * math.tan(tn)
        ve += h * G * math.tan(te)
        n += h * vn
        e += h * ve
        vz += h * (3.2 * (zr - z) - 2.5 * vz)
        z += h * vz
        if z > -0.046:
            z, vz = -0.046, 0.0
        xy.append((n, e))
        states.append(logic.state.value)
        if logic.state is MissionState.DONE:
            break
    return world, logic, np.array(xy), np.array(states)


@pytest.mark.parametrize("name", ["seed", "turns", "scurve", "zigzag", "textured"])
def test_closed_loop_completes_every_builtin_world(name):
    world, logic, xy, states = fly(name)
    assert logic.state is MissionState.DONE and logic.reason == "marker", logic.transitions
    assert math.dist(xy[-1], world.marker.center) < 0.05
    d, part = world.distance_to_track(xy[states == "following"])
    assert d.max() < 0.12 and np.sqrt(np.mean(d**2)) < 0.06
    assert set(part) == set(range(len(world.track)))      # every part was followed
