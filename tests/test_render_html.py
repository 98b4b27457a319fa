"""The 3D HTML page: self-contained, the PNG's colour scale, a step slider for
several frames, and (where Chromium is installed) a screenshot that shows
the bricks in their heat-map colours."""
import os

import numpy as np
import pytest
from conftest import EXAMPLES

from stablelego_jax.formats.reader import load_layout
from stablelego_jax.render import score_cmap
from stablelego_jax.render import Z_SCALE
from stablelego_jax.render_html import (Frame, box_corners, find_chromium, html_frames, html_heatmap, score_colors,
                                        screenshot)
from stablelego_jax.scene import BLOCK, BRICK, make_scene

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


def test_box_corners_of_grid_bricks_and_of_a_scene():
    lay = load_layout(STAIR)
    c = box_corners(lay)
    assert c.shape == (lay.n, 8, 3)
    i = 3
    (x, y, z), (sx, sy) = lay.pos[i], lay.size[i]
    assert np.allclose(c[i, :4, :2], [[x, y], [x + sx, y], [x + sx, y + sy], [x, y + sy]])
    assert np.allclose(c[i, 4:, :2], c[i, :4, :2]) and np.allclose(c[i, :4, 2], z * Z_SCALE)
    assert np.allclose(c[i, 4:, 2], (z + 1) * Z_SCALE)
    # a 2x4 brick, a 2x4 plate on it turned by 90 degrees, a 2x2 brick at 45 degrees, a 10 cm block
    sc = make_scene(["b", "p", "t", "k"], [BRICK, BRICK, BRICK, BLOCK],
                    [(2, 1, 0), (2, 1, 3), (2, 1, 4), (0.3, 0.3, 0.05)], [(4, 2, 3), (4, 2, 1), (2, 2, 3), (0.1, 0.1, 0.1)],
                    [0, 90, 45, 0], [2.3e-3, 1e-3, 1.2e-3, 0.5])
    c = box_corners(sc)
    assert np.allclose(c[0, :4, :2], [[0, 0], [4, 0], [4, 2], [0, 2]]) and np.allclose(c[0, 4:, 2], Z_SCALE)
    assert np.allclose(c[1, :4, :2], [[3, -1], [3, 3], [1, 3], [1, -1]])  # turned: long side along y
    assert np.allclose(c[1, :4, 2], Z_SCALE) and np.allclose(c[1, 4:, 2], Z_SCALE * 4 / 3)  # a third of a layer
    r = np.hypot(*(c[2, 0, :2] - [2, 1]))
    assert np.isclose(r, np.sqrt(2)) and np.isclose(c[2, 0, 0], 2.0)  # corner (-1,-1) turned 45 deg: straight down
    assert np.allclose(c[3, 0], [0.25 / 0.0078, 0.25 / 0.0078, 0.0]) and np.allclose(c[3, 4, 2], 0.1 / 0.0078)


def test_page_of_a_scene_names_plates_turned_bricks_and_blocks(tmp_path):
    sc = make_scene(["b", "p", "k"], [BRICK, BRICK, BLOCK], [(2, 1, 0), (2, 1, 3), (0.3, 0.3, 0.05)],
                    [(4, 2, 3), (4, 2, 1), (0.1, 0.1, 0.1)], [0, 90, 30], [2.3e-3, 1e-3, 0.5])
    p = tmp_path / "s.html"
    html_heatmap(sc, [0.2, 1.0, np.nan], str(p))
    text = p.read_text()
    assert "brick 'b' 4x2 at (2,1) studs, level 0: score 0.200" in text
    assert "plate 'p' 4x2 at (2,1) studs, level 3, yaw 90 deg: score 1.000 FAILS" in text
    assert "block 'k' 100x100x100 mm at (300,300,50) mm, yaw 30 deg: no score" in text


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
