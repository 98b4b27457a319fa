"""StableLego-style dataset objects (stablelego_jax.formats.dataset)."""
import json
import os

import numpy as np
import pytest

from stablelego_jax.analysis import analyze_layout
from stablelego_jax.files import current_umask
from stablelego_jax import render
from stablelego_jax.formats import dataset
from stablelego_jax.formats.dataset import OBJECT_FILES, find_objects, read_object, score_grid, write_object
from stablelego_jax.generate.procedural import stairs, wall
from stablelego_jax.layout import LayoutError, layout_voxels


def _leftovers(parent):
    return [f for f in os.listdir(parent) if f.startswith((".tmp-", ".old-"))]


def test_write_read_round_trip(tmp_path):
    lay = stairs(5, load_kg=0.2)  # a load block too
    a = analyze_layout(lay, solver="exact")
    path = tmp_path / "stairs5"
    write_object(str(path), lay, a.scores, vis=True, meta={"family": "stairs"})
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
    assert os.stat(path).st_mode & 0o777 == 0o777 & ~current_umask()
    assert dataset.META_FILE in os.listdir(path)


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
        write_object(str(tmp_path / "bad"), lay, [0.0] * lay.n, vox=bad, vis=False)
    assert os.listdir(tmp_path) == []


def test_find_objects_nested_and_skips_temporaries(tmp_path):
    lay = stairs(2)
    write_object(str(tmp_path / "02691156" / "abc" / "models"), lay, [0.0, 0.0], vis=False)
    write_object(str(tmp_path / "flat"), lay, [0.0, 0.0], vis=False)
    (tmp_path / ".tmp-junk-1").mkdir()
    (tmp_path / ".tmp-junk-1" / "task_graph.json").write_text("{}")
    assert find_objects(str(tmp_path)) == [str(tmp_path / "02691156" / "abc" / "models"), str(tmp_path / "flat")]


def test_atomic_write_and_overwrite(tmp_path, monkeypatch):
    lay = stairs(3)
    path = tmp_path / "obj"
    write_object(str(path), lay, [0.1, 0.2, 0.3], vis=False)
    with pytest.raises(FileExistsError):
        write_object(str(path), lay, [0.0] * 3, vis=False)
    # a failure half-way (here: while drawing vis.png) leaves the old object untouched, no temporaries
    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(render, "render_heatmap", boom)
    with pytest.raises(RuntimeError):
        write_object(str(path), lay, [0.9] * 3, vis=True, overwrite=True)
    assert read_object(str(path)).brick_scores() == pytest.approx({"1": 0.1, "2": 0.2, "3": 0.3})
    with pytest.raises(RuntimeError):
        write_object(str(tmp_path / "new"), lay, [0.9] * 3, vis=True)
    assert not (tmp_path / "new").exists()
    assert _leftovers(tmp_path) == []
    monkeypatch.undo()
    write_object(str(path), lay, [0.5] * 3, vis=False, overwrite=True)
    assert read_object(str(path)).brick_scores()["2"] == 0.5
    assert _leftovers(tmp_path) == []


def test_read_errors_name_the_folder(tmp_path):
    lay = stairs(2)
    path = tmp_path / "o"
    write_object(str(path), lay, [0.0, 0.0], vis=False)
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
