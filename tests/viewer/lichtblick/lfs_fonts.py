"""Lichtblick's fonts (Inter, IBM Plex Mono: SIL Open Font License) are in Git LFS, which a
checkout without git-lfs (or GitHub's archive) leaves as pointer files; its app then fails to
start ("A network error occurred": the browser cannot load a font it must). Foxglove Studio
1.48's npm bundle (tests/viewer/setup.sh installs it) carries the same font files inline: each
pointer is replaced by the bundle's file with the pointer's sha256 (the same bytes, checked).

    python3 lfs_fonts.py LICHTBLICK_SOURCE_DIR FOXGLOVE_STUDIO_BASE_DIR"""

from __future__ import annotations

import base64
import hashlib
import re
import sys
from pathlib import Path


def main() -> int:
    src, studio = Path(sys.argv[1]), Path(sys.argv[2])
    fonts = {}
    for js in sorted((studio / "assets").glob("*.js")):
        for m in re.finditer(rb"data:font/woff2;base64,([A-Za-z0-9+/=]+)", js.read_bytes()):
            data = base64.b64decode(m.group(1))
            fonts[hashlib.sha256(data).hexdigest()] = data
    missing = []
    for font in sorted((src / "packages" / "suite-base" / "src" / "styles" / "assets")
                       .glob("*.woff2")):
        m = re.search(r"oid sha256:([0-9a-f]{64})", font.read_text(errors="replace"))
        if m is None:
            continue                # the font itself (fetched by git-lfs)
        if m.group(1) not in fonts:
            missing.append(font.name)
            continue
        font.write_bytes(fonts[m.group(1)])
        print(f"lichtblick: {font.name} from Foxglove Studio 1.48's bundle "
              f"(sha256 {m.group(1)[:12]})")
    if missing:
        print(f"lichtblick: no font with the sha256 of {', '.join(missing)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
