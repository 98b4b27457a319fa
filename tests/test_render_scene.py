"""Heat maps of scenes (rotated bricks and blocks): a PNG with the score colours."""
import os

import numpy as np
import pytest

from stablelego_jax.formats.reader import load_layout
from stablelego_jax.render_scene import render_scene, scene_faces

EXT = os.path.join(os.path.dirname(__file__), "..", "examples", "extensions")


def test_faces_of_boxes_and_studs():
    sc = load_layout(os.path.join(EXT, "lego_single_knob_load.json"))
    verts, owner, normal = scene_faces(sc)
    studs = int(np.prod(sc.size[:, :2], axis=1).sum())
    assert len(verts) == 6 * sc.n + studs
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0)


def test_png_shows_the_failing_body_white(tmp_path):
    import matplotlib.image as mpimg

    sc = load_layout(os.path.join(EXT, "pallet_top_moved.json"))
    scores = np.zeros(sc.n)
    scores[sc.keys.index("top")] = 1.0
    p = tmp_path / "pallet.png"
    render_scene(sc, scores, str(p))
    img = mpimg.imread(str(p))[..., :3]
    white = (img > 0.97).all(-1)
    dark = (img < 0.2).all(-1)  # black (score 0) boxes
    assert dark.mean() > 0.02 and white.mean() > 0.01
    assert [f for f in os.listdir(tmp_path) if f.startswith(".tmp")] == []
    with pytest.raises(ValueError, match="scores must have shape"):
        render_scene(sc, scores[:-1], str(p))
