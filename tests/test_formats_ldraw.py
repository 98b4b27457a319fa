"""LDraw export and import (stablelego_jax.formats.ldraw)."""
import os

import numpy as np
import pytest

from stablelego_jax.generate.procedural import bridge, pallet_of_boxes, stairs, tower
from stablelego_jax.generate.voxels import merge_voxels, random_voxel_shape
from stablelego_jax import load_layout, make_layout
from stablelego_jax.layout import LayoutError
from stablelego_jax.formats.ldraw import PARTS, layout_to_ldr, parse_ldr, read_ldr, write_ldr

HERE = os.path.dirname(os.path.abspath(__file__))
BRICKGPT = os.path.join(HERE, "..", "examples", "brickgpt")
SHARED = os.path.join(HERE, "..", "..", "shared", "reference", "brickgpt")


def _guitar(ext):
    for d in (BRICKGPT, SHARED):
        p = os.path.join(d, "guitar" + ext)
        if os.path.isfile(p):
            return p
    pytest.skip("guitar reference files not available")


def _placements(text):
    """(colour, X, Y, Z, rotation, part) of every type-1 line, parsed."""
    out = []
    for line in text.splitlines():
        t = line.split()
        if t and t[0] == "1":
            out.append((int(t[1]), *(float(v) for v in t[2:5]), tuple(float(v) for v in t[5:14]),
                        t[14].lower().removesuffix(".dat")))
    return out


def _same(a, b):
    """Same bricks under the same keys (the file lists them bottom layer first)."""
    assert sorted(a.keys) == sorted(b.keys)
    if a.keys != b.keys:
        where = {k: i for i, k in enumerate(b.keys)}
        b = b.subset([where[k] for k in a.keys])
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.size, b.size)
    assert np.array_equal(a.mass, b.mass)
    assert a.brick_id == b.brick_id and np.array_equal(a.ori, b.ori)


def test_guitar_matches_brickgpt_ldr():
    guitar = load_layout(_guitar(".txt"))
    ref = open(_guitar(".ldr")).read()
    ours = layout_to_ldr(guitar)  # default: header, one step per layer, lower-case .dat
    assert _placements(ours) == _placements(ref)
    # BrickGPT's own style (no header, a step per brick, .DAT) reproduces the file byte for byte
    assert layout_to_ldr(guitar, header=False, step="brick", part_suffix=".DAT") == ref
    # and importing BrickGPT's file gives the text layout back
    _same(read_ldr(_guitar(".ldr")), guitar)


def test_steps_per_layer_and_header(tmp_path):
    lay = stairs(4)
    text = layout_to_ldr(lay, title="four stairs")
    lines = text.splitlines()
    assert lines[0] == "0 four stairs" and lines[1] == "0 Name: layout.ldr" and lines[2].startswith("0 Author:")
    assert text.count("0 STEP") == 4  # one per layer
    assert layout_to_ldr(lay, step="none").count("STEP") == 0
    assert layout_to_ldr(lay, step="brick").count("0 STEP") == lay.n
    path = tmp_path / "stairs.ldr"
    write_ldr(lay, str(path))
    assert "0 Name: stairs.ldr" in path.read_text()
    assert all(ln.split()[-1] == "3001.dat" for ln in lines if ln.startswith("1 "))
    with pytest.raises(ValueError):
        layout_to_ldr(lay, step="sometimes")


def test_colours():
    lay = stairs(3)
    assert {p[0] for p in _placements(layout_to_ldr(lay, color=4))} == {4}
    assert [p[0] for p in _placements(layout_to_ldr(lay, colors=[0, 4, 15]))] == [0, 4, 15]


@pytest.mark.parametrize("make", [
    lambda: stairs(5, load_kg=0.2),  # a 200 g load block: mass and library id "1" must survive
    lambda: tower(6, (4, 2), lean=1, seed=2),
    lambda: bridge(span=5, height=3, width=2),
    lambda: pallet_of_boxes(4, seed=1, pallet=(10, 8)),
    lambda: merge_voxels(random_voxel_shape(4, grid=10, kind="arch"), seed=1),
])
def test_round_trip(tmp_path, make):
    lay = make()
    path = str(tmp_path / "x.ldr")
    write_ldr(lay, path)
    _same(read_ldr(path), lay)
    _same(load_layout(path), lay)  # the generic reader dispatches .ldr here
    for step in ("brick", "none"):
        _same(parse_ldr(layout_to_ldr(lay, step=step, header=False)), lay)


def test_round_trip_keeps_keys_order_and_odd_ori():
    lay = make_layout(["top", "b", "a"], [(0, 0, 1), (0, 0, 0), (2, 0, 0)], [(2, 2), (2, 1), (1, 2)],
                      [1.15e-3, 0.81e-3, 0.5], brick_id=["12", "9", "9"], ori=[1, 1, 0])
    text = layout_to_ldr(lay)
    back = parse_ldr(text)
    assert back.keys == ("b", "a", "top")  # bottom layer first in the file
    _same(back, lay)
    assert "stablelego" in text  # keys, the odd ori and the 0.5 kg mass travel as comments


def test_import_foreign_models(tmp_path):
    # LeoCAD-style: built on the ground plane (bottom bricks at Y = -24),
    # centred on the origin, lattice shifted by half a stud, mirrored turn.
    text = "\n".join([
        "0 FILE model.ldr",
        "0 Untitled",
        "0 // a comment",
        "1 4 -30 -24 -10 1 0 0 0 1 0 0 0 1 parts\\3001.DAT",   # 2x4 along x
        "1 14 -40 -48 10 0 0 -1 0 1 0 1 0 0 3010.dat",          # 1x4 along LDraw Z
        "0 STEP",
        "",
    ])
    lay = parse_ldr(text, source="model.ldr")
    assert lay.fmt == "ldr"
    assert lay.size.tolist() == [[4, 2], [1, 4]]
    assert lay.pos[:, 2].tolist() == [0, 1]  # dropped onto the baseplate
    assert (lay.pos >= 0).all()
    # brick 2 sits on the stud lattice of brick 1: one stud right of its left end, flush at the back
    assert (lay.pos[1, :2] - lay.pos[0, :2]).tolist() == [1, 0]
    kept = parse_ldr(text, ground=False)
    assert kept.pos[:, 2].tolist() == [1, 2]


@pytest.mark.parametrize("line, needle", [
    ("1 4 0 0 0 1 0 0 0 1 0 0 0 1 3039.dat", "3039"),  # a slope: not a basic brick
    ("1 4 0 0 0 1 0 0 0 1 0 0 0 1 house.ldr", "house.ldr"),  # a submodel
    ("1 4 0 0 0 1 0 0 0 0.7071 -0.7071 0 0.7071 0.7071 3001.dat", "tilted"),
    ("1 4 0 0 0 1 0 0 0 -1 0 0 0 -1 3001.dat", "upside down"),
    ("1 4 0 0 0 3001.dat", "15 fields"),
    ("1 4 0 0 zero 1 0 0 0 1 0 0 0 1 3001.dat", "not a number"),
    ("3 4 0 0 0 1 0 0 0 1 0 0 0 1", "primitive"),
    ("0 // stablelego {not json", "stablelego comment"),
])
def test_import_errors_name_file_line_and_part(line, needle):
    text = "1 4 40 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n" + line + "\n"
    with pytest.raises(LayoutError) as ei:
        parse_ldr(text, source="bad.ldr")
    msg = str(ei.value)
    assert msg.startswith("bad.ldr") and needle in msg and "line 2" in msg


def test_import_errors_grid_overlap_empty(tmp_path):
    off_grid = "1 4 40 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n1 4 47 -24 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n"
    with pytest.raises(LayoutError, match="stud grid"):
        parse_ldr(off_grid, source="g.ldr")
    overlap = "1 4 40 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n1 4 60 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n"
    with pytest.raises(LayoutError, match="overlaps"):
        parse_ldr(overlap, source="o.ldr")
    with pytest.raises(LayoutError, match="no brick parts"):
        parse_ldr("0 empty model\n0 STEP\n", source="e.ldr")
    p = tmp_path / "missing.ldr"
    with pytest.raises(LayoutError, match="missing.ldr"):
        load_layout(str(p))


def test_export_error_for_sizes_without_a_part(tmp_path):
    lay = make_layout(["1", "odd"], [(0, 0, 0), (0, 2, 0)], [(2, 2), (3, 3)], [1e-3, 1e-3])
    path = tmp_path / "odd.ldr"
    with pytest.raises(LayoutError) as ei:
        write_ldr(lay, str(path))
    assert str(ei.value).startswith(str(path)) and "'odd'" in str(ei.value) and "3x3" in str(ei.value)
    assert not path.exists()


def test_every_part_both_ways():
    keys, pos, size, mass = [], [], [], []
    x = 0
    for (a, b) in PARTS:
        for s in ((a, b), (b, a)):
            keys.append(str(len(keys) + 1))
            pos.append((x, 0, 0))
            size.append(s)
            mass.append(0.001)
            x += max(s) + 1
    lay = make_layout(keys, pos, size, mass)
    back = parse_ldr(layout_to_ldr(lay))
    assert np.array_equal(back.pos, lay.pos) and np.array_equal(back.size, lay.size)
    parts = [p[-1] for p in _placements(layout_to_ldr(lay))]
    assert parts == [PARTS[tuple(sorted(s))] for s in size]
