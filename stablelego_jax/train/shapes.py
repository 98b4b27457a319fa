"""Target shapes for the generator: objects in a (G, G, G) grid, split by object.

Two procedural sources. *Small* (the default configs): objects of at most
~8 cells across and a few layers high (decoded layouts of ~5-40 bricks),
placed in the 20^3 grid, so that every soft problem of a training step
stays a few dozen placements, which a CPU factorises in a step. Most of
their kinds have overhangs (arms, caps, decks, table tops, leaning stairs),
where whether the layout stands depends on the bricks chosen: a cell with
nothing below it must be held by a brick that reaches a supported cell.
*Full*: shapes of the whole grid (:func:`full_shape`: blobs, stacked boxes,
balls, arches, stems with caps or arms; hundreds to thousands of cells),
for training at full scale with the layered factorisation (the config's
``layers``), a CPU step of 8 shapes costing minutes (BENCHMARKS.md).

Every shape is one *object* (a procedural seed or a mesh file); the split
into train and held-out is over objects, seeded. :func:`fresh_shapes` draws
more procedural objects of the same recipe from the seeds a dataset did not
use: a larger set for choices made on validation, with no retraining.
"""
from __future__ import annotations

import dataclasses
import glob
import os

import numpy as np

__all__ = ["Shape", "KINDS", "FULL_KINDS", "PROCEDURAL", "SPLITS", "procedural_shape", "full_shape", "mesh_shapes",
           "build_dataset", "procedural_seeds", "fresh_shapes", "SEED_RANGE", "FRESH_COUNT"]

KINDS = ("cantilever", "tee", "bridge", "table", "mushroom", "stairs", "box")
#: the kinds of :func:`full_shape`: :func:`~stablelego_jax.generate.voxels.random_voxel_shape`'s,
#: less "floating" (a part over an empty layer, which no layout of the shape's cells can hold)
FULL_KINDS = ("blob", "boxes", "spheres", "arch", "overhang")
#: the procedural sources of :func:`build_dataset`
PROCEDURAL = ("small", "full")
#: the splits of a config's shapes (:func:`stablelego_jax.train.train.split_shapes`); "fresh":
#: procedural objects none of the others holds (:func:`fresh_shapes`)
SPLITS = ("heldout", "val", "train", "fresh")
#: procedural objects are drawn from the seeds 0 .. SEED_RANGE - 1
SEED_RANGE = 10**5
#: the number of shapes of the split "fresh" unless told
FRESH_COUNT = 100


@dataclasses.dataclass(frozen=True)
class Shape:
    """One target object: ``name`` (unique), ``kind``, ``vox`` (G, G, G) bool."""

    name: str
    kind: str
    vox: np.ndarray


def _box(v, x0, y0, z0, x1, y1, z1):
    v[x0:x1, y0:y1, z0:z1] = True


def procedural_shape(seed: int, grid: int = 20, kind: str | None = None) -> Shape:
    """A small random object (extent <= 8 cells, <= 5 layers) at a random
    place on layer 0 of a (grid,)*3 box. ``kind`` in :data:`KINDS` (None: drawn)."""
    rng = np.random.default_rng(seed)
    kind = KINDS[int(rng.integers(len(KINDS)))] if kind is None else kind
    r = lambda lo, hi: int(rng.integers(lo, hi + 1))  # noqa: E731  inclusive
    v = np.zeros((10, 10, 6), bool)  # local box, moved into the grid below
    d = r(1, 2)  # depth along y
    if kind == "cantilever":  # column with an arm at the top (L shape)
        cw, h, arm, t = r(1, 2), r(1, 3), r(2, 6), r(1, 2)
        _box(v, 0, 0, 0, cw, d, h)
        _box(v, 0, 0, h, cw + arm, d, h + t)
    elif kind == "tee":  # column with a cap sticking out on both sides
        cw, h, a1, a2, t = r(1, 2), r(1, 3), r(1, 3), r(1, 3), r(1, 2)
        _box(v, a1, 0, 0, a1 + cw, d, h)
        _box(v, 0, 0, h, a1 + cw + a2, d, h + t)
    elif kind == "bridge":  # two pillars and a deck
        pw, gap, h, t = r(1, 2), r(2, 5), r(1, 3), r(1, 2)
        _box(v, 0, 0, 0, pw, d, h)
        _box(v, pw + gap, 0, 0, 2 * pw + gap, d, h)
        _box(v, 0, 0, h, 2 * pw + gap, d, h + t)
    elif kind == "table":  # four legs and a one-layer top
        w, dd, h = r(3, 6), r(3, 5), r(1, 3)
        for x in (0, w - 1):
            for y in (0, dd - 1):
                _box(v, x, y, 0, x + 1, y + 1, h)
        _box(v, 0, 0, h, w, dd, h + 1)
    elif kind == "mushroom":  # thin stem, square cap
        s, h, c = r(1, 2), r(1, 3), r(3, 5)
        off = (c - s) // 2
        _box(v, off, off, 0, off + s, off + s, h)
        _box(v, 0, 0, h, c, c, h + 1)
    elif kind == "stairs":  # leaning stairs: each layer shifted by one or two cells
        L, sh, n = r(2, 4), r(1, 2), r(2, 4)
        for z in range(n):
            _box(v, z * sh, 0, z, z * sh + L, d, z + 1)
    elif kind == "box":  # no overhang
        _box(v, 0, 0, 0, r(1, 5), r(1, 3), r(1, 3))
    else:
        raise ValueError(f"unknown shape kind {kind!r}; expected one of {KINDS}")
    if rng.random() < 0.5:  # swap x and y
        v = v.transpose(1, 0, 2)
    out = np.zeros((grid,) * 3, bool)
    xs, ys, zs = np.nonzero(v)
    ex, ey = xs.max() + 1, ys.max() + 1
    ox, oy = r(0, grid - ex), r(0, grid - ey)
    out[xs + ox, ys + oy, zs] = True
    return Shape(name=f"proc{seed:05d}_{kind}", kind=kind, vox=out)


def full_shape(seed: int, grid: int = 20, kind: str | None = None) -> Shape:
    """A random object of the whole (grid,)*3 box (resting on layer 0, only
    parts that touch it): :func:`~stablelego_jax.generate.voxels.random_voxel_shape`
    of ``kind`` in :data:`FULL_KINDS` (None: drawn). May be empty (a blob
    whose noise kept nothing); :func:`build_dataset` skips those."""
    from ..generate.voxels import random_voxel_shape

    rng = np.random.default_rng(seed)
    kind = FULL_KINDS[int(rng.integers(len(FULL_KINDS)))] if kind is None else kind
    if kind not in FULL_KINDS:
        raise ValueError(f"unknown full-scale kind {kind!r} (known: {', '.join(FULL_KINDS)})")
    return Shape(name=f"full{seed:05d}_{kind}", kind=kind, vox=random_voxel_shape(seed, grid, kind))


def mesh_shapes(folder: str, grid: int = 20, extent: int = 6, max_cells: int = 90) -> tuple[list, list]:
    """The meshes of ``folder`` voxelized at ``extent`` cells and set on
    layer 0 of a (grid,)*3 box; meshes that fail to load, are empty or have
    more than ``max_cells`` cells are skipped. Returns (shapes, skipped
    [(file, reason)])."""
    from ..generate.mesh import mesh_to_voxels
    from ..generate.voxels import ground

    out, skipped = [], []
    files = sorted(f for f in glob.glob(os.path.join(folder, "*"))
                   if os.path.splitext(f)[1].lower() in (".stl", ".obj", ".ply", ".off", ".glb"))
    for f in files:
        try:
            v = ground(mesh_to_voxels(f, grid=extent), keep="grounded")
        except Exception as exc:  # noqa: BLE001 - any unreadable mesh is skipped and reported
            skipped.append((os.path.basename(f), str(exc)[:80]))
            continue
        n = int(v.sum())
        if n == 0 or n > max_cells:
            skipped.append((os.path.basename(f), f"{n} cells"))
            continue
        big = np.zeros((grid,) * 3, bool)
        big[: v.shape[0], : v.shape[1], : v.shape[2]] = v
        out.append(Shape(name="mesh_" + os.path.splitext(os.path.basename(f))[0], kind="mesh", vox=big))
    return out, skipped


def build_dataset(n_procedural: int, mesh_dir: str | None, seed: int, heldout_frac: float = 0.2,
                  grid: int = 20, mesh_extent: int = 6, mesh_max_cells: int = 90, procedural: str = "small"):
    """(train, heldout, skipped): ``n_procedural`` procedural objects (seeds
    derived from ``seed``; ``procedural``: "small", :func:`procedural_shape`,
    or "full", :func:`full_shape`, whose empty draws are skipped) plus the
    meshes of ``mesh_dir``, split by object (a seeded permutation; a
    fraction ``heldout_frac`` of each source held out)."""
    make = _maker(procedural)
    rng = np.random.default_rng(seed)
    seeds = _draw_seeds(rng, n_procedural)
    procs = [sh for sh in (make(int(s), grid) for s in seeds) if sh.vox.any()]
    meshes, skipped = mesh_shapes(mesh_dir, grid, mesh_extent, mesh_max_cells) if mesh_dir else ([], [])
    train, held = [], []
    for group in (procs, meshes):
        perm = rng.permutation(len(group))
        k = int(round(heldout_frac * len(group)))
        held += [group[i] for i in sorted(perm[:k])]
        train += [group[i] for i in sorted(perm[k:])]
    return train, held, skipped


def _maker(procedural: str):
    """The shape function of a procedural source (ValueError if unknown)."""
    if procedural not in PROCEDURAL:
        raise ValueError(f"unknown procedural source {procedural!r} (known: {', '.join(PROCEDURAL)})")
    return procedural_shape if procedural == "small" else full_shape


def _draw_seeds(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.choice(SEED_RANGE, size=n, replace=False)


def procedural_seeds(n_procedural: int, seed: int) -> np.ndarray:
    """(n_procedural,) int: the procedural objects' seeds of
    :func:`build_dataset` (the first draw of its generator)."""
    return _draw_seeds(np.random.default_rng(seed), n_procedural)


def fresh_shapes(n: int, n_procedural: int, seed: int, grid: int = 20, procedural: str = "small") -> list:
    """``n`` procedural objects of the recipe of :func:`build_dataset` (same
    ``procedural``, ``grid``) whose seeds are none of its ``n_procedural``
    objects' (so none is in its train, validation or held-out shapes):
    seeds drawn in a fixed order (seeded by ``seed``), empty draws skipped;
    fewer when the seeds run out. In the order of the draw, so the first k
    of n are the k of a smaller call."""
    make = _maker(procedural)
    if n < 0:
        raise ValueError(f"the number of fresh shapes must be >= 0, got {n}")
    used = set(procedural_seeds(n_procedural, seed).tolist())
    out = []
    for s in np.random.default_rng([seed, 3]).permutation(SEED_RANGE).tolist():
        if len(out) == n:
            break
        if s not in used:
            sh = make(int(s), grid)
            if sh.vox.any():
                out.append(sh)
    return out
