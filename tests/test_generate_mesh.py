"""Meshes to voxels (stablelego_jax.generate.mesh) and on to bricks."""
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from stablelego_jax.generate.mesh import MESH_SUFFIXES, MeshError, load_mesh, mesh_to_voxels, resolve_up, voxelize
from stablelego_jax.generate.voxels import merge_voxels
from stablelego_jax.layout import TABLE_I_MASS_KG

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")
MESHES = os.path.join(HERE, "..", "..", "shared", "meshes")


def _shared_meshes():
    if not os.path.isdir(MESHES):
        return []
    return sorted(f for f in os.listdir(MESHES) if f.lower().endswith(MESH_SUFFIXES))


def _extent(vox, axis):
    other = tuple(a for a in range(3) if a != axis)
    idx = np.nonzero(vox.any(axis=other))[0]
    return int(idx.max() - idx.min() + 1)


def _check_bricks(vox, layout):
    occ = layout.occupancy() >= 0
    full = np.zeros(vox.shape, bool)
    assert all(o <= v for o, v in zip(occ.shape, vox.shape))
    full[: occ.shape[0], : occ.shape[1], : occ.shape[2]] = occ
    assert np.array_equal(full, vox)  # covers exactly the voxels (and no overlap: make_layout checks)
    assert int((layout.size[:, 0] * layout.size[:, 1]).sum()) == int(vox.sum())
    assert {tuple(sorted(s)) for s in layout.size.tolist()} <= set(TABLE_I_MASS_KG)


@pytest.mark.parametrize("suffix", [".stl", ".obj", ".ply", ".off", ".glb"])
def test_every_format_gives_the_exact_grid(tmp_path, suffix):
    mesh = trimesh.creation.box(extents=(4.0, 2.0, 1.0))
    mesh.apply_translation((10.0, -3.0, 7.5))  # position must not matter
    path = tmp_path / f"box{suffix}"
    mesh.export(path)
    r = voxelize(str(path), grid=10, up="z")
    vox = r.vox
    assert vox.shape == (10, 10, 10) and vox.dtype == bool
    assert r.watertight and r.fill == "solid"
    # largest extent spans the grid exactly; a box of 5 x 2.5 cells -> 5 x 3 cells
    assert (_extent(vox, 0), _extent(vox, 1), _extent(vox, 2)) == (10, 5, 3)
    assert vox.sum() == 10 * 5 * 3
    assert vox[:, :, 0].any()  # resting on the ground
    ys = np.nonzero(vox.any(axis=(0, 2)))[0]
    assert abs(ys.min() - (9 - ys.max())) <= 1  # centred in y


def test_up_axis(tmp_path):
    mesh = trimesh.creation.box(extents=(1.0, 4.0, 2.0))  # tall along y: a Y-up scan
    path = str(tmp_path / "tall.obj")
    mesh.export(path)
    ey = voxelize(path, grid=8, up="y").vox
    assert (_extent(ey, 0), _extent(ey, 1), _extent(ey, 2)) == (2, 4, 8)
    ez = voxelize(path, grid=8, up="z").vox
    assert (_extent(ez, 0), _extent(ez, 1), _extent(ez, 2)) == (2, 8, 4)
    ex = voxelize(path, grid=8, up="x").vox
    assert _extent(ex, 2) == 2
    assert resolve_up("auto", "a.glb") == "y" and resolve_up("auto", "a.GLTF") == "y"
    assert resolve_up("auto", "a.stl") == "z" and resolve_up("y", "a.stl") == "y"
    with pytest.raises(ValueError):
        resolve_up("w")


def test_glb_scene_with_transforms_and_auto_up(tmp_path):
    a = trimesh.creation.box(extents=(1.0, 3.0, 1.0))  # glTF is Y-up: a column 3 high
    b = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    scene = trimesh.Scene()
    scene.add_geometry(a, node_name="a", transform=trimesh.transformations.translation_matrix((0.0, 1.5, 0.0)))
    scene.add_geometry(b, node_name="b", transform=trimesh.transformations.translation_matrix((3.0, 0.5, 0.0)))
    path = str(tmp_path / "scene.glb")
    scene.export(path)
    r = voxelize(path, grid=8)  # auto: y up for glb
    assert r.up == "y"
    vox = r.vox
    assert _extent(vox, 2) == 6  # the column spans 3 of 4 units of the largest extent (x)
    from scipy import ndimage

    _, parts = ndimage.label(vox)
    assert parts == 2  # two separate blocks, both placed by their node transforms
    xs = np.nonzero(vox.any(axis=(1, 2)))[0]
    assert vox[xs[0], :, 0].any() and vox[xs[-1], :, 0].any()  # both stand on the ground


def test_solid_sphere_and_fill_modes():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    solid = voxelize(sphere, grid=12, fill="solid").vox
    surface = voxelize(sphere, grid=12, fill="surface").vox
    assert surface.sum() < solid.sum()
    assert solid[6, 6, 6] and not surface[6, 6, 6]
    # every cell whose centre is inside the ball is occupied, and no cell far outside
    c = (np.arange(12) + 0.5 - 6) / 6.0
    r2 = c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2
    assert solid[r2 < 0.95].all()
    assert not solid[r2 > 1.4].any()
    # an open sphere (a cap cut away): vote still fills it, holes cannot
    keep = sphere.triangles_center[:, 2] < 0.8
    open_ball = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
    assert not open_ball.is_watertight
    r = voxelize(open_ball, grid=12)
    assert r.fill == "vote" and not r.watertight
    assert r.vox[6, 6, 5] and r.vox.sum() >= 0.9 * solid.sum()
    hollow = voxelize(open_ball, grid=12, fill="holes").vox
    assert not hollow[6, 6, 5]
    with pytest.raises(ValueError):
        voxelize(sphere, grid=12, fill="magic")
    with pytest.raises(ValueError):
        voxelize(sphere, grid=1)


def test_open_sheet_stays_one_cell_thick():
    sheet = trimesh.Trimesh([[0, 0, 0], [4, 0, 0], [4, 0, 3], [0, 0, 3]], [[0, 1, 2], [0, 2, 3]])  # a wall
    vox = voxelize(sheet, grid=8).vox
    assert _extent(vox, 1) == 1 and _extent(vox, 0) == 8 and _extent(vox, 2) == 6
    assert vox.sum() == 8 * 6


def test_textured_obj_loads_without_an_image_library(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl skin\nmap_Kd missing_texture.png\n")
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 2.0))
    obj = "mtllib m.mtl\nusemtl skin\n"
    obj += "".join(f"v {x} {y} {z}\n" for x, y, z in mesh.vertices)
    obj += "vt 0 0\nvt 1 0\nvt 1 1\n"
    obj += "".join(f"f {a + 1}/1 {b + 1}/2 {c + 1}/3\n" for a, b, c in mesh.faces)
    (tmp_path / "textured.obj").write_text(obj)
    code = (
        "import sys; sys.modules['PIL'] = None\n"  # no image library at all
        f"sys.path.insert(0, {os.path.abspath(ROOT)!r})\n"
        "from stablelego_jax.generate.mesh import voxelize\n"
        f"v = voxelize({str(tmp_path / 'textured.obj')!r}, grid=6).vox\n"
        "print(int(v.sum()))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) == 3 * 3 * 6
    for name in ("capsule.obj", "fuze.obj"):  # the shared textured OBJ files, where present
        if name in _shared_meshes():
            assert voxelize(os.path.join(MESHES, name), grid=8).vox.any()


def test_bad_files_give_clear_errors(tmp_path):
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"solid nothing\nthis is not an stl file\n")
    empty = tmp_path / "empty.obj"
    empty.write_text("# no geometry\n")
    txt = tmp_path / "notes.txt"
    txt.write_text("hello")
    for path in (junk, empty, txt, tmp_path / "missing.ply", tmp_path):
        with pytest.raises(MeshError) as ei:
            voxelize(str(path), grid=6)
        assert str(ei.value).startswith(str(path))
    flat = tmp_path / "point.obj"
    flat.write_text("v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n")
    with pytest.raises(MeshError):
        voxelize(str(flat), grid=6)


def test_mesh_to_bricks_covers_exactly(tmp_path):
    mesh = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=1.5)
    path = str(tmp_path / "ring.stl")
    mesh.export(path)
    vox = mesh_to_voxels(path, grid=10)
    assert not vox[5, 5, 2] and vox.any()  # the hole stays open
    for seed in (0, 1):
        lay = merge_voxels(vox, seed=seed, source=path)
        _check_bricks(vox, lay)
    a, b = merge_voxels(vox, seed=3), merge_voxels(vox, seed=3)
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.size, b.size)


@pytest.mark.skipif(not _shared_meshes(), reason="shared meshes not available")
def test_all_shared_meshes_to_bricks():
    """Every mesh of ../shared/meshes goes through mesh -> voxels -> bricks."""
    names = _shared_meshes()
    assert len(names) >= 30
    for name in names:
        path = os.path.join(MESHES, name)
        mesh = load_mesh(path)
        assert len(mesh.faces) > 0
        vox = mesh_to_voxels(path, grid=8)
        assert vox.shape == (8, 8, 8) and vox[:, :, 0].any(), name
        _check_bricks(vox, merge_voxels(vox, source=path))
