"""StableLego JSON and text layouts (stablelego_jax.formats.stablelego), the
reader by path (formats.reader) and the atomic writers (stablelego_jax.files)."""
import glob
import json
import math
import os
import shutil

import numpy as np
import pytest

from stablelego_jax.files import atomic_write_text
from stablelego_jax.formats import reader
from stablelego_jax.formats.reader import load_layout, write_layout
from stablelego_jax.formats.stablelego import layout_to_json_dict, layout_to_text, parse_json_layout, parse_text_layout
from stablelego_jax.layout import TABLE_I_MASS_KG, Library, default_library, make_layout

from conftest import SHARED_BRICKGPT as BRICKGPT, SHARED_REF as REF, needs_shared, raises_layout_error as _raises  # noqa: E402

NOT_LAYOUTS = {"config.json", "labels.json", "lego_library.json"}


def _ref_jsons():
    if not os.path.isdir(REF):
        return []
    return sorted(f for f in glob.glob(os.path.join(REF, "*.json")) if os.path.basename(f) not in NOT_LAYOUTS)


def _brickgpt_txts():
    if not os.path.isdir(BRICKGPT):
        return []
    return sorted(glob.glob(os.path.join(BRICKGPT, "*.txt")))


def _ids(paths):
    return [os.path.basename(p) for p in paths]


def _brick(x=0, y=0, z=0, bid=2, ori=0, **extra):
    d = {"x": x, "y": y, "z": z, "brick_id": bid, "ori": ori}
    d.update(extra)
    return d


def _write_json(tmp_path, obj, name="layout.json"):
    p = tmp_path / name
    p.write_text(json.dumps(obj))
    return str(p)


def _write_text(tmp_path, text, name="layout.txt"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def _same(a, b, keys=True):
    if keys:
        assert a.keys == b.keys
    assert a.pos.tolist() == b.pos.tolist()
    assert a.size.tolist() == b.size.tolist()
    np.testing.assert_allclose(a.mass, b.mass)


# ---------------------------------------------------------------------------
# reference files


@needs_shared
def test_reference_folder_has_layouts():
    assert len(_ref_jsons()) >= 8
    assert len(_brickgpt_txts()) >= 4


@needs_shared
@pytest.mark.parametrize("path", _ref_jsons(), ids=_ids(_ref_jsons()))
def test_reference_json_loads(path):
    with open(path) as fh:
        raw = json.load(fh)
    lay = load_layout(path)
    assert lay.fmt == "json"
    assert lay.source == path
    assert lay.keys == tuple(raw)  # exactly the file's keys, in file order
    lib = default_library()
    for i, k in enumerate(lay.keys):
        b = raw[k]
        assert lay.pos[i].tolist() == [b["x"], b["y"], b["z"]]
        h, w, m = lib.bricks[str(b["brick_id"])]
        assert lay.size[i].tolist() == ([h, w] if b["ori"] == 0 else [w, h])
        assert lay.mass[i] == m
        assert lay.brick_id[i] == str(b["brick_id"])
        assert lay.ori[i] == b["ori"]


@needs_shared
def test_reference_keys_not_in_numeric_order_are_kept():
    lay = load_layout(os.path.join(REF, "stick_heavy.json"))
    assert lay.keys[:3] == ("1", "2", "13")


@needs_shared
def test_reference_load_block():
    lay = load_layout(os.path.join(REF, "external_weight_fail.json"))
    assert lay.mass.max() == pytest.approx(0.2)  # id 1: the 200 g load block


@needs_shared
@pytest.mark.parametrize("path", _brickgpt_txts(), ids=_ids(_brickgpt_txts()))
def test_brickgpt_text_loads(path):
    with open(path) as fh:
        lines = fh.read().splitlines()
    lay = load_layout(path)
    assert lay.fmt == "text"
    assert lay.source == path
    want = [(i + 1, ln.strip()) for i, ln in enumerate(lines) if ln.strip() and not ln.strip().startswith("#")]
    assert lay.n == len(want)
    assert lay.keys == tuple(str(i) for i, _ in want)  # keys are line numbers
    for i, (_, ln) in enumerate(want):
        hw, xyz = ln.split(" ", 1)
        h, w = (int(v) for v in hw.split("x"))
        assert lay.size[i].tolist() == [h, w]
        assert lay.pos[i].tolist() == [int(v) for v in xyz.strip("()").split(",")]
        assert lay.mass[i] == TABLE_I_MASS_KG[(min(h, w), max(h, w))]
        bid = lay.brick_id[i]
        lh, lw, _ = default_library().bricks[bid]
        assert (lh, lw) == ((h, w) if lay.ori[i] == 0 else (w, h))


@needs_shared
@pytest.mark.parametrize("name", ["config.json", "labels.json", "lego_library.json"])
def test_non_layout_reference_json_is_rejected(name):
    path = os.path.join(REF, name)
    _raises(lambda: load_layout(path), path)


# ---------------------------------------------------------------------------
# dataset object folders


def test_dataset_folder(tmp_path):
    obj = {"5": _brick(0, 0, 0, 2, 0), "3": _brick(0, 0, 1, 12, 0), "4": _brick(1, 0, 2, 10, 1)}
    d = tmp_path / "object_0001"
    d.mkdir()
    (d / "task_graph.json").write_text(json.dumps(obj))
    np.save(d / "vox.npy", np.zeros((4, 4, 4), np.int32))
    np.save(d / "stability_score.npy", np.zeros((4, 4, 4)))
    lay = load_layout(str(d))
    assert lay.fmt == "dataset"
    assert lay.keys == ("5", "3", "4")
    assert lay.source == os.path.join(str(d), "task_graph.json")
    assert lay.size.tolist() == [[2, 4], [2, 2], [1, 1]]


@needs_shared
def test_dataset_folder_from_reference(tmp_path):
    d = tmp_path / "obj"
    d.mkdir()
    shutil.copy(os.path.join(REF, "stair_19.json"), d / "task_graph.json")
    lay = load_layout(str(d))
    _same(lay, load_layout(os.path.join(REF, "stair_19.json")))


def test_folder_without_task_graph(tmp_path):
    _raises(lambda: load_layout(str(tmp_path)), str(tmp_path), "task_graph.json")


def test_dataset_folder_errors_name_the_task_graph(tmp_path):
    (tmp_path / "task_graph.json").write_text(json.dumps({"9": _brick(bid=99)}))
    tg = os.path.join(str(tmp_path), "task_graph.json")
    e = _raises(lambda: load_layout(str(tmp_path)), tg, "'9'", "99")
    assert e.key == "9"


# ---------------------------------------------------------------------------
# JSON errors: the message names the file and, where there is one, the brick


def test_overlapping_bricks_json(tmp_path):
    p = _write_json(tmp_path, {"1": _brick(0, 0, 0), "2": _brick(1, 3, 0)})
    e = _raises(lambda: load_layout(p), p, "'1'", "'2'", "overlap")
    assert e.key == "2"


def test_overlap_respects_ori(tmp_path):
    # 2x4 with ori 1 spans 4 along x: x in [0, 4); a brick at x=3 overlaps, one at x=4 does not
    ok = _write_json(tmp_path, {"1": _brick(0, 0, 0, ori=1), "2": _brick(4, 0, 0, ori=1)}, "ok.json")
    assert load_layout(ok).n == 2
    bad = _write_json(tmp_path, {"1": _brick(0, 0, 0, ori=1), "2": _brick(3, 0, 0, ori=1)}, "bad.json")
    _raises(lambda: load_layout(bad), bad, "'2'", "overlap")


@pytest.mark.parametrize("bid", [7, 99, "x", 2.5, None, True])
def test_unknown_brick_id(tmp_path, bid):
    p = _write_json(tmp_path, {"1": _brick(), "b7": _brick(z=1, bid=bid)})
    e = _raises(lambda: load_layout(p), p, "'b7'", "brick_id")
    assert e.key == "b7"


def test_brick_id_as_string_is_accepted():
    lay = parse_json_layout({"1": _brick(bid="12")})
    assert lay.brick_id == ("12",)


@pytest.mark.parametrize("field, value", [("x", 1.5), ("y", 0.25), ("z", 2.5), ("x", "1"), ("y", None),
                                          ("z", True), ("x", [1])])
def test_non_integer_coordinates(tmp_path, field, value):
    b = _brick(z=1)
    b[field] = value
    p = _write_json(tmp_path, {"1": _brick(), "k": b})
    e = _raises(lambda: load_layout(p), p, "'k'", field, "not an integer")
    assert e.key == "k"


def test_nan_and_infinite_coordinates(tmp_path):
    for v in ("NaN", "Infinity"):
        p = tmp_path / f"{v}.json"
        p.write_text('{"k": {"x": %s, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}' % v)
        _raises(lambda: load_layout(str(p)), str(p), "'k'", "not an integer")


def test_integer_valued_float_coordinates_are_accepted():
    lay = parse_json_layout({"1": _brick(x=2.0, y=3.0, z=0.0)})
    assert lay.pos.tolist() == [[2, 3, 0]]


@pytest.mark.parametrize("field", ["x", "y", "z"])
def test_negative_coordinates(tmp_path, field):
    b = _brick(z=1)
    b[field] = -1
    p = _write_json(tmp_path, {"1": _brick(), "k": b})
    e = _raises(lambda: load_layout(p), p, "'k'", "negative")
    assert e.key == "k"


@pytest.mark.parametrize("field", ["x", "y", "z", "brick_id", "ori"])
def test_missing_field(tmp_path, field):
    b = _brick(z=1)
    del b[field]
    p = _write_json(tmp_path, {"1": _brick(), "k": b})
    e = _raises(lambda: load_layout(p), p, "'k'", "missing", field)
    assert e.key == "k"


def test_brick_not_an_object(tmp_path):
    p = _write_json(tmp_path, {"1": _brick(), "k": [0, 0, 0]})
    _raises(lambda: load_layout(p), p, "'k'", "not an object")


@pytest.mark.parametrize("ori", [2, -1, "0", None, True])
def test_bad_ori(tmp_path, ori):
    p = _write_json(tmp_path, {"k": _brick(ori=ori)})
    _raises(lambda: load_layout(p), p, "'k'", "ori")


@pytest.mark.parametrize("mass", ["NaN", "-0.001", "Infinity", '"heavy"', "true"])
def test_bad_per_brick_mass(tmp_path, mass):
    p = tmp_path / "m.json"
    p.write_text('{"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},'
                 ' "k": {"x": 0, "y": 0, "z": 1, "brick_id": 2, "ori": 0, "mass": %s}}' % mass)
    e = _raises(lambda: load_layout(str(p)), str(p), "'k'", "mass")
    assert e.key == "k"


def test_per_brick_mass_override():
    lay = parse_json_layout({"1": _brick(), "2": _brick(z=1, mass=0.05)})
    assert lay.mass.tolist() == [default_library().bricks["2"][2], 0.05]


@pytest.mark.parametrize("mass", ["NaN", "-0.002", "Infinity"])
def test_bad_mass_in_custom_library(tmp_path, mass):
    lib = tmp_path / "lib.json"
    lib.write_text('{"2": {"height": 2, "width": 4, "mass": %s}}' % mass)
    p = _write_json(tmp_path, {"1": _brick()})
    _raises(lambda: load_layout(p, library=str(lib)), str(lib), "'2'", "mass")


def test_custom_library(tmp_path):
    lib = tmp_path / "lib.json"
    lib.write_text(json.dumps({"7": {"height": 3, "width": 1, "mass": 0.01}}))
    p = _write_json(tmp_path, {"a": _brick(bid=7, ori=1)})
    for library in (str(lib), Library.from_json(str(lib))):
        lay = load_layout(p, library=library)
        assert lay.size.tolist() == [[1, 3]]
        assert lay.mass.tolist() == [0.01]
    # a brick id of the default library is unknown to the custom one
    p2 = _write_json(tmp_path, {"a": _brick(bid=2)}, "l2.json")
    _raises(lambda: load_layout(p2, library=str(lib)), p2, "'a'", str(lib))


def test_missing_library_file(tmp_path):
    p = _write_json(tmp_path, {"1": _brick()})
    lib = str(tmp_path / "nolib.json")
    _raises(lambda: load_layout(p, library=lib), lib)


def test_nan_mass_via_make_layout():
    _raises(lambda: make_layout(["q"], [(0, 0, 0)], [(2, 2)], [math.nan], source="mem.json"),
            "mem.json", "'q'", "mass")
    _raises(lambda: make_layout(["q"], [(0, 0, 0)], [(2, 2)], [-1.0], source="mem.json"),
            "mem.json", "'q'", "mass")


def test_empty_json_object(tmp_path):
    p = _write_json(tmp_path, {})
    e = _raises(lambda: load_layout(p), p, "empty")
    assert e.key is None


@pytest.mark.parametrize("text", ["[]", "[1, 2]", "3", '"x"', "null"])
def test_json_not_an_object(tmp_path, text):
    p = _write_text(tmp_path, text, "x.json")
    _raises(lambda: load_layout(p), p)


@pytest.mark.parametrize("text", ['{"1": {"x": 0,', "", "{'1': 2}", '{"1": }'])
def test_malformed_json(tmp_path, text):
    p = _write_text(tmp_path, text, "bad.json")
    _raises(lambda: load_layout(p), p, "JSON")


def test_not_utf8(tmp_path):
    p = tmp_path / "bin.json"
    p.write_bytes(b'\xff\xfe{"1": \x00\x81')
    _raises(lambda: load_layout(str(p)), str(p))


def test_nonexistent_file(tmp_path):
    for name in ("nope.json", "nope.txt", "nope"):
        p = str(tmp_path / name)
        _raises(lambda: load_layout(p), p, "no such file")


def test_parse_json_layout_in_memory_source():
    e = _raises(lambda: parse_json_layout({"z": _brick(x=-3)}), "<memory>", "'z'")
    assert e.source == "<memory>"


# ---------------------------------------------------------------------------
# text layouts


def test_text_basic_and_whitespace():
    lay = parse_text_layout("# a comment\n2x4 (0,0,0)\n\n  4x2( 1 , 0 ,1 )  \n1x1 (0, 0, 1)\n", "t.txt")
    assert lay.keys == ("2", "4", "5")  # line numbers, comments and blanks skipped
    assert lay.size.tolist() == [[2, 4], [4, 2], [1, 1]]
    assert lay.pos.tolist() == [[0, 0, 0], [1, 0, 1], [0, 0, 1]]
    assert lay.brick_id == ("2", "2", "10")
    assert lay.ori.tolist() == [0, 1, 0]
    assert lay.fmt == "text" and lay.source == "t.txt"


@pytest.mark.parametrize("hw", ["1x1", "1x2", "2x1", "1x4", "4x1", "1x6", "6x1", "1x8", "8x1",
                                "2x2", "2x4", "4x2", "2x6", "6x2"])
def test_text_all_library_sizes(hw):
    lay = parse_text_layout(f"{hw} (0,0,0)")
    h, w = (int(v) for v in hw.split("x"))
    assert lay.size.tolist() == [[h, w]]
    assert lay.mass[0] == TABLE_I_MASS_KG[(min(h, w), max(h, w))]
    lh, lw, lm = default_library().bricks[lay.brick_id[0]]
    assert lay.brick_id[0] != "1"  # never the 200 g load block
    assert (lh, lw) == ((h, w) if lay.ori[0] == 0 else (w, h))
    assert lm == pytest.approx(lay.mass[0])


def test_text_file_via_load_layout(tmp_path):
    p = _write_text(tmp_path, "2x2 (0,0,0)\n1x2 (0,0,1)\n")
    lay = load_layout(p)
    assert lay.n == 2 and lay.fmt == "text" and lay.source == p


def test_text_detected_without_txt_extension(tmp_path):
    p = _write_text(tmp_path, "2x2 (0,0,0)\n", "layout.dat")
    assert load_layout(p).fmt == "text"


def test_json_detected_without_json_extension(tmp_path):
    p = _write_text(tmp_path, json.dumps({"1": _brick()}), "layout.dat")
    assert load_layout(p).fmt == "json"


def test_unknown_format(tmp_path):
    p = _write_text(tmp_path, "hello\n", "layout.dat")
    _raises(lambda: load_layout(p), p, "format")


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "   \n# x\n"])
def test_empty_text_file(tmp_path, text):
    p = _write_text(tmp_path, text)
    e = _raises(lambda: load_layout(p), p, "empty")
    assert e.key is None


@pytest.mark.parametrize("line", ["2x4 0,0,0", "2x4 (0,0)", "brick (0,0,0)", "2 x (0,0,0)",
                                  "2x4 (0,0,0) extra", "2*4 (0,0,0)", "2x4 (a,0,0)", "2x4 (1e2,0,0)"])
def test_unparseable_text_line(tmp_path, line):
    p = _write_text(tmp_path, f"2x2 (9,9,0)\n{line}\n")
    e = _raises(lambda: load_layout(p), p, "line 2", "'2'", "cannot parse")
    assert e.key == "2"


@pytest.mark.parametrize("hw", ["3x3", "1x3", "2x3", "4x4", "0x2", "1x10", "2x8"])
def test_text_non_library_size(tmp_path, hw):
    p = _write_text(tmp_path, f"2x2 (9,9,0)\n{hw} (0,0,0)\n")
    e = _raises(lambda: load_layout(p), p, "line 2", hw, "not a library brick")
    assert e.key == "2"


@pytest.mark.parametrize("coord", ["-1", "-0.5"])
def test_text_negative_coordinate(tmp_path, coord):
    p = _write_text(tmp_path, f"2x2 (9,9,0)\n2x2 (0,{coord},0)\n")
    e = _raises(lambda: load_layout(p), p, "line 2")
    assert e.key == "2"


def test_text_non_integer_coordinate(tmp_path):
    p = _write_text(tmp_path, "2x2 (0,0.5,0)\n")
    _raises(lambda: load_layout(p), p, "line 1", "not an integer")


def test_text_integer_valued_float_is_accepted():
    assert parse_text_layout("2x2 (1.0,2.,0)").pos.tolist() == [[1, 2, 0]]


def test_text_overlap(tmp_path):
    p = _write_text(tmp_path, "2x4 (0,0,0)\n1x1 (0,0,1)\n1x2 (1,3,0)\n")
    e = _raises(lambda: load_layout(p), p, "'1'", "'3'", "overlap")
    assert e.key == "3"


@pytest.mark.parametrize("coord", ["1.2.3", ".", "1..0", "-.", "..", "-"])
def test_text_garbled_number(tmp_path, coord):
    p = _write_text(tmp_path, f"2x2 ({coord},0,0)\n")
    e = _raises(lambda: load_layout(p), p, "line 1", coord)
    assert e.key == "1"


@pytest.mark.parametrize("line", ["2x2 (" + "9" * 400 + ",0,0)", "2x2 (0,0," + "1" * 5000 + ")",
                                  "2x2 (65537,0,0)", "2x2 (0,1e9,0)"])
def test_text_huge_coordinate(tmp_path, line):
    p = _write_text(tmp_path, f"2x2 (9,9,0)\n{line}\n")
    e = _raises(lambda: load_layout(p), p, "line 2")
    assert e.key == "2"
    assert len(str(e)) < 400  # the garbage is not echoed in full


@pytest.mark.parametrize("hw", ["9" * 5000 + "x2", "2x" + "1" * 20])
def test_text_huge_brick_size(tmp_path, hw):
    p = _write_text(tmp_path, f"{hw} (0,0,0)\n")
    e = _raises(lambda: load_layout(p), p, "line 1", "not a library brick")
    assert len(str(e)) < 400


def test_text_leading_zeros_are_accepted():
    lay = parse_text_layout("0002x04 (00,0,0)")
    assert lay.size.tolist() == [[2, 4]] and lay.pos.tolist() == [[0, 0, 0]]


def test_text_largest_coordinate_is_accepted():
    lay = parse_text_layout("1x1 (65536,0,0)")
    assert lay.pos.tolist() == [[65536, 0, 0]]


def test_text_long_garbage_line_is_cut_in_message(tmp_path):
    p = _write_text(tmp_path, "x" * 100000 + "\n")
    e = _raises(lambda: load_layout(p), p, "line 1")
    assert len(str(e)) < 400


# ---------------------------------------------------------------------------
# writing


@needs_shared
@pytest.mark.parametrize("path", _ref_jsons(), ids=_ids(_ref_jsons()))
def test_json_round_trip_reference(tmp_path, path):
    lay = load_layout(path)
    out = str(tmp_path / "out.json")
    write_layout(lay, out)
    back = load_layout(out)
    _same(lay, back)
    assert back.brick_id == lay.brick_id
    assert back.ori.tolist() == lay.ori.tolist()
    with open(path) as fh:
        raw = json.load(fh)
    assert layout_to_json_dict(lay) == {k: {f: raw[k][f] for f in ("x", "y", "z", "brick_id", "ori")}
                                        for k in raw}


@needs_shared
@pytest.mark.parametrize("path", _brickgpt_txts(), ids=_ids(_brickgpt_txts()))
def test_text_round_trip_brickgpt(tmp_path, path):
    lay = load_layout(path)
    out = str(tmp_path / "out.txt")
    write_layout(lay, out)
    back = load_layout(out)
    _same(lay, back, keys=False)
    # through JSON too: text layouts carry library ids, so they can be written as JSON
    out_j = str(tmp_path / "out.json")
    write_layout(lay, out_j)
    back_j = load_layout(out_j)
    _same(lay, back_j)


def test_text_round_trip_keys_are_line_numbers(tmp_path):
    src = "# header\n2x4 (0,0,0)\n\n1x2 (0,0,1)\n"
    lay = parse_text_layout(src)
    assert lay.keys == ("2", "4")
    text = layout_to_text(lay)
    assert text == "2x4 (0,0,0)\n1x2 (0,0,1)\n"
    assert parse_text_layout(text).keys == ("1", "2")


def test_write_layout_format_choice(tmp_path):
    lay = parse_text_layout("2x4 (0,0,0)\n4x2 (0,0,1)\n")
    p = str(tmp_path / "a.json")
    write_layout(lay, p)
    assert json.loads(open(p).read()) == {
        "1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},
        "2": {"x": 0, "y": 0, "z": 1, "brick_id": 2, "ori": 1},
    }
    p = str(tmp_path / "a.txt")
    write_layout(lay, p)
    assert open(p).read() == "2x4 (0,0,0)\n4x2 (0,0,1)\n"
    p = str(tmp_path / "a.layout")
    write_layout(lay, p, fmt="text")
    assert open(p).read() == "2x4 (0,0,0)\n4x2 (0,0,1)\n"


def test_write_layout_from_make_layout_without_ids(tmp_path):
    lay = make_layout(["p", "q"], [(0, 0, 0), (0, 0, 1)], [(1, 8), (6, 2)], [3.03e-3, 3.23e-3])
    p = str(tmp_path / "m.json")
    write_layout(lay, p)
    back = load_layout(p)
    _same(lay, back)


def test_write_layout_overwrites(tmp_path):
    p = str(tmp_path / "w.txt")
    write_layout(parse_text_layout("2x2 (0,0,0)\n"), p)
    write_layout(parse_text_layout("1x1 (5,5,5)\n"), p)
    assert open(p).read() == "1x1 (5,5,5)\n"
    assert os.listdir(tmp_path) == ["w.txt"]


def test_json_round_trip_keeps_mass_override(tmp_path):
    lay = parse_json_layout({"1": _brick(), "2": _brick(z=1, mass=0.05)})
    d = layout_to_json_dict(lay)
    assert "mass" not in d["1"]  # library mass: not written
    assert d["2"]["mass"] == 0.05
    p = str(tmp_path / "o.json")
    write_layout(lay, p)
    back = load_layout(p)
    np.testing.assert_allclose(back.mass, lay.mass)
    assert back.brick_id == lay.brick_id


def test_json_round_trip_mass_without_brick_id(tmp_path):
    # make_layout without ids: a real 2x2 with an extra load gets id 12 and its mass
    lay = make_layout(["a", "b"], [(0, 0, 0), (0, 0, 1)], [(2, 2), (1, 2)], [0.1, TABLE_I_MASS_KG[(1, 2)]])
    p = str(tmp_path / "m.json")
    write_layout(lay, p)
    raw = json.loads(open(p).read())
    assert raw["a"]["brick_id"] == 12 and raw["a"]["mass"] == 0.1
    assert "mass" not in raw["b"]
    np.testing.assert_allclose(load_layout(p).mass, lay.mass)


@needs_shared
def test_json_round_trip_load_block(tmp_path):
    lay = load_layout(os.path.join(REF, "external_weight_fail.json"))
    assert "1" in lay.brick_id
    d = layout_to_json_dict(lay)
    assert not any("mass" in b for b in d.values())  # the load block's mass is its library mass
    p = str(tmp_path / "w.json")
    write_layout(lay, p)
    _same(load_layout(p), lay)


def test_write_non_library_brick_is_refused(tmp_path):
    lay = make_layout(["a"], [(0, 0, 0)], [(3, 3)], [1e-3])
    p = str(tmp_path / "n.json")
    _raises(lambda: write_layout(lay, p), p, "'a'", "3x3")
    assert not os.path.exists(p)
    assert os.listdir(tmp_path) == []
    _raises(lambda: layout_to_json_dict(lay), "<memory>", "'a'", "3x3")


@pytest.mark.parametrize("name", ["n.txt", "n.json"])
def test_write_non_library_brick_is_refused_both_formats(tmp_path, name):
    lay = make_layout(["ok", "bad"], [(0, 0, 0), (0, 0, 1)], [(2, 2), (1, 3)], [1.15e-3, 1e-3])
    p = str(tmp_path / name)
    e = _raises(lambda: write_layout(lay, p), p, "'bad'", "1x3")
    assert e.key == "bad"
    assert os.listdir(tmp_path) == []


def test_write_brick_id_that_does_not_match_size_is_refused(tmp_path):
    lay = make_layout(["a"], [(0, 0, 0)], [(1, 1)], [1e-3], brick_id=["2"], ori=[0])
    p = str(tmp_path / "x.json")
    _raises(lambda: write_layout(lay, p), p, "'a'", "brick_id")
    assert not os.path.exists(p)


def test_write_load_block_as_text_is_refused(tmp_path):
    lay = parse_json_layout({"1": _brick(), "w": _brick(z=1, bid=1)})
    p = str(tmp_path / "w.txt")
    e = _raises(lambda: write_layout(lay, p), p, "'w'", "load block")
    assert e.key == "w"
    assert not os.path.exists(p)
    # as JSON it is fine and round-trips
    pj = str(tmp_path / "w.json")
    write_layout(lay, pj)
    _same(load_layout(pj), lay)


def test_write_mass_override_as_text_is_refused(tmp_path):
    lay = parse_json_layout({"1": _brick(), "2": _brick(z=1, mass=0.05)})
    p = str(tmp_path / "m.txt")
    _raises(lambda: write_layout(lay, p), p, "'2'", "mass")
    assert not os.path.exists(p)


def test_write_layout_with_custom_library_id(tmp_path):
    lib = tmp_path / "lib.json"
    lib.write_text(json.dumps({"7": {"height": 3, "width": 1, "mass": 0.01}}))
    lay = load_layout(_write_json(tmp_path, {"a": _brick(bid=7, ori=1)}), library=str(lib))
    out = str(tmp_path / "out.json")
    write_layout(lay, out, library=str(lib))
    assert json.loads(open(out).read()) == {"a": {"x": 0, "y": 0, "z": 0, "brick_id": 7, "ori": 1}}
    # without that library the id is unknown: its mass is kept explicit
    out2 = str(tmp_path / "out2.json")
    write_layout(lay, out2)
    assert json.loads(open(out2).read())["a"]["mass"] == 0.01
    _same(load_layout(out2, library=str(lib)), lay)


def test_write_layout_unknown_format(tmp_path):
    with pytest.raises(ValueError):
        write_layout(parse_text_layout("2x2 (0,0,0)"), str(tmp_path / "a.x"), fmt="yaml")


def test_duplicate_json_keys(tmp_path):
    p = tmp_path / "dup.json"
    p.write_text('{"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},'
                 ' "1": {"x": 5, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}')
    e = _raises(lambda: load_layout(str(p)), str(p), "'1'", "duplicate brick key")
    assert e.key == "1"


def test_duplicate_json_keys_in_dataset_folder(tmp_path):
    (tmp_path / "task_graph.json").write_text('{"a": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},'
                                              ' "b": {"x": 0, "y": 0, "z": 1, "brick_id": 2, "ori": 0},'
                                              ' "a": {"x": 0, "y": 0, "z": 2, "brick_id": 2, "ori": 0}}')
    tg = os.path.join(str(tmp_path), "task_graph.json")
    e = _raises(lambda: load_layout(str(tmp_path)), tg, "'a'", "duplicate")
    assert e.key == "a"


def test_duplicate_field_in_a_brick(tmp_path):
    p = tmp_path / "dupf.json"
    p.write_text('{"k": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0, "x": 4}}')
    e = _raises(lambda: load_layout(str(p)), str(p), "'k'", "duplicate", "'x'")
    assert e.key == "k"


@pytest.mark.parametrize("text", ['{"k": {"x": %s, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}' % ("1" * 5000),
                                  '{"k": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0, "mass": %s}}' % ("1" * 400),
                                  '{"k": {"x": %s, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}' % ("1" * 400),
                                  '{"k": {"x": 65537, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}',
                                  '{"k": {"x": 0, "y": 1e300, "z": 0, "brick_id": 2, "ori": 0}}',
                                  "[" * 100000 + "]" * 100000])
def test_huge_json_numbers_and_nesting(tmp_path, text):
    p = _write_text(tmp_path, text, "big.json")
    e = _raises(lambda: load_layout(p), p)
    assert len(str(e)) < 400


# ---------------------------------------------------------------------------
# atomic_write_text


def test_atomic_write_text_writes(tmp_path):
    p = str(tmp_path / "f.txt")
    atomic_write_text(p, "hello\n")
    assert open(p).read() == "hello\n"
    assert os.listdir(tmp_path) == ["f.txt"]


def test_atomic_write_text_is_utf8(tmp_path, monkeypatch):
    import locale

    monkeypatch.setattr(locale, "getpreferredencoding", lambda *a, **k: "ascii")
    p = tmp_path / "u.txt"
    atomic_write_text(str(p), "Stein \u00e9\u2603\n")
    assert p.read_bytes() == "Stein \u00e9\u2603\n".encode("utf-8")


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_write_text_permissions(tmp_path, umask):
    old = os.umask(umask)
    try:
        p = str(tmp_path / "f.json")
        atomic_write_text(p, "{}\n")
        plain = str(tmp_path / "plain")
        open(plain, "w").close()
    finally:
        os.umask(old)
    assert os.stat(p).st_mode & 0o777 == 0o666 & ~umask
    assert os.stat(p).st_mode & 0o777 == os.stat(plain).st_mode & 0o777
    assert os.umask(old) == old  # restored
    os.umask(old)


def test_atomic_write_text_failure_leaves_no_file(tmp_path):
    p = str(tmp_path / "f.txt")
    with pytest.raises(TypeError):
        atomic_write_text(p, 12345)  # not text: fh.write raises inside the try
    assert os.listdir(tmp_path) == []  # neither the target nor a temp file


def test_atomic_write_text_failure_keeps_old_file(tmp_path):
    p = str(tmp_path / "f.txt")
    atomic_write_text(p, "old\n")
    with pytest.raises(UnicodeEncodeError):
        atomic_write_text(p, "x" * 100000 + "\udcff")  # lone surrogate: cannot be encoded
    assert open(p).read() == "old\n"
    assert os.listdir(tmp_path) == ["f.txt"]


def test_atomic_write_text_interrupted(tmp_path, monkeypatch):
    p = str(tmp_path / "f.txt")

    def fail_replace(src, dst):
        raise OSError("disk on fire")

    monkeypatch.setattr(os, "replace", fail_replace)
    with pytest.raises(OSError):
        atomic_write_text(p, "data\n")
    assert os.listdir(tmp_path) == []


def test_write_layout_failure_leaves_no_file(tmp_path, monkeypatch):
    lay = parse_text_layout("2x2 (0,0,0)\n")
    p = str(tmp_path / "l.json")

    def boom(layout):
        raise RuntimeError("boom")

    monkeypatch.setattr(reader, "layout_to_json_dict", boom)
    with pytest.raises(RuntimeError):
        write_layout(lay, p)
    assert os.listdir(tmp_path) == []


def test_atomic_write_text_missing_directory(tmp_path):
    p = str(tmp_path / "no" / "such" / "f.txt")
    with pytest.raises(OSError):
        atomic_write_text(p, "x")
    assert not os.path.exists(os.path.dirname(p))
