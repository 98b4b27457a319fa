"""Procedural layout families."""
import json
import os

import numpy as np
import pytest

from stablelego_jax.generate.procedural import (
    FAMILIES,
    bridge,
    cuboid,
    lever,
    pallet_of_boxes,
    random_family_layout,
    stairs,
    tower,
    voxel_layout,
    wall,
    with_floating,
)
from stablelego_jax.generate.voxels import floating_bricks
from stablelego_jax.formats.stablelego import layout_to_json_dict, parse_json_layout
from stablelego_jax.layout import TABLE_I_MASS_KG

from conftest import SHARED_REF as REF  # noqa: E402


def _valid(layout):
    assert layout.n >= 1
    assert (layout.pos >= 0).all()
    occ = layout.occupancy()  # raises on overlap
    assert int((occ >= 0).sum()) == int((layout.size[:, 0] * layout.size[:, 1]).sum())
    assert layout.keys == tuple(str(i + 1) for i in range(layout.n))
    for s, m, b in zip(layout.size.tolist(), layout.mass.tolist(), layout.brick_id):
        key = tuple(sorted(s))
        if b == "1":  # load block
            assert key == (2, 2)
        else:
            assert m == TABLE_I_MASS_KG[key]
    back = parse_json_layout(layout_to_json_dict(layout))
    assert np.array_equal(back.pos, layout.pos) and np.array_equal(back.size, layout.size)
    return occ


def _grounded(layout):
    """Per brick: connected to the baseplate through knob connections."""
    return ~floating_bricks(layout)


def _ref_cells(name):
    path = os.path.join(REF, name)
    if not os.path.exists(path):
        pytest.skip("reference layouts not available")
    with open(path) as fh:
        ref = parse_json_layout(json.load(fh))
    return sorted(zip(map(tuple, ref.pos.tolist()), map(tuple, ref.size.tolist()), ref.mass.tolist()))


def _cells(layout):
    return sorted(zip(map(tuple, layout.pos.tolist()), map(tuple, layout.size.tolist()), layout.mass.tolist()))


def test_stairs_match_paper():
    for n in (1, 5, 20):
        lay = stairs(n)
        _valid(lay)
        assert lay.n == n and _grounded(lay).all()
    assert _cells(stairs(20, origin=(0, 21))) == _ref_cells("stair_20.json")
    assert _cells(stairs(4, load_kg=0.2, origin=(0, 21))) == _ref_cells("external_weight_fail.json")
    _valid(stairs(6, step=1, brick=(2, 6)))


@pytest.mark.parametrize("kw", [
    {},
    {"beam_len": 4, "loads": ()},
    {"beam_len": 20, "loads": (0.2, 0.1, 0.05), "width": 2, "blen": 4},
    {"beam_len": 30, "base_len": 5, "base_height": 3, "loads": (0.02,), "load_x": (10,)},
])
def test_lever(kw):
    lay = lever(**kw)
    _valid(lay)
    assert _grounded(lay).all()
    loads = [i for i, b in enumerate(lay.brick_id) if b == "1"]
    assert len(loads) == len(kw.get("loads", (0.2,)))
    top = lay.pos[:, 2].max()
    assert all(lay.pos[i, 2] == top for i in loads)


@pytest.mark.parametrize("h,fp,lean", [(1, (1, 1), 0), (5, (2, 2), 0), (6, (4, 4), 0), (7, (3, 5), 1), (4, (4, 2), 2)])
def test_tower(h, fp, lean):
    lay = tower(h, fp, lean=lean)
    occ = _valid(lay)
    assert occ.shape[2] == h
    assert int((occ >= 0).sum()) == h * fp[0] * fp[1]
    assert _grounded(lay).all()


def test_leaning_towers_stay_connected():
    for fx in (2, 4, 6):
        for fy in (1, 2, 3, 4):
            for lean in range(fx):
                lay = tower(8, (fx, fy), lean=lean, origin=(1, 2))
                occ = _valid(lay)
                assert (occ[1:, 2:, :] >= 0).sum() == 8 * fx * fy
                assert _grounded(lay).all(), (fx, fy, lean)


@pytest.mark.parametrize("kw", [{}, {"span": 1, "height": 1}, {"span": 15, "height": 6, "width": 3, "deck_layers": 1},
                                {"span": 12, "pillar_len": 4, "deck_layers": 3, "blen": 4}])
def test_bridge(kw):
    lay = bridge(**kw)
    occ = _valid(lay)
    g = _grounded(lay)
    if kw.get("deck_layers", 2) >= 2:
        assert g.all()
    else:  # a single deck layer longer than a brick leaves mid-span bricks loose
        assert not g.all()
    span = kw.get("span", 8)
    pl = kw.get("pillar_len", 2)
    h = kw.get("height", 4)
    # the gap under the deck is empty
    assert (occ[pl:pl + span, :, :h] < 0).all()


@pytest.mark.parametrize("length,height,width,blen", [(16, 6, 1, 4), (7, 3, 2, 6), (40, 10, 1, 6), (3, 2, 2, 2)])
def test_wall_running_bond(length, height, width, blen):
    lay = wall(length, height, width=width, blen=blen)
    occ = _valid(lay)
    assert occ.shape == (length, width, height)
    assert (occ >= 0).all()
    assert _grounded(lay).all()
    if length >= 2 * blen and height >= 2:
        # joints of consecutive layers differ (bricks are bridged)
        j0 = set(lay.pos[lay.pos[:, 2] == 0, 0].tolist())
        j1 = set(lay.pos[lay.pos[:, 2] == 1, 0].tolist())
        assert j0 != j1


def test_cuboid():
    lay = cuboid(10, 10, 10)
    assert lay.n == 1000
    assert (lay.size == 1).all()
    assert (lay.occupancy() >= 0).all()
    assert np.allclose(lay.mass, TABLE_I_MASS_KG[(1, 1)])
    _valid(cuboid(2, 3, 4))


def test_pallet_of_boxes():
    for seed in range(4):
        lay = pallet_of_boxes(n_boxes=5, seed=seed, pallet=(12, 10))
        occ = _valid(lay)
        assert (occ[:12, :10, :2] >= 0).all()
    a, b = pallet_of_boxes(seed=3), pallet_of_boxes(seed=3)
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.size, b.size)


def test_with_floating():
    for seed in range(8):
        base = wall(12, 4)
        lay = with_floating(base, seed=seed, n=3)
        _valid(lay)
        assert lay.n == base.n + 3
        g = _grounded(lay)
        assert g[: base.n].all() and not g[base.n:].any()
        assert lay.keys[: base.n] == base.keys


def test_voxel_layout():
    lay = voxel_layout(seed=1, grid=10, kind="overhang")
    _valid(lay)


def test_random_family_layout():
    seen = set()
    sizes = []
    for seed in range(60):
        name, lay = random_family_layout(seed)
        _valid(lay)
        seen.add(name.split("/")[0])
        sizes.append(lay.n)
        if name.startswith("floating"):
            assert not _grounded(lay).all()
    assert seen == set(FAMILIES)
    assert min(sizes) <= 10 and max(sizes) >= 100
    n1, a = random_family_layout(11)
    n2, b = random_family_layout(11)
    assert n1 == n2 and np.array_equal(a.pos, b.pos) and np.array_equal(a.size, b.size)
    for fam in FAMILIES:
        name, lay = random_family_layout(123, family=fam)
        assert name.split("/")[0] == fam
    with pytest.raises(ValueError):
        random_family_layout(0, family="nope")
