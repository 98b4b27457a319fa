"""Meshes to voxel grids (the first step of a StableLego-style dataset).

:func:`voxelize` reads any mesh trimesh reads (STL, OBJ, PLY, OFF, GLB/glTF;
scenes are flattened with their transforms), turns it so that the chosen
axis points up, scales it uniformly so that its largest extent spans exactly
``grid`` cells, and returns a ``(grid, grid, grid)`` bool array indexed
``[x, y, z]``: z is the layer (up), the lowest occupied layer is z = 0 (the
object rests on the ground), and the object is centred in x and y.

Occupancy:

* **surface** cells are the cells that contain a point of the surface. The
  surface is sampled on a barycentric lattice finer than half a cell, so
  every triangle leaves a gap-free (26-connected) trail of cells.
* ``fill="solid"``: plus every cell whose centre lies inside the mesh, by
  the parity of the crossings of a vertical ray from it. Exact for closed
  (watertight) meshes, unreliable for open ones.
* ``fill="vote"``: plus every cell that the parity test along at least two
  of the three axes puts inside, plus every region the surface cells
  enclose completely (``scipy.ndimage.binary_fill_holes``); the parity
  voting of ``binvox``. This is the answer for open meshes (scans with holes,
  unmerged STL soups): a hole lets some rays through with the wrong parity,
  but rarely along two axes at once. A shell open on one side (a dome, a
  bowl) comes out as a solid under it; a flat open sheet stays one cell
  thick.
* ``fill="holes"``: plus only the regions the surface cells enclose
  completely: a shell whose openings are wider than a cell stays hollow.
* ``fill="surface"``: the shell only.
* ``fill="auto"`` (default): "solid" for watertight meshes, else "vote".

Materials and textures are never loaded (``skip_materials``), so textured OBJ
and glTF files need no image library. Errors are :class:`MeshError`, whose
message starts with the file name.
"""
from __future__ import annotations

import dataclasses
import io
import os

import numpy as np

from ..files import read_bytes
from ..layout import LayoutError

__all__ = [
    "MAX_GRID",
    "ply_strip_faces",
    "MESH_SUFFIXES",
    "UP_AXES",
    "FILL_MODES",
    "MeshError",
    "VoxelizedMesh",
    "load_mesh",
    "resolve_up",
    "voxelize",
    "mesh_to_voxels",
]

#: File suffixes :func:`load_mesh` accepts (lower case).
#: Largest ``grid`` (cells per axis): the voxelisation holds several grid^3
#: arrays (int64 ray counts among them), 134 MB each at 256.
MAX_GRID = 256
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
#: Values of ``up``: the mesh axis that points up. "auto": y for glTF/GLB
#: (Y-up by the glTF specification), z for everything else.
UP_AXES = ("auto", "z", "y", "x")
FILL_MODES = ("auto", "solid", "vote", "holes", "surface")

# Cell centres of the parity rays are moved by these fractions of a cell so
# that a ray never runs exactly through a mesh edge or vertex of a CAD part
# whose coordinates sit on round numbers (it would be counted twice or not
# at all).
_RAY_JITTER = (1.37e-5, 2.71e-5)


class MeshError(ValueError):
    """A mesh file that cannot be used; the message starts with the file."""

    def __init__(self, source: str, message: str):
        self.source = source
        self.message = message
        super().__init__(f"{source}: {message}")


@dataclasses.dataclass(frozen=True)
class VoxelizedMesh:
    """Result of :func:`voxelize`.

    vox: (grid, grid, grid) bool, ``[x, y, z]``; source: the file (or
    "<mesh>"); up: the mesh axis used as up; fill: the fill mode used
    ("solid", "vote", "holes" or "surface"); watertight: whether the mesh is closed;
    pitch: cell size in mesh units; n_faces: triangles read.
    """

    vox: np.ndarray
    source: str
    up: str
    fill: str
    watertight: bool
    pitch: float
    n_faces: int


def load_mesh(path: str):
    """Read a mesh file into one ``trimesh.Trimesh`` (scenes flattened; PLY
    triangle strips read as triangles).

    Raises MeshError naming ``path`` for a missing, unreadable or empty file.
    """
    import trimesh

    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(path, "no such file")
    if os.path.isdir(path):
        raise MeshError(path, "is a folder, not a mesh file")
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_SUFFIXES:
        raise MeshError(path, f"unsupported mesh format {ext or '(no suffix)'!r} "
                              f"(expected one of {', '.join(MESH_SUFFIXES)})")
    try:
        data = read_bytes(path, "mesh file")  # refuses named pipes and devices
    except LayoutError as exc:
        raise MeshError(path, exc.message) from None
    file_obj = None
    if ext == ".stl" and len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data):
        # binary STL: its 80-byte header is free text, often not UTF-8, which trimesh would
        # try to decode with an optional package; the header carries nothing we use
        file_obj = io.BytesIO(b" " * 80 + data[80:])
    elif ext in (".stl", ".obj", ".off"):
        try:
            data.decode("utf-8")
        except UnicodeDecodeError:
            if ext == ".stl":
                raise MeshError(path, "not an STL mesh: neither binary STL (its size does not match its "
                                      "triangle count) nor UTF-8 text") from None
            raise MeshError(path, f"not an {ext[1:].upper()} mesh: not UTF-8 text") from None
    try:
        if file_obj is not None:
            scene = trimesh.load_scene(file_obj, file_type="stl", skip_materials=True)
        else:
            scene = trimesh.load_scene(path, skip_materials=True)
        mesh = _flatten(scene)
    except ImportError:  # an optional package trimesh wanted for this file
        raise MeshError(path, f"cannot read mesh: not a valid {ext[1:].upper()} file") from None
    except Exception as exc:  # trimesh raises many kinds on junk input
        raise MeshError(path, f"cannot read mesh: not a valid {ext[1:].upper()} file ({_cut(str(exc)) or 'unreadable'})") from None
    if mesh is None:
        raise MeshError(path, "mesh has no triangles")
    v = np.asarray(mesh.vertices, np.float64)
    if not np.isfinite(v).all():
        raise MeshError(path, "mesh has non-finite vertex coordinates")
    return mesh


def _flatten(scene):
    """All triangles of a scene, placed by their node transforms, as one
    Trimesh without visuals (copying visuals could need an image library),
    duplicate vertices merged so that watertightness can be judged. None
    when the scene holds no triangles."""
    import trimesh

    vs, fs, off = [], [], 0
    for node in scene.graph.nodes_geometry:
        transform, gname = scene.graph[node]
        geom = scene.geometry[gname]
        faces = getattr(geom, "faces", None)
        if faces is None or len(faces) == 0:
            faces = ply_strip_faces(geom)  # a PLY of triangle strips loads as points
        if faces is None or len(faces) == 0:  # paths, point clouds
            continue
        v = trimesh.transformations.transform_points(np.asarray(geom.vertices, np.float64), transform)
        vs.append(v)
        fs.append(np.asarray(faces, np.int64) + off)
        off += len(v)
    if not fs:
        return None
    return trimesh.Trimesh(np.concatenate(vs), np.concatenate(fs), process=True)


def ply_strip_faces(geom):
    """Triangles of a PLY ``tristrips`` element (which trimesh reads as bare
    points): each strip split at -1 restarts, triangle k of a strip is
    (s[k], s[k+1], s[k+2]) with every other one flipped to keep the
    winding, degenerate ones dropped. None when ``geom`` has no strips."""
    el = (getattr(geom, "metadata", None) or {}).get("_ply_raw", {}).get("tristrips")
    if not el or not el.get("length") or not isinstance(el.get("data"), dict):
        return None
    n_vert = len(getattr(geom, "vertices", ()))
    tris = []
    for strips in el["data"].values():
        for strip in strips:
            idx = np.asarray(strip, np.int64).ravel()
            for part in np.split(idx, np.nonzero(idx < 0)[0]):
                part = part[part >= 0]
                for k in range(len(part) - 2):
                    a, b, c = part[k: k + 3]
                    if len({int(a), int(b), int(c)}) == 3:
                        tris.append((a, b, c) if k % 2 == 0 else (b, a, c))
        break  # one list property: the vertex indices
    if not tris:
        return None
    faces = np.asarray(tris, np.int64)
    if faces.max() >= n_vert:
        raise ValueError(f"triangle strip refers to vertex {int(faces.max())} of {n_vert}")
    return faces


def resolve_up(up: str, source: str = "") -> str:
    """The up axis for ``up`` ("auto" -> "y" for .glb/.gltf, else "z")."""
    if up not in UP_AXES:
        raise ValueError(f"up must be one of {UP_AXES}, got {up!r}")
    if up == "auto":
        return "y" if os.path.splitext(str(source))[1].lower() in (".glb", ".gltf") else "z"
    return up


def _turn_up(v: np.ndarray, up: str) -> np.ndarray:
    """Rotate (proper rotation, no mirror) so that axis ``up`` becomes +z."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    if up == "z":
        return v
    if up == "y":  # +90 deg about x: y -> z, z -> -y
        return np.stack([x, -z, y], axis=1)
    return np.stack([y, z, x], axis=1)  # up == "x": cyclic x -> z, y -> x, z -> y


def _surface_points(tri: np.ndarray, spacing: float) -> np.ndarray:
    """Points on every triangle of ``tri`` (t, 3, 3), no two neighbours
    further apart than ``spacing``: a barycentric lattice of n divisions per
    edge, n from the triangle's longest edge."""
    edges = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]], axis=1)
    longest = np.linalg.norm(edges, axis=2).max(axis=1)
    ndiv = np.maximum(np.ceil(longest / spacing).astype(np.int64), 1)
    out = [tri.reshape(-1, 3)]  # the vertices themselves
    for n in np.unique(ndiv[ndiv > 1]):
        sel = tri[ndiv == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        a = (i[keep] / n)[None, :, None]
        b = (j[keep] / n)[None, :, None]
        p = sel[:, None, 0] * (1 - a - b) + sel[:, None, 1] * a + sel[:, None, 2] * b
        out.append(p.reshape(-1, 3))
    return np.concatenate(out)


def _parity_inside(tri: np.ndarray, lo: np.ndarray, pitch: float, grid: int) -> np.ndarray:
    """(grid, grid, grid) bool: cell centres inside the closed surface ``tri``
    by the parity of crossings of a vertical ray upwards from each centre."""
    cx0 = lo[0] + (0.5 + _RAY_JITTER[0]) * pitch
    cy0 = lo[1] + (0.5 + _RAY_JITTER[1]) * pitch
    p0, p1, p2 = tri[:, 0], tri[:, 1], tri[:, 2]
    # 2-D area (twice, signed) of each triangle's projection; vertical ones never cross
    area = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p2[:, 0] - p0[:, 0]) * (p1[:, 1] - p0[:, 1])
    ok = np.abs(area) > 1e-18 * pitch * pitch
    p0, p1, p2, area = p0[ok], p1[ok], p2[ok], area[ok]
    # candidate columns: the column centres inside each triangle's xy box
    xs = np.stack([p0[:, 0], p1[:, 0], p2[:, 0]], 1)
    ys = np.stack([p0[:, 1], p1[:, 1], p2[:, 1]], 1)
    i0 = np.clip(np.ceil((xs.min(1) - cx0) / pitch), 0, grid).astype(np.int64)
    i1 = np.clip(np.floor((xs.max(1) - cx0) / pitch), -1, grid - 1).astype(np.int64)
    j0 = np.clip(np.ceil((ys.min(1) - cy0) / pitch), 0, grid).astype(np.int64)
    j1 = np.clip(np.floor((ys.max(1) - cy0) / pitch), -1, grid - 1).astype(np.int64)
    ni, nj = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
    diff = np.zeros((grid, grid, grid + 1), np.int64)
    cnt = ni * nj
    chunk = 1 << 21  # bound the memory of the pair arrays
    starts = np.cumsum(cnt) - cnt
    t_all = np.nonzero(cnt)[0]
    pos = 0
    while pos < len(t_all):
        # triangles whose pairs fit in this chunk (at least one)
        end = int(np.searchsorted(starts[t_all], starts[t_all[pos]] + chunk, side="left"))
        end = max(end, pos + 1)
        ts = t_all[pos:end]
        pos = end
        c = cnt[ts]
        t = np.repeat(ts, c)
        local = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        ci = i0[t] + local // nj[t]
        cj = j0[t] + local % nj[t]
        px, py = cx0 + ci * pitch, cy0 + cj * pitch
        # barycentric coordinates of the column centre in the projected triangle
        w1 = ((px - p0[t, 0]) * (p2[t, 1] - p0[t, 1]) - (p2[t, 0] - p0[t, 0]) * (py - p0[t, 1])) / area[t]
        w2 = ((p1[t, 0] - p0[t, 0]) * (py - p0[t, 1]) - (px - p0[t, 0]) * (p1[t, 1] - p0[t, 1])) / area[t]
        hit = (w1 >= 0) & (w2 >= 0) & (w1 + w2 <= 1)
        t, ci, cj, w1, w2 = t[hit], ci[hit], cj[hit], w1[hit], w2[hit]
        zh = p0[t, 2] + w1 * (p1[t, 2] - p0[t, 2]) + w2 * (p2[t, 2] - p0[t, 2])
        # the crossing at zh lies above the centres k with lo + (k + .5) pitch < zh
        k = np.clip(np.ceil((zh - lo[2]) / pitch - 0.5), 0, grid).astype(np.int64)
        np.add.at(diff, (ci, cj, np.zeros_like(k)), 1)
        np.add.at(diff, (ci, cj, k), -1)
    above = np.cumsum(diff, axis=2)[:, :, :grid]
    return (above % 2) == 1


def voxelize(source, grid: int = 20, up: str = "auto", fill: str = "auto") -> VoxelizedMesh:
    """Voxelise a mesh file (or a ``trimesh.Trimesh``) into a grid^3 bool array.

    Args:
      source: mesh file path, or a trimesh.Trimesh.
      grid: cells per axis (>= 2); the largest extent spans exactly ``grid``.
      up: the mesh axis that points up: "z" (CAD parts), "y" (scans, glTF),
        "x", or "auto" (y for .glb/.gltf files, else z).
      fill: "auto", "solid", "vote", "holes" or "surface" (see the module doc).

    Returns a :class:`VoxelizedMesh`; ``.vox`` is (grid, grid, grid) bool
    ``[x, y, z]`` resting on z = 0 and centred in x and y.
    """
    from scipy import ndimage  # imported here: building the CLI parser needs this module, not scipy

    grid = int(grid)
    if not 2 <= grid <= MAX_GRID:
        raise ValueError(f"grid must be between 2 and {MAX_GRID}, got {grid}")
    if fill not in FILL_MODES:
        raise ValueError(f"fill must be one of {FILL_MODES}, got {fill!r}")
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        mesh = load_mesh(name)
    else:
        name, mesh = "<mesh>", source
    up = resolve_up(up, name)
    v = _turn_up(np.asarray(mesh.vertices, np.float64), up)
    faces = np.asarray(mesh.faces, np.int64)
    if len(faces) == 0:
        raise MeshError(name, "mesh has no triangles")
    used = v[np.unique(faces)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    ext = float((hi - lo).max())
    if not ext > 0:
        raise MeshError(name, "mesh has zero size")
    pitch = ext / grid
    tri = v[faces]
    watertight = bool(getattr(mesh, "is_watertight", False))
    mode = ("solid" if watertight else "vote") if fill == "auto" else fill

    vox = np.zeros((grid, grid, grid), bool)
    pts = _surface_points(tri, 0.5 * pitch)
    # a point exactly on a cell boundary counts for the lower cell, so that a
    # box of k cells' extent covers k cells, not k + 1
    idx = np.clip(np.floor((pts - lo) / pitch - 1e-7).astype(np.int64), 0, grid - 1)
    vox[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    if mode == "solid":
        vox |= _parity_inside(tri, lo, pitch, grid)
    elif mode == "vote":
        votes = _parity_inside(tri, lo, pitch, grid).astype(np.int8)
        for perm in ((1, 2, 0), (2, 0, 1)):  # rays along x, then along y
            inv = np.argsort(perm)
            votes += _parity_inside(tri[:, :, perm], lo[list(perm)], pitch, grid).transpose(inv)
        vox = ndimage.binary_fill_holes(vox | (votes >= 2))
    elif mode == "holes":
        vox = ndimage.binary_fill_holes(vox)
    # centre in x and y (z already starts at 0: the lowest vertex is in layer 0)
    occ = np.nonzero(vox.any(axis=2))
    for axis in (0, 1):
        a0, a1 = int(occ[axis].min()), int(occ[axis].max()) + 1
        shift = (grid - (a1 - a0)) // 2 - a0
        if shift:
            vox = np.roll(vox, shift, axis=axis)  # the empty margin wraps: no cell is lost
    return VoxelizedMesh(vox=vox, source=name, up=up, fill=mode, watertight=watertight,
                         pitch=pitch, n_faces=int(len(faces)))


def mesh_to_voxels(source, grid: int = 20, up: str = "auto", fill: str = "auto") -> np.ndarray:
    """``voxelize(...).vox``: the (grid, grid, grid) bool occupancy."""
    return voxelize(source, grid=grid, up=up, fill=fill).vox


def _cut(s: str, limit: int = 160) -> str:
    s = " ".join(s.split())
    return s if len(s) <= limit else s[: limit - 3] + "..."
