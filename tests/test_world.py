"""World model: the seed track against reference/minidrone.md §5, built-in worlds, distances,
validation with field paths, and the rasterised floor."""

import math

import numpy as np
import pytest

from cosim.errors import ScenarioError
from cosim.world.floor import (
    Arena,
    PolylinePart,
    RectPart,
    World,
    builtin_worlds,
    load_world,
)

START = np.array([57.0, 95.0])
BUILTINS = ["seed", "turns", "scurve", "zigzag", "textured"]


def _turns_deg(line: np.ndarray) -> np.ndarray:
    d = np.diff(line, axis=0)
    h = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    return (np.diff(h) + 180.0) % 360.0 - 180.0


def _all_turns(w: World) -> np.ndarray:
    """Heading changes between consecutive segments along the whole track (across parts)."""
    h = np.concatenate([np.degrees(np.arctan2(np.diff(c, axis=0)[:, 1], np.diff(c, axis=0)[:, 0]))
                        for c in w.centreline()])
    return (np.diff(h) + 180.0) % 360.0 - 180.0


def test_seed_matches_reference_table():
    w = load_world("seed")
    assert w.name == "seed" and len(w.track) == 5
    assert all(isinstance(p, RectPart) and p.width == 0.10 and p.rgb == (255, 0, 0)
               for p in w.track)
    # reference/minidrone.md §5: ends relative to the start point, in track order
    ends = [((0.025, 0.000), (-1.425, 0.000)), ((-1.393, 0.007), (-2.807, -1.407)),
            ((-2.780, -1.300), (-2.780, -2.250)), ((-2.739, -2.183), (-3.561, -2.657)),
            ((-3.512, -2.641), (-3.988, -1.819))]
    for c, (a, b) in zip(w.centreline(), ends, strict=True):
        np.testing.assert_allclose(c - START, [a, b], atol=1.5e-3)
    assert w.marker.center == (52.93, 93.325) and w.marker.radius == 0.10
    assert w.marker.rgb == (255, 0, 0)
    assert w.track_length() == pytest.approx(6.3, abs=0.01)
    assert w.floor_rgb == (180, 180, 180) and w.floor_texture == "plain"
    assert w.start == (57.0, 95.0, 0.0)
    np.testing.assert_allclose(_all_turns(w), [45, 45, -60, -90], atol=0.6)


def test_builtin_list():
    assert set(BUILTINS) <= set(builtin_worlds())


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_worlds_are_flyable(name):
    w = load_world(name)
    a = w.arena
    assert a.contains(*START) and a.n_max - a.n_min >= 4.0 and a.e_max - a.e_min >= 4.0
    lines = w.centreline()
    first = lines[0]
    # starts under the drone and runs South (the IPS's initial lower-left arc sees it)
    assert np.linalg.norm(first[0] - START) < 0.05
    d0 = first[1] - first[0]
    assert abs(math.degrees(math.atan2(d0[1], d0[0]))) > 135.0
    for c in lines:
        assert all(a.contains(*q) for q in c)
    assert all(p.width == pytest.approx(0.10) for p in w.track)
    # turns no sharper than 120 deg; marker just past the end
    assert np.abs(_all_turns(w)).max() <= 120.01  # points are given to 1 mm
    assert w.marker is not None and w.marker.radius == pytest.approx(0.10)
    assert 0.10 < np.linalg.norm(np.array(w.marker.center) - lines[-1][-1]) < 0.25
    d, _ = w.distance_to_track(np.array([w.marker.center]))
    assert d[0] > 0.1


def test_named_worlds_have_their_difficulty():
    turns = np.abs(_all_turns(load_world("turns")))
    assert sorted(np.round(turns)) == [90, 120]
    sc = load_world("scurve")
    assert isinstance(sc.track[0], PolylinePart) and len(sc.track[0].points) > 50
    assert np.abs(_turns_deg(sc.centreline()[0])).max() <= 8.0  # 5 deg steps, 1 mm rounding
    zz = load_world("zigzag")
    assert zz.track_length() > 10.0
    c = zz.centreline()[0]
    margin = min(c[:, 0].min() - zz.arena.n_min, zz.arena.n_max - 57.0,
                 c[:, 1].min() - zz.arena.e_min, zz.arena.e_max - c[:, 1].max())
    assert margin <= 0.55
    tx = load_world("textured")
    assert tx.floor_texture == "competition"
    colours = {d.rgb for d in tx.distractors}
    assert (220, 220, 60) in colours and (40, 90, 200) in colours
    assert all(d.shape == "square" and d.size == pytest.approx(0.2) for d in tx.distractors)
    d, _ = tx.distance_to_track(np.array([x.center for x in tx.distractors]))
    assert d.min() >= 0.29


def test_distance_to_track():
    w = load_world("seed")
    pts = np.array([[56.3, 95.0],            # on S1
                    [56.3, 95.3],            # 0.3 m East of S1
                    [57.325, 95.0],          # 0.3 m beyond S1's start
                    [54.22, 93.225],         # centre of S2
                    [52.93, 93.325]])        # the marker
    d, part = w.distance_to_track(pts)
    assert d.shape == (5,) and part.shape == (5,)
    np.testing.assert_allclose(d[:4], [0.0, 0.3, 0.3, 0.0], atol=1e-9)
    assert list(part[:4]) == [0, 0, 0, 2]
    assert d[4] == pytest.approx(math.hypot(52.93 - 53.0125, 93.325 - 93.1814), abs=2e-3)
    # vectorised over many points, chunked
    many = np.tile(pts, (3000, 1))
    d2, p2 = w.distance_to_track(many)
    np.testing.assert_array_equal(d2[:5], d)
    np.testing.assert_array_equal(p2[-5:], part)


def test_no_track():
    w = World(arena=Arena(0, 1, 0, 1))
    d, part = w.distance_to_track(np.zeros((3, 2)))
    assert np.isinf(d).all() and (part == -1).all()
    assert w.centreline() == []


def _base() -> dict:
    return {"arena": {"n_min": 50.0, "n_max": 60.0, "e_min": 90.0, "e_max": 100.0},
            "track": [{"center": [55.0, 95.0], "length": 1.0, "width": 0.1, "heading_deg": 0.0},
                      {"points": [[54.0, 95.0], [54.0, 96.0]], "width": 0.1},
                      {"center": [53.0, 95.0], "length": 1.0, "width": 0.1, "heading_deg": 0.0}],
            "marker": {"center": [52.0, 95.0], "radius": 0.1},
            "distractor": [{"shape": "square", "center": [56, 96], "size": 0.2,
                            "rgb": [220, 220, 60]}]}


def _set(path, value):
    def f(d):
        keys = path.split(".")
        for k in keys[:-1]:
            d = d[int(k)] if k.isdigit() else d[k]
        last = keys[-1]
        if value is KeyError:
            del d[last]
        else:
            d[last] = value
    return f


@pytest.mark.parametrize("edit, field", [
    (_set("track.2.width", -0.1), "world.track[2].width"),
    (_set("track.0.heading_deg", "north"), "world.track[0].heading_deg"),
    (_set("track.0.colour", [1, 2, 3]), "world.track[0].colour"),
    (_set("track.1.points", [[54.0, 95.0]]), "world.track[1].points"),
    (_set("track.1.points", [[54.0, 95.0], [70.0, 95.0]]), "world.track[1].points[1]"),
    (_set("track.0.center", [55.0]), "world.track[0].center"),
    (_set("track.0.length", 30.0), "world.track[0].length"),
    (_set("track.0.rgb", [255, 0, 256]), "world.track[0].rgb"),
    (_set("track.0.rgb", [255, 0, True]), "world.track[0].rgb"),
    (_set("marker.radius", 0.0), "world.marker.radius"),
    (_set("marker.center", [0.0, 0.0]), "world.marker.center"),
    (_set("distractor.0.shape", "triangle"), "world.distractor[0].shape"),
    (_set("distractor.0.rgb", KeyError), "world.distractor[0].rgb"),
    (_set("arena.n_max", 50.1), "world.arena.n_max"),
    (_set("arena", KeyError), "world.arena"),
    (_set("floor_texture", "wood"), "world.floor_texture"),
    (_set("tile_rgb", [1, 2, 3]), "world.tile_rgb"),
    (_set("floor_rgb", "grey"), "world.floor_rgb"),
    (_set("lights", 3), "world.lights"),
    (_set("start", {"n": 0.0, "e": 0.0}), "world.start"),
    (_set("track", {"center": [55, 95]}), "world.track"),
])
def test_validation_names_the_field(edit, field):
    d = _base()
    World.from_dict(d)  # the base is valid
    edit(d)
    with pytest.raises(ScenarioError) as ei:
        World.from_dict(d)
    assert ei.value.field == field
    assert ei.value.allowed


def test_load_world_errors(tmp_path):
    with pytest.raises(ScenarioError, match="seed"):
        load_world("no_such_world")
    p = tmp_path / "w.toml"
    p.write_text("[world]\narena = { n_min = 0.0, n_max = 2.0, e_min = 0.0, e_max = 2.0 }\n")
    assert load_world(p).arena == Arena(0.0, 2.0, 0.0, 2.0)
    assert load_world({"arena": {"n_min": 0, "n_max": 1, "e_min": 0, "e_max": 1}}).track == ()


def test_floor_image_transform_and_cache():
    w = load_world("seed")
    img, T = w.floor_image(200.0)
    assert img.dtype == np.uint8 and img.ndim == 3 and not img.flags.writeable
    assert w.floor_image(200.0)[0] is img

    def px(n, e):
        c, r, _ = T @ [n, e, 1.0]
        return img[int(round(r)), int(round(c))]

    assert tuple(px(*w.marker.center)) == (255, 0, 0)
    assert tuple(px(56.3, 95.0)) == (255, 0, 0)
    assert tuple(px(56.3, 95.2)) == (180, 180, 180)
    # the texture covers the arena plus the margin
    a = w.arena
    for n, e in [(a.n_min - 1.4, a.e_min - 1.4), (a.n_max + 1.4, a.e_max + 1.4)]:
        c, r, _ = T @ [n, e, 1.0]
        assert 0 <= r < img.shape[0] and 0 <= c < img.shape[1]


def test_floor_image_antialiased_width_and_round_joins():
    s = 200.0
    w = World.from_dict({"arena": {"n_min": 0, "n_max": 4, "e_min": 0, "e_max": 4},
                         "track": [{"points": [[3.0, 1.0], [2.0, 1.0], [2.0, 3.0], [1.0, 2.0]],
                                    "width": 0.1}]})
    img, T = w.floor_image(s)
    red = (180.0 - img[..., 1].astype(float)) / 180.0    # coverage of the red line
    # across the N-S leg at N = 2.5: coverage integrates to width * px_per_m
    _, r, _ = T @ [2.5, 1.0, 1.0]
    assert red[int(round(r))].sum() == pytest.approx(0.1 * s, abs=0.05)
    assert 0.0 < red[int(round(r))].max() <= 1.0
    # anti-aliasing: a leg whose edges fall mid-pixel (E = 1.0025 +- 0.05 at 200 px/m) gets
    # partial coverage on both edges, and still integrates to width * px_per_m
    w2 = World.from_dict({"arena": {"n_min": 0, "n_max": 4, "e_min": 0, "e_max": 4},
                          "track": [{"points": [[3.0, 1.0025], [1.0, 1.0025]], "width": 0.1}]})
    img2, T2 = w2.floor_image(s)
    _, r2, _ = T2 @ [2.0, 1.0025, 1.0]
    row = (180.0 - img2[int(round(r2)), :, 1].astype(float)) / 180.0
    assert ((row > 0.05) & (row < 0.95)).sum() >= 2
    assert row.sum() == pytest.approx(0.1 * s, abs=0.05)
    # round joins: everything within width/2 of a vertex is red, incl. the outer corners
    for n, e in [(2.0, 1.0), (2.0, 3.0)]:
        for ang in np.linspace(0, 2 * np.pi, 16, endpoint=False):
            q = [n + 0.04 * math.cos(ang), e + 0.04 * math.sin(ang), 1.0]
            c, r, _ = T @ q
            assert red[int(round(r)), int(round(c))] > 0.99


def test_competition_floor_texture():
    w = World.from_dict({"arena": {"n_min": 0, "n_max": 2, "e_min": 0, "e_max": 2},
                         "floor_texture": "competition"})
    img, _ = w.floor_image(200.0)
    base, tile = np.array(w.floor_rgb, float), np.array(w.tile_rgb, float)
    frac = ((base - img.astype(float)) / (base - tile)).mean()
    assert frac == pytest.approx(0.15 * 0.05 / 0.25**2, rel=0.02)
    # tiles are well below the seed's red filter F = R - G/2 - B/2 >= 100
    f = img[..., 0].astype(float) - img[..., 1] / 2 - img[..., 2] / 2
    assert f.max() < 40
