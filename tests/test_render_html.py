"""The 3D HTML page: self-contained, the PNG's colour scale, a step slider for
several frames, and (where Chromium is installed) a screenshot that shows
the bricks in their heat-map colours."""
import os

import numpy as np
import pytest
from conftest import EXAMPLES

from stablelego_jax.formats.reader import load_layout
from stablelego_jax.render import score_cmap
from stablelego_jax.render_html import Frame, find_chromium, html_frames, html_heatmap, score_colors, screenshot

pytest.importorskip("plotly")
STAIR = os.path.join(EXAMPLES, "stablelego", "stair_20.json")


def test_page_is_self_contained_with_a_hover_text_per_brick(tmp_path):
    lay = load_layout(STAIR)
    p = tmp_path / "h.html"
    html_heatmap(lay, np.linspace(0, 1, lay.n), str(p), note="20 bricks")
    text = p.read_text()
    assert "<script src=" not in text and "Plotly.react" in text and len(text) > 1_000_000  # plotly.js inside
    for k in lay.keys:
        assert f"brick '{k}' " in text
    assert "score 1.000 FAILS" in text and 'display:none' in text  # one frame: no slider


def test_colours_are_the_png_scale():
    cols = score_colors([0.0, 0.5, 1.0, 3.0, np.nan])
    assert cols[0] == "#000000" and cols[2] == cols[3] == "#ffffff"
    r, g, b, _ = score_cmap()(0.5)
    assert cols[1] == "#%02x%02x%02x" % tuple(int(round(255 * c)) for c in (r, g, b))
    assert cols[4] == "#4a78b5"  # no score: blue, as in the PNG


def test_frames_get_a_slider(tmp_path):
    lay = load_layout(STAIR)
    frames = [Frame(lay.subset(range(k)), np.zeros(k), label=f"step {k}") for k in (1, 2, 3)]
    html_frames(frames, str(tmp_path / "s.html"), title="steps")
    text = (tmp_path / "s.html").read_text()
    assert 'type="range" id="step" min="0" max="2" value="2"' in text and "display:flex" in text
    with pytest.raises(ValueError):
        html_frames([], str(tmp_path / "e.html"))


@pytest.mark.skipif(find_chromium() is None, reason="Chromium not installed")
def test_screenshot_in_headless_chromium_shows_the_heat_map(tmp_path):
    from matplotlib.image import imread

    lay = load_layout(STAIR)
    scores = np.linspace(0.0, 1.0, lay.n)  # black through red to one white (failing) brick
    html_heatmap(lay, scores, str(tmp_path / "h.html"))
    screenshot(str(tmp_path / "h.html"), str(tmp_path / "h.png"), size=(800, 600))
    img = imread(str(tmp_path / "h.png"))[..., :3]
    assert img.shape[1] == 800 and 300 <= img.shape[0] <= 600
    img = img[:, :600]  # the scene, left of the colour bar
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    red = (r > 0.35) & (g < 0.2) & (b < 0.2)       # stressed bricks
    dark = (r < 0.15) & (g < 0.15) & (b < 0.15)    # unstressed bricks and outlines
    assert red.mean() > 0.005 and dark.mean() > 0.002, (red.mean(), dark.mean())
