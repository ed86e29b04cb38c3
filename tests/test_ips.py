"""Image processing system: synthetic frames with known answers, presets, and agreement with a
plain full-frame reference implementation of Algorithm 1."""

import math

import cv2
import numpy as np
import pytest

from cosim.apps.ips import ImageProcessor, IPSParams
from cosim.frames import quat_from_euler
from cosim.sensors.down import DownwardCamera
from cosim.world.floor import load_world

FLOOR = (180, 180, 180)
RED = (255, 0, 0)
C_ROW, C_COL = 59.5, 79.5


def blank(rgb=FLOOR) -> np.ndarray:
    img = np.empty((120, 160, 3), np.uint8)
    img[:] = rgb
    return img


def _pt(angle: float, r: float) -> tuple[int, int]:
    """cv2 point (x=col, y=row) in 1/16 px at image angle (atan2(e_x, e_y)) and radius (px)."""
    return (int(round((C_COL + r * math.cos(angle)) * 16)),
            int(round((C_ROW - r * math.sin(angle)) * 16)))


def ray(img, angle, r0=0.0, r1=200.0, width=14, rgb=RED):
    cv2.line(img, _pt(angle, r0), _pt(angle, r1), rgb, width, cv2.LINE_AA, shift=4)
    return img


def disc(img, row, col, radius, rgb=RED):
    cv2.circle(img, (int(round(col * 16)), int(round(row * 16))), int(round(radius * 16)), rgb,
               -1, cv2.LINE_AA, shift=4)
    return img


def vtp_angle(res) -> float:
    return math.degrees(math.atan2(res.e_x, res.e_y))


def ang_diff(a, b) -> float:
    return (a - b + 180.0) % 360.0 - 180.0


@pytest.mark.parametrize("theta_deg", [-90, -135, -30, 0, 45, 90, 170])
def test_straight_line_gives_vtp_at_the_ring_angle(theta_deg):
    th = math.radians(theta_deg)
    img = ray(ray(blank(), th), th + math.pi)          # a full line through the centre
    for direction in (th, th + math.pi):
        ips = ImageProcessor()
        ips.prev_direction = direction + math.radians(20)   # close to one end
        r = ips.process(img)
        assert r.flag_track and not r.flag_marker
        assert abs(ang_diff(vtp_angle(r), math.degrees(direction))) < 3.0
        assert math.hypot(r.e_x, r.e_y) == pytest.approx(27.5, abs=1.0)
        assert r.vtp_rc == pytest.approx((C_ROW - r.e_x, C_COL + r.e_y))
        assert ips.prev_direction == pytest.approx(math.atan2(r.e_x, r.e_y))


def test_error_signs():
    r = ImageProcessor().process(ray(blank(), -math.pi / 2 + 0.3))   # down, slightly right
    assert r.e_x < -20 and r.e_y > 0
    ips = ImageProcessor()
    ips.prev_direction = math.pi / 2
    r = ips.process(ray(blank(), math.pi / 2 + 0.3))                   # up, slightly left
    assert r.e_x > 20 and r.e_y < 0


def test_initial_direction_picks_the_lower_end():
    img = ray(ray(blank(), math.pi / 2), -math.pi / 2)      # vertical line through the centre
    r = ImageProcessor().process(img)
    assert r.flag_track and r.e_x < -26 and abs(r.e_y) < 0.6


def test_arc_restriction_ignores_a_second_branch():
    img = ray(ray(blank(), -math.pi / 2), 0.0)             # branches down and right
    ips = ImageProcessor()
    ips.prev_direction = -math.pi / 2
    r = ips.process(img)
    assert abs(ang_diff(vtp_angle(r), -90.0)) < 3.0        # right branch is 90 deg off: outside
    # the paper's arc (2.3 rad) still excludes it; a 200 deg arc takes both (centroid between)
    ips = ImageProcessor(IPSParams.paper())
    ips.prev_direction = -math.pi / 2
    assert abs(ang_diff(vtp_angle(ips.process(img)), -90.0)) < 3.0
    ips = ImageProcessor(IPSParams(arc_width=math.radians(200)))
    ips.prev_direction = -math.pi / 2
    assert abs(ang_diff(vtp_angle(ips.process(img)), -45.0)) < 5.0


def test_lost_then_search():
    ips = ImageProcessor()
    ips.prev_direction = -math.pi / 2
    r = ips.process(blank())
    assert not r.flag_track and not r.flag_marker and (r.e_x, r.e_y) == (0.0, 0.0)
    assert r.vtp_rc is None and r.marker_evaluated and not ips.prev_seen
    # a branch 150 deg away from the last direction is found by the whole-ring search
    r = ips.process(ray(blank(), math.radians(60)))
    assert r.flag_track and abs(ang_diff(vtp_angle(r), 60.0)) < 3.0


def test_search_takes_the_branch_nearest_the_last_direction():
    # after a miss, a line through the centre shows two opposite branches; the released rule
    # (centroid of all ring pixels) gives a point near the centre, ours the branch ahead
    img = ray(ray(blank(), math.radians(-100)), math.radians(80))
    ips = ImageProcessor()
    ips.prev_direction = math.radians(-60)
    ips.process(blank())
    r = ips.process(img)
    assert abs(ang_diff(vtp_angle(r), -100.0)) < 3.0 and math.hypot(r.e_x, r.e_y) > 26
    rel = ImageProcessor(IPSParams(search_nearest=False))
    rel.prev_direction = math.radians(-60)
    rel.process(blank())
    r = rel.process(img)
    assert r.flag_track and math.hypot(r.e_x, r.e_y) < 3.0
    # and a VTP that near the centre does not redefine the direction
    assert rel.prev_direction == pytest.approx(math.radians(-60))


def test_branch_across_plus_minus_pi_is_one_branch():
    img = ray(blank(), math.pi)                             # pointing left: angles near +-pi
    ips = ImageProcessor()
    ips.prev_direction = 0.0
    ips.process(blank())
    r = ips.process(img)
    assert abs(ang_diff(vtp_angle(r), 180.0)) < 3.0


def test_marker_disc_centroid():
    img = disc(blank(), 70.25, 95.75, 14.5)
    ips = ImageProcessor()
    r = ips.process(img)
    assert not r.flag_track and r.flag_marker and r.marker_evaluated
    assert r.marker_rc == pytest.approx((70.25, 95.75), abs=0.3)
    assert (r.e_x, r.e_y) == pytest.approx((C_ROW - 70.25, 95.75 - C_COL), abs=0.3)
    assert (r.marker_e_x, r.marker_e_y) == (r.e_x, r.e_y)
    # ellipse kernel agrees
    r2 = ImageProcessor(IPSParams(marker_kernel="ellipse")).process(img)
    assert r2.marker_rc == pytest.approx((70.25, 95.75), abs=0.3)


def test_line_is_not_a_marker_and_small_discs_are_eroded():
    ips = ImageProcessor()
    r = ips.process(ray(blank(), math.radians(30), r0=40), detect_marker=True)
    assert not r.flag_marker
    r = ips.process(disc(blank(), 60, 80, 9.0), detect_marker=True)
    assert not r.flag_marker


def test_marker_branch_policy():
    img = disc(ray(blank(), -math.pi / 2), 40.0, 110.0, 14.5)
    r = ImageProcessor().process(img)                      # track found: marker not evaluated
    assert r.flag_track and not r.marker_evaluated and not r.flag_marker
    r = ImageProcessor().process(img, detect_marker=True)
    assert r.flag_track and r.flag_marker
    assert (r.e_x, r.e_y) != (r.marker_e_x, r.marker_e_y)  # e = the VTP's when on track
    r = ImageProcessor().process(disc(blank(), 40.0, 110.0, 14.5), detect_marker=False)
    assert not r.marker_evaluated and not r.flag_marker


def test_distractor_colours_are_ignored():
    img = blank()
    for row, col, rgb in [(20, 40, (220, 220, 60)), (90, 120, (40, 90, 200)),
                          (45, 100, (220, 220, 60)), (80, 60, (40, 90, 200))]:
        cv2.rectangle(img, (col - 14, row - 14), (col + 14, row + 14), rgb, -1)
    for params in (IPSParams.released(), IPSParams.paper()):
        ips = ImageProcessor(params)
        r = ips.process(img, detect_marker=True)
        assert not r.flag_track and not r.flag_marker
        assert not ips.binarise(img).any()


def test_saturated_yellow_passes_the_released_threshold_only():
    # F(255, 255, 0) = 127.5: above the released K_T = 100, below the paper's 150
    img = blank()
    cv2.rectangle(img, (60, 70), (100, 110), (255, 255, 0), -1)
    assert ImageProcessor(IPSParams.released()).process(img, detect_marker=True).flag_track
    assert not ImageProcessor(IPSParams.paper()).process(img, detect_marker=True).flag_track


def test_threshold_is_exact():
    ips = ImageProcessor()
    img = blank((0, 0, 0))
    img[:, :80] = (200, 200, 0)          # F = 100.0  -> set
    img[:, 80:] = (200, 201, 0)          # F = 99.5   -> not set
    b = ips.binarise(img) > 0
    assert b[:, :80].all() and not b[:, 80:].any()


def test_thin_line_is_eroded_away():
    r = ImageProcessor().process(ray(blank(), -math.pi / 2, width=4))   # ~5 px after AA
    assert not r.flag_track


def test_empty_frame_and_bad_input():
    r = ImageProcessor().process(blank())
    assert not r.flag_track and not r.flag_marker and r.n_ring_px == 0
    with pytest.raises(ValueError, match="120x160x3"):
        ImageProcessor().process(np.zeros((120, 160), np.uint8))


def test_presets_and_validation():
    rel, pap = IPSParams.released(), IPSParams.paper()
    assert rel == IPSParams()
    assert (rel.k_t, rel.square_kernel, rel.disk_radius, rel.r_min, rel.r_max) == \
        (100.0, 8, 11, 27.0, 28.0)
    assert rel.arc_width == pytest.approx(2 * math.pi / 2.9)
    assert (pap.k_t, pap.r_min, pap.r_max, pap.arc_width) == (150.0, 26.0, 28.0, 2.3)
    assert (pap.square_kernel, pap.disk_radius, pap.gg, pap.gb) == (8, 11, 2.0, 2.0)
    assert IPSParams.paper(k_t=120.0).k_t == 120.0
    for bad in ({"gg": 0.5}, {"r_min": 30.0}, {"r_max": 70.0}, {"arc_width": 0.0},
                {"marker_kernel": "star"}, {"disk_radius": 0}):
        with pytest.raises(ValueError):
            IPSParams(**bad)


def test_reset_restores_the_initial_direction():
    ips = ImageProcessor()
    ips.process(ray(blank(), -math.pi / 4))
    ips.process(blank())
    ips.reset()
    assert ips.prev_seen and ips.prev_direction == pytest.approx(-0.75 * math.pi)


# ---------------------------------------------------------------------- reference agreement
def reference_vtp(img, p: IPSParams, prev_dir: float):
    """Algorithm 1's track branch written plainly on the full frame (no crop, float F)."""
    f = img[..., 0].astype(float) - img[..., 1] / p.gg - img[..., 2] / p.gb
    b = (f >= p.k_t).astype(np.uint8)
    e = cv2.erode(b, np.ones((p.square_kernel, p.square_kernel), np.uint8)) > 0
    rows, cols = np.mgrid[0:120, 0:160]
    ex, ey = -(rows - C_ROW), cols - C_COL
    d = np.hypot(ex, ey)
    ang = np.arctan2(ex, ey)
    dang = np.abs((ang - prev_dir + np.pi) % (2 * np.pi) - np.pi)
    m = e & (d >= p.r_min) & (d <= p.r_max) & (dang <= p.arc_width / 2 + 1e-9)
    if not m.any():
        return None
    shift = 0.5 * (p.square_kernel - 1) - p.square_kernel // 2
    return rows[m].mean() + shift, cols[m].mean() + shift


@pytest.mark.parametrize("params", [IPSParams.released(), IPSParams.paper()])
def test_agrees_with_the_plain_full_frame_reference(params):
    world = load_world("seed")
    cam = DownwardCamera(world)
    rng = np.random.default_rng(3)
    cl = np.concatenate(world.centreline())
    n_found = 0
    for _ in range(40):
        i = rng.integers(len(cl) - 1)
        t = rng.uniform()
        ne = cl[i] + t * (cl[i + 1] - cl[i]) + rng.normal(0, 0.05, 2)
        q = quat_from_euler(*rng.normal(0, 0.08, 2), rng.uniform(-np.pi, np.pi))
        img = cam.render(np.array([ne[0], ne[1], -rng.uniform(0.9, 1.3)]), q)
        prev = rng.uniform(-np.pi, np.pi)
        ips = ImageProcessor(params)
        ips.prev_direction = prev
        r = ips.process(img)
        ref = reference_vtp(img, params, prev)
        if ref is None:
            assert not r.flag_track
        else:
            n_found += 1
            assert r.vtp_rc == pytest.approx(ref, abs=1e-9)
    assert n_found >= 15
