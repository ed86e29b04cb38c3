"""Downward camera: geometry against the exact projection, orientation conventions, line width
and continuity, no-floor behaviour, determinism and noise, config validation, saving."""

import math

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from cosim.errors import ScenarioError
from cosim.sensors.camera import Renderer, save_png, save_video
from cosim.sensors.down import CameraConfig, DownwardCamera, project_floor_point
from cosim.world.floor import World
from mav.rotations import quat_from_euler

ARENA = {"n_min": 3.0, "n_max": 7.0, "e_min": 3.0, "e_max": 7.0}
P0 = np.array([5.0, 5.0, -1.1])        # body CoG 1.1 m above the floor: camera at 1.0 m
Q0 = quat_from_euler(0.0, 0.0, 0.0)


def dots_world(points, diameter=0.03) -> World:
    return World.from_dict({
        "arena": ARENA, "floor_rgb": [0, 0, 0],
        "distractor": [{"shape": "disc", "center": list(p), "size": diameter,
                        "rgb": [255, 255, 255]} for p in points]})


def blob_centroids(img: np.ndarray) -> list[tuple[float, float]]:
    """Intensity-weighted centroids (row, col) of the bright blobs."""
    g = img[..., 0].astype(float)
    n, lab = cv2.connectedComponents((g > 8).astype(np.uint8))
    out = []
    rows, cols = np.mgrid[0:g.shape[0], 0:g.shape[1]]
    for k in range(1, n):
        w = g * (lab == k)
        out.append(((w * rows).sum() / w.sum(), (w * cols).sum() / w.sum()))
    return out


def test_config_defaults():
    c = CameraConfig()
    assert (c.width, c.height, c.supersample, c.texture_px_per_m) == (160, 120, 1, 150.0)
    assert c.focal_px == pytest.approx(60.0 / math.tan(math.radians(22.5)))
    assert c.focal_px == pytest.approx(144.85, abs=0.01)
    assert c.center_rc == (59.5, 79.5)
    assert c.mount_B == (0.0, 0.0, 0.1)


POSES = [
    (0.0, 0.0, 0.0),
    (0.0, 0.0, math.radians(90)),
    (math.radians(8), 0.0, 0.0),
    (0.0, math.radians(-10), 0.0),
    (math.radians(-6), math.radians(7), math.radians(-140)),
    (math.radians(12), math.radians(-9), math.radians(33)),
]


@pytest.mark.parametrize("rpy", POSES)
def test_rendered_points_land_on_the_projection(rpy):
    pts = [(5.0, 5.0), (5.25, 5.1), (4.8, 4.7), (5.1, 4.65), (4.7, 5.35), (5.35, 5.4)]
    world = dots_world(pts)
    cam = DownwardCamera(world)
    q = quat_from_euler(*rpy)
    img = cam.render(P0, q)
    found = blob_centroids(img)
    expected = [project_floor_point(p, P0, q) for p in pts]
    inside = [e for e in expected if 5 <= e[0] <= 114 and 5 <= e[1] <= 154]
    assert len(inside) >= 3
    for e in inside:
        d = min(math.dist(e, f) for f in found)
        assert d < 0.5, (e, found)
    # and nothing appears where no point projects
    for f in found:
        if 5 <= f[0] <= 114 and 5 <= f[1] <= 154:
            assert min(math.dist(e, f) for e in expected) < 0.5


def test_image_orientation():
    # yaw 0: a point North of the drone appears up, a point East appears right
    cam = DownwardCamera(dots_world([(5.2, 5.0)]))
    (r, c), = blob_centroids(cam.render(P0, Q0))
    assert r < 59.5 - 20 and c == pytest.approx(79.5, abs=0.3)
    cam = DownwardCamera(dots_world([(5.0, 5.2)]))
    (r, c), = blob_centroids(cam.render(P0, Q0))
    assert c > 79.5 + 20 and r == pytest.approx(59.5, abs=0.3)
    # yaw 90 deg (facing East): East appears up
    (r, c), = blob_centroids(cam.render(P0, quat_from_euler(0, 0, math.pi / 2)))
    assert r < 59.5 - 20 and c == pytest.approx(79.5, abs=0.3)


def test_tilt_signs_independent_of_the_projection_code():
    # camera 1.0 m above the floor, 0.1 m below the CoG. Roll right (+): the camera looks to
    # the left (West), so the image centre sees a point West of the camera.
    roll = math.radians(10)
    q = quat_from_euler(roll, 0, 0)
    # camera position: CoG + R_WB (0, 0, 0.1) -> E shifts by -0.1 sin(roll)
    cam_e, cam_h = 5.0 - 0.1 * math.sin(roll), 1.1 - 0.1 * math.cos(roll)
    target = (5.0, cam_e - cam_h * math.tan(roll))
    (r, c), = blob_centroids(DownwardCamera(dots_world([target])).render(P0, q))
    assert (r, c) == pytest.approx((59.5, 79.5), abs=0.3)
    # pitch nose-down (-): the belly, and the camera, face backward (South)
    pitch = math.radians(-10)
    q = quat_from_euler(0, pitch, 0)
    cam_n, cam_h = 5.0 + 0.1 * math.sin(pitch), 1.1 - 0.1 * math.cos(pitch)
    target = (cam_n + cam_h * math.tan(pitch), 5.0)
    assert target[0] < 5.0
    (r, c), = blob_centroids(DownwardCamera(dots_world([target])).render(P0, q))
    assert (r, c) == pytest.approx((59.5, 79.5), abs=0.3)


@pytest.mark.parametrize("heading_deg", [0.0, 45.0, 90.0, 120.0])
def test_line_width_and_continuity(heading_deg):
    world = World.from_dict({"arena": ARENA, "floor_rgb": [180, 180, 180],
                             "track": [{"center": [5.0, 5.0], "length": 3.0, "width": 0.10,
                                        "heading_deg": heading_deg}]})
    img = DownwardCamera(world).render(P0, Q0)
    cover = (180.0 - img[..., 1].astype(float)) / 180.0
    expected = 0.10 * CameraConfig().focal_px / 1.0         # camera 1.0 m above the floor
    assert expected == pytest.approx(14.5, abs=0.1)
    # profiles across the line at every pixel along it (bilinear samples every 0.25 px)
    h = math.radians(heading_deg)
    d_img = np.array([-math.cos(h), math.sin(h)])          # (row, col): North up, East right
    n_img = np.array([d_img[1], -d_img[0]])
    s_along = np.arange(-45.0, 45.5, 1.0)
    t_across = np.arange(-16.0, 16.01, 0.25)
    S, T = np.meshgrid(s_along, t_across, indexing="ij")
    rows = 59.5 + S * d_img[0] + T * n_img[0]
    cols = 79.5 + S * d_img[1] + T * n_img[1]
    prof = map_coordinates(cover, [rows, cols], order=1)
    widths = prof.sum(axis=1) * 0.25
    assert widths.min() > expected - 0.6 and widths.max() < expected + 0.6   # no gaps
    assert np.median(widths) == pytest.approx(expected, abs=0.3)
    # the core of the line is fully red everywhere along it
    assert prof[:, np.abs(t_across) <= 5.0].min() > 0.95


def test_no_floor_in_view():
    world = dots_world([(5.0, 5.0)])
    cam = DownwardCamera(world)
    # on the ground: the camera (0.1 m below the CoG) is below the floor
    assert not cam.render(np.array([5.0, 5.0, -0.046]), Q0).any()
    # nose up 80 deg: the camera looks North almost horizontally; the top of the image
    # (body x, now nearly straight up) sees the sky (black), the bottom the far floor
    grey = World.from_dict({"arena": ARENA, "floor_rgb": [100, 100, 100]})
    img = DownwardCamera(grey).render(P0, quat_from_euler(0, math.radians(80), 0))
    assert (img[0] == 0).all() and (img[-1] == 100).all()
    # upside down: nothing
    img = DownwardCamera(grey).render(P0, quat_from_euler(math.pi, 0, 0))
    assert not img.any()
    # beyond the texture the floor continues in the floor colour
    img = DownwardCamera(grey).render(np.array([500.0, 500.0, -1.1]), Q0)
    assert (img == 100).all()


def test_determinism_and_noise():
    world = World.from_dict({"arena": ARENA, "track": [
        {"center": [5.0, 5.0], "length": 2.0, "width": 0.1, "heading_deg": 30.0}]})
    q = quat_from_euler(0.05, -0.03, 0.2)
    clean = DownwardCamera(world, seed=1).render(P0, q)
    assert np.array_equal(clean, DownwardCamera(world, seed=2).render(P0, q))
    cfg = CameraConfig(noise_std=6.0, lighting_noise=0.1)
    a = [DownwardCamera(world, cfg, seed=3).render(P0, q) for _ in range(2)]
    cam = DownwardCamera(world, cfg, seed=3)
    seq1 = [cam.render(P0, q) for _ in range(3)]
    cam = DownwardCamera(world, cfg, seed=3)
    seq2 = [cam.render(P0, q) for _ in range(3)]
    assert np.array_equal(a[0], a[1])
    assert all(np.array_equal(x, y) for x, y in zip(seq1, seq2, strict=True))
    assert not np.array_equal(seq1[0], seq1[1])          # fresh noise per frame
    other = DownwardCamera(world, cfg, seed=4).render(P0, q)
    assert not np.array_equal(other, seq1[0])
    # pixel noise statistics (no gain jitter), on unsaturated pixels
    cam = DownwardCamera(world, CameraConfig(noise_std=6.0), seed=5)
    diff = cam.render(P0, q).astype(float) - clean
    m = (clean > 30) & (clean < 225)
    assert diff[m].std() == pytest.approx(6.0, rel=0.1)
    assert abs(diff[m].mean()) < 0.3
    # gain jitter scales the whole frame
    cam = DownwardCamera(world, CameraConfig(lighting_noise=0.2), seed=6)
    ratios = []
    for _ in range(20):
        g = cam.render(P0, q)[..., 1].astype(float)
        ratios.append(g[clean[..., 1] == 180].mean() / 180.0)
    assert 0.05 < np.std(ratios) < 0.4


def test_renderer_protocol_and_project_method():
    cam = DownwardCamera(dots_world([(5.0, 5.0)]))
    assert isinstance(cam, Renderer)
    assert cam.project((5.0, 5.0), P0, Q0) == pytest.approx((59.5, 79.5))
    # a point behind the camera does not project
    assert all(math.isnan(v) for v in project_floor_point((5.0, 5.0), P0,
                                                          quat_from_euler(math.pi, 0, 0)))


@pytest.mark.parametrize("table, field", [
    ({"width": 0}, "camera.width"),
    ({"height": 12.5}, "camera.height"),
    ({"vfov_deg": 0}, "camera.vfov_deg"),
    ({"vfov_deg": True}, "camera.vfov_deg"),
    ({"noise_std": -1}, "camera.noise_std"),
    ({"lighting_noise": 0.9}, "camera.lighting_noise"),
    ({"supersample": 0}, "camera.supersample"),
    ({"mount_B": [0, 0]}, "camera.mount_B"),
    ({"fov": 45}, "camera.fov"),
    ({"interpolation": "cubic"}, "camera.interpolation"),
])
def test_config_validation(table, field):
    with pytest.raises(ScenarioError) as ei:
        CameraConfig.from_dict(table)
    assert ei.value.field == field


def test_config_from_dict():
    c = CameraConfig.from_dict({"noise_std": 3, "lighting_noise": 0.05, "supersample": 3,
                                "mount_B": [0.01, 0, 0.1], "vfov_deg": 50})
    assert (c.noise_std, c.lighting_noise, c.supersample) == (3.0, 0.05, 3)
    assert c.mount_B == (0.01, 0.0, 0.1) and c.vfov_deg == 50.0


def test_nearest_interpolation_keeps_the_geometry():
    pts = [(5.0, 5.0), (5.25, 5.1), (4.8, 4.7)]
    q = quat_from_euler(0.1, -0.05, 0.7)
    cam = DownwardCamera(dots_world(pts), CameraConfig(interpolation="nearest"))
    found = blob_centroids(cam.render(P0, q))
    for p in pts:
        e = project_floor_point(p, P0, q)
        assert min(math.dist(e, f) for f in found) < 0.5


def test_custom_resolution_keeps_the_centre():
    cfg = CameraConfig(width=64, height=48, supersample=3)
    cam = DownwardCamera(dots_world([(5.0, 5.0)]), cfg)
    img = cam.render(P0, Q0)
    assert img.shape == (48, 64, 3)
    (r, c), = blob_centroids(img)
    assert (r, c) == pytest.approx((23.5, 31.5), abs=0.3)


def test_save_png_and_video(tmp_path):
    cam = DownwardCamera(dots_world([(5.0, 5.0)]))
    frames = [cam.render(P0 + [0.01 * k, 0, 0], Q0) for k in range(5)]
    p = save_png(frames[0], tmp_path / "f.png")
    back = cv2.imread(str(p))[..., ::-1]
    assert np.array_equal(back, frames[0])
    out = save_video(frames, tmp_path / "v.mp4", fps=5.0)
    assert out.exists() and out.stat().st_size > 0
    with pytest.raises(ValueError):
        save_video([], tmp_path / "e.mp4", fps=5.0)


@pytest.mark.parametrize(("interpolation", "supersample"),
                         [("linear", 1), ("linear", 2), ("nearest", 1), ("nearest", 3)])
def test_rgba_sampling_matches_a_plain_rgb_warp(interpolation, supersample):
    """The renderer samples an RGBA copy of the texture (faster in OpenCV); the image must be
    byte for byte the plain 3-channel warp + INTER_AREA resize, horizon cases included."""
    world = World.from_dict({"arena": ARENA, "floor_rgb": [30, 60, 90],
                             "track": [{"width": 0.02,
                                        "points": [[3.5, 3.5], [6.5, 5.0], [4.0, 6.5]]}]})
    cam = DownwardCamera(world, CameraConfig(interpolation=interpolation,
                                             supersample=supersample,
                                             texture_px_per_m=150.0 * supersample))
    tex = np.ascontiguousarray(cam.texture)
    rng = np.random.default_rng(3)
    flags = (cv2.INTER_NEAREST if interpolation == "nearest" else cv2.INTER_LINEAR) | \
        cv2.WARP_INVERSE_MAP
    for i in range(40):
        p = [rng.uniform(3.0, 7.0), rng.uniform(3.0, 7.0), -rng.uniform(0.3, 3.0)]
        tilt = 1.2 if i % 8 == 0 else 0.3          # some with the horizon in view
        q = quat_from_euler(*rng.normal(0.0, tilt, 2), rng.uniform(-math.pi, math.pi))
        M, dz, c_z = cam.homography(p, q)
        hi = cv2.warpPerspective(tex, M, cam._size_hi, flags=flags,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=(30, 60, 90))
        w_hi, h_hi = cam._size_hi
        u, v = np.arange(w_hi)[None, :], np.arange(h_hi)[:, None]
        hi[dz[0] * u + dz[1] * v + dz[2] <= 1e-9] = 0
        if (dz @ cam._corners_hi).max() <= 0.0:
            hi[...] = 0
        ref = cv2.resize(hi, cam._size, interpolation=cv2.INTER_AREA) if supersample > 1 else hi
        assert np.array_equal(cam.render(p, q), ref), (i, p, q)
