"""A run opened in a real viewer: Foxglove Studio 1.48's web build (npm
`@foxglove/studio-base`) in headless Chromium (Debian's `chromium`, driven by Playwright's
Python package), loading run.mcap over HTTP with the shipped layout for Studio 1.x,
docs/cosim-layout-studio1.json, the way a user opens a run (docs/viewers.md). Checks that
a plot panel resolves a JSON field (its legend shows the recorded altitude at the chosen
time, its line is drawn), that the camera panel shows the camera's image (the red track on
the grey floor), that the 3D panel draws the vehicle above the floor, and that it still does
after pressing Play for 5 s (a scene written once vanished then).

Slow and optional: install what it needs first with `bash tests/viewer/setup.sh` (Debian
chromium, the `viewer` extra, the npm packages into ~/.cache/cosim-viewer or
$COSIM_VIEWER_DIR); then `.venv/bin/pytest -m slow tests/viewer`. Without them it fails and
says what is missing (it is not skipped: a slow check that cannot run is a failure)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from viewer_http import CHROMIUM, FLAGS, NODE, ROOT, SHOTS, run_url, serve

from cosim.load import load_scenario, with_set
from cosim.outputs.series import COL
from cosim.sim.master import RunOptions, run_scenario

T_SEEK_S = 8.0        # hovering by then
PLAY_S = 5.0          # then played for this long (the run lasts beyond: it does not stop)
WAIT_S = float(os.environ.get("COSIM_VIEWER_WAIT_S", 180.0))

pytestmark = pytest.mark.slow


def _missing() -> str | None:
    if not Path(CHROMIUM).exists():
        return f"{CHROMIUM} (apt-get install chromium)"
    if not (NODE / "@foxglove" / "studio-base" / "assets" / "index.js").exists():
        return f"{NODE}/@foxglove/studio-base (npm)"
    try:
        import playwright  # noqa: F401
    except ImportError:
        return "playwright (pip install -e '.[viewer]')"
    return None


def _rgb(png: bytes) -> np.ndarray:
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(int)


def test_foxglove_studio_shows_the_run(tmp_path):
    missing = _missing()
    assert missing is None, f"run `bash tests/viewer/setup.sh` first: missing {missing}"
    from playwright.sync_api import sync_playwright

    sc = with_set(load_scenario(ROOT / "scenarios" / "mambo_seed_track.toml"),
                  {"timing.t_final_s": T_SEEK_S + PLAY_S + 3.0})
    res = run_scenario(sc, RunOptions(out_dir=tmp_path / "run", mcap=True))
    k = int(round(T_SEEK_S / sc.timing.tick_s))
    alt = -float(res.series[k, COL["z"]])
    assert alt > 0.8                                    # flying at the seek time
    # the shipped layout, its 3D view aimed at where the vehicle flies (the map frame's
    # origin is the arena's centre, z up) from a little above, grid off
    layout = json.loads((ROOT / "docs" / "cosim-layout-studio1.json").read_text())
    a = sc.world.arena
    x, y = (float(res.series[k, COL["y"]]) - 0.5 * (a[2] + a[3]),
            float(res.series[k, COL["x"]]) - 0.5 * (a[0] + a[1]))
    view = layout["configById"]["3D!scene"]
    assert view["followTf"] == "map"
    view["cameraState"].update(targetOffset=[x, y, alt], distance=2.0, phi=75.0,
                               thetaOffset=0.0)
    view["layers"]["grid"]["visible"] = False
    (tmp_path / "layout.json").write_text(json.dumps(layout))

    with serve(res.mcap, tmp_path / "layout.json", NODE) as base, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(run_url(base, T_SEEK_S))
            # the plot legend shows the altitude recorded at T_SEEK_S, to the last digit
            plot = page.locator(".mosaic-window").filter(has_text="altitude (m)")
            end = time.monotonic() + WAIT_S
            while repr(alt) not in plot.inner_text():
                assert time.monotonic() < end, (plot.inner_text(), errors)
                time.sleep(1.0)
            # its line (the altitude series is magenta in the layout; the chart draws it
            # darker, about (114, 23, 114)) is drawn: more magenta than the legend's 8 x 8
            # px swatch
            while True:
                png = plot.screenshot()
                img = _rgb(png)
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
                img = _rgb(png)
                r, g, b = img[..., 0], img[..., 1], img[..., 2]
                red = (r > 150) & (g < 80) & (b < 80)
                grey = (abs(r - g) < 10) & (abs(g - b) < 10) & (r > 90) & (r < 215)
                if red.sum() > 500 and grey.sum() > 5000:
                    break
                assert time.monotonic() < end, (red.sum(), grey.sum(), tmp_path / "camera.png",
                                                camera.inner_text(), errors)
                time.sleep(1.0)
            # the Log panel (/log): after a seek it shows the last message before that time,
            # here the run's last event so far
            event = [what for t, what in res.events if t <= T_SEEK_S][-1]
            log = page.locator(".mosaic-window").filter(has_text="DEBUG").first
            while f"[cosim]:\xa0{event}" not in log.inner_text():
                assert time.monotonic() < end, (log.inner_text(), event, errors)
                time.sleep(1.0)
            # the 3D panel: the vehicle (orange) above the floor (grey)
            scene = page.locator(".mosaic-window").filter(has_text="3D").first
            _vehicle_above_floor(scene, tmp_path / "scene.png", end, errors)
            # the estimate (green arrow and trail) and the setpoint (a blue sphere)
            img = _rgb((tmp_path / "scene.png").read_bytes())
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
            _vehicle_above_floor(scene, tmp_path / "played.png", time.monotonic() + 30, errors)
            _keep(page, "foxglove_file_played.png")
            assert not errors, errors
        finally:
            browser.close()


def _vehicle_above_floor(scene, png_path: Path, end: float, errors: list[str]) -> None:
    """Wait (until `end`) for the 3D panel to show the vehicle (orange) above the floor
    (grey rows across the panel); the last screenshot is at `png_path`."""
    while True:
        png = scene.screenshot()
        png_path.write_bytes(png)
        img = _rgb(png)
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


def _legend(plot) -> dict[str, float]:
    """A plot's legend: {label: value} (the panel's text is its title, then label, value...)."""
    lines = plot.inner_text().splitlines()[1:]
    out = {}
    for label, value in zip(lines[::2], lines[1::2], strict=False):
        try:
            out[label] = float(value)
        except ValueError:
            pass
    return out


def test_foxglove_studio_shows_a_live_run(tmp_path):
    """`cosim run --realtime --foxglove 0` watched live: Studio 1.48 asks for the protocol's
    first name (foxglove.websocket.v1), shows the vehicle flying (the legends' altitude above
    0.5 m, north changing), on the simulation's clock (its start time a few seconds, not
    today's date), and the run still ends on SIGTERM with 143."""
    import re
    import signal
    import subprocess
    import sys
    import threading

    missing = _missing()
    assert missing is None, f"run `bash tests/viewer/setup.sh` first: missing {missing}"
    from playwright.sync_api import sync_playwright

    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", str(ROOT / "scenarios" /
                                                      "mambo_seed_track.toml"),
         "--realtime", "--foxglove", "0", "--no-plots", "--set", "timing.t_final_s=120",
         "--out", str(tmp_path / "run")],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        url = None
        for line in proc.stdout:
            lines.append(line)
            m = re.search(r"live view on (ws://\S+)", line)
            if m:
                url = m.group(1)
                break
        assert url, "".join(lines)
        threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
        layout = ROOT / "docs" / "cosim-layout-studio1.json"
        with serve(tmp_path / "none.mcap", layout, NODE) as base, sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
            try:
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                page.goto(f"{base}/?ds=foxglove-websocket&ds.url={url}&layoutId=cosim")
                alt = page.locator(".mosaic-window").filter(has_text="altitude (m)")
                ne = page.locator(".mosaic-window").filter(has_text="north, east")
                end = time.monotonic() + WAIT_S
                while _legend(alt).get("altitude", 0.0) < 0.5:
                    assert time.monotonic() < end and proc.poll() is None, (
                        alt.inner_text(), "".join(lines))
                    time.sleep(1.0)
                north = _legend(ne)["north"]
                while _legend(ne).get("north") == north:          # it flies on
                    assert time.monotonic() < end, ne.inner_text()
                    time.sleep(0.5)
                # the viewer's clock: simulation time (s since 0), not the wall clock
                # (its start time in seconds, e.g. "12.055000000"; the wall clock: a date)
                m = re.search(r"START TIME\n([^\n]*)\n", page.inner_text("body"))
                assert m and re.fullmatch(r"\d+\.\d+", m.group(1).strip()), m and m.group(1)
                assert float(m.group(1)) < 3600, m.group(1)
                page.screenshot(path=str(tmp_path / "live.png"))
                _keep(page, "foxglove_live.png")
            finally:
                browser.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5) == 143, "".join(lines)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def _keep(page, name: str) -> None:
    """The whole page as SHOTS/name, if COSIM_VIEWER_SHOTS names a folder (docs/screenshots)."""
    if SHOTS:
        page.screenshot(path=str(Path(SHOTS) / name))
