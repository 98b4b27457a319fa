"""The "blocks" format and rotated bricks in StableLego JSON: reading,
errors that name the file and the body, and writing what was read."""
import json

import numpy as np
import pytest

from stablelego_jax.formats.blocks import is_scene_json, parse_scene_json, scene_to_json_dict
from stablelego_jax.formats.reader import load_layout, write_layout
from stablelego_jax.layout import Layout, LayoutError
from stablelego_jax.scene import BLOCK, BRICK, Scene

DOC = {
    "units": "m", "friction": 0.3,
    "blocks": {"a": {"center": [0.0, 0.0, 0.025], "size": [0.2, 0.1, 0.05], "yaw": 0.0, "mass": 0.5},
               "b": {"center": [0.05, 0.0, 0.075], "size": [0.2, 0.1, 0.05], "yaw": 12.5, "mass": 0.5}},
    "bricks": {"1": {"x": 30, "y": 0, "z": 0, "brick_id": 2, "ori": 1},
               "2": {"center": [31.0, 2.25], "yaw": 33.0, "z": 1, "brick_id": 9, "mass": 0.01},
               "p": {"center": [40.5, 1.0], "yaw": 0, "level": 0, "studs": [1, 2], "mass": 0.0004, "thickness": 1,
                     "part": "3023"}},
}


def test_reads_blocks_and_bricks_in_file_order(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(DOC))
    sc = load_layout(str(p))
    assert isinstance(sc, Scene) and sc.fmt == "blocks" and sc.friction == 0.3
    assert sc.keys == ("a", "b", "1", "2", "p")
    assert sc.kind.tolist() == [BLOCK, BLOCK, BRICK, BRICK, BRICK]
    np.testing.assert_allclose(sc.pos[2], [32.0, 1.0, 0.0])  # 2x4 with ori 1: 4 along x, 2 along y
    np.testing.assert_allclose(sc.size[2], [4, 2, 3])
    np.testing.assert_allclose(sc.pos[3], [31.0, 2.25, 3.0])
    assert sc.mass[3] == 0.01 and sc.yaw[3] == 33.0 and sc.brick_id[4] == "3023"
    np.testing.assert_allclose(sc.size[4], [1, 2, 1])


def test_write_then_read_gives_the_same_scene(tmp_path):
    p, q = tmp_path / "scene.json", tmp_path / "out.json"
    p.write_text(json.dumps(DOC))
    sc = load_layout(str(p))
    write_layout(sc, str(q))
    back = load_layout(str(q))
    assert back.keys == sc.keys and back.friction == sc.friction and back.brick_id == sc.brick_id
    for f in ("kind", "pos", "size", "yaw", "mass"):
        np.testing.assert_array_equal(getattr(back, f), getattr(sc, f))
    with pytest.raises(LayoutError, match="no text form"):
        write_layout(sc, str(tmp_path / "out.txt"))


def test_stablelego_json_with_a_rotated_brick_is_a_scene_and_writes_back_as_stablelego(tmp_path):
    doc = {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},
           "2": {"center": [1.5, 3.5], "yaw": 45, "z": 1, "brick_id": 5}}
    assert is_scene_json(doc) and not is_scene_json({"1": doc["1"]})
    sc = parse_scene_json(doc, source="x.json")
    assert sc.fmt == "json"
    out = scene_to_json_dict(sc)
    assert out == {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},
                   "2": {"center": [1.5, 3.5], "yaw": 45.0, "z": 1, "brick_id": 5}}
    p = tmp_path / "plain.json"
    p.write_text(json.dumps({"1": doc["1"]}))
    assert isinstance(load_layout(str(p)), Layout)


@pytest.mark.parametrize("change, msg", [
    ({"units": "mm"}, "units must be 'm'"),
    ({"friction": -1}, "friction must be a finite number >= 0"),
    ({"blocks": {"a": {"center": [0, 0], "size": [1, 1, 1], "mass": 1}}}, "block 'a': center must be a list of 3"),
    ({"blocks": {"a": {"center": [0, 0, 0.5], "size": [1, 1, 1]}}}, "block 'a': missing field"),
    ({"blocks": {"a": {"center": [0, 0, 0.5], "size": [1, 1, 1], "mass": 1, "colour": 3}}},
     "block 'a': unknown field"),
    ({"blocks": {"a": {"center": [0, 0, 0.4], "size": [1, 1, 1], "mass": 1}}}, "block 'a': lies below the ground"),
    ({"blocks": {"a": {"center": [0, 0, 0.5], "size": [1, -1, 1], "mass": 1}}}, "block 'a': size .* positive"),
    ({"blocks": {"a": {"center": [0, 0, 0.5], "size": [1, 1, 1], "mass": 0}}}, "block 'a': mass 0 kg must be"),
    ({"blocks": {"a": {"center": [0, 0, 0.5], "size": [1, 1, 1], "mass": 1},
                 "b": {"center": [0.5, 0, 0.5], "size": [1, 1, 1], "mass": 1}}}, "block 'b': overlaps block 'a'"),
    ({"bricks": {"1": {"center": [0, 0], "x": 1, "z": 0, "brick_id": 2}}}, "brick '1': give either center"),
    ({"bricks": {"1": {"center": [0, 0], "z": 0, "level": 0, "brick_id": 2}}}, "brick '1': give exactly one"),
    ({"bricks": {"1": {"center": [0, 0], "z": 0, "brick_id": 77}}}, "brick '1': unknown brick_id 77"),
    ({"bricks": {"1": {"center": [0, 0], "z": 0, "studs": [2, 2]}}}, "brick '1': a brick given by studs needs a mass"),
])
def test_errors_name_the_file_and_the_body(tmp_path, change, msg):
    doc = {"units": "m", "blocks": {"a": {"center": [0, 0, 0.5], "size": [1, 1, 1], "mass": 1}}}
    doc.update(change)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(LayoutError, match=f"bad.json: .*{msg}"):
        load_layout(str(p))
