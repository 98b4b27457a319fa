"""Validation in stablelego_jax.layout: make_layout, Library, occupancy."""
import json
import math
import os

import numpy as np
import pytest

from stablelego_jax.layout import (
    MAX_COORD,
    MAX_GRID_CELLS,
    MAX_SIZE,
    TABLE_I_MASS_KG,
    Layout,
    LayoutError,
    Library,
    cells_of,
    default_library,
    make_layout,
)

from conftest import SHARED_REF as REF, needs_shared, raises_layout_error as _raises  # noqa: E402

SRC = "/some/dir/layout.json"


def _two(pos2=(4, 0, 0), size2=(2, 4), mass2=2.16e-3, keys=("a", "b")):
    return make_layout(keys, [(0, 0, 0), pos2], [(2, 4), size2], [2.16e-3, mass2], source=SRC)


# ---------------------------------------------------------------------------
# valid layouts


def test_make_layout_basic():
    lay = make_layout(
        ["1", "2"], [(0, 0, 0), (1, 0, 1)], [(2, 4), (1, 2)], [2.16e-3, 0.81e-3],
        brick_id=["2", "9"], ori=[0, 0], source=SRC, fmt="json",
    )
    assert isinstance(lay, Layout)
    assert lay.n == 2
    assert lay.keys == ("1", "2")
    assert lay.pos.dtype == np.int64 and lay.pos.tolist() == [[0, 0, 0], [1, 0, 1]]
    assert lay.size.dtype == np.int64 and lay.size.tolist() == [[2, 4], [1, 2]]
    assert lay.mass.dtype == np.float64
    assert lay.brick_id == ("2", "9")
    assert lay.ori.tolist() == [0, 0]
    assert lay.source == SRC and lay.fmt == "json"


def test_keys_become_strings_and_keep_order():
    lay = make_layout([10, 2, 7], [(0, 0, 0), (0, 0, 1), (0, 0, 2)], [(1, 1)] * 3, [1e-3] * 3)
    assert lay.keys == ("10", "2", "7")


def test_defaults_for_brick_id_and_ori():
    lay = make_layout(["a"], [(0, 0, 0)], [(3, 3)], [1e-3])
    assert lay.brick_id == ("",)
    assert lay.ori.tolist() == [0]
    assert lay.source == "<memory>" and lay.fmt == "memory"


def test_integer_valued_floats_are_accepted():
    lay = make_layout(["a"], [(1.0, 2.0, 3.0)], [(2.0, 2.0)], [0])
    assert lay.pos.tolist() == [[1, 2, 3]]
    assert lay.size.tolist() == [[2, 2]]
    assert lay.mass.tolist() == [0.0]  # zero mass is allowed


def test_touching_bricks_are_not_an_overlap():
    lay = _two(pos2=(2, 0, 0))  # side by side along x
    assert lay.n == 2
    lay = _two(pos2=(0, 0, 1))  # directly on top
    assert lay.n == 2


def test_occupancy_grid():
    lay = make_layout(["a", "b"], [(0, 0, 0), (1, 1, 1)], [(2, 3), (1, 1)], [1e-3, 1e-3])
    occ = lay.occupancy()
    assert occ.shape == (2, 3, 2)
    assert occ.dtype == np.int32
    assert (occ[:, :, 0] == 0).all()
    assert occ[1, 1, 1] == 1
    assert (occ[:, :, 1] >= 0).sum() == 1


def test_cells_of_matches_brute_force():
    rng = np.random.default_rng(0)
    pos = rng.integers(0, 10, (20, 3))
    size = rng.integers(1, 5, (20, 2))
    cells, owner = cells_of(pos, size)
    want = []
    for i, ((x, y, z), (sx, sy)) in enumerate(zip(pos, size)):
        want += [(x + dx, y + dy, z, i) for dx in range(sx) for dy in range(sy)]
    got = [tuple(c) + (o,) for c, o in zip(cells.tolist(), owner.tolist())]
    assert sorted(got) == sorted(want)


def test_subset():
    lay = make_layout(["a", "b", "c"], [(0, 0, 0), (0, 0, 1), (0, 0, 2)], [(1, 2), (2, 2), (1, 1)],
                      [1.0, 2.0, 3.0], brick_id=["9", "12", "10"], ori=[0, 0, 0])
    sub = lay.subset([2, 0])
    assert sub.keys == ("c", "a")
    assert sub.pos.tolist() == [[0, 0, 2], [0, 0, 0]]
    assert sub.size.tolist() == [[1, 1], [1, 2]]
    assert sub.mass.tolist() == [3.0, 1.0]
    assert sub.brick_id == ("10", "9")


# ---------------------------------------------------------------------------
# LayoutError


def test_layout_error_attributes_and_message():
    e = LayoutError("f.json", "bad thing", "7")
    assert isinstance(e, ValueError)
    assert e.source == "f.json" and e.key == "7"
    assert str(e) == "f.json: brick '7': bad thing"
    e = LayoutError("f.json", "bad thing")
    assert e.key is None
    assert str(e) == "f.json: bad thing"


# ---------------------------------------------------------------------------
# make_layout errors: every message names the source and the brick


def test_empty_layout():
    e = _raises(lambda: make_layout([], np.zeros((0, 3)), np.zeros((0, 2)), [], source=SRC), SRC, "empty")
    assert e.key is None


def test_duplicate_keys():
    e = _raises(lambda: _two(keys=("a", "a")), SRC, "'a'", "duplicate")
    assert e.key == "a"


@pytest.mark.parametrize("pos2, size2", [((1, 0, 0), (2, 4)), ((1, 2, 0), (2, 2)),
                                         ((0, 0, 0), (2, 2)), ((1, 3, 0), (1, 1))])
def test_overlap(pos2, size2):
    e = _raises(lambda: _two(pos2=pos2, size2=size2), SRC, "overlaps", "'a'", "'b'")
    assert e.key == "b"  # the later brick is the one at fault


def test_overlap_names_the_cell():
    _raises(lambda: _two(pos2=(1, 3, 0), size2=(1, 1)), "(1, 3, 0)")


def test_overlap_among_many():
    n = 50
    pos = [(0, 0, z) for z in range(n)] + [(1, 1, 25)]
    keys = [f"k{i}" for i in range(n + 1)]
    e = _raises(lambda: make_layout(keys, pos, [(2, 2)] * (n + 1), [1e-3] * (n + 1), source=SRC),
                "k25", "k50")
    assert e.key == "k50"


@pytest.mark.parametrize("bad", [(0.5, 0, 0), (0, 1.25, 0), (0, 0, 2.5), (math.nan, 0, 0),
                                 (math.inf, 0, 0)])
def test_non_integer_coordinates(bad):
    e = _raises(lambda: _two(pos2=bad), SRC, "'b'", "non-integer coordinates")
    assert e.key == "b"


@pytest.mark.parametrize("bad", [(-1, 0, 0), (0, -4, 0), (0, 0, -1)])
def test_negative_coordinates(bad):
    e = _raises(lambda: _two(pos2=bad), SRC, "'b'", "negative")
    assert e.key == "b"


@pytest.mark.parametrize("bad", [(0, 2), (2, 0), (-1, 2), (1.5, 2), (math.nan, 1)])
def test_bad_sizes(bad):
    e = _raises(lambda: _two(pos2=(8, 0, 0), size2=bad), SRC, "'b'", "size")
    assert e.key == "b"


@pytest.mark.parametrize("bad", [math.nan, -1e-3, math.inf, -math.inf])
def test_bad_mass(bad):
    e = _raises(lambda: _two(mass2=bad), SRC, "'b'", "mass")
    assert e.key == "b"


@pytest.mark.parametrize("bad", [(MAX_COORD + 1, 0, 0), (0, 2**40, 0), (0, 0, 1e18), (0, 0, 2**16 + 1)])
def test_coordinates_too_large(bad):
    e = _raises(lambda: _two(pos2=bad), SRC, "'b'", "too large", str(MAX_COORD))
    assert e.key == "b"


def test_largest_coordinates_are_accepted():
    lay = _two(pos2=(MAX_COORD, MAX_COORD, 0))
    assert lay.pos[1].tolist() == [MAX_COORD, MAX_COORD, 0]
    lay = _two(pos2=(0, 0, MAX_COORD))
    assert lay.pos[1].tolist() == [0, 0, MAX_COORD]


@pytest.mark.parametrize("bad", [(MAX_SIZE + 1, 1), (1, 10**6), (2**40, 2**40)])
def test_sizes_too_large(bad):
    e = _raises(lambda: _two(pos2=(8, 0, 0), size2=bad), SRC, "'b'", "too large", str(MAX_SIZE))
    assert e.key == "b"


def test_largest_size_is_accepted():
    lay = _two(pos2=(8, 0, 0), size2=(MAX_SIZE, MAX_SIZE))
    assert lay.size[1].tolist() == [MAX_SIZE, MAX_SIZE]


def test_far_apart_bricks_validate_without_a_dense_grid():
    # make_layout checks overlap sparsely; only occupancy() builds the dense grid, and refuses a huge one
    lay = _two(pos2=(MAX_COORD, MAX_COORD, MAX_COORD))
    assert lay.n == 2
    _raises(lay.occupancy, SRC, "grid", str(MAX_GRID_CELLS))
    # overlap among far-apart bricks is still found
    far = MAX_COORD - 1
    _raises(lambda: make_layout(["a", "b", "c"], [(0, 0, 0), (far, far, far), (far + 1, far + 1, far)],
                                [(1, 1), (2, 2), (1, 1)], [1e-3] * 3, source=SRC), SRC, "'c'", "overlaps")


@pytest.mark.parametrize("ori", [[0, 2], [-1, 0], [0, 0.5], [math.nan, 0], [0, 1, 0]])
def test_bad_ori(ori):
    e = _raises(lambda: make_layout(["a", "b"], [(0, 0, 0), (0, 0, 1)], [(1, 1)] * 2, [1e-3] * 2, ori=ori,
                                    source=SRC), SRC, "ori")
    if len(ori) == 2:
        assert e.key == ("a" if ori[0] != 0 else "b")


def test_ori_accepts_bools_and_floats():
    lay = make_layout(["a", "b"], [(0, 0, 0), (0, 0, 1)], [(1, 1)] * 2, [1e-3] * 2, ori=np.array([1.0, 0.0]))
    assert lay.ori.dtype == np.int64 and lay.ori.tolist() == [1, 0]


@pytest.mark.parametrize("bid", [["2"], ["2", "9", "10"], "29", []])
def test_brick_id_length(bid):
    _raises(lambda: make_layout(["a", "b"], [(0, 0, 0), (0, 0, 1)], [(1, 1)] * 2, [1e-3] * 2, brick_id=bid,
                                source=SRC), SRC, "brick_id")


@pytest.mark.parametrize("field, value", [("pos", [(0, 0, 0)]), ("pos", [(0, 0), (0, 1)]), ("size", [(1, 1)]),
                                          ("mass", [1e-3]), ("pos", [("q", 0, 0), (0, 0, 1)]),
                                          ("mass", [None, {}]), ("pos", [(10**400, 0, 0), (0, 0, 1)])])
def test_bad_array_shapes_and_types(field, value):
    args = {"pos": [(0, 0, 0), (0, 0, 1)], "size": [(1, 1)] * 2, "mass": [1e-3] * 2}
    args[field] = value
    _raises(lambda: make_layout(["a", "b"], args["pos"], args["size"], args["mass"], source=SRC), SRC)


def test_layout_error_keeps_bare_message():
    e = LayoutError("f.json", "bad thing", "7")
    assert e.message == "bad thing"


def test_first_bad_brick_is_named():
    keys = ["a", "b", "c", "d"]
    pos = [(0, 0, 0), (0, 0, 1), (0, 0, -1), (0, 0, -2)]
    e = _raises(lambda: make_layout(keys, pos, [(1, 1)] * 4, [1e-3] * 4, source=SRC), "'c'")
    assert e.key == "c"


# ---------------------------------------------------------------------------
# Library


def test_default_library_contents():
    lib = default_library()
    assert lib is default_library()  # cached
    assert lib.bricks["1"] == (2, 2, 0.2)  # the 200 g load block
    real = {k: v for k, v in lib.bricks.items() if k != "1"}
    assert len(real) == len(TABLE_I_MASS_KG)
    for h, w, m in real.values():
        assert m == pytest.approx(TABLE_I_MASS_KG[(min(h, w), max(h, w))])


@needs_shared
def test_default_library_is_the_reference_library():
    with open(os.path.join(REF, "lego_library.json")) as fh:
        raw = json.load(fh)
    lib = default_library()
    assert list(lib.bricks) == list(raw)
    for k, e in raw.items():
        assert lib.bricks[k] == (e["height"], e["width"], e["mass"])


def test_library_from_dict_extra_fields_ignored():
    lib = Library.from_dict({"7": {"height": 1, "width": 3, "mass": 0.001, "inventory": 5}}, source="L")
    assert lib.bricks == {"7": (1, 3, 0.001)}
    assert lib.source == "L"


@pytest.mark.parametrize(
    "raw, words",
    [
        ({}, ["non-empty"]),
        ([], ["non-empty"]),
        ({"7": 3}, ["'7'", "not an object"]),
        ({"7": {"height": 1, "width": 3}}, ["'7'", "mass"]),
        ({"7": {"width": 3, "mass": 1e-3}}, ["'7'", "height"]),
        ({"7": {"height": 0, "width": 3, "mass": 1e-3}}, ["'7'", "size"]),
        ({"7": {"height": 1.5, "width": 3, "mass": 1e-3}}, ["'7'", "size"]),
        ({"7": {"height": True, "width": 3, "mass": 1e-3}}, ["'7'", "size"]),
        ({"7": {"height": 1, "width": 3, "mass": math.nan}}, ["'7'", "mass"]),
        ({"7": {"height": 1, "width": 3, "mass": -1e-3}}, ["'7'", "mass"]),
        ({"7": {"height": 1, "width": 3, "mass": math.inf}}, ["'7'", "mass"]),
        ({"7": {"height": 1, "width": 3, "mass": "1"}}, ["'7'", "mass"]),
        ({"7": {"height": 1, "width": 3, "mass": None}}, ["'7'", "mass"]),
    ],
)
def test_library_from_dict_errors(raw, words):
    _raises(lambda: Library.from_dict(raw, source="lib.json"), "lib.json", *words)


def test_library_from_json_errors(tmp_path):
    missing = str(tmp_path / "nope.json")
    _raises(lambda: Library.from_json(missing), missing, "cannot read")
    bad = tmp_path / "bad.json"
    bad.write_text('{"2": {"height": 2,')
    _raises(lambda: Library.from_json(str(bad)), str(bad), "JSON")
    nan = tmp_path / "nan.json"
    nan.write_text('{"2": {"height": 2, "width": 4, "mass": NaN}}')
    _raises(lambda: Library.from_json(str(nan)), str(nan), "'2'", "mass")


def test_library_from_json_ok(tmp_path):
    p = tmp_path / "lib.json"
    p.write_text(json.dumps({"2": {"height": 2, "width": 4, "mass": 0.5}}))
    lib = Library.from_json(str(p))
    assert lib.bricks == {"2": (2, 4, 0.5)}
    assert lib.source == str(p)
