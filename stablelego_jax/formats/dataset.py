"""StableLego-style dataset objects: write and read them (making them from
meshes is :mod:`stablelego_jax.generate.objects`).

A dataset object is a folder (StableLego's layout, one folder per object):

* ``vox.npy``: (X, Y, Z) uint8 occupancy (1 = occupied), indexed ``[x, y, z]``
  in the coordinates of the bricks of ``task_graph.json``: the bricks cover
  exactly the occupied cells;
* ``task_graph.json``: the bricks, StableLego JSON (``{"1": {"x", "y", "z",
  "brick_id", "ori"}, ...}``, default library), keys in assembly order
  (bottom layer first);
* ``stability_score.npy``: (X, Y, Z) float64, each occupied cell the Eq. 10
  score of its brick (0 no stress ... >= 1 fails), 0 in empty cells;
* ``vis.png``: the heat map of those scores;
* ``meta.json`` (ours, optional): where the object came from (mesh, grid,
  up axis, fill, seed, brick set) and the analysis summary.

Folders are written atomically: everything goes into a temporary sibling
folder that is renamed into place at the end, so an interrupted or failed
write leaves nothing half-written. A shard (a folder of such objects) can be
fed straight to ``stablelego analyze shard/*`` or read back with
:func:`read_dataset`.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from typing import Iterator, Mapping, Sequence

import numpy as np

from ..files import current_umask
from ..layout import Layout, LayoutError, cells_of, layout_voxels
from .reader import load_layout
from .stablelego import layout_to_json_dict

__all__ = [
    "OBJECT_FILES",
    "META_FILE",
    "DatasetObject",
    "score_grid",
    "write_object",
    "read_object",
    "find_objects",
    "read_dataset",
]

#: The files of a StableLego dataset object.
OBJECT_FILES = ("vox.npy", "task_graph.json", "stability_score.npy", "vis.png")
META_FILE = "meta.json"


@dataclasses.dataclass
class DatasetObject:
    """One dataset object read back by :func:`read_object`.

    path: the folder; name: its base name; layout: the bricks; vox: (X, Y, Z)
    bool occupancy; scores: (X, Y, Z) float per-cell score grid (None if the
    folder has no stability_score.npy); meta: meta.json ({} if absent).
    """

    path: str
    name: str
    layout: Layout
    vox: np.ndarray
    scores: np.ndarray | None
    meta: dict

    def brick_scores(self) -> dict:
        """{key: score} of every brick, read from the score grid."""
        if self.scores is None:
            return {}
        x, y, z = (self.layout.pos[:, k] for k in range(3))
        return dict(zip(self.layout.keys, self.scores[x, y, z].astype(float).tolist()))

    @property
    def stable(self) -> bool | None:
        """Every brick scores < 1 (None without a score grid)."""
        if self.scores is None:
            return None
        return bool(max(self.brick_scores().values()) < 1.0)


# --------------------------------------------------------------------------
# grids


def score_grid(layout: Layout, scores, shape: Sequence[int] | None = None) -> np.ndarray:
    """(X, Y, Z) float64 grid: each brick's cells hold its score, empty cells 0.

    ``scores``: {key: score} or a sequence aligned with layout.keys; ``shape``
    at least the layout's extent (default exactly its extent).
    """
    if isinstance(scores, Mapping):
        s = np.array([float(scores[k]) for k in layout.keys])
    else:
        s = np.asarray(scores, np.float64).reshape(-1)
        if s.shape != (layout.n,):
            raise ValueError(f"scores must hold one value per brick ({layout.n}), got {s.shape}")
    shape = layout_voxels(layout, shape).shape
    grid = np.zeros(shape, np.float64)
    cells, owner = cells_of(layout.pos, layout.size)
    grid[cells[:, 0], cells[:, 1], cells[:, 2]] = s[owner]
    return grid


def _check_cover(layout: Layout, vox: np.ndarray, where: str) -> None:
    """LayoutError unless the bricks cover exactly the occupied cells of vox."""
    try:
        occ = layout_voxels(layout, vox.shape)
    except LayoutError as exc:
        raise LayoutError(where, exc.message) from None
    missing = int((vox & ~occ).sum())
    extra = int((occ & ~vox).sum())
    if missing or extra:
        raise LayoutError(where, f"bricks do not cover the voxels exactly: {missing} occupied cell(s) "
                                 f"without a brick, {extra} brick cell(s) on empty voxels")


# --------------------------------------------------------------------------
# write / read


def _write_dir_atomically(path: str, fill, overwrite: bool) -> None:
    """Create folder ``path`` by filling a temporary sibling and renaming it.

    ``fill(tmpdir)`` writes the files. With ``overwrite`` an existing
    ``path`` is replaced (moved aside first, removed after); without it an
    existing path raises FileExistsError before anything is written.
    """
    path = os.path.abspath(path)
    parent, base = os.path.dirname(path), os.path.basename(path)
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(f"{path}: already exists (use overwrite to replace it)")
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(dir=parent, prefix=f".tmp-{base}-")
    old = None
    try:
        fill(tmp)
        os.chmod(tmp, 0o777 & ~current_umask())
        if os.path.lexists(path):
            old = tempfile.mkdtemp(dir=parent, prefix=f".old-{base}-")
            os.rename(path, os.path.join(old, base))
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and not os.path.lexists(path) and os.path.lexists(os.path.join(old, base)):
            os.rename(os.path.join(old, base), path)  # put the previous object back
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def write_object(
    path: str,
    layout: Layout,
    scores,
    vox: np.ndarray | None = None,
    *,
    vis: bool = True,
    meta: Mapping | None = None,
    overwrite: bool = False,
    title: str | None = None,
) -> None:
    """Write one dataset object folder (atomically).

    Args:
      path: the object folder to create.
      layout: the bricks (written as task_graph.json, default library).
      scores: per-brick Eq. 10 scores ({key: score} or aligned with
        layout.keys); :func:`stablelego_jax.generate.objects.analyze_and_write`
        analyses a layout first.
      vox: (X, Y, Z) occupancy the bricks must cover exactly (LayoutError
        otherwise); default the layout's own occupancy.
      vis: write vis.png (the heat map).
      meta: extra facts for meta.json (the analysis summary is added).
      overwrite: replace an existing folder (else FileExistsError).
    """
    path = os.fspath(path)
    name = os.path.basename(os.path.normpath(path))
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(f"{path}: already exists (use overwrite to replace it)")
    if vox is None:
        vox = layout_voxels(layout)
    else:
        vox = np.asarray(vox).astype(bool)
        if vox.ndim != 3:
            raise ValueError(f"vox must be a 3-D (X, Y, Z) array, got shape {vox.shape}")
        _check_cover(layout, vox, layout.source)
    tg = layout_to_json_dict(layout)  # raises LayoutError before anything is written
    grid = score_grid(layout, scores, vox.shape)
    per_brick = dict(zip(layout.keys, [float(grid[tuple(p)]) for p in layout.pos.tolist()]))
    weakest = max(layout.keys, key=lambda k: per_brick[k])
    info = dict(meta or {})
    info.update({
        "n_voxels": int(vox.sum()),
        "n_bricks": layout.n,
        "grid": list(vox.shape),
        "stable": bool(max(per_brick.values()) < 1.0),
        "weakest": weakest,
        "max_score": per_brick[weakest],
        "n_failing": int(sum(v >= 1.0 for v in per_brick.values())),
    })

    def fill(tmp):
        np.save(os.path.join(tmp, "vox.npy"), vox.astype(np.uint8))
        np.save(os.path.join(tmp, "stability_score.npy"), grid)
        with open(os.path.join(tmp, "task_graph.json"), "w", encoding="utf-8") as fh:
            json.dump(tg, fh, indent=1)
            fh.write("\n")
        with open(os.path.join(tmp, META_FILE), "w", encoding="utf-8") as fh:
            json.dump(info, fh, indent=1)
            fh.write("\n")
        if vis:  # matplotlib is imported only here: scoring and reading never pay for it
            from ..render import render_heatmap

            render_heatmap(layout, [per_brick[k] for k in layout.keys], os.path.join(tmp, "vis.png"),
                           title=title if title is not None else name)

    _write_dir_atomically(path, fill, overwrite)


def read_object(path: str) -> DatasetObject:
    """Read a dataset object folder; checks that the bricks of task_graph.json
    cover exactly the occupied cells of vox.npy and that the score grid has
    its shape (LayoutError naming the folder otherwise). vox.npy and
    stability_score.npy are optional (vox then from the bricks)."""
    path = os.fspath(path)
    layout = load_layout(path)  # raises LayoutError for a folder without task_graph.json
    vox_p = os.path.join(path, "vox.npy")
    if os.path.isfile(vox_p):
        vox = _load_npy(vox_p)
        if vox.ndim != 3:
            raise LayoutError(vox_p, f"must be a 3-D (X, Y, Z) grid, got shape {vox.shape}")
        vox = vox != 0
        _check_cover(layout, vox, path)
    else:
        vox = layout_voxels(layout)
    scores = None
    sc_p = os.path.join(path, "stability_score.npy")
    if os.path.isfile(sc_p):
        scores = _load_npy(sc_p).astype(np.float64)
        if scores.shape != vox.shape:
            raise LayoutError(sc_p, f"shape {scores.shape} differs from the voxel grid {vox.shape}")
    meta = {}
    meta_p = os.path.join(path, META_FILE)
    if os.path.isfile(meta_p):
        try:
            with open(meta_p, encoding="utf-8") as fh:
                meta = json.load(fh)
        except (OSError, ValueError) as exc:
            raise LayoutError(meta_p, f"cannot read: {exc}") from None
    return DatasetObject(path=path, name=os.path.basename(os.path.normpath(path)), layout=layout,
                         vox=vox, scores=scores, meta=meta)


def _load_npy(p: str) -> np.ndarray:
    try:
        return np.load(p, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise LayoutError(p, f"cannot read: {exc}") from None


def find_objects(root: str) -> list[str]:
    """Dataset object folders (holding task_graph.json) at or below ``root``,
    sorted; StableLego's own ``category/id/models/`` nesting is found too.
    Temporary folders of unfinished writes are skipped."""
    out = []
    for d, subdirs, files in os.walk(root):
        subdirs[:] = sorted(s for s in subdirs if not s.startswith((".tmp-", ".old-")))
        if "task_graph.json" in files:
            out.append(d)
    return sorted(out)


def read_dataset(root: str) -> Iterator[DatasetObject]:
    """:func:`read_object` of every object of :func:`find_objects`."""
    for p in find_objects(root):
        yield read_object(p)
