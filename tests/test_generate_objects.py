"""Dataset objects made from voxels and meshes (stablelego_jax.generate.objects)."""
import os

import numpy as np
import pytest
import trimesh

from stablelego_jax import load_layout
from stablelego_jax.formats import dataset
from stablelego_jax.formats.dataset import read_dataset, read_object
from stablelego_jax.generate.mesh import MeshError
from stablelego_jax.generate.objects import analyze_and_write, generate_from_mesh, generate_from_voxels
from stablelego_jax.generate.procedural import stairs
from stablelego_jax.generate.voxels import random_voxel_shape


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

    bad = tmp_path / "bad.obj"
    bad.write_text("not a mesh\n")
    with pytest.raises(MeshError, match="bad.obj"):
        generate_from_mesh(str(bad), str(tmp_path / "out" / "bad"), grid=8, vis=False)
    assert sorted(os.listdir(tmp_path / "out")) == ["can"]
    assert dataset.META_FILE in os.listdir(r.path)


def test_analyze_and_write_refuses_an_existing_folder_before_solving(tmp_path):
    lay = stairs(3)
    a = analyze_and_write(str(tmp_path / "o"), lay, vis=False)
    assert a.solver == "exact" and read_object(str(tmp_path / "o")).meta["solver"] == "exact"
    with pytest.raises(FileExistsError):
        analyze_and_write(str(tmp_path / "o"), lay, vis=False)
