#!/usr/bin/env bash
# Builds what tests/viewer/test_lichtblick_web.py needs: Lichtblick's web app (the open fork of
# Foxglove Studio), whose web build is not on npm (npm has only @lichtblick/suite, the
# extension API). SLOW AND OPTIONAL: it checks out Lichtblick's sources at a pinned commit,
# installs their ~2,000 npm packages with Lichtblick's own package manager (yarn 3 through
# corepack; ~2.5 GB in node_modules) and runs webpack on the app (a production bundle; tens of
# minutes on 2 cores, several GB of memory), all in $COSIM_VIEWER_DIR/lichtblick (default
# ~/.cache/cosim-viewer/lichtblick), outside the repository. Run `bash tests/viewer/setup.sh`
# first (chromium, Playwright). Needs node >= 20 with corepack, git, and the npm registry.
#
#   bash tests/viewer/setup_lichtblick.sh            # clones github.com/lichtblick-suite/lichtblick
#   LICHTBLICK_GIT=/path/to/lichtblick.git bash tests/viewer/setup_lichtblick.sh   # a local copy
#
# The build is $DIR/web/index.html and its assets. Files Lichtblick keeps in Git LFS are not
# fetched: its fonts (without them the app does not start) are taken from Foxglove Studio
# 1.48's npm bundle, the same files (lichtblick/lfs_fonts.py checks their sha256); its icons
# and panel thumbnails stay missing (not drawn); its four yarn plugins are not needed.
set -euo pipefail
cd "$(dirname "$0")/../.."
HERE="$PWD/tests/viewer"
DIR="${COSIM_VIEWER_DIR:-$HOME/.cache/cosim-viewer}/lichtblick"
STUDIO="${COSIM_VIEWER_DIR:-$HOME/.cache/cosim-viewer}/node_modules/@foxglove/studio-base"
if [ ! -f "$STUDIO/assets/index.js" ]; then
    echo "run bash tests/viewer/setup.sh first (Foxglove Studio 1.48's bundle: the fonts)" >&2
    exit 1
fi
# Lichtblick 1.10.8 (2025-03-21, "bump versions in root and suite package.json")
COMMIT="${LICHTBLICK_COMMIT:-9554e1e429c2c6409d4ea44d2f0e3082049f82ab}"
REGISTRY="${NPM_REGISTRY:-https://registry.npmjs.org}"
mkdir -p "$DIR"

if [ -f "$DIR/web/index.html" ] && [ "$(cat "$DIR/web/COMMIT" 2>/dev/null)" = "$COMMIT" ]; then
    echo "lichtblick: web build of $COMMIT in $DIR/web"
    exit 0
fi

if [ ! -f "$DIR/src/package.json" ] || [ "$(cat "$DIR/src/COMMIT" 2>/dev/null)" != "$COMMIT" ]; then
    GIT="${LICHTBLICK_GIT:-}"
    if [ -z "$GIT" ]; then
        GIT="$DIR/lichtblick.git"
        [ -d "$GIT" ] || git clone --bare --filter=blob:none \
            https://github.com/lichtblick-suite/lichtblick.git "$GIT"
        git --git-dir="$GIT" fetch --quiet origin "$COMMIT" || true
    fi
    rm -rf "$DIR/src"
    mkdir -p "$DIR/src"
    GIT_LFS_SKIP_SMUDGE=1 git --git-dir="$GIT" archive "$COMMIT" | tar -x -C "$DIR/src"
    echo "$COMMIT" > "$DIR/src/COMMIT"
fi

python3 "$HERE/lichtblick/lfs_fonts.py" "$DIR/src" "$STUDIO"
cd "$DIR/src"
# the yarn plugins are LFS pointers in a checkout without git-lfs: not loaded; packages from
# the npm registry (yarn's default host is not always reachable)
python3 - "$REGISTRY" <<'PY'
import re, sys
s = open(".yarnrc.yml").read()
s = re.sub(r"plugins:\n(  - .*\n    spec: .*\n)+", "", s)
if "npmRegistryServer" not in s:
    s += f'\nnpmRegistryServer: "{sys.argv[1]}"\nenableTelemetry: false\n'
open(".yarnrc.yml", "w").write(s)
PY
export COREPACK_NPM_REGISTRY="$REGISTRY" COREPACK_ENABLE_DOWNLOAD_PROMPT=0
# the desktop app's and the integration tests' binaries are not needed for the web build
export ELECTRON_SKIP_BINARY_DOWNLOAD=1 PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 PUPPETEER_SKIP_DOWNLOAD=1
nice -n 10 corepack yarn install
# the app bundle only: no dev server, type check or source maps (webpack.cosim.config.ts)
cp "$HERE/lichtblick/webpack.cosim.config.ts" web/
rm -rf web/.webpack
nice -n 10 corepack yarn webpack --mode production --config web/webpack.cosim.config.ts
rm -rf "$DIR/web"
cp -r web/.webpack "$DIR/web"
echo "$COMMIT" > "$DIR/web/COMMIT"
echo "lichtblick: web build of $COMMIT in $DIR/web"
