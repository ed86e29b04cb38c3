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

import os
import time
from pathlib import Path

import pytest
from viewer_checks import T_SEEK_S, aimed_layout, check_file_view, keep, legend, seed_run
from viewer_http import CHROMIUM, FLAGS, NODE, ROOT, run_url, serve

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


def test_foxglove_studio_shows_the_run(tmp_path):
    missing = _missing()
    assert missing is None, f"run `bash tests/viewer/setup.sh` first: missing {missing}"
    from playwright.sync_api import sync_playwright

    sc, res, alt = seed_run(tmp_path / "run")
    (tmp_path / "layout.json").write_text(
        aimed_layout(ROOT / "docs" / "cosim-layout-studio1.json", sc, res, alt))

    with serve(res.mcap, tmp_path / "layout.json", NODE) as base, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(run_url(base, T_SEEK_S))
            check_file_view(page, res, alt, tmp_path, time.monotonic() + WAIT_S, errors,
                            "foxglove_file_played.png")
            assert not errors, errors
        finally:
            browser.close()


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
                while legend(alt).get("altitude", 0.0) < 0.5:
                    assert time.monotonic() < end and proc.poll() is None, (
                        alt.inner_text(), "".join(lines))
                    time.sleep(1.0)
                north = legend(ne)["north"]
                while legend(ne).get("north") == north:          # it flies on
                    assert time.monotonic() < end, ne.inner_text()
                    time.sleep(0.5)
                # the viewer's clock: simulation time (s since 0), not the wall clock
                # (its start time in seconds, e.g. "12.055000000"; the wall clock: a date)
                m = re.search(r"START TIME\n([^\n]*)\n", page.inner_text("body"))
                assert m and re.fullmatch(r"\d+\.\d+", m.group(1).strip()), m and m.group(1)
                assert float(m.group(1)) < 3600, m.group(1)
                page.screenshot(path=str(tmp_path / "live.png"))
                keep(page, "foxglove_live.png")
            finally:
                browser.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5) == 143, "".join(lines)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
