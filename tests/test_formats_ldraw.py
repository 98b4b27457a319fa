"""LDraw export and import (stablelego_jax.formats.ldraw, formats.ldraw_parts)."""
import dataclasses
import json
import os

import numpy as np
import pytest

from stablelego_jax.generate.procedural import bridge, pallet_of_boxes, stairs, tower
from stablelego_jax.generate.voxels import merge_voxels, random_voxel_shape
from stablelego_jax import load_layout, make_layout
from stablelego_jax.layout import LayoutError
from stablelego_jax.contacts import scene_contacts
from stablelego_jax.formats.ldraw import PARTS, layout_to_ldr, parse_ldr, read_ldr, write_ldr
from stablelego_jax.formats.ldraw_parts import LDRAW_PARTS, part_mass, part_number
from stablelego_jax.layout import TABLE_I_MASS_KG
from stablelego_jax.scene import Scene, make_scene

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
    ("1 4 0 0 0 1 0 0 0 1 0 0 0 1 house.ldr", "house.ldr (missing sub-model)"),
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


def test_import_off_grid_overlap_empty(tmp_path):
    # a brick off the stud grid is placed where the file puts it, joined to nothing
    off_grid = "1 4 40 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n1 4 47 -24 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n"
    sc = parse_ldr(off_grid, source="g.ldr")
    assert isinstance(sc, Scene) and sc.pos.tolist() == [[2, 1, 0], [2.35, 1, 3]]
    assert set(scene_contacts(sc).knob_pair[:, 1].tolist()) == {2}  # only the baseplate under brick 1
    overlap = "1 4 40 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n1 4 60 0 20 -1 0 0 0 1 0 0 0 -1 3001.dat\n"
    with pytest.raises(LayoutError, match=r"^o.ldr: brick '2': line 2: part 3001 overlaps part 3001 \(line 1\)"):
        parse_ldr(overlap, source="o.ldr")
    report = {}
    assert parse_ldr(overlap, skip_unsupported=True, report=report).n == 1
    assert report == {"3001 overlapping another part": [1, "line 2"]}
    with pytest.raises(LayoutError, match="no brick parts"):
        parse_ldr("0 empty model\n0 STEP\n", source="e.ldr")
    only_unsupported = "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3039.dat\n1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3039.dat\n"
    with pytest.raises(LayoutError, match=r"^s.ldr: nothing left to analyse: 2 parts cannot be modelled: 3039 x2"):
        parse_ldr(only_unsupported, source="s.ldr", skip_unsupported=True)
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


# ---- LDraw as people write it (issue 22): .mpd, plates, other sizes, unsupported parts

# a tower (2x4 brick, 2x4 plate on it, 2x4 brick on the plate; origins at the
# top of each part, -Y up), placed twice: as is, and turned a quarter about
# the vertical and moved 100 LDU along X, 40 along Z
TOWER = """0 FILE tower.ldr
0 tower
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
1 4 0 -32 0 1 0 0 0 1 0 0 0 1 3001.dat
0 NOFILE
"""
MAIN = """0 FILE main.ldr
0 Main model
1 16 0 0 0 1 0 0 0 1 0 0 0 1 tower.ldr
1 16 100 0 40 0 0 1 0 1 0 -1 0 0 Tower.ldr
0 NOFILE
"""
FLAT = """1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
1 4 0 -32 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 100 0 40 0 0 1 0 1 0 -1 0 0 3001.dat
1 4 100 -8 40 0 0 1 0 1 0 -1 0 0 3020.dat
1 4 100 -32 40 0 0 1 0 1 0 -1 0 0 3001.dat
"""


def _same_scene(a, b):
    """Same parts under the same keys (an exported file lists them bottom level first)."""
    assert isinstance(a, Scene) and isinstance(b, Scene)
    assert sorted(a.keys) == sorted(b.keys)
    a = a.subset([a.keys.index(k) for k in b.keys])
    assert a.brick_id == b.brick_id
    for f in ("kind", "pos", "size", "yaw", "mass"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def _knobs(scene):
    """{(upper, lower): knob connections} (lower == scene.n: the baseplate)."""
    pairs, counts = np.unique(scene_contacts(scene).knob_pair, axis=0, return_counts=True)
    return {tuple(p): int(c) for p, c in zip(pairs.tolist(), counts)}


def test_mpd_submodels_are_placed_by_their_transforms(tmp_path):
    path = tmp_path / "towers.mpd"
    path.write_text(MAIN + TOWER)
    sc = load_layout(str(path))  # a plate in it: a Scene
    _same_scene(sc, parse_ldr(FLAT, source=str(path)))
    assert sc.brick_id == ("2", "3020", "2") * 2 and sc.fmt == "ldr"
    assert sc.pos[:, 2].tolist() == [0, 3, 4] * 2  # plate heights: the brick on the plate at 3 + 1
    assert sc.size[:3].tolist() == [[4, 2, 3], [4, 2, 1], [4, 2, 3]]
    assert sc.yaw.tolist() == [0, 0, 0, -90, -90, -90]
    assert (sc.pos[3:, :2] - sc.pos[:3, :2]).tolist() == [[5, 2]] * 3
    # plate on brick and brick on plate, every stud
    assert _knobs(sc) == {(0, 6): 8, (1, 0): 8, (2, 1): 8, (3, 6): 8, (4, 3): 8, (5, 4): 8}
    # the sub-model in a file of its own beside the main one
    (tmp_path / "tower.ldr").write_text(TOWER.replace("0 FILE tower.ldr\n", "").replace("0 NOFILE\n", ""))
    (tmp_path / "main.ldr").write_text(MAIN.replace("0 FILE main.ldr\n", "").replace("0 NOFILE\n", ""))
    _same_scene(read_ldr(str(tmp_path / "main.ldr")), parse_ldr(FLAT, source=str(tmp_path / "main.ldr")))
    # a sub-model that includes itself
    loop = "0 FILE a.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 b.ldr\n0 FILE b.ldr\n1 4 0 -24 0 1 0 0 0 1 0 0 0 1 a.ldr\n"
    with pytest.raises(LayoutError, match=r"^l.mpd: b.ldr line 4: sub-model 'a.ldr' includes itself"):
        parse_ldr(loop, source="l.mpd")


def test_plates_stack_in_plate_heights_and_join_bricks():
    # three plates are one brick high: the brick on them sits level with the
    # brick on the neighbouring brick; a plate on the ground joins the baseplate
    lines = [
        "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat",  # 1: brick, level 0
        "1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat",  # 2..4: plates, levels 3, 4, 5
        "1 4 0 -16 0 1 0 0 0 1 0 0 0 1 3020.dat",
        "1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3020.dat",
        "1 4 0 -48 0 1 0 0 0 1 0 0 0 1 3001.dat",  # 5: brick, level 6
        "1 4 80 0 0 1 0 0 0 1 0 0 0 1 3001.dat",  # 6, 7: two bricks beside, levels 0 and 3
        "1 4 80 -24 0 1 0 0 0 1 0 0 0 1 3001.dat",
        "1 4 70 -32 10 1 0 0 0 1 0 0 0 1 3024.dat",  # 8: a 1x1 plate on brick 7, level 6
        "1 4 160 16 10 1 0 0 0 1 0 0 0 1 3023.dat",  # 9: a 1x2 plate on the ground, level 0
    ]
    sc = parse_ldr("\n".join(lines) + "\n", source="p.ldr")
    assert sc.pos[:, 2].tolist() == [0, 3, 4, 5, 6, 0, 3, 6, 0]
    assert sc.size[:, 2].tolist() == [3, 1, 1, 1, 3, 3, 3, 1, 1]
    assert np.allclose(sc.mass[[1, 7, 8]], [TABLE_I_MASS_KG[(2, 4)] / 3, TABLE_I_MASS_KG[(1, 1)] / 3,
                                            TABLE_I_MASS_KG[(1, 2)] / 3])
    k = _knobs(sc)
    assert k == {(0, 9): 8, (1, 0): 8, (2, 1): 8, (3, 2): 8, (4, 3): 8, (5, 9): 8, (6, 5): 8, (7, 6): 1, (8, 9): 2}
    from stablelego_jax.analysis import analyze_layout

    a = analyze_layout(sc, solver="exact")
    assert a.stable and max(a.scores.values()) < 1


@pytest.mark.parametrize("part, studs, plates, points", [
    ("3622", (3, 1), 3, 3 * 4),  # 1x3 brick: four points a knob
    ("3002", (3, 2), 3, 6 * 3),  # 2x3 brick: three
    ("3007", (8, 2), 3, 16 * 3),  # 2x8 brick
    ("3006", (10, 2), 3, 20 * 3),  # 2x10 brick
    ("2356", (6, 4), 3, 8 * 4 + 16 * 3),  # 4x6 brick (Q >= 3): inner knobs four, edge knobs three
    ("3031", (4, 4), 1, 4 * 4 + 12 * 3),  # 4x4 plate
    ("3958", (6, 6), 1, 16 * 4 + 20 * 3),  # 6x6 plate
])
def test_other_sizes_follow_the_knob_rules(part, studs, plates, points):
    sc = parse_ldr(f"1 4 0 0 0 1 0 0 0 1 0 0 0 1 {part}.dat\n", source="s.ldr")
    assert isinstance(sc, Scene) and sc.size.tolist() == [[*studs, plates]] and sc.brick_id == (part,)
    assert sc.mass[0] == pytest.approx(part_mass(*studs, plates)) and sc.mass[0] > 0
    c = scene_contacts(sc)
    assert len(c.knob_pair) == studs[0] * studs[1] and len(c.lego_point) == points


def test_part_table_and_names():
    assert LDRAW_PARTS["3020"] == (2, 4, 1) and LDRAW_PARTS["3001"] == (2, 4, 3)
    for number in ("3024", "3023", "3623", "3710", "3666", "3460", "3022", "3021", "3020", "3795", "3034",
                   "3832", "3622", "3002", "3007", "3006"):  # the plates and bricks named in issue 22
        assert number in LDRAW_PARTS
    assert part_number("parts\\3001p11.DAT") == "3001"  # a printed brick is the brick
    assert part_number("3001a.dat") == "3001"  # a mould variant too
    assert part_number("s/3001s01.dat") == "3001s01" and part_number("3039.dat") == "3039"
    for (a, b), p in PARTS.items():  # the basic bricks keep Table I
        assert part_mass(a, b, 3) == TABLE_I_MASS_KG[(a, b)] and LDRAW_PARTS[p] == (a, b, 3)
    # estimates grow with the stud count; a plate is a third of its brick
    assert part_mass(1, 3, 3) == pytest.approx(3 * part_mass(1, 3, 1))
    assert TABLE_I_MASS_KG[(1, 2)] < part_mass(1, 3, 3) < TABLE_I_MASS_KG[(1, 4)]


UNSUPPORTED = MAIN.replace("0 NOFILE\n", "") + """1 4 0 -40 0 1 0 0 0 1 0 0 0 1 3039.dat
1 4 0 -40 -20 1 0 0 0 1 0 0 0 1 3068b.dat
1 4 40 -40 0 1 0 0 0 1 0 0 0 1 parts/3039.dat
1 4 100 -40 40 1 0 0 0 1 0 0 0 1 wheel.ldr
0 NOFILE
""" + TOWER


def test_unsupported_parts_reported_once_each_with_count():
    with pytest.raises(LayoutError) as ei:
        parse_ldr(UNSUPPORTED, source="u.mpd")
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg.startswith("u.mpd: line 5: 4 parts cannot be modelled: 3039 x2 (line 5), ")
    assert msg.count("3039") == 1 and "3068b x1 (line 6)" in msg and "wheel.ldr (missing sub-model) x1 (line 8)" in msg
    assert msg.endswith("; --skip-unsupported analyses the rest")
    report = {}
    sc = parse_ldr(UNSUPPORTED, source="u.mpd", skip_unsupported=True, report=report)
    _same_scene(sc, parse_ldr(FLAT, source="u.mpd"))  # the rest, as without those parts
    assert report == {"3039": [2, "line 5"], "3068b": [1, "line 6"], "wheel.ldr (missing sub-model)": [1, "line 8"]}
    # turned parts that are not upright cannot be modelled either
    tilted = FLAT + "1 4 200 0 0 1 0 0 0 -1 0 0 0 -1 3001.dat\n1 4 300 0 0 1 0 0 0 -1 0 0 0 -1 3001.dat\n"
    with pytest.raises(LayoutError, match=r"3001 upside down x2 \(line 7\)"):
        parse_ldr(tilted, source="t.ldr")


def test_export_writes_what_it_reads(tmp_path):
    path = tmp_path / "towers.mpd"
    path.write_text(MAIN + TOWER)
    sc = read_ldr(str(path))
    out = tmp_path / "back.ldr"
    write_ldr(sc, str(out))
    text = out.read_text()
    notes = [json.loads(ln[len("0 // stablelego "):]) for ln in text.splitlines() if ln.startswith("0 // stablelego")]
    assert notes and all(set(m) == {"key"} for m in notes)  # only the keys (parts go bottom level first)
    assert [p[-1] for p in _placements(text)] == ["3001", "3001", "3020", "3020", "3001", "3001"]
    _same_scene(read_ldr(str(out)), dataclasses.replace(sc, source=str(out)))
    # yawed parts, other sizes, keys and masses of our own travel too
    sc = make_scene(["base", "tilted", "plate", "load"], [0] * 4, [[0.5, 0.5, 0], [0.5, 2, 3], [0, 0, 6], [8, 0.5, 0]],
                    [[3, 1, 3], [3, 1, 3], [4, 4, 1], [2, 3, 3]], [0, 30, 90, 0],
                    [part_mass(3, 1, 3), part_mass(3, 1, 3), part_mass(4, 4, 1), 0.2],
                    ["3622", "3622", "3031", "1"], source="y.ldr", fmt="ldr")
    _same_scene(parse_ldr(layout_to_ldr(sc), source="y.ldr"), sc)
    # parts on two stud lattices: the first in the file (on top) sets the lattice, the export writes the bottom
    # part first and marks the anchor, so that reading it back puts every part where it was
    two = "1 4 0 -48 0 1 0 0 0 1 0 0 0 1 3003.dat\n1 4 50 0 10 1 0 0 0 1 0 0 0 1 3003.dat\n"
    sc = parse_ldr(two, source="two.ldr")
    assert sc.pos.tolist() == [[0.0, 0.0, 6.0], [2.5, 0.5, 0.0]]
    text = layout_to_ldr(sc)
    lines = text.splitlines()
    assert text.count('"anchor":true') == 1 and lines.index(next(ln for ln in lines if "anchor" in ln)) > \
        lines.index(next(ln for ln in lines if ln.startswith("1 ")))  # the top part, written after the bottom one
    _same_scene(parse_ldr(text, source="two.ldr"), sc)
