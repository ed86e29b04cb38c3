"""Regenerate the documentation's figures from real runs: `make docs-figures`.

Flies the seed mission (`cosim run scenarios/mambo_seed_track.toml`) and paper 2's E2
(`cosim run scenarios/bebop2_vs_e2.toml`), renders one front-camera view with its depth
(`cosim render`), and writes the figures below into this folder (or `--out DIR`), each a
palette PNG well under MAX_BYTES. About a minute on two cores; the runs go to a temporary
folder that is removed afterwards. Same code, same figures: the runs are seeded.

    .venv/bin/python docs/figures/make_figures.py [--out DIR]
"""

from __future__ import annotations

import argparse
import io
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
MAX_BYTES = 300_000  # each committed figure stays small (tests/test_docs.py checks it)

# name -> what it shows (the pages that use each name it)
FIGURES = {
    "seed_trajectory.png": "the seed mission from above: track, flown path, touchdown",
    "seed_timeseries.png": "the seed mission over time: altitude, velocities, path error",
    "down_camera.png": "the Mambo's downward camera along the seed mission",
    "e2_trajectory.png": "paper 2's E2 from above: room, obstacles, taught keys, flown path",
    "e2_visual_servo.png": "E2's visual servoing: eps, the 6-D error, commands, activations",
    "front_camera.png": "E2's key images and the front camera during the repeat",
    "room_render.png": "`cosim render` of the E2 room: the image and its depth",
}

SEED = "scenarios/mambo_seed_track.toml"
E2 = "scenarios/bebop2_vs_e2.toml"
SEED_FRAMES_S = (10.0, 25.0, 45.0, 65.0)        # --png-every 25: a frame every 5 s
E2_FRAMES_S = (6.0, 14.0, 24.0, 32.0)           # --png-every 50: a frame every 2 s
RENDER_AT = "1,0.3,-1.2,20"                     # the render example of the Cameras page


def cosim(*args: str) -> None:
    """Run the `cosim` command of this environment (the one beside this Python)."""
    exe = Path(sys.executable).with_name("cosim")
    if not exe.exists():
        raise SystemExit(f"make_figures: no `cosim` beside {sys.executable}: run `make setup`")
    subprocess.run([str(exe), *args], cwd=ROOT, check=True)


def save_small(fig_or_rgb, path: Path) -> None:
    """Save a matplotlib figure or an RGB array as a 256-colour PNG, no metadata."""
    if isinstance(fig_or_rgb, np.ndarray):
        img = Image.fromarray(fig_or_rgb)
    else:
        buf = io.BytesIO()
        fig_or_rgb.savefig(buf, format="png", dpi=100, bbox_inches="tight", pad_inches=0.05)
        plt.close(fig_or_rgb)
        img = Image.open(io.BytesIO(buf.getvalue())).convert("RGB")
    img.quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise SystemExit(f"make_figures: {path.name} is {size} bytes (> {MAX_BYTES})")
    print(f"  {path.name}: {img.width}x{img.height}, {size // 1000} KB")


def copy_plot(src: Path, dst: Path) -> None:
    save_small(np.asarray(Image.open(src).convert("RGB")), dst)


def frame(folder: Path, t: float) -> np.ndarray:
    return np.asarray(Image.open(folder / f"frame_{t:08.3f}.png").convert("RGB"))


def grid(rows: list[list[tuple[np.ndarray, str]]], width_in: float, path: Path) -> None:
    """Images in a grid, each with a caption underneath."""
    n_rows, n_cols = len(rows), max(len(r) for r in rows)
    h, w = rows[0][0][0].shape[:2]
    fig, axes = plt.subplots(n_rows, n_cols, squeeze=False,
                             figsize=(width_in, width_in * n_rows * h / w / n_cols + 0.35 * n_rows))
    for r, row in enumerate(rows):
        for c in range(n_cols):
            ax = axes[r][c]
            ax.axis("off")
            if c < len(row):
                img, caption = row[c]
                ax.imshow(img, interpolation="nearest")
                ax.set_title(caption, fontsize=8, y=-0.16)
    fig.tight_layout(pad=0.3)
    save_small(fig, path)


def seed_figures(run: Path, out: Path) -> None:
    cosim("run", SEED, "--out", str(run), "--png-every", "25", "--quiet")
    copy_plot(run / "trajectory.png", out / "seed_trajectory.png")
    copy_plot(run / "timeseries.png", out / "seed_timeseries.png")
    grid([[(frame(run / "frames", t), f"t = {t:.0f} s") for t in SEED_FRAMES_S]], 8.0,
         out / "down_camera.png")


def e2_figures(run: Path, out: Path) -> None:
    cosim("run", E2, "--out", str(run), "--png-every", "50", "--quiet")
    copy_plot(run / "trajectory.png", out / "e2_trajectory.png")
    copy_plot(run / "visual_servo.png", out / "e2_visual_servo.png")
    keys = sorted((run / "visual_path").glob("*.png"))
    grid([[(np.asarray(Image.open(k).convert("RGB")), f"key image I{i + 1}")
           for i, k in enumerate(keys)],
          [(frame(run / "frames", t), f"repeat, t = {t:.0f} s") for t in E2_FRAMES_S]],
         10.0, out / "front_camera.png")


def render_figure(tmp: Path, out: Path) -> None:
    view, depth = tmp / "view.png", tmp / "depth.png"
    cosim("render", "scenarios/bebop2_room_e2.toml", "--at", RENDER_AT,
          "--out", str(view), "--depth", str(depth))
    depth_m = np.asarray(Image.open(depth)).astype(float) / 1000.0
    fig, (a, b) = plt.subplots(1, 2, figsize=(10.0, 3.2))
    a.imshow(np.asarray(Image.open(view).convert("RGB")))
    a.set_title(f"front camera at N,E,D,yaw = {RENDER_AT}", fontsize=9)
    shown = b.imshow(np.where(depth_m > 0, depth_m, np.nan), cmap="viridis")
    b.set_title("depth along the optical axis (m)", fontsize=9)
    fig.colorbar(shown, ax=b, fraction=0.03)
    for ax in (a, b):
        ax.axis("off")
    fig.tight_layout(pad=0.3)
    save_small(fig, out / "room_render.png")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE, help="where the figures go (default: here)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="cosim-figures-") as tmp:
        tmp = Path(tmp)
        seed_figures(tmp / "seed", args.out)
        e2_figures(tmp / "e2", args.out)
        render_figure(tmp, args.out)
    made = sorted(p.name for p in args.out.glob("*.png") if p.name in FIGURES)
    assert made == sorted(FIGURES), made
    return 0


if __name__ == "__main__":
    sys.exit(main())
