"""Foxglove Studio's web build on this machine, for the real-viewer test and for screenshots:
a loopback HTTP server for the page (index.html, boot.js), the layout, the npm packages
(/node/...) and one run's MCAP, with byte ranges (Foxglove reads a remote MCAP by ranges) and
CORS; the headless Chromium flags; the URL that opens a run at a time with the layout.

A screenshot of a run (for the docs), after `bash tests/viewer/setup.sh`:
    .venv/bin/python tests/viewer/viewer_http.py runs/e1/run.mcap foxglove.png --time 10
Not a test module itself."""

from __future__ import annotations

import argparse
import contextlib
import mimetypes
import os
import re
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
SHOTS = os.environ.get("COSIM_VIEWER_SHOTS")   # a folder: the tests keep their screenshots there
CACHE = Path(os.environ.get("COSIM_VIEWER_DIR", Path.home() / ".cache" / "cosim-viewer"))
NODE = CACHE / "node_modules"
LICHTBLICK = CACHE / "lichtblick" / "web"      # Lichtblick's web build (setup_lichtblick.sh)
CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync",
         # WebGL without a GPU: ANGLE on SwiftShader (Chromium no longer falls back to it
         # by itself)
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def run_url(base: str, t_s: float, layout_id: str | None = "cosim") -> str:
    """The page opening base/run.mcap at simulation time t_s (s) with the layout "cosim"
    (layout_id None: the viewer's current layout)."""
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(int(t_s)))
    layout = f"&layoutId={layout_id}" if layout_id else ""
    return (f"{base}/?ds=remote-file&ds.url={base}/run.mcap{layout}"
            f"&time={stamp}.{int(round(t_s % 1 * 1e9)):09d}Z")


def _handler(routes: dict[str, Path], node: Path, app: Path | None):
    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args) -> None:   # quiet
            pass

        def _path(self) -> Path | None:
            url = self.path.split("?", 1)[0]
            if url in routes:
                return routes[url]
            if url.startswith("/node/"):
                p = (node / url[len("/node/"):]).resolve()
                if node.resolve() in p.parents and p.is_file():
                    return p
            if app is not None:     # a web app's own build: its index.html and assets
                p = (app / (url.lstrip("/") or "index.html")).resolve()
                if app.resolve() in p.parents and p.is_file():
                    return p
            return None

        def do_GET(self) -> None:   # noqa: N802 (the stdlib's name)
            p = self._path()
            if p is None:
                self.send_error(404)
                return
            size = p.stat().st_size
            start, end = 0, size - 1
            m = re.fullmatch(r"bytes=(\d*)-(\d*)", self.headers.get("Range", ""))
            if m and (m.group(1) or m.group(2)):
                if m.group(1):
                    start = int(m.group(1))
                    end = min(int(m.group(2)), size - 1) if m.group(2) else size - 1
                else:
                    start = max(size - int(m.group(2)), 0)
                self.send_response(206)
                self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
            else:
                self.send_response(200)
            ctype = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
            if p.suffix == ".wasm":
                ctype = "application/wasm"
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(end - start + 1))
            self.send_header("Accept-Ranges", "bytes")
            self.send_header("Access-Control-Allow-Origin", "*")
            self.send_header("Access-Control-Expose-Headers", "Content-Range, Content-Length")
            self.end_headers()
            with open(p, "rb") as f:
                f.seek(start)
                left = end - start + 1
                while left > 0:
                    chunk = f.read(min(left, 1 << 20))
                    if not chunk:
                        break
                    self.wfile.write(chunk)
                    left -= len(chunk)

    return Handler


@contextlib.contextmanager
def serve(mcap: Path, layout: Path, node: Path, app: Path | None = None) -> Iterator[str]:
    """Serve on 127.0.0.1, a free port; yields the base URL. With `app` (a web build's
    folder, Lichtblick's), the page is that app's own index.html, not ours."""
    routes = {"/layout.json": layout, "/run.mcap": mcap}
    if app is None:
        routes.update({"/": HERE / "index.html", "/index.html": HERE / "index.html",
                       "/boot.js": HERE / "boot.js"})
    server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(routes, node, app))
    server.handle_error = lambda *_: None      # a browser dropping a range read it no longer needs
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def main() -> None:
    from playwright.sync_api import sync_playwright

    p = argparse.ArgumentParser(description="a screenshot of a run in Foxglove Studio 1.48")
    p.add_argument("mcap", type=Path)
    p.add_argument("png", type=Path)
    p.add_argument("--time", type=float, default=0.0, help="s of simulation time to show")
    p.add_argument("--layout", type=Path, default=ROOT / "docs" / "cosim-layout-studio1.json")
    p.add_argument("--wait", type=float, default=30.0, help="s to let it load and draw")
    a = p.parse_args()
    with serve(a.mcap, a.layout, NODE) as base, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        page = browser.new_page(viewport={"width": 1600, "height": 1000})
        page.goto(run_url(base, a.time))
        time.sleep(a.wait)
        page.screenshot(path=str(a.png))
        browser.close()


if __name__ == "__main__":
    main()
