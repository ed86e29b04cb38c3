#!/usr/bin/env bash
# Installs what the slow real-viewer test (tests/viewer/test_foxglove_web.py) needs:
# - Debian's chromium (the browser; Playwright drives it, it does not download one),
# - the `viewer` extra of this project (Playwright's Python package) into .venv,
# - from npm: Foxglove Studio 1.48's web build (`@foxglove/studio-base`, whose assets/ folder
#   is the webpack bundle of the app) and the React 17 it was built against (its UMD builds),
#   into $COSIM_VIEWER_DIR (default ~/.cache/cosim-viewer), outside the repository.
# Run from the repository root after `make setup`:  bash tests/viewer/setup.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
DIR="${COSIM_VIEWER_DIR:-$HOME/.cache/cosim-viewer}"

if ! command -v chromium >/dev/null; then
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium
fi
.venv/bin/python -m pip install --quiet -e '.[test,viewer]'
mkdir -p "$DIR"
if [ ! -f "$DIR/node_modules/@foxglove/studio-base/assets/index.js" ]; then
    npm install --prefix "$DIR" --no-save --no-audit --no-fund --ignore-scripts \
        @foxglove/studio-base@1.48.0 react@17.0.2 react-dom@17.0.2
fi
echo "viewer: chromium $(chromium --version 2>/dev/null | awk '{print $2}'), web build in $DIR"
