"""Issue 31, defect 3: a taught path that does not fit the scenario's camera, or whose files
were changed after teaching, is refused before anything flies: exit 2 naming the file and
the field (never numpy's advice to load pickles)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from cosim.apps.vs import visual_path as VP
from cosim.cli import main
from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set

ROOT = Path(__file__).resolve().parents[1]
E1 = ROOT / "scenarios" / "bebop2_vs_e1.toml"
HALF = {"camera.width": 428, "camera.height": 240}


@pytest.fixture(scope="module")
def taught(tmp_path_factory):
    """A two-key path taught (rendered) with a 428 x 240 camera; and the scenario."""
    d = tmp_path_factory.mktemp("vp")
    sc = with_set(load_scenario(E1), HALF)
    VP.teach_by_render(sc, [(1.5, 0.0, -0.5, 0.0), (1.0, 0.2, -1.0, 10.0)], d / "a", "orb", 300)
    VP.teach_by_render(sc, [(1.2, 0.1, -0.7, 5.0), (0.8, 0.0, -1.0, 0.0)], d / "b", "orb", 300)
    return sc, d


def _use(sc, folder: Path, **more):
    return with_set(sc, {"app.params.visual_path": str(folder), **more})


def _copy(taught, name="a") -> Path:
    sc, d = taught
    dst = d / f"copy-{len(list(d.iterdir()))}"
    shutil.copytree(d / name, dst)
    return dst


def _refused(sc, folder: Path, *words: str, **more) -> str:
    with pytest.raises(ScenarioError) as ei:
        _use(sc, folder, **more)
    msg = str(ei.value)
    assert ei.value.field == "app.params.visual_path"
    for w in words:
        assert w in msg, msg
    assert "allow_pickle" not in msg and "pickle" not in msg
    return msg


def test_a_fitting_path_loads(taught):
    sc, d = taught
    assert _use(sc, d / "a").app.params["visual_path"] == str(d / "a")


def test_another_image_size_or_intrinsics_are_refused(taught):
    sc, d = taught
    _refused(sc, d / "a", "path.json", "428x240", "856x480",
             **{"camera.width": 856, "camera.height": 480})
    _refused(sc, d / "a", "camera.fx", **{"camera.fx": 300.0})
    _refused(sc, d / "a", "mount_B", **{"camera.mount_B": [0.2, 0.0, 0.0]})


@pytest.mark.parametrize("fx", [-537.3, "nan", 0, None, 1e400])
def test_bad_intrinsics_in_path_json_are_refused(taught, fx):
    sc, _ = taught
    f = _copy(taught)
    meta = json.loads((f / "path.json").read_text())
    meta["camera"]["fx"] = fx
    (f / "path.json").write_text(json.dumps(meta))
    _refused(sc, f, "path.json", "camera.fx")


def test_changed_key_images_and_features_are_refused(taught):
    sc, d = taught
    f = _copy(taught)
    black = np.zeros((240, 428, 3), np.uint8)
    cv2.imwrite(str(f / "001.png"), black)
    _refused(sc, f, "001.png", "sha256")
    f = _copy(taught)
    noise = np.random.default_rng(0).integers(0, 256, (240, 428, 3), dtype=np.uint8)
    cv2.imwrite(str(f / "000.png"), noise)
    _refused(sc, f, "000.png", "sha256")
    f = _copy(taught)
    shutil.copyfile(d / "b" / "features.npz", f / "features.npz")   # another path's
    _refused(sc, f, "features.npz", "key 0")


def test_garbage_features_are_refused_without_pickle_advice(taught):
    sc, _ = taught
    f = _copy(taught)
    np.save(f / "x.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    import zipfile
    with zipfile.ZipFile(f / "features.npz", "w") as z:   # an object array inside
        z.write(f / "x.npy", "pts_0.npy")
    _refused(sc, f, "features.npz", "numeric arrays")
    (f / "features.npz").write_bytes(b"junk")
    _refused(sc, f, "features.npz")


def test_validate_checks_the_visual_path(taught, tmp_path, capsys):
    sc, d = taught
    good = tmp_path / "good.toml"
    text = E1.read_text().replace('file = "worlds/room_e1.toml"',
                                  f'file = "{ROOT / "scenarios/worlds/room_e1.toml"}"')
    text = text.replace('kind = "front"', 'kind = "front"\nwidth = 428\nheight = 240')
    good.write_text(text.replace('preset = "e1"', f'preset = "e1"\nvisual_path = "{d / "a"}"'))
    assert main(["validate", str(good)]) == 0
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('preset = "e1"', f'preset = "e1"\nvisual_path = "{tmp_path}"'))
    assert main(["validate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "app.params.visual_path" in err and "no visual path here" in err
