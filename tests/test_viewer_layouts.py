"""The shipped viewer layouts (docs/viewers.md): one for the current Foxglove and Lichtblick
(its camera panel the `Image` panel), one for Foxglove Studio 1.x (`ImageViewPanel`), the same
otherwise; every plotted path is a field of a topic the run writes, and each plot shows one
unit (the fields' descriptions say which)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cosim.outputs.fox_topics import DESCRIPTIONS, JSON_SCHEMAS, TOPICS, vision_description

DOCS = Path(__file__).resolve().parents[1] / "docs"
LAYOUTS = {"current": DOCS / "cosim-layout.json", "studio1": DOCS / "cosim-layout-studio1.json"}
CAMERA = {"current": "Image!camera", "studio1": "ImageViewPanel!camera"}
VISION = ("e_x_px", "e_y_px", "eps_px")        # the line follower's and visual servoing's


def _panels(tree) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return _panels(tree["first"]) + _panels(tree["second"])


def _unit(path: str) -> str:
    topic, field = path.split(".", 1)
    assert topic in TOPICS, path
    if topic == "/app/vision":
        assert field in VISION, path
        return vision_description(field).rsplit(", ", 1)[1]
    assert field in JSON_SCHEMAS[topic][1], path
    return DESCRIPTIONS[topic][field].rsplit(", ", 1)[1]


@pytest.mark.parametrize("which", sorted(LAYOUTS))
def test_every_panel_is_placed_and_every_plot_path_exists_in_one_unit(which):
    layout = json.loads(LAYOUTS[which].read_text())
    panels = _panels(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"])
    assert CAMERA[which] in panels and "3D!scene" in panels
    for name, cfg in layout["configById"].items():
        if name.startswith("Plot!"):
            units = {_unit(p["value"]) for p in cfg["paths"]}
            assert len(units) == 1, (name, units)
            assert cfg["foxglovePanelTitle"].endswith(f"({units.pop()})"), name


def test_the_layouts_differ_only_in_the_camera_panel():
    cur, old = (json.loads(LAYOUTS[w].read_text()) for w in ("current", "studio1"))
    assert cur["configById"]["Image!camera"]["imageMode"]["imageTopic"] == "/camera/image"
    assert old["configById"]["ImageViewPanel!camera"]["cameraTopic"] == "/camera/image"
    for layout, name in ((cur, "Image!camera"), (old, "ImageViewPanel!camera")):
        del layout["configById"][name]
    assert cur["configById"] == old["configById"]
    assert json.dumps(cur["layout"]).replace("Image!camera", "ImageViewPanel!camera") == \
        json.dumps(old["layout"])
