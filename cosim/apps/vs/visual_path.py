"""The visual path of teach-and-repeat: a folder of key images and what goes with them.

Format (version 1), a folder:
- `path.json`: {"format": "cosim-visual-path", "version": 1, "taught_by": "render" |
  "flight", "scenario": name, "world": name, "detector": "sift" | "gftt" | "orb",
  "n_features": int, "camera": {"width", "height", "fx", "fy", "cx", "cy", "mount_B"},
  "keys": [{"image": "000.png", "pose": [n, e, d, yaw_deg], "sha256": hash of the PNG file,
  "features_sha256": hash of the key's features}, ...]}. The poses are the true poses the
  key images were taken at (world NED, m; yaw from North): for metrics only, never given to
  the controller. The hashes (issue 31) refuse a key image or features changed after
  teaching; a hand-made folder without them has its features detected from the images.
A repeat refuses a folder whose camera (size, intrinsics, mount) is not the scenario's.
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

import hashlib
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from cosim import cache
from cosim.apps.vs.features import (
    DETECTORS,
    Detector,
    gray_of,
    homography,
    match,
    sort_points,
)
from cosim.apps.vs.geometry import homography_error

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


def folder_of(value: str, source: str | None) -> Path:
    """The folder an `app.params.visual_path` names: relative to the scenario file's folder."""
    folder = Path(value)
    if not folder.is_absolute() and source:
        folder = Path(source).parent / folder
    return folder


def teach_by_render(scenario, poses, folder: Path, detector: str, n_features: int) -> Path:
    """Render the key images at `poses` ([n, e, d, yaw_deg] rows) and write the folder."""
    from cosim.sensors.camera import make_camera
    from cosim.sensors.pinhole import FrontCameraConfig
    from cosim.sensors.stream import StreamSpec

    cfg = scenario.camera
    if not isinstance(cfg, FrontCameraConfig):
        raise ValueError("camera: teach-and-repeat needs [camera] kind = 'front'")
    cfg = replace(cfg, brightness=1.0, exposure_s=0.0, stream=StreamSpec())   # keys: still
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

    noisy = cfg.noisy
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


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def features_hash(pts: np.ndarray, desc: np.ndarray) -> str:
    """The hash of one key's features (dtype, shape and bytes of both arrays)."""
    h = hashlib.sha256()
    for a in (pts, desc):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def write(folder: Path, images, poses, camera: dict, detector: str, n_features: int, *,
          taught_by: str, scenario: str, world: str,
          features: dict[str, np.ndarray] | None = None) -> Path:
    """Write the folder; path.json holds the sha256 of each key image file and of its
    features, so a key whose image or features were changed afterwards is refused.
    `features`: the key images' `features_of` when already known."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    keys = []
    for i, (img, pose) in enumerate(zip(images, poses, strict=True)):
        name = f"{i:03d}.png"
        ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OSError(f"could not encode {folder / name}")
        (folder / name).write_bytes(png.tobytes())
        keys.append({"image": name, "pose": [float(v) for v in pose],
                     "sha256": _sha256(png.tobytes())})
    arrays = features if features is not None else features_of(images, detector, n_features)
    for i, key in enumerate(keys):
        key["features_sha256"] = features_hash(arrays[f"pts_{i}"], arrays[f"desc_{i}"])
    np.savez(folder / "features.npz", **arrays)
    meta = {"format": FORMAT, "version": VERSION, "taught_by": taught_by, "scenario": scenario,
            "world": world, "detector": detector, "n_features": int(n_features),
            "camera": camera, "keys": keys}
    (folder / "path.json").write_text(json.dumps(meta, indent=2))
    return folder


def _finite(v, what: str, pj: Path, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or (
            positive and v <= 0):
        raise ValueError(f"{pj}: {what} must be a finite number{' > 0' if positive else ''}"
                         f" (got {str(v)[:40]!r})")
    return float(v)


def read_meta(folder: Path | str) -> dict:
    """path.json of a visual path folder, every field checked: ValueError naming the file and
    the field. Adds the parsed `_K`, `_size`, `_mount`, `_poses`."""
    folder = Path(folder)
    pj = folder / "path.json"
    try:
        meta = json.loads(pj.read_text())
    except FileNotFoundError:
        raise ValueError(f"{pj}: no visual path here (teach one with `cosim teach`)") from None
    except (OSError, UnicodeDecodeError, RecursionError) as exc:
        raise ValueError(f"{pj}: unreadable ({type(exc).__name__})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{pj}: not JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != 1:
        raise ValueError(f"{pj}: not a {FORMAT} version {VERSION} file")
    cam = meta.get("camera")
    if not isinstance(cam, dict):
        raise ValueError(f"{pj}: camera must be a table of the taught camera")
    w, h = cam.get("width"), cam.get("height")
    for k, v in (("width", w), ("height", h)):
        if isinstance(v, bool) or not isinstance(v, int) or not 16 <= v <= 4096:
            raise ValueError(f"{pj}: camera.{k} must be an integer 16..4096 (got "
                             f"{str(v)[:40]!r})")
    fx, fy = (_finite(cam.get(k), f"camera.{k}", pj, positive=True) for k in ("fx", "fy"))
    cx, cy = (_finite(cam.get(k), f"camera.{k}", pj) for k in ("cx", "cy"))
    mount = cam.get("mount_B")
    if not isinstance(mount, list) or len(mount) != 3:
        raise ValueError(f"{pj}: camera.mount_B must be [x, y, z] (m)")
    meta["_mount"] = tuple(_finite(v, "camera.mount_B", pj) for v in mount)
    meta["_K"] = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    meta["_size"] = (w, h)
    if meta.get("detector") not in DETECTORS:
        raise ValueError(f"{pj}: detector must be one of {', '.join(DETECTORS)}")
    n = meta.get("n_features")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"{pj}: n_features must be an integer >= 1")
    entries = meta.get("keys")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{pj}: keys must be a non-empty list")
    poses = []
    for i, k in enumerate(entries):
        if not isinstance(k, dict) or not isinstance(k.get("image"), str) or not k["image"] \
                or Path(k["image"]).name != k["image"]:
            raise ValueError(f"{pj}: keys[{i}].image must name a file of the folder")
        pose = k.get("pose", [math.nan] * 4)
        if not isinstance(pose, list) or len(pose) != 4:
            raise ValueError(f"{pj}: keys[{i}].pose must be [n, e, d, yaw_deg]")
        poses.append(tuple(_finite(v, f"keys[{i}].pose", pj) for v in pose))
    meta["_poses"] = poses
    return meta


def _features(folder: Path, meta: dict) -> dict[int, tuple[np.ndarray, np.ndarray]] | None:
    """The precomputed features, checked against the hashes in path.json; None when the
    folder has no hashes (hand-made: the features are then detected from the images)."""
    npz = folder / "features.npz"
    entries = meta["keys"]
    if not all(isinstance(k.get("features_sha256"), str) for k in entries):
        return None
    try:
        with np.load(npz, allow_pickle=False) as f:
            arrays = {name: f[name] for name in f.files}
    except FileNotFoundError:
        raise ValueError(f"{npz}: missing (path.json lists features for every key)") from None
    except Exception as exc:         # not a zip of plain arrays (object arrays need pickle)
        raise ValueError(f"{npz}: not a features file of numeric arrays "
                         f"({type(exc).__name__})") from None
    out = {}
    for i, k in enumerate(entries):
        pts, desc = arrays.get(f"pts_{i}"), arrays.get(f"desc_{i}")
        if pts is None or desc is None or features_hash(pts, desc) != k["features_sha256"]:
            raise ValueError(f"{npz}: the features of key {i} ({k['image']}) do not match "
                             f"path.json keys[{i}].features_sha256 (changed after teaching; "
                             "teach the path again)")
        out[i] = (pts, desc)
    return out


def check_camera(meta: dict, cfg, folder: Path) -> None:
    """The scenario's camera must be the taught one: same kind (front), image size,
    intrinsics and mount. ValueError naming path.json and the field."""
    pj = Path(folder) / "path.json"
    if getattr(cfg, "kind", None) != "front":
        raise ValueError(f"{pj}: taught with a front camera; the scenario has "
                         f"{getattr(cfg, 'kind', 'no')} camera")
    w, h = meta["_size"]
    if (w, h) != (cfg.width, cfg.height):
        raise ValueError(f"{pj}: camera.width x height {w}x{h} taught, the scenario's camera "
                         f"is {cfg.width}x{cfg.height}")
    K = meta["_K"]
    for name, taught, now in (("fx", K[0, 0], cfg.fx), ("fy", K[1, 1], cfg.fy),
                              ("cx", K[0, 2], cfg.cx), ("cy", K[1, 2], cfg.cy)):
        if not math.isclose(taught, now, rel_tol=1e-6, abs_tol=1e-6):
            raise ValueError(f"{pj}: camera.{name} {taught:g} taught, the scenario's camera has "
                             f"{now:g}")
    if not all(math.isclose(a, b, abs_tol=1e-9) for a, b in zip(meta["_mount"], cfg.mount_B,
                                                                  strict=True)):
        raise ValueError(f"{pj}: camera.mount_B {list(meta['_mount'])} taught, the scenario's "
                         f"camera has {list(cfg.mount_B)}")


def _image(folder: Path, meta: dict, i: int) -> np.ndarray:
    k = meta["keys"][i]
    path = folder / k["image"]
    try:
        data = path.read_bytes()
    except OSError:
        raise ValueError(f"{path}: missing or unreadable") from None
    want = k.get("sha256")
    if isinstance(want, str) and _sha256(data) != want:
        raise ValueError(f"{path}: differs from the image taught (path.json keys[{i}].sha256); "
                         "teach the path again")
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    size = meta["_size"]
    if bgr is None or (bgr.shape[1], bgr.shape[0]) != size:
        raise ValueError(f"{path}: missing, unreadable or not {size[0]}x{size[1]}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def check(folder: Path | str, camera=None) -> dict:
    """A readable taught folder that fits `camera` (when given): path.json, each key image
    against its hash, the features against theirs. The checked meta; ValueError otherwise."""
    folder = Path(folder)
    meta = read_meta(folder)
    if camera is not None:
        check_camera(meta, camera, folder)
    for i in range(len(meta["keys"])):
        _image(folder, meta, i)
    _features(folder, meta)
    return meta


def load(folder: Path | str, camera=None) -> VisualPath:
    """Read a visual path folder (checked as `check` does); ValueError naming the file and
    what is wrong."""
    folder = Path(folder)
    meta = read_meta(folder)
    if camera is not None:
        check_camera(meta, camera, folder)
    feats = _features(folder, meta)
    det = None
    keys = []
    for i, pose in enumerate(meta["_poses"]):
        img = _image(folder, meta, i)
        gray = gray_of(img)
        if feats is not None:
            pts, desc = feats[i]
        else:                                    # a hand-made folder: detect now
            det = det or Detector(meta["detector"], meta["n_features"])
            pts, desc = det.detect(gray)
        keys.append(Key(img, gray, pts, desc, pose))
    return VisualPath(keys, meta["_K"], meta["_size"], meta["_mount"], meta["detector"],
                      meta["n_features"], meta)


def key_pair_errors(vp: VisualPath, det: Detector, K: np.ndarray, method: str, seed: int,
                    min_tracked: int, px: float = 1.0) -> list[np.ndarray | None]:
    """Eq. 2's error between consecutive key images (I*_k+1 seen from I*_k), or None where
    they do not match: the feed-forward of Eqs. 31-32 and the turn keys."""
    out: list[np.ndarray | None] = []
    for a, b in zip(vp.keys[:-1], vp.keys[1:], strict=False):
        tgt, cur = match(det, b.pts, b.desc, a.pts, a.desc, seed, px=px)
        e = None
        if len(tgt) >= min_tracked:
            tgt, cur = sort_points(tgt, cur)
            r = homography(cur, tgt, K, method, seed, px=px)
            if r.H is not None:
                e = homography_error(r.H)
        out.append(e)
    return out
