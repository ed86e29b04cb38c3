"""The README stays short and its links resolve; the documentation site builds with
`mkdocs build --strict` (a broken link, a missing page or anchor, or a missing included
README fails it); the committed figures are the small ones docs/figures/make_figures.py makes.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FIGURES = ROOT / "docs" / "figures"

# [text](target) and ![alt](target), the target up to a space or the closing parenthesis
LINK = re.compile(r'!?\[[^\]]*\]\(([^)\s]+)(?:\s+"[^"]*")?\)')


def relative_links(markdown: str) -> list[str]:
    """The relative link targets of a Markdown text (no URLs, no in-page anchors)."""
    targets = []
    for target in LINK.findall(markdown):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue
        targets.append(target.split("#", 1)[0])
    return targets


def load_make_figures():
    spec = importlib.util.spec_from_file_location("make_figures", FIGURES / "make_figures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_readme_is_at_most_300_lines():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= 300, f"README.md has {n} lines; move the rest to a page under docs/"


def test_readme_quick_start_is_the_two_commands():
    text = README.read_text(encoding="utf-8")
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    commands = [line.split("#", 1)[0].strip() for line in block.splitlines() if line.strip()]
    assert commands == ["make demo", "make test"]
    assert "Python 3.11+" in section and "gcc" in section and "make" in section


def test_every_relative_link_in_the_readme_exists():
    targets = relative_links(README.read_text(encoding="utf-8"))
    assert len(targets) >= 10  # the images and the "where to go next" table
    missing = [t for t in targets if not (ROOT / t).exists()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


def test_link_finder_sees_what_it_must():
    text = ('see [a](docs/a.md#x) and ![b](docs/figures/b.png) [c](https://x.org/y) [d](#top)\n'
            '| [e](mailto:x@y.z) | [f](scenarios/README.md "title") | [`g`](mav/README.md) |')
    assert relative_links(text) == ["docs/a.md", "docs/figures/b.png", "scenarios/README.md",
                                     "mav/README.md"]


def test_mkdocs_build_strict(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict",  # not --quiet: it hides warnings
         "--config-file", str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},  # Material's banner, not a warning
    )
    assert out.returncode == 0, out.stdout + out.stderr
    site = tmp_path / "site"
    # the READMEs beside the code are included into the site, not copied into docs/
    assert "One tick" in (site / "architecture" / "index.html").read_text(encoding="utf-8")
    assert "Controllers" in (site / "reference" / "flight-stack" / "index.html").read_text(
        encoding="utf-8")
    for name in load_make_figures().FIGURES:
        assert (site / "figures" / name).exists(), name


def test_committed_figures_are_the_small_ones_the_script_makes():
    mod = load_make_figures()
    committed = sorted(p.name for p in FIGURES.glob("*.png"))
    assert committed == sorted(mod.FIGURES)
    for name in committed:
        size = (FIGURES / name).stat().st_size
        assert size <= mod.MAX_BYTES, f"{name}: {size} bytes"


def test_every_figure_is_shown_on_some_page():
    pages = "".join(p.read_text(encoding="utf-8") for p in (ROOT / "docs").rglob("*.md"))
    pages += README.read_text(encoding="utf-8")
    unused = [name for name in load_make_figures().FIGURES if name not in pages]
    assert not unused, f"figures no page shows: {unused}"


@pytest.mark.slow
def test_make_figures_regenerates_the_committed_set(tmp_path):
    """The script flies the runs and makes every figure, each small (~1 min)."""
    subprocess.run([sys.executable, str(FIGURES / "make_figures.py"), "--out", str(tmp_path)],
                   cwd=ROOT, check=True, capture_output=True, timeout=900)
    mod = load_make_figures()
    made = sorted(p.name for p in tmp_path.glob("*.png"))
    assert made == sorted(mod.FIGURES)
    assert all(p.stat().st_size <= mod.MAX_BYTES for p in tmp_path.glob("*.png"))
