"""Target shapes of the generator (stablelego_jax.train.shapes)."""
import json
import os

import numpy as np
import pytest

from stablelego_jax.generate.voxels import ground
from stablelego_jax.train import train as T
from stablelego_jax.train.shapes import FULL_KINDS, build_dataset, fresh_shapes, full_shape


def test_full_scale_shapes_span_the_grid_and_stand_on_layer_0():
    train, held, skipped = build_dataset(30, None, seed=0, procedural="full")
    shapes = train + held
    assert skipped == [] and len(held) == 6 and len(shapes) <= 30
    names = [s.name for s in shapes]
    assert len(set(names)) == len(names)  # one object each: the split is by object
    assert {s.kind for s in shapes} <= set(FULL_KINDS) and len({s.kind for s in shapes}) >= 3
    cells = [int(s.vox.sum()) for s in shapes]
    assert min(cells) > 0 and max(cells) > 500  # realistic sizes, not the small objects' <= 8 across
    heights = [int(np.nonzero(s.vox)[2].max()) + 1 for s in shapes]
    assert max(heights) > 6  # taller than the small objects' crop
    for s in shapes:
        assert s.vox.shape == (20, 20, 20)
        assert (ground(s.vox, keep="grounded") == s.vox).all()  # every part touches layer 0
    again = build_dataset(30, None, seed=0, procedural="full")
    assert [s.name for s in again[0]] == [s.name for s in train]
    assert all((a.vox == b.vox).all() for a, b in zip(again[0], train))


def test_full_scale_kinds_and_sources_are_checked(tmp_path):
    assert full_shape(7, kind="arch").kind == "arch"
    with pytest.raises(ValueError, match="floating"):
        full_shape(7, kind="floating")  # no layout of its cells can stand
    with pytest.raises(ValueError, match="procedural"):
        build_dataset(2, None, seed=0, procedural="huge")
    bad = tmp_path / "cfg.json"
    bad.write_text(json.dumps({"procedural": "huge"}))
    with pytest.raises(T.ConfigError, match="procedural"):
        T.load_config(str(bad))


def test_the_full_scale_config_loads_and_is_layered():
    cfg = T.load_config(os.path.join(os.path.dirname(T.__file__), "configs", "full_scale.json"))
    assert cfg["procedural"] == "full" and cfg["crop"] == [20, 20, 20]
    assert cfg["layers"] >= cfg["crop"][2]


def test_fresh_shapes_are_new_objects_of_the_same_recipe():
    """split "fresh": procedural objects of the config's recipe, none of them
    among its train, validation or held-out objects; the same on every call."""
    cfg = T.load_config(os.path.join(os.path.dirname(T.__file__), "configs", "default.json"))
    used = {s.name for split in ("train", "val", "heldout") for s in T.split_shapes(cfg, split)}
    fresh = T.split_shapes(cfg, "fresh", n_fresh=40)
    names = [s.name for s in fresh]
    assert len(fresh) == 40 and len(set(names)) == 40 and not set(names) & used
    assert all(s.vox.any() and s.vox.shape == (20, 20, 20) for s in fresh)
    assert names == [s.name for s in T.split_shapes(cfg, "fresh", n_fresh=40)]
    assert names[:10] == [s.name for s in T.split_shapes(cfg, "fresh", n_fresh=10)]  # a prefix: more is a superset
    full = fresh_shapes(12, 30, seed=0, procedural="full")
    assert {s.kind for s in full} <= set(FULL_KINDS)
    assert not {s.name for s in full} & {s.name for part in build_dataset(30, None, 0, procedural="full")[:2] for s in part}
    with pytest.raises(ValueError, match="procedural"):
        fresh_shapes(2, 30, seed=0, procedural="huge")
    with pytest.raises(ValueError, match=">= 0"):
        fresh_shapes(-1, 30, seed=0)
