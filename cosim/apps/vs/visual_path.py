"""The visual path of teach-and-repeat: a folder of key images and what goes with them.

Format (version 1), a folder:
- `path.json`: {"format": "cosim-visual-path", "version": 1, "taught_by": "render" |
  "flight", "scenario": name, "world": name, "detector": "sift" | "gftt" | "orb",
  "n_features": int, "camera": {"width", "height", "fx", "fy", "cx", "cy", "mount_B"},
  "keys": [{"image": "000.png", "pose": [n, e, d, yaw_deg]}, ...]}. The poses are the true
  poses the key images were taken at (world NED, m; yaw from North): for metrics only, never
  given to the controller.
- `000.png`, `001.png`, ...: the key images (RGB as PNG), in the order they are repeated.
- `features.npz`: for key i, `pts_i` (N x 2 float32 pixel positions) and `desc_i` (N x D
  descriptors) of the path's detector: precomputed so the repeat does not detect on keys.

Teach by rendering (`teach_by_render`): the scenario's front camera in its world at each
listed pose, level (as in hover), with the camera's noise from a teach-only seed, at
brightness 1 (the camera's `brightness` is the repeat's lighting). The key images and their
features are a function of the world, the camera, the poses, the detector (and the seed when
the camera has noise): they are made once per process for those, and kept on disk in a
study (`cosim/cache.py`); each run folder still gets its own copy of the folder.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from cosim import cache
from cosim.apps.vs.features import DETECTORS, Detector, gray_of

FORMAT = "cosim-visual-path"
VERSION = 1


@dataclass
class Key:
    image: np.ndarray          # H x W x 3 uint8 RGB
    gray: np.ndarray
    pts: np.ndarray            # N x 2 float32
    desc: np.ndarray
    pose: tuple[float, float, float, float]   # n, e, d m, yaw deg: metrics only


@dataclass
class VisualPath:
    keys: list[Key]
    K: np.ndarray
    size: tuple[int, int]      # width, height
    mount_B: tuple[float, float, float]
    detector: str
    n_features: int
    meta: dict = field(default_factory=dict)

    @property
    def poses(self) -> list[tuple[float, float, float, float]]:
        return [k.pose for k in self.keys]


def camera_dict(cfg) -> dict:
    return {"width": cfg.width, "height": cfg.height, "fx": cfg.fx, "fy": cfg.fy,
            "cx": cfg.cx, "cy": cfg.cy, "mount_B": list(cfg.mount_B)}


def teach_by_render(scenario, poses, folder: Path, detector: str, n_features: int) -> Path:
    """Render the key images at `poses` ([n, e, d, yaw_deg] rows) and write the folder."""
    from cosim.sensors.camera import make_camera
    from cosim.sensors.pinhole import FrontCameraConfig

    cfg = scenario.camera
    if not isinstance(cfg, FrontCameraConfig):
        raise ValueError("camera: teach-and-repeat needs [camera] kind = 'front'")
    cfg = replace(cfg, brightness=1.0)
    seed = scenario.seed + 7919
    poses = [tuple(float(v) for v in p) for p in poses]

    def make() -> dict[str, np.ndarray]:
        cam = make_camera(cfg, scenario.world, seed=seed)
        images = []
        for n, e, d, yaw_deg in poses:
            half = math.radians(yaw_deg) / 2.0
            q = (math.cos(half), 0.0, 0.0, math.sin(half))       # level, heading yaw_deg
            images.append(cam.render(np.array([n, e, d], dtype=float), q))
        out = features_of(images, detector, n_features)
        out.update({f"image_{i}": img for i, img in enumerate(images)})
        return out

    noisy = cfg.noise_std > 0.0 or cfg.lighting_noise > 0.0
    got = cache.arrays("visual-path", cache.key("taught", scenario.world, cfg, poses,
                                                seed if noisy else None, detector, n_features),
                       make)
    images = [got[f"image_{i}"] for i in range(len(poses))]
    feats = {k: v for k, v in got.items() if not k.startswith("image_")}
    return write(folder, images, poses, camera_dict(cfg), detector, n_features,
                 taught_by="render", scenario=scenario.name, world=scenario.world.name,
                 features=feats)


def features_of(images, detector: str, n_features: int) -> dict[str, np.ndarray]:
    """`pts_i`, `desc_i` of each key image (the arrays of `features.npz`)."""
    det = Detector(detector, n_features)
    arrays = {}
    for i, img in enumerate(images):
        arrays[f"pts_{i}"], arrays[f"desc_{i}"] = det.detect(gray_of(img))
    return arrays


def write(folder: Path, images, poses, camera: dict, detector: str, n_features: int, *,
          taught_by: str, scenario: str, world: str,
          features: dict[str, np.ndarray] | None = None) -> Path:
    """Write the folder; `features`: the key images' `features_of` when already known."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    keys = []
    for i, (img, pose) in enumerate(zip(images, poses, strict=True)):
        name = f"{i:03d}.png"
        if not cv2.imwrite(str(folder / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {folder / name}")
        keys.append({"image": name, "pose": [float(v) for v in pose]})
    arrays = features if features is not None else features_of(images, detector, n_features)
    np.savez(folder / "features.npz", **arrays)
    meta = {"format": FORMAT, "version": VERSION, "taught_by": taught_by, "scenario": scenario,
            "world": world, "detector": detector, "n_features": int(n_features),
            "camera": camera, "keys": keys}
    (folder / "path.json").write_text(json.dumps(meta, indent=2))
    return folder


def load(folder: Path | str) -> VisualPath:
    """Read a visual path folder; ValueError naming the file and what is wrong."""
    folder = Path(folder)
    pj = folder / "path.json"
    try:
        meta = json.loads(pj.read_text())
    except FileNotFoundError:
        raise ValueError(f"{pj}: no visual path here (teach one with `cosim teach`)") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{pj}: not JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != 1:
        raise ValueError(f"{pj}: not a {FORMAT} version {VERSION} file")
    try:
        cam = meta["camera"]
        K = np.array([[float(cam["fx"]), 0.0, float(cam["cx"])],
                      [0.0, float(cam["fy"]), float(cam["cy"])], [0.0, 0.0, 1.0]])
        size = (int(cam["width"]), int(cam["height"]))
        mount = tuple(float(v) for v in cam["mount_B"])
        detector = str(meta["detector"])
        n_features = int(meta["n_features"])
        entries = list(meta["keys"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{pj}: missing or bad field ({exc})") from None
    if detector not in DETECTORS or not entries:
        raise ValueError(f"{pj}: detector must be one of {DETECTORS} and keys not empty")
    feats = np.load(folder / "features.npz") if (folder / "features.npz").exists() else None
    det = None
    keys = []
    for i, k in enumerate(entries):
        path = folder / str(k["image"])
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None or (bgr.shape[1], bgr.shape[0]) != size:
            raise ValueError(f"{path}: missing, unreadable or not {size[0]}x{size[1]}")
        img = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        gray = gray_of(img)
        if feats is not None and f"pts_{i}" in feats:
            pts, desc = feats[f"pts_{i}"], feats[f"desc_{i}"]
        else:                                    # a hand-made folder: detect now
            det = det or Detector(detector, n_features)
            pts, desc = det.detect(gray)
        pose = tuple(float(v) for v in k.get("pose", [math.nan] * 4))
        if len(pose) != 4:
            raise ValueError(f"{pj}: keys[{i}].pose must be [n, e, d, yaw_deg]")
        keys.append(Key(img, gray, pts, desc, pose))
    return VisualPath(keys, K, size, mount, detector, n_features, meta)
