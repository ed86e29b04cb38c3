"""`cosim render`: what a scenario's camera sees from a given pose, without flying."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from cosim.errors import OutputError, ScenarioError
from cosim.sensors.camera import KINDS, make_camera, save_png
from mav.rotations import quat_from_euler


def _numbers(text: str, n: int, flag: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ScenarioError(flag, text, f"{n} comma-separated finite numbers")
    return vals


def save_depth_png(depth: np.ndarray, path: str | Path) -> Path:
    """Depth (m, inf = nothing) as a 16-bit PNG of millimetres (0 = nothing, max 65.535 m)."""
    mm = np.where(np.isfinite(depth), np.clip(np.round(depth * 1000.0), 1, 65535), 0)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(p), mm.astype(np.uint16)):
        raise OSError(f"could not write PNG {p}")
    return p


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _image_path(path: Path, flag: str, suffixes: tuple[str, ...]) -> None:
    """An image file name with a suffix the writer knows, not a folder."""
    p = Path(path)
    if p.suffix.lower() not in suffixes:
        raise ScenarioError(flag, str(p), f"an image file name ending in {', '.join(suffixes)}")
    if p.is_dir():
        raise ScenarioError(flag, str(p), "an image file name (this is a folder)")


def render_command(args) -> int:
    from cosim.load import load_scenario, with_set
    from cosim.scenario.sets import one_each

    _image_path(args.out, "--out", IMAGE_SUFFIXES)
    if args.depth is not None:
        _image_path(args.depth, "--depth", (".png",))
    sc = load_scenario(args.scenario)
    if args.set:
        sc = with_set(sc, one_each(args.set))
    n, e, d, yaw = _numbers(args.at, 4, "--at")
    roll, pitch = _numbers(args.attitude, 2, "--attitude")
    if abs(roll) >= 90 or abs(pitch) >= 90:
        raise ScenarioError("--attitude", args.attitude, "roll and pitch within +-90 deg")
    config = sc.camera
    if args.camera is not None and (config is None or getattr(config, "kind", "down")
                                    != args.camera):
        config = KINDS[args.camera][0]()
    if config is None:
        config = KINDS["front"][0]() if not sc.world.scene.empty else KINDS["down"][0]()
    front = getattr(config, "kind", "down") == "front"
    if args.exact or args.depth is not None:
        if not front:
            raise ScenarioError("--exact/--depth", args.camera or "down",
                                "the front camera (--camera front or [camera] kind = 'front')")
        config = replace(config, exact=args.exact or config.exact, depth=True)
    cam = make_camera(config, sc.world, seed=sc.seed)
    q = quat_from_euler(*(math.radians(v) for v in (roll, pitch, yaw)))
    img = cam.render(np.array([n, e, d]), q)
    try:
        out = save_png(img, args.out)
        if args.depth is not None:
            save_depth_png(cam.last_depth, args.depth)
    except OSError as exc:
        raise OutputError(f"cannot write {exc.filename or args.out}: "
                          f"{exc.strerror or exc}") from None
    print(f"{out}: {img.shape[1]}x{img.shape[0]} {getattr(config, 'kind', 'down')} camera at "
          f"N {n:g} E {e:g} D {d:g} m, yaw {yaw:g} deg")
    if args.depth is not None:
        depth = cam.last_depth
        seen = depth[np.isfinite(depth)]
        rng = f"{seen.min():.3f}-{seen.max():.3f} m" if seen.size else "nothing seen"
        print(f"{args.depth}: depth (16-bit mm), {rng}", file=sys.stdout)
    return 0
