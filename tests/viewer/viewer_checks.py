"""What the real-viewer tests check on a page showing a run (Foxglove Studio 1.48 in
test_foxglove_web.py, Lichtblick in test_lichtblick_web.py; both drive the same panels of the
shipped layouts): the seed mission's short run, the layout's 3D view aimed at the vehicle, and
the checks of the file view, by reading the panels' text and pixels. Not a test module itself."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
from viewer_http import ROOT, SHOTS

from cosim.load import load_scenario, with_set
from cosim.outputs.series import COL
from cosim.sim.master import RunOptions, run_scenario

T_SEEK_S = 8.0        # hovering by then
PLAY_S = 5.0          # then played for this long (the run lasts beyond: it does not stop)


def seed_run(out: Path):
    """The seed mission to T_SEEK_S + PLAY_S + 3 s with its MCAP: (scenario, result, the
    altitude at T_SEEK_S, m); it flies at T_SEEK_S."""
    sc = with_set(load_scenario(ROOT / "scenarios" / "mambo_seed_track.toml"),
                  {"timing.t_final_s": T_SEEK_S + PLAY_S + 3.0})
    res = run_scenario(sc, RunOptions(out_dir=out, mcap=True))
    alt = -float(res.series[_tick(sc), COL["z"]])
    assert alt > 0.8                                    # flying at the seek time
    return sc, res, alt


def _tick(sc) -> int:
    return int(round(T_SEEK_S / sc.timing.tick_s))


def aimed_layout(layout: Path, sc, res, alt: float) -> str:
    """The shipped layout (JSON text), its 3D view aimed at where the vehicle flies at
    T_SEEK_S (the map frame's origin is the arena's centre, z up) from a little above, grid
    off."""
    data = json.loads(layout.read_text())
    k = _tick(sc)
    a = sc.world.arena
    x, y = (float(res.series[k, COL["y"]]) - 0.5 * (a[2] + a[3]),
            float(res.series[k, COL["x"]]) - 0.5 * (a[0] + a[1]))
    view = data["configById"]["3D!scene"]
    assert view["followTf"] == "map"
    view["cameraState"].update(targetOffset=[x, y, alt], distance=2.0, phi=75.0,
                               thetaOffset=0.0)
    view["layers"]["grid"]["visible"] = False
    return json.dumps(data)


def rgb(png: bytes) -> np.ndarray:
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(int)


def check_file_view(page, res, alt: float, tmp_path: Path, end: float, errors: list[str],
                    shot: str, log_panel: str | re.Pattern = "DEBUG") -> None:
    """A page showing `res`'s run.mcap at T_SEEK_S with a shipped layout (until `end`, a
    time.monotonic(), for it to load and draw): the altitude plot resolves
    /vehicle/truth.alt (its legend shows the recorded value, its line is drawn), the camera
    panel shows the camera's image, the Log panel the run's last event so far, the 3D panel
    the vehicle above the floor with its estimate and setpoint; then Play for PLAY_S: time
    went on and the 3D panel still draws the vehicle above the floor. The page is kept as
    SHOTS/shot. `log_panel`: a text of the Log panel's own (Studio 1.x: its level menu's
    "DEBUG"; Lichtblick has no level menu: its title, "Log")."""
    # the plot legend shows the altitude recorded at T_SEEK_S, to the last digit
    plot = page.locator(".mosaic-window").filter(has_text="altitude (m)")
    while repr(alt) not in plot.inner_text():
        assert time.monotonic() < end, (plot.inner_text(), errors)
        time.sleep(1.0)
    # its line (the altitude series is magenta in the layout; the chart draws it darker,
    # about (114, 23, 114)) is drawn: more magenta than the legend's 8 x 8 px swatch
    while True:
        png = plot.screenshot()
        img = rgb(png)
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        if ((abs(r - b) < 15) & (r - g > 50)).sum() > 200:
            break
        (tmp_path / "plot.png").write_bytes(png)
        assert time.monotonic() < end, tmp_path / "plot.png"
        time.sleep(1.0)
    # the camera panel: the frame at T_SEEK_S, the red track across the grey floor
    camera = page.locator(".mosaic-window").filter(has_text="/camera/image").first
    while True:
        png = camera.screenshot()
        (tmp_path / "camera.png").write_bytes(png)
        img = rgb(png)
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        red = (r > 150) & (g < 80) & (b < 80)
        grey = (abs(r - g) < 10) & (abs(g - b) < 10) & (r > 90) & (r < 215)
        if red.sum() > 500 and grey.sum() > 5000:
            break
        assert time.monotonic() < end, (red.sum(), grey.sum(), tmp_path / "camera.png",
                                        camera.inner_text(), errors)
        time.sleep(1.0)
    # the Log panel (/log): after a seek it shows the last message before that time, here
    # the run's last event so far
    event = [what for t, what in res.events if t <= T_SEEK_S][-1]
    log = page.locator(".mosaic-window").filter(has_text=log_panel).first
    while f"[cosim]:\xa0{event}" not in log.inner_text():
        assert time.monotonic() < end, (log.inner_text(), event, errors)
        time.sleep(1.0)
    # the 3D panel: the vehicle (orange) above the floor (grey)
    scene = page.locator(".mosaic-window").filter(has_text="3D").first
    vehicle_above_floor(scene, tmp_path / "scene.png", end, errors)
    # the estimate (green arrow and trail) and the setpoint (a blue sphere)
    img = rgb((tmp_path / "scene.png").read_bytes())
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    green = ((g > r + 40) & (g > b + 30)).sum()
    blue = ((b > r + 80) & (b > g + 40)).sum()
    assert green > 200 and blue > 200, (green, blue, tmp_path / "scene.png")
    # Play (the space bar) for PLAY_S, pause: time went on, the scene is still drawn
    page.keyboard.press("Space")
    time.sleep(PLAY_S)
    page.keyboard.press("Space")
    legend = plot.inner_text()
    assert repr(alt) not in legend, legend              # it played
    vehicle_above_floor(scene, tmp_path / "played.png", time.monotonic() + 30, errors)
    keep(page, shot)


def vehicle_above_floor(scene, png_path: Path, end: float, errors: list[str]) -> None:
    """Wait (until `end`) for the 3D panel to show the vehicle (orange) above the floor
    (grey rows across the panel); the last screenshot is at `png_path`."""
    while True:
        png = scene.screenshot()
        png_path.write_bytes(png)
        img = rgb(png)
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        # the vehicle's orange, lit from one side: (188, 82, 0) down to (47, 21, 0) (not the
        # estimate's green trail over the red end marker, about (141, 39, 17))
        orange = (r > 40) & (g > 0.38 * r) & (g < 0.6 * r) & (b < 0.15 * r + 5)
        grey = (abs(r - g) < 10) & (abs(g - b) < 10) & (r > 90) & (r < 215)
        if orange.sum() > 30 and (grey.sum(axis=1) > 0.6 * grey.shape[1]).any():
            break
        assert time.monotonic() < end, (orange.sum(), grey.sum(), png_path, errors)
        time.sleep(1.0)
    rows_v = np.nonzero(orange.any(axis=1))[0]
    # floor rows: grey across most of the panel (not the grey of a tooltip)
    rows_f = np.nonzero(grey.sum(axis=1) > 0.6 * grey.shape[1])[0]
    assert rows_v.max() < rows_f.min(), (rows_v, rows_f, png_path)


def legend(plot) -> dict[str, float]:
    """A plot's legend: {label: value} (the panel's text is its title, then label, value...)."""
    lines = plot.inner_text().splitlines()[1:]
    out = {}
    for label, value in zip(lines[::2], lines[1::2], strict=False):
        try:
            out[label] = float(value)
        except ValueError:
            pass
    return out


def keep(page, name: str) -> None:
    """The whole page as SHOTS/name, if COSIM_VIEWER_SHOTS names a folder (docs/screenshots)."""
    if SHOTS:
        page.screenshot(path=str(Path(SHOTS) / name))
