"""StableLego-style dataset objects (generators.dataset)."""
import json
import os

import numpy as np
import pytest
import trimesh

from generators import dataset
from generators.dataset import (
    OBJECT_FILES,
    find_objects,
    generate_from_mesh,
    generate_from_voxels,
    layout_voxels,
    read_dataset,
    read_object,
    score_grid,
    write_object,
)
from generators.procedural import stairs, wall
from generators.voxels import random_voxel_shape
from stablelego_jax import load_layout
from stablelego_jax.api import analyze_layout
from stablelego_jax.layout import LayoutError


def _leftovers(parent):
    return [f for f in os.listdir(parent) if f.startswith((".tmp-", ".old-"))]


def test_write_read_round_trip(tmp_path):
    lay = stairs(5, load_kg=0.2)  # a load block too
    a = analyze_layout(lay, solver="exact")
    path = tmp_path / "stairs5"
    write_object(str(path), lay, scores=a.scores, vis=True, meta={"family": "stairs"})
    assert set(OBJECT_FILES) <= set(os.listdir(path))
    assert open(path / "vis.png", "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    obj = read_object(str(path))
    assert obj.name == "stairs5" and obj.meta["family"] == "stairs"
    assert obj.layout.keys == lay.keys
    assert np.array_equal(obj.layout.pos, lay.pos) and np.array_equal(obj.layout.size, lay.size)
    assert np.allclose(obj.layout.mass, lay.mass)
    assert obj.brick_scores() == pytest.approx(a.scores)
    assert obj.stable == a.stable is False and obj.meta["weakest"] == a.weakest
    # vox.npy is [x, y, z] in the coordinates of task_graph.json: every brick cell, nothing else
    vox = np.load(path / "vox.npy")
    tg = json.load(open(path / "task_graph.json"))
    cells = set()
    for key, b in tg.items():
        i = lay.keys.index(key)
        sx, sy = lay.size[i]
        for dx in range(sx):
            for dy in range(sy):
                cells.add((b["x"] + dx, b["y"] + dy, b["z"]))
    assert {tuple(c) for c in np.argwhere(vox).tolist()} == cells
    sc = np.load(path / "stability_score.npy")
    assert sc.shape == vox.shape and (sc[vox == 0] == 0).all()
    assert sc.max() == pytest.approx(max(a.scores.values()))
    assert os.stat(path).st_mode & 0o777 == 0o777 & ~_umask()


def _umask():
    m = os.umask(0o022)
    os.umask(m)
    return m


def test_grids_and_cover_check(tmp_path):
    lay = wall(6, 3)
    assert layout_voxels(lay).shape == (6, 1, 3)
    assert layout_voxels(lay, (8, 8, 8)).sum() == 18
    with pytest.raises(LayoutError):
        layout_voxels(lay, (4, 4, 4))
    g = score_grid(lay, np.arange(lay.n) / 10.0, (8, 8, 8))
    assert g[lay.pos[-1, 0], 0, lay.pos[-1, 2]] == pytest.approx((lay.n - 1) / 10.0)
    with pytest.raises(ValueError):
        score_grid(lay, [0.1])
    bad = layout_voxels(lay, (8, 8, 8))
    bad[7, 7, 0] = True  # a voxel no brick covers
    with pytest.raises(LayoutError, match="cover"):
        write_object(str(tmp_path / "bad"), lay, scores=[0.0] * lay.n, vox=bad, vis=False)
    assert os.listdir(tmp_path) == []


def test_generate_from_voxels_and_read_dataset(tmp_path):
    shard = tmp_path / "shard"
    results = []
    for seed, kind in enumerate(("boxes", "arch")):
        vox = random_voxel_shape(seed, grid=8, kind=kind)
        r = generate_from_voxels(vox, str(shard / f"{kind}"), seed=seed, vis=False, bricks="basic")
        assert r.n_voxels == int(vox.sum()) and r.converged
        results.append(r)
        assert np.array_equal(np.load(shard / kind / "vox.npy").astype(bool), vox)  # the full 8^3 grid
    objs = list(read_dataset(str(shard)))
    assert [o.name for o in objs] == ["arch", "boxes"]
    for o in objs:
        r = next(r for r in results if r.name == o.name)
        assert o.stable == r.stable and o.layout.n == r.n_bricks
        assert o.meta["bricks"] == "2x4,2x2,1x4,1x2,1x1"
        assert {tuple(sorted(s)) for s in o.layout.size.tolist()} <= {(2, 4), (2, 2), (1, 4), (1, 2), (1, 1)}


def test_find_objects_nested_and_skips_temporaries(tmp_path):
    lay = stairs(2)
    write_object(str(tmp_path / "02691156" / "abc" / "models"), lay, scores=[0.0, 0.0], vis=False)
    write_object(str(tmp_path / "flat"), lay, scores=[0.0, 0.0], vis=False)
    (tmp_path / ".tmp-junk-1").mkdir()
    (tmp_path / ".tmp-junk-1" / "task_graph.json").write_text("{}")
    assert find_objects(str(tmp_path)) == [str(tmp_path / "02691156" / "abc" / "models"), str(tmp_path / "flat")]


def test_atomic_write_and_overwrite(tmp_path, monkeypatch):
    lay = stairs(3)
    path = tmp_path / "obj"
    write_object(str(path), lay, scores=[0.1, 0.2, 0.3], vis=False)
    with pytest.raises(FileExistsError):
        write_object(str(path), lay, scores=[0.0] * 3, vis=False)
    # a failure half-way (here: while drawing vis.png) leaves the old object untouched, no temporaries
    import stablelego_jax.render as render

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(render, "render_heatmap", boom)
    with pytest.raises(RuntimeError):
        write_object(str(path), lay, scores=[0.9] * 3, vis=True, overwrite=True)
    assert read_object(str(path)).brick_scores() == pytest.approx({"1": 0.1, "2": 0.2, "3": 0.3})
    with pytest.raises(RuntimeError):
        write_object(str(tmp_path / "new"), lay, scores=[0.9] * 3, vis=True)
    assert not (tmp_path / "new").exists()
    assert _leftovers(tmp_path) == []
    monkeypatch.undo()
    write_object(str(path), lay, scores=[0.5] * 3, vis=False, overwrite=True)
    assert read_object(str(path)).brick_scores()["2"] == 0.5
    assert _leftovers(tmp_path) == []


def test_read_errors_name_the_folder(tmp_path):
    lay = stairs(2)
    path = tmp_path / "o"
    write_object(str(path), lay, scores=[0.0, 0.0], vis=False)
    vox = np.load(path / "vox.npy")
    vox[-1, -1, -1] = 1 - vox[-1, -1, -1]
    np.save(path / "vox.npy", vox)
    with pytest.raises(LayoutError) as ei:
        read_object(str(path))
    assert str(path) in str(ei.value) and "cover" in str(ei.value)
    np.save(path / "vox.npy", np.zeros((2, 2), np.uint8))
    with pytest.raises(LayoutError, match="3-D"):
        read_object(str(path))
    os.remove(path / "vox.npy")
    np.save(path / "stability_score.npy", np.zeros((1, 1, 1)))
    with pytest.raises(LayoutError, match="shape"):
        read_object(str(path))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(LayoutError, match="task_graph.json"):
        read_object(str(empty))


def test_generate_from_mesh(tmp_path):
    mesh = trimesh.creation.cylinder(radius=1.0, height=3.0)
    src = tmp_path / "can.stl"
    mesh.export(src)
    r = generate_from_mesh(str(src), str(tmp_path / "out" / "can"), grid=8, vis=False)
    assert r.name == "can" and r.n_voxels > 0 and r.stable  # a solid column stands
    obj = read_object(r.path)
    assert obj.vox.shape == (8, 8, 8)
    assert obj.meta["source"] == str(src) and obj.meta["fill"] == "solid" and obj.meta["up"] == "z"
    assert load_layout(r.path).n == r.n_bricks  # the folder is a layout for every reader
    from generators.mesh import MeshError

    bad = tmp_path / "bad.obj"
    bad.write_text("not a mesh\n")
    with pytest.raises(MeshError, match="bad.obj"):
        generate_from_mesh(str(bad), str(tmp_path / "out" / "bad"), grid=8, vis=False)
    assert sorted(os.listdir(tmp_path / "out")) == ["can"]
    assert dataset.META_FILE in os.listdir(r.path)
