"""A run opened in Lichtblick (the open fork of Foxglove Studio most labs run): its web app,
built from its sources by tests/viewer/setup_lichtblick.sh, in headless Chromium (Debian's
`chromium`, driven by Playwright), loading run.mcap over HTTP, with the shipped layout for
the current viewers, docs/cosim-layout.json, imported as a user does (the left sidebar's
Layouts tab, Import from file...; the browser's file picker answered with the layout file). The
same checks as Studio 1.48's (viewer_checks.check_file_view): the altitude plot resolves its
field and draws its line, the `Image` panel shows the camera's pixels, the Log panel the
run's last event, the 3D panel the vehicle above the floor, and still after Play for 5 s.

Slow and optional: `bash tests/viewer/setup.sh`, then `bash tests/viewer/setup_lichtblick.sh`
(it builds Lichtblick: tens of minutes, GBs); then `.venv/bin/pytest -m slow tests/viewer`.
Without them it fails and says what is missing (it is not skipped)."""

from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

import pytest
from viewer_checks import T_SEEK_S, aimed_layout, check_file_view, seed_run
from viewer_http import CHROMIUM, FLAGS, LICHTBLICK, NODE, ROOT, run_url, serve

WAIT_S = float(os.environ.get("COSIM_VIEWER_WAIT_S", 180.0))

pytestmark = pytest.mark.slow

# the browser's file picker (window.showOpenFilePicker, which Lichtblick's "Import from file..."
# calls) answers with one file: the layout's text
PICKER = """window.showOpenFilePicker = async () => [{
  getFile: async () => new File([%s], "cosim-layout.json", { type: "application/json" }),
}];"""


def _missing() -> str | None:
    if not Path(CHROMIUM).exists():
        return f"{CHROMIUM} (apt-get install chromium; bash tests/viewer/setup.sh)"
    if not (LICHTBLICK / "index.html").exists():
        return f"{LICHTBLICK}/index.html (bash tests/viewer/setup_lichtblick.sh)"
    try:
        import playwright  # noqa: F401
    except ImportError:
        return "playwright (bash tests/viewer/setup.sh)"
    return None


def test_lichtblick_shows_the_run(tmp_path):
    missing = _missing()
    assert missing is None, f"missing {missing}"
    from playwright.sync_api import sync_playwright

    sc, res, alt = seed_run(tmp_path / "run")
    layout = aimed_layout(ROOT / "docs" / "cosim-layout.json", sc, res, alt)
    (tmp_path / "layout.json").write_text(layout)

    with serve(res.mcap, tmp_path / "layout.json", NODE, LICHTBLICK) as base, \
            sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.add_init_script(PICKER % json.dumps(layout))
            page.goto(run_url(base, T_SEEK_S, layout_id=None))
            end = time.monotonic() + WAIT_S
            # import the layout as a user does
            page.get_by_role("tab", name="Layouts").click(timeout=WAIT_S * 1000)
            page.get_by_text("Import from file…").click()
            # focus off that button (the space bar, Play, would press it again)
            page.evaluate("document.activeElement.blur()")
            check_file_view(page, res, alt, tmp_path, end, errors,
                            "lichtblick_file_played.png", log_panel=re.compile(r"^Log"))
            assert not errors, errors
        finally:
            browser.close()
