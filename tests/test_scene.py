"""Scenes: validation of blocks and rotated bricks, unit conversion."""
import numpy as np
import pytest

from stablelego_jax.layout import LayoutError, brick_layout
from stablelego_jax.scene import BLOCK, BRICK, STUD_M, boxes, make_scene, scene_from_layout


def _blocks(pos, size=None, yaw=None, mass=None, keys=None):
    n = len(pos)
    return make_scene(keys or [f"b{i}" for i in range(n)], [BLOCK] * n, pos, size or [[0.2, 0.1, 0.05]] * n,
                      yaw or [0.0] * n, mass or [0.5] * n, source="s.json")


def test_touching_blocks_are_fine_and_overlapping_ones_are_named():
    _blocks([[0, 0, 0.025], [0.2, 0, 0.025], [0.05, 0, 0.075]])  # side by side and stacked
    _blocks([[0, 0, 0.025], [0.2 - 5e-10, 0, 0.025]])  # within the 1e-9 m tolerance
    with pytest.raises(LayoutError, match=r"s\.json: block 'b1': overlaps block 'b0'"):
        _blocks([[0, 0, 0.025], [0.2 - 1e-8, 0, 0.025]])
    # a 45-degree block whose corner pokes into its neighbour
    with pytest.raises(LayoutError, match="overlaps block"):
        _blocks([[0, 0, 0.025], [0.11, 0, 0.025]], size=[[0.1, 0.1, 0.05]] * 2, yaw=[0.0, 45.0])
    _blocks([[0, 0, 0.025], [0.1208, 0, 0.025]], size=[[0.1, 0.1, 0.05]] * 2, yaw=[0.0, 45.0])


@pytest.mark.parametrize("kw, msg", [
    (dict(size=[[0.2, 0.0, 0.05]]), "size .* must be positive"),
    (dict(mass=[0.0]), "mass 0 kg must be positive"),
    (dict(pos=[[0, 0, 0.02]]), "lies below the ground"),
    (dict(pos=[[0, float("nan"), 0.025]]), "position .* is not finite"),
    (dict(yaw=[float("inf")]), "yaw inf is not finite"),
])
def test_bad_blocks(kw, msg):
    args = dict(pos=[[0, 0, 0.025]])
    args.update(kw)
    with pytest.raises(LayoutError, match=f"s.json: block 'b0': {msg}"):
        _blocks(**args)


def test_bricks_of_one_layer_must_not_overlap_and_need_integer_sizes():
    ok = make_scene(["1", "2"], [BRICK] * 2, [[1, 2, 0], [1, 2, 3]], [[2, 4, 3]] * 2, [0, 45], [0.00216] * 2)
    assert ok.n == 2
    with pytest.raises(LayoutError, match="brick '2': overlaps brick '1'"):
        make_scene(["1", "2"], [BRICK] * 2, [[1, 2, 0], [2, 2, 0]], [[2, 4, 3]] * 2, [0, 45], [0.00216] * 2)
    with pytest.raises(LayoutError, match="brick '1': stud counts"):
        make_scene(["1"], [BRICK], [[1, 2, 0]], [[2.5, 4, 3]], [0], [0.001])
    with pytest.raises(LayoutError, match="bottom level -3 must be >= 0"):
        make_scene(["1"], [BRICK], [[1, 2, -3]], [[2, 4, 3]], [0], [0.001])
    with pytest.raises(LayoutError, match="duplicate key"):
        make_scene(["1", "1"], [BRICK] * 2, [[1, 2, 0], [5, 2, 0]], [[2, 4, 3]] * 2, [0, 0], [0.001] * 2)


def test_boxes_in_metres_and_scene_from_layout():
    lay = brick_layout([[0, 0, 0], [0, 0, 1]], [[2, 4], [4, 2]])
    sc = scene_from_layout(lay)
    centre, size, yaw = boxes(sc)
    np.testing.assert_allclose(centre[1], [2 * STUD_M, 1 * STUD_M, 1.5 * 0.0096])
    np.testing.assert_allclose(size[1], [4 * STUD_M, 2 * STUD_M, 0.0096])
    assert sc.keys == lay.keys and (yaw == 0).all() and (sc.kind == BRICK).all()
    assert sc.subset([1]).keys == ("2",)
